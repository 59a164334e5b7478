"""The verification benchmarks of `make verify` (experiments/verify.py), one module each: its
reference with the reference's source, its computation (which the tests in tests/ import), its run
under refinement (`run() -> dict`, with the failures against its tolerance) and its section of the
report (`section(r) -> list of lines`).

- cantilever: a slender clamped strip's first four bending frequencies against Euler-Bernoulli and
  Timoshenko;
- cooks_membrane: Cook's membrane, nearly incompressible Neo-Hookean, against 6.93 mm;
- st_venant_kirchhoff: a homogeneous uniaxial plane-strain stress against its closed form;
- turek_hron: Turek and Hron's CSM1 and CSM2, the elastic flag under gravity, against the published
  displacements of its tip;
- mooney_rivlin_block: a nearly incompressible Mooney-Rivlin block in plane-strain compression
  against the incompressible closed form;
- treloar: each law fitted to Treloar's uniaxial data and its prediction of his equibiaxial and pure
  shear data.
"""

BENCHMARKS = (
    "cantilever",
    "cooks_membrane",
    "st_venant_kirchhoff",
    "turek_hron",
    "mooney_rivlin_block",
    "treloar",
)
