"""Periodic scenes and their macroscopic loads: a SceneConfig held by periodicity instead of
supports (nma.periodic), and nma.simulate's `load` group, the path a periodic scene follows."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Optional

from ..settings import Schema, bounded, choice, option
from .scene import SceneConfig

LOAD_KINDS = ("uniaxial_x", "uniaxial_y", "biaxial", "shear")


@dataclass
class PeriodicSceneConfig(SceneConfig):
    """A scene read as a periodic cell: SceneConfig's fields and checks, but held by periodicity
    instead of supports (`periodic` is always true).  `pinned` is at most one point, where the
    fluctuation w is held at zero (rigid translation removed; none: the control point nearest the
    grid's bottom-left corner); `groups` and `supports` must be empty (F_bar is the load).
    `contact` is the pores' own: every pore lies inside its cell, so its walls meet no wall across
    a periodic seam."""

    periodic: bool = True
    porosity: Optional[float] = bounded(
        None,
        "(0, 0.75)",
        doc="the pores as circles of this share of the box's area (nma.periodic.circular_holes; "
        "needs round_pore_corners); null: the design radii_init gives",
    )

    def __post_init__(self):
        self.periodic = True
        super().__post_init__()

    def check(self):
        super().check()
        if self.porosity is not None and not self.round_pore_corners:
            self.fail(
                "porosity",
                "makes the pores circles, which needs round_pore_corners: true",
                self.porosity,
            )


@dataclass
class LoadConfig(Schema):
    """nma.simulate's macroscopic load of a periodic scene: F_bar from I to its target in `steps`
    equal steps, its prescribed components linearly, its free ones solved with zero average
    stress (nma.periodic.load)."""

    prefix: ClassVar[str] = "load"
    kind: str = choice(
        "uniaxial_y",
        LOAD_KINDS,
        doc="uniaxial_x / uniaxial_y: F_aa prescribed, the lateral stretch free (uniaxial nominal "
        "stress), the shear components 0; biaxial: both normal stretches prescribed; shear: "
        "F12 = strain, the normal stretches held at 1",
    )
    strain: float = bounded(
        -0.2,
        "(-0.9, 10)",
        doc="the path's end: the axial nominal strain F_aa - 1 (biaxial: along x; shear: gamma)",
    )
    lateral_strain: float = bounded(
        0.0, "(-0.9, 10)", doc="biaxial: the nominal strain along y at the path's end"
    )
    steps: int = bounded(20, "[1, 10000]", doc="reported states along the path, equally spaced")
    escape: bool = option(
        True,
        "past a bifurcation, leave the saddle along its mode, downhill in energy, onto the buckled "
        "branch; false: stay on the symmetric path (unstable past the bifurcation)",
    )

    def check(self):
        if self.kind != "biaxial" and self.lateral_strain != 0.0:
            self.fail(
                "lateral_strain",
                f"is biaxial's second strain, which load.kind={self.kind} does not use: choose "
                "load=biaxial, or leave it out",
                self.lateral_strain,
            )
