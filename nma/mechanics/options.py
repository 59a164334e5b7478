"""The mechanical model's own options: plain values, each declared once with its range and meaning
(the config schema, nma.schema, takes them from here)."""

from __future__ import annotations

from dataclasses import dataclass

from ..settings import bounded
from .laws import POISSON, law_names

# how the strain energy treats volume change (nma.mechanics.energy): at every Gauss point, or
# through each element's mean dilatation (locking-free as nu -> 0.5)
FORMULATIONS = ("displacement", "mixed")
# the coefficient of the volumetric term 1/2 (log J)^2 of a law that has one
# (Material.volume_modulus): `lame`, the Lame constant lambda that makes nu the Poisson's ratio of
# the law's 3D compressible form, whose plane strain then has the plane modulus E / (1 - nu^2) and
# the in-plane Poisson's ratio nu / (1 - nu) at small strain; `bulk`, the 3D bulk modulus
# kappa = E / (3 (1 - 2 nu)) (the paper's form: 1.064 E / (1 - nu^2) and 0.52 at nu = 0.3)
VOLUMETRIC = ("lame", "bulk")
# mass per unit area: absolute, and against the material's initial shear modulus mu0 (mu0 / density,
# a squared wave speed, sets the natural frequencies and the time step); outside these the mass
# matrix and the modal solve (ARPACK, shift-invert) leave float64's range
DENSITY_RANGE = "[1e-30, 1e30]"
WAVE_SPEED_SQUARED_RANGE = "[1e-40, 1e40]"
# the hyperelastic laws, by the name a config gives: each declared in its module of
# nma/mechanics/laws/ with its parameters' defaults, ranges and meanings
LAW_NAMES = law_names()
# every law's Poisson's ratio, by name (each law's own parameters: law_of(name).parameters)
MATERIAL_RANGES = {"nu": POISSON.range}
# the homogeneous incompressible tests a material is characterised by
# (nma.mechanics.laws.mode_stretches)
MODES = ("uniaxial", "biaxial", "planar")
# the physical units a material's stresses may be stated in, with their value in MPa (N / mm^2)
STRESS_UNITS = ("Pa", "kPa", "MPa", "GPa")
MPA_PER_UNIT = {"Pa": 1e-6, "kPa": 1e-3, "MPa": 1.0, "GPa": 1e3}
# nu from which the volume constraint, not the load path, sets Newton's pace: a nearly
# incompressible material (bulk over shear modulus at least 100), which the auto settings model
# locking-free
NEARLY_INCOMPRESSIBLE = 0.495


@dataclass(frozen=True)
class ContactSettings:
    """The pores' self-contact (nma.mechanics.contact), each setting declared once here with its
    range and meaning (the config's `contact` group, nma.schema.ContactConfig, takes them all)."""

    # d_hat as a fraction of the median pore's extent (its bounding box's larger side) in the
    # scene's canonical design (radii mid-range): a constant while training moves the radii
    distance: float = bounded(
        0.02,
        "(0, 0.25]",
        doc="gap at which the barrier starts, as a fraction of the median pore's width",
    )
    # kappa / (mu d_hat): two walls at a gap d << d_hat press with about 4 stiffness mu d_hat / d
    stiffness: float = bounded(
        1.0, "(0, 1000]", doc="barrier stiffness / (shear modulus x distance)"
    )
    per_span: int = bounded(3, "[1, 16]", doc="chords per knot span of a pore wall")
