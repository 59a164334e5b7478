"""Scenes: a cell grid, its actuated groups, supports, pinned and tracked points; a well-formed
scene that cannot be a physical set-up is refused here, before any work
(the checks: nma.schema.scene_checks)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Dict, List, Optional

from omegaconf import MISSING

from ..errors import ConfigError
from ..geometry.scene import Group, SceneSpec, Support
from ..mechanics.options import VOLUMETRIC
from ..settings import Schema, _points, bounded, choice, option
from .scene_checks import SceneChecks


@dataclass
class GroupConfig(Schema):
    """Control points on a straight boundary segment moved as a block: u = d[actuation] *
    direction."""

    prefix: ClassVar[str] = "scene.groups"
    name: str = MISSING
    segment: List[Any] = MISSING  # [[x, y], [x, y]]
    actuation: int = bounded(MISSING, "[0, 1000]")
    direction: List[float] = MISSING

    def check(self):
        _points(f"{self.prefix}.segment", self.segment, float)
        if len(self.segment) != 2:
            self.fail(
                "segment", f"of group {self.name} must be two points [[x, y], [x, y]]", self.segment
            )
        if len(self.direction) != 2:
            self.fail("direction", f"of group {self.name} must be [dx, dy]", self.direction)
        if not any(self.direction):
            self.fail(
                "direction",
                f"of group {self.name} must not be [0, 0] (the group would be pinned; "
                "use scene.pinned or scene.supports for that)",
                self.direction,
            )


@dataclass
class SupportConfig(Schema):
    """A straight boundary segment that holds the body: `clamped` (both displacement components 0)
    or `sliding` (the component normal to the segment 0, the tangential one free).  Unlike a pinned
    point, a support of finite length has a continuum limit (a point constraint fades under
    refinement)."""

    prefix: ClassVar[str] = "scene.supports"
    segment: List[Any] = MISSING  # [[x, y], [x, y]], along the material's outer boundary
    kind: str = choice("clamped", ("clamped", "sliding"))

    def check(self):
        _points(f"{self.prefix}.segment", self.segment, float)
        if len(self.segment) != 2:
            self.fail("segment", "must be two points [[x, y], [x, y]]", self.segment)
        (x0, y0), (x1, y1) = self.segment
        if (x0, y0) == (x1, y1) or (x0 != x1 and y0 != y1):
            self.fail(
                "segment",
                "must be a horizontal or vertical segment of positive length "
                "(the outer boundary of a cell grid is)",
                self.segment,
            )

    def fixed_components(self) -> tuple[int, ...]:
        """The displacement components held: both, or the one normal to the segment."""
        if self.kind == "clamped":
            return (0, 1)
        return (0,) if self.segment[0][0] == self.segment[1][0] else (1,)


@dataclass
class SceneConfig(Schema, SceneChecks):
    """A cell grid: tokens P (porous), S (solid), . (empty), listed top row first.

    The scene specification: the structure as data, what `conf/scene/<name>.yaml` holds.  Its fields
    (each with its default and range in docs/reference/settings.md): `name`, `cells`, `cell_size`
    (or `x_breaks`, `y_breaks`), the actuated `groups` (`GroupConfig`), the `supports`
    (`SupportConfig`) and `pinned` points that hold the body, the `tracked` material points a task
    reads, the `gravity` whose dead load the body carries, the design's box (`radii_init`,
    `radii_bounds`, `corner_box`, `locked_nodes`), shape matching's `central_pore`, digital
    MNIST's `colours`, and `round_pore_corners`, `contact`, `fidelity` and `volumetric`.  Every
    field is checked on construction, and `spec()` refuses a well-formed scene that cannot be a
    physical set-up (a body nothing holds, a group off the outer boundary, cells in pieces), naming
    the field.

    Examples:
        >>> strip = SceneConfig(name="strip", cells="PP\\nPP", tracked={"tip": [10, 5]},
        ...     groups=[GroupConfig(name="pull", segment=[[10, 0], [10, 10]], actuation=0,
        ...                         direction=[1, 0])],
        ...     supports=[SupportConfig(segment=[[0, 0], [0, 10]], kind="clamped")])
        >>> strip.spec().name
        'strip'
        >>> SceneConfig(name="strip", cells="PP\\nPP", radii_init=1.0)
        Traceback (most recent call last):
        ...
        nma.errors.ConfigError: scene.radii_init must be ...
    """

    prefix: ClassVar[str] = "scene"
    name: str = MISSING  # the scene's name (a task runs on the scene of its own name)
    cells: str = MISSING  # the grid, a row of tokens a line, top row first
    cell_size: float = bounded(5.0, "(0, inf)", doc="a cell's side, in the scene's length units")
    x_breaks: Optional[List[float]] = None  # cell boundaries, overriding cell_size
    y_breaks: Optional[List[float]] = None  # as x_breaks, for the rows
    # actuated boundary segments (docs/reference/scenes.md)
    groups: List[GroupConfig] = field(default_factory=list)
    pinned: List[Any] = field(default_factory=list)  # [[x, y], ...]
    supports: List[SupportConfig] = field(default_factory=list)  # segments that hold the body
    tracked: Dict[str, Any] = field(default_factory=dict)  # name -> [x, y] (a material point)
    gravity: Optional[List[float]] = bounded(
        None,
        "[-1e30, 1e30]",
        doc="[gx, gy]: an acceleration, in the scene's length units per time unit squared (those "
        "of material.density), whose dead load material.density x gravity per unit reference area "
        "the body carries, ramped with the load steps like the other dead loads; null or [0, 0]: "
        "none",
    )
    radii_init: float = bounded(
        0.5, "(0, 1)", doc="the pores' initial radii, a fraction of the cell"
    )
    radii_bounds: List[float] = bounded(
        spec="(0, 1)",
        factory=lambda: [0.1, 0.9],
        doc="0 closes a pore, 1 cuts a cell apart: both degenerate",
    )
    corner_box: float = bounded(0.0, "[0, inf)", doc="half-width of the box interior nodes move in")
    # grid nodes [[i, j], ...] that never move
    locked_nodes: List[Any] = field(default_factory=list)
    # ring of grid nodes [[i, j], ...], counter-clockwise
    central_pore: List[Any] = field(default_factory=list)
    central_radii_init: float = bounded(0.8, "(0, 1)", doc="the central pore's initial radii")
    colours: bool = False  # a colour field on the material (digital MNIST's display)
    # the pore walls meet tangent at the pore corners (each corner's radius derived from its
    # neighbours', 3 design radii per side), not at an angle: no re-entrant corner, so no singular
    # stress there for refinement to chase; false: the paper's pores, a radius per corner
    round_pore_corners: bool = False
    periodic: bool = option(
        False,
        "a periodic cell: opposite edges tied, no supports, groups or actuations, loaded by a "
        "macroscopic deformation gradient (nma.simulate's load group; "
        "docs/how-to/periodic-metamaterials.md); its scene file names periodic_scene_schema "
        "(nma.schema.periodic.PeriodicSceneConfig) in its defaults",
    )
    # contact=auto (the commands' default) turns the pores' self-contact on for a scene that says
    # so: one whose pores close under its task's actuations, where without contact they pass through
    # themselves
    contact: bool = False
    # the discretisation its runs use where the command names none (fidelity=scene, the default): a
    # mapping of fidelity.ctrl_per_patch and/or fidelity.quad_points; empty: the paper's 5 x 5
    fidelity: Dict[str, int] = field(default_factory=dict)
    volumetric: Optional[str] = choice(
        None,
        (None, *VOLUMETRIC),
        doc="the material's volume term where material.volumetric is auto: the form the scene's "
        "results are stated in (the paper's scenes and strip state bulk, the paper's); null: lame",
    )

    def body_force(self, density: float):
        """The dead load per unit reference area, density x gravity (2,), or None without
        gravity."""
        if self.gravity is None or not any(self.gravity):
            return None
        return (float(density * self.gravity[0]), float(density * self.gravity[1]))

    def rows(self) -> list[str]:
        return [r.replace(" ", "") for r in self.cells.split()]

    def breaks(self, axis: str) -> list[float]:
        given = self.x_breaks if axis == "x" else self.y_breaks
        if given is not None:
            return [float(b) for b in given]
        rows = self.rows()
        n = len(rows[0]) if axis == "x" else len(rows)
        return [self.cell_size * k for k in range(n + 1)]

    @property
    def n_actuations(self) -> int:
        return 1 + max((g.actuation for g in self.groups), default=-1)

    def spec(self) -> SceneSpec:
        """The geometry's own description of this scene (nma.geometry.scene); cells bottom row
        first."""
        pair = lambda v: (float(v[0]), float(v[1]))
        return SceneSpec(
            name=self.name,
            x_breaks=tuple(self.breaks("x")),
            y_breaks=tuple(self.breaks("y")),
            cells=tuple(reversed(self.rows())),
            groups=tuple(
                Group(
                    g.name, (pair(g.segment[0]), pair(g.segment[1])), g.actuation, pair(g.direction)
                )
                for g in self.groups
            ),
            pinned=tuple(pair(p) for p in self.pinned),
            tracked={k: pair(v) for k, v in self.tracked.items()},
            radii_init=self.radii_init,
            radii_bounds=pair(self.radii_bounds),
            corner_box=self.corner_box,
            locked_nodes=tuple((int(i), int(j)) for i, j in self.locked_nodes),
            central_pore=tuple((int(i), int(j)) for i, j in self.central_pore),
            central_radii_init=self.central_radii_init,
            colours=self.colours,
            round_pore_corners=self.round_pore_corners,
            supports=tuple(
                Support((pair(t.segment[0]), pair(t.segment[1])), t.fixed_components())
                for t in self.supports
            ),
        )

    def check(self):
        rows = self.rows()
        if not rows or len({len(r) for r in rows}) != 1:
            self.fail("cells", "must be rows of equal length", self.cells)
        bad = {c for r in rows for c in r} - set("PS.")
        if bad:
            self.fail("cells", f"holds unknown cell tokens {sorted(bad)}; allowed 'P', 'S', '.'")
        for axis, n in (("x", len(rows[0])), ("y", len(rows))):
            b = self.breaks(axis)
            if len(b) != n + 1 or any(b1 <= b0 for b0, b1 in zip(b, b[1:])):
                self.fail(f"{axis}_breaks", f"must be {n + 1} increasing values for {n} cells", b)
        if self.gravity is not None and len(self.gravity) != 2:
            self.fail("gravity", "must be [gx, gy] (or null: no gravity)", self.gravity)
        unknown = set(self.fidelity) - {"ctrl_per_patch", "quad_points"}
        if unknown:
            self.fail(
                "fidelity",
                f"may set ctrl_per_patch and quad_points only, not {sorted(unknown)}",
                self.fidelity,
            )
        from .physics import Fidelity

        try:
            Fidelity(**self.fidelity)
        except ConfigError as exc:
            raise ConfigError(f"scene.{exc}") from None
        lo, hi = (self.radii_bounds + [None, None])[:2]
        if len(self.radii_bounds) != 2 or not lo < hi:
            self.fail("radii_bounds", "must be [lo, hi] with 0 < lo < hi < 1", self.radii_bounds)
        for name in ("radii_init",) + (("central_radii_init",) if self.central_pore else ()):
            if not lo <= getattr(self, name) <= hi:
                self.fail(name, f"must lie in radii_bounds [{lo}, {hi}]", getattr(self, name))
        half_cell = 0.5 * min(
            min(b1 - b0 for b0, b1 in zip(b, b[1:])) for b in (self.breaks("x"), self.breaks("y"))
        )
        if self.corner_box >= half_cell:
            # below half a cell, neighbouring nodes can never meet; cells stay convex by the
            # trainer's projection
            self.fail(
                "corner_box", f"must be < half the smallest cell ({half_cell:g})", self.corner_box
            )
        n_act = 1 + max((g.actuation for g in self.groups), default=-1)
        used = {g.actuation for g in self.groups}
        if used != set(range(n_act)):
            self.fail(
                "groups", f"actuation indices must be 0..{n_act - 1} without gaps", sorted(used)
            )
        _points("scene.pinned", self.pinned, float)
        _points("scene.tracked", list(self.tracked.values()), float)
        _points("scene.locked_nodes", self.locked_nodes, int)
        _points("scene.central_pore", self.central_pore, int)
        self._check_one_piece()
        self._check_in_material()
        for path, name, segment in [
            ("groups", f"of group {g.name}", g.segment) for g in self.groups
        ] + [(f"supports[{k}]", "", s.segment) for k, s in enumerate(self.supports)]:
            self._check_on_boundary(path, name, segment)
        self._check_no_contradiction()
        self._check_held()
