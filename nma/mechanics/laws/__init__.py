"""The hyperelastic laws, one module each: Neo-Hookean, Mooney-Rivlin, Yeoh, Ogden, Gent,
Arruda-Boyce and St Venant-Kirchhoff.

Every law has the same compressible form, the paper's Neo-Hookean generalised:

    W(F) = psi(F) - c0 log J + k/2 (log J)^2

psi is the law's strain energy of the 3D deformation, of the invariants I1, I2 of C = F^T F or of
the principal stretches, taken in plane strain (F_33 = 1: nma.mechanics.laws.base); c0 =
dpsi/dlambda at rest makes the reference stress-free, and k is, by material.volumetric, the bulk
modulus of the material's Poisson's ratio nu at its initial shear modulus mu0, kappa = 2 mu0 (1 +
nu) / (3 (1 - 2 nu)) as Neo-Hookean's E / (3 (1 - 2 nu)) (`bulk`, the paper's form), or the Lame
constant that makes nu the 3D Poisson's ratio of the law's compressible form (`lame`:
Law.lame_modulus).  With c0 = mu0 = mu and psi = mu/2 (I1 - 3)
the form is Neo-Hookean's, so a Mooney-Rivlin with C01 = 0, a Yeoh with C20 = C30 = 0 and a
one-term Ogden with alpha = 2 are it.  St Venant-Kirchhoff's psi is its whole energy
(`Law.volume_term` False: no log J terms).  The volumetric term is the part the `mixed` formulation
evaluates at each element's mean dilatation.

A material is one array: the law's parameters in `Law.names` order, then nu (Neo-Hookean's
[E, nu]); the laws read them by name.  Stresses are in the unit of the parameters.

A law is one module of this package (its class declares its parameters and registers itself:
nma.mechanics.laws.base), or of an installed package's `nma.laws` entry point.  Every module here
but `base` and `homogeneous` is a law, imported at the first look-up (no JAX: the config schema
reads the declarations); `homogeneous` (JAX) characterises a law in the homogeneous tests.
"""

from __future__ import annotations

import pkgutil
from importlib import import_module

from .base import (
    LAWS,
    POISSON,
    InvariantLaw,
    Law,
    Parameter,
    StretchLaw,
    principal_power_sum,
    register,
)

PLUGIN_GROUP = "nma.laws"  # entry points of installed packages whose modules register laws
# entry point -> why it did not import (its laws are unavailable)
BROKEN_PLUGINS: dict[str, str] = {}
_HOMOGENEOUS = (
    "mode_stretches",
    "nominal_stress",
    "drucker_unstable",
    "checked_parameters",
    "check_stable",
    "principal_stretch_range",
)
_found = False

__all__ = [
    "LAWS",
    "POISSON",
    "InvariantLaw",
    "Law",
    "Parameter",
    "StretchLaw",
    "law_names",
    "law_of",
    "principal_power_sum",
    "register",
    *_HOMOGENEOUS,
]


def _discover() -> None:
    """Import every law module of this package, then every `nma.laws` entry point's, once; an entry
    point that does not import is named in a warning and in BROKEN_PLUGINS."""
    global _found
    if _found:
        return
    _found = True
    for module in pkgutil.iter_modules(__path__):
        if module.name not in ("base", "homogeneous"):
            import_module(f"{__name__}.{module.name}")
    from ...registry import load_entry_points

    load_entry_points(PLUGIN_GROUP, "laws", BROKEN_PLUGINS)


def law_names() -> tuple[str, ...]:
    """Every law's name, the package's in the order of their modules' names, then the plugins'."""
    _discover()
    return tuple(LAWS.names())


def builtin(name: str) -> bool:
    """Whether law `name` is one of this package's modules (an installed package's is not)."""
    _discover()
    return LAWS.get(name).__module__.startswith(f"{__name__}.")


def law_of(name: str, parameters=()) -> Law:
    """The law `name` taking the parameters `parameters` names (Ogden's terms: as many as mu's;
    none: the law's defaults); ConfigError naming the laws there are for another name."""
    _discover()
    return LAWS.get(name).of(tuple(parameters))


def __getattr__(name: str):
    if name in _HOMOGENEOUS:  # JAX: imported where asked for
        return getattr(import_module(f"{__name__}.homogeneous"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
