"""Declarative scenes: what a structure is, as data.

A `SceneSpec` is a grid of cell tokens plus boundary groups, pinned and tracked points, the
movable corners and an optional central pore.  A `PatchSceneSpec` is a general multi-patch
geometry given by its design nets (Cook's membrane is one patch).  Both are validated on
construction, so a bad scene fails before any work starts.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

POROUS, SOLID, EMPTY = "P", "S", "."


@dataclass(frozen=True)
class Group:
    """Control points on a straight boundary segment moved as a rigid block: u = d[actuation] * direction."""
    name: str
    segment: tuple[tuple[float, float], tuple[float, float]]
    actuation: int
    direction: tuple[float, float]


@dataclass(frozen=True)
class Traction:
    """A dead load per unit reference length on a straight boundary segment (used by Cook's membrane)."""
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
    radii_init: float = 0.5
    radii_bounds: tuple[float, float] = (0.1, 0.9)
    corner_box: float = 0.0  # half-width of the box corners may move in (0: corners fixed)
    locked_nodes: tuple[tuple[int, int], ...] = ()
    central_pore: tuple[tuple[int, int], ...] = ()  # ring of grid nodes (i, j), counter-clockwise
    central_radii_init: float = 0.8
    colours: bool = False

    def __post_init__(self):
        nx, ny = len(self.x_breaks) - 1, len(self.y_breaks) - 1
        if nx < 1 or ny < 1 or np.any(np.diff(self.x_breaks) <= 0) or np.any(np.diff(self.y_breaks) <= 0):
            raise ValueError(f"scene {self.name}: x_breaks and y_breaks must be increasing with >= 2 entries")
        if len(self.cells) != ny or any(len(r) != nx for r in self.cells):
            raise ValueError(f"scene {self.name}: cells must be {ny} rows of {nx} tokens")
        bad = {c for r in self.cells for c in r} - {POROUS, SOLID, EMPTY}
        if bad:
            raise ValueError(f"scene {self.name}: unknown cell tokens {sorted(bad)}; allowed 'P', 'S', '.'")
        lo, hi = self.radii_bounds
        if not 0.0 <= lo < hi <= 1.0:
            raise ValueError(f"scene.radii_bounds must satisfy 0 <= lo < hi <= 1, got {self.radii_bounds}")
        if not lo <= self.radii_init <= hi:
            raise ValueError(f"scene.radii_init must lie in radii_bounds [{lo}, {hi}], got {self.radii_init}")
        if self.central_pore and not lo <= self.central_radii_init <= hi:
            raise ValueError(f"scene.central_radii_init must lie in [{lo}, {hi}], got {self.central_radii_init}")
        if not 0.0 <= self.corner_box < 0.5 * min(np.diff(self.x_breaks).min(), np.diff(self.y_breaks).min()):
            raise ValueError(f"scene.corner_box must be in [0, half the smallest cell), got {self.corner_box}")
        n_act = self.n_actuations
        for g in self.groups:
            if not 0 <= g.actuation < n_act:
                raise ValueError(f"scene {self.name}: group {g.name} actuation index {g.actuation} out of range")

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


def _pair(v) -> tuple[float, float]:
    v = tuple(float(a) for a in v)
    if len(v) != 2:
        raise ValueError(f"expected a point [x, y], got {v}")
    return v


def _breaks(cfg: Mapping[str, Any], axis: str) -> tuple[float, ...]:
    if cfg.get(f"{axis}_breaks") is not None:
        return tuple(float(b) for b in cfg[f"{axis}_breaks"])
    n = len(cfg["cells"][0]) if axis == "x" else len(cfg["cells"])
    return tuple(float(cfg.get("cell_size", 5.0)) * k for k in range(n + 1))


def scene_from_config(cfg: Mapping[str, Any]) -> SceneSpec:
    """Build a SceneSpec from a (Hydra/OmegaConf or plain) mapping; cells are listed top row first."""
    cfg = dict(cfg)
    rows = [r.replace(" ", "") for r in (cfg["cells"].split() if isinstance(cfg["cells"], str) else cfg["cells"])]
    cfg["cells"] = rows
    groups = tuple(Group(str(g["name"]), (_pair(g["segment"][0]), _pair(g["segment"][1])),
                         int(g["actuation"]), _pair(g["direction"])) for g in cfg.get("groups", []))
    return SceneSpec(
        name=str(cfg["name"]),
        x_breaks=_breaks(cfg, "x"), y_breaks=_breaks(cfg, "y"),
        cells=tuple(reversed(rows)),
        groups=groups,
        pinned=tuple(_pair(p) for p in cfg.get("pinned", [])),
        tracked={str(k): _pair(v) for k, v in dict(cfg.get("tracked", {})).items()},
        radii_init=float(cfg.get("radii_init", 0.5)),
        radii_bounds=_pair(cfg.get("radii_bounds", (0.1, 0.9))),
        corner_box=float(cfg.get("corner_box", 0.0) or 0.0),
        locked_nodes=tuple(tuple(int(a) for a in n) for n in cfg.get("locked_nodes", []) or []),
        central_pore=tuple(tuple(int(a) for a in n) for n in cfg.get("central_pore", []) or []),
        central_radii_init=float(cfg.get("central_radii_init", 0.8)),
        colours=bool(cfg.get("colours", False)),
    )


def bilinear_net(corners: Sequence[Sequence[float]], n: int = 5) -> np.ndarray:
    """(n, n, 2) control net of the bilinear map of a quadrilateral (corners counter-clockwise from (0,0))."""
    c = np.asarray(corners, float)
    s = np.linspace(0.0, 1.0, n)
    S, T = np.meshgrid(s, s, indexing="ij")
    return ((1 - S) * (1 - T))[..., None] * c[0] + (S * (1 - T))[..., None] * c[1] \
        + (S * T)[..., None] * c[2] + ((1 - S) * T)[..., None] * c[3]


def cooks_membrane() -> PatchSceneSpec:
    """Cook's membrane: plane-strain trapezoid, left edge clamped, 100 N shear on the right edge."""
    nets = bilinear_net([(0.0, 0.0), (48.0, 44.0), (48.0, 60.0), (0.0, 44.0)])[None]
    return PatchSceneSpec(
        name="cooks_membrane", nets=nets,
        clamped=(((0.0, 0.0), (0.0, 44.0)),),
        tractions=(Traction(((48.0, 44.0), (48.0, 60.0)), (0.0, 100.0 / 16.0)),),
        tracked={"tip": (48.0, 60.0)},
    )
