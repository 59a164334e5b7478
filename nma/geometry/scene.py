"""Declarative scenes: what a structure is, as data.

A `SceneSpec` is a grid of cell tokens plus boundary groups, pinned points, supports, tracked
points, the movable corners and an optional central pore, built from a checked `SceneConfig`
(nma/schema/scene.py: `SceneConfig.spec()`, or `nma.schema.scene_from_config` of a mapping), so a
bad scene fails before any work starts.  A `PatchSceneSpec` is a general multi-patch
geometry given by its design nets (Cook's membrane is one patch).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

POROUS, SOLID, EMPTY = "P", "S", "."


@dataclass(frozen=True)
class Group:
    """Control points on a straight boundary segment moved as a rigid block: u = d[actuation] *
    direction."""

    name: str
    segment: tuple[tuple[float, float], tuple[float, float]]
    actuation: int
    direction: tuple[float, float]


@dataclass(frozen=True)
class Support:
    """Control points on a straight boundary segment held still in the given displacement components
    ((0, 1): clamped; one of them: sliding along the segment)."""

    segment: tuple[tuple[float, float], tuple[float, float]]
    components: tuple[int, ...]


@dataclass(frozen=True)
class Traction:
    """A dead load per unit reference length on a straight boundary segment (used by Cook's
    membrane)."""

    segment: tuple[tuple[float, float], tuple[float, float]]
    traction: tuple[float, float]


@dataclass(frozen=True)
class SceneSpec:
    name: str
    x_breaks: tuple[float, ...]
    y_breaks: tuple[float, ...]
    cells: tuple[str, ...]  # rows from bottom (y = y_breaks[0]) to top, one token per column
    groups: tuple[Group, ...]
    pinned: tuple[tuple[float, float], ...]
    tracked: Mapping[str, tuple[float, float]]
    radii_init: float
    radii_bounds: tuple[float, float]
    corner_box: float  # half-width of the box corners may move in (0: corners fixed)
    locked_nodes: tuple[tuple[int, int], ...]
    central_pore: tuple[tuple[int, int], ...]  # ring of grid nodes (i, j), counter-clockwise
    central_radii_init: float
    colours: bool
    supports: tuple[Support, ...] = ()
    # walls meet tangent at pore corners (nma.geometry.design.pore_nets)
    round_pore_corners: bool = False
    # built by scene_from_config from a SceneConfig, whose schema holds the defaults and checks

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.x_breaks) - 1, len(self.y_breaks) - 1

    @property
    def n_actuations(self) -> int:
        return 1 + max((g.actuation for g in self.groups), default=-1)

    def token(self, i: int, j: int) -> str:
        return self.cells[j][i]


@dataclass(frozen=True)
class PatchSceneSpec:
    """A general multi-patch geometry: design nets (P, 5, 5, 2), clamped segments and tractions."""

    name: str
    nets: np.ndarray
    clamped: tuple[tuple[tuple[float, float], tuple[float, float]], ...] = ()
    groups: tuple[Group, ...] = ()
    tractions: tuple[Traction, ...] = ()
    tracked: Mapping[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def n_actuations(self) -> int:
        return 1 + max((g.actuation for g in self.groups), default=-1)


def bilinear_net(corners: Sequence[Sequence[float]], n: int = 5) -> np.ndarray:
    """(n, n, 2) control net of the bilinear map of a quadrilateral (corners counter-clockwise from
    (0,0))."""
    c = np.asarray(corners, float)
    s = np.linspace(0.0, 1.0, n)
    S, T = np.meshgrid(s, s, indexing="ij")
    return (
        ((1 - S) * (1 - T))[..., None] * c[0]
        + (S * (1 - T))[..., None] * c[1]
        + (S * T)[..., None] * c[2]
        + ((1 - S) * T)[..., None] * c[3]
    )


def cooks_membrane() -> PatchSceneSpec:
    """Cook's membrane: plane-strain trapezoid, left edge clamped, 100 N shear on the right edge."""
    nets = bilinear_net([(0.0, 0.0), (48.0, 44.0), (48.0, 60.0), (0.0, 44.0)])[None]
    return PatchSceneSpec(
        name="cooks_membrane",
        nets=nets,
        clamped=(((0.0, 0.0), (0.0, 44.0)),),
        tractions=(Traction(((48.0, 44.0), (48.0, 60.0)), (0.0, 100.0 / 16.0)),),
        tracked={"tip": (48.0, 60.0)},
    )
