"""Macroscopic loads of a periodic cell: which components of F_bar are prescribed (and where their
path ends), which are free unknowns solved with the cell (their conjugate average first
Piola-Kirchhoff stress then vanishes: the energy is minimised over them).

F_bar's components are ordered F11, F12, F21, F22 (nma.periodic.cell.COMPONENTS).  The path runs
from F_bar = I at t = 0 to the prescribed values at t = 1, linearly in t.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from .cell import COMPONENTS

_INDEX = {name: k for k, name in enumerate(COMPONENTS)}
IDENTITY = np.array([1.0, 0.0, 0.0, 1.0])


@dataclass(frozen=True)
class MacroLoad:
    """Prescribed components of F_bar with their final values, and the free ones.

    Attributes:
        name: How reports call it (uniaxial_x, biaxial, shear...).
        target: (4,) F_bar's final value in its prescribed components (the free ones' entries are
            their starting values, those of I).
        free: The free components' indices (0..3, COMPONENTS order).
        axial: The component whose nominal strain (F_bar - I there) is the axial one (Poisson's
            ratio's denominator; shear's: gamma).
        lateral: The free component whose strain is the lateral one, or None.
    """

    name: str
    target: np.ndarray
    free: tuple[int, ...]
    axial: int
    lateral: int | None = None

    def __post_init__(self):
        if len(set(self.free)) != len(self.free) or not set(self.free) <= set(range(4)):
            raise ConfigError(f"load {self.name}: free components must be distinct in 0..3")
        if {1, 2} <= set(self.free):
            raise ConfigError(
                f"load {self.name}: F12 and F21 cannot both be free (a rigid rotation of the cell "
                "would be left undetermined); prescribe one of them"
            )
        t = np.asarray(self.target, float)
        if t.shape != (4,) or not np.all(np.isfinite(t)):
            raise ConfigError(f"load {self.name}: target must be 4 finite numbers, got {t}")
        if t[0] * t[3] - t[1] * t[2] <= 0 and not self.free:
            raise ConfigError(f"load {self.name}: the target F_bar must have det > 0, got {t}")

    @property
    def prescribed(self) -> tuple[int, ...]:
        return tuple(k for k in range(4) if k not in self.free)

    def at(self, t: float) -> np.ndarray:
        """F_bar's prescribed values (4,) at path parameter t in [0, 1] (free entries: I's)."""
        return IDENTITY + t * (np.asarray(self.target, float) - IDENTITY)


def _strain(where: str, value: float, lo: float = -0.9, hi: float = 10.0) -> float:
    """A path's end: finite, in (lo, hi) (the config's range, LoadConfig), and not 0 where it is
    the load's axis (a path of no strain has no Poisson's ratio)."""
    value = float(value)
    if not (np.isfinite(value) and lo < value < hi):
        raise ConfigError(f"{where} must be a nominal strain in ({lo}, {hi}), got {value}")
    return value


def _axial(where: str, value: float) -> float:
    value = _strain(where, value)
    if value == 0.0:
        raise ConfigError(f"{where} must not be 0: the path would not move")
    return value


def uniaxial(axis: str, strain: float) -> MacroLoad:
    """Uniaxial nominal stress along `axis` ('x' or 'y'): F_aa = 1 + strain prescribed, the lateral
    stretch free (zero average lateral stress), the shear components held at 0 (no rotation)."""
    if axis not in ("x", "y"):
        raise ConfigError(f"load.axis must be one of ['x', 'y'], got {axis!r}")
    e = _axial("load.strain", strain)
    a, b = (0, 3) if axis == "x" else (3, 0)
    target = IDENTITY.copy()
    target[a] = 1.0 + e
    return MacroLoad(f"uniaxial_{axis}", target, (b,), a, b)


def biaxial(strain_x: float, strain_y: float) -> MacroLoad:
    """Both normal stretches prescribed, F = diag(1 + strain_x, 1 + strain_y)."""
    ex, ey = _strain("load.strain", strain_x), _strain("load.lateral_strain", strain_y)
    if ex == ey == 0.0:
        raise ConfigError("load.strain and load.lateral_strain must not both be 0: no path")
    return MacroLoad("biaxial", np.array([1.0 + ex, 0.0, 0.0, 1.0 + ey]), (), 0, None)


def shear(gamma: float, free_normal: bool = False) -> MacroLoad:
    """Simple shear F12 = gamma (F21 = 0); the normal stretches held at 1, or with `free_normal`
    free (zero average normal stresses)."""
    g = _axial("load.strain", gamma)
    return MacroLoad("shear", np.array([1.0, g, 0.0, 1.0]), (0, 3) if free_normal else (), 1, None)


LOADS = {"uniaxial_x": "x", "uniaxial_y": "y", "biaxial": None, "shear": None}


def load_of(kind: str, strain: float, lateral_strain: float = 0.0) -> MacroLoad:
    """A load by name (LOADS): uniaxial_x/uniaxial_y to nominal strain `strain`, biaxial to
    (strain, lateral_strain), shear to gamma = strain."""
    if kind not in LOADS:
        raise ConfigError(f"load must be one of {list(LOADS)}, got {kind!r}")
    if kind.startswith("uniaxial"):
        return uniaxial(LOADS[kind], strain)
    if kind == "biaxial":
        return biaxial(strain, lateral_strain)
    return shear(strain)
