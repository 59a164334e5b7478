"""Scenes: a cell grid, its actuated groups, supports, pinned and tracked points; a well-formed scene that
cannot be a physical set-up is refused here, before any work."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Dict, List, Optional

from omegaconf import MISSING

from ..errors import ConfigError
from ..geometry.scene import Group, SceneSpec, Support
from ..settings import Schema, _points, bounded, choice


@dataclass
class GroupConfig(Schema):
    """Control points on a straight boundary segment moved as a block: u = d[actuation] * direction."""
    prefix: ClassVar[str] = "scene.groups"
    name: str = MISSING
    segment: List[Any] = MISSING           # [[x, y], [x, y]]
    actuation: int = bounded(MISSING, "[0, 1000]")
    direction: List[float] = MISSING

    def check(self):
        _points(f"{self.prefix}.segment", self.segment, float)
        if len(self.segment) != 2:
            self.fail("segment", f"of group {self.name} must be two points [[x, y], [x, y]]", self.segment)
        if len(self.direction) != 2:
            self.fail("direction", f"of group {self.name} must be [dx, dy]", self.direction)
        if not any(self.direction):
            self.fail("direction", f"of group {self.name} must not be [0, 0] (the group would be pinned; "
                      "use scene.pinned or scene.supports for that)", self.direction)


@dataclass
class SupportConfig(Schema):
    """A straight boundary segment that holds the body: `clamped` (both displacement components 0) or
    `sliding` (the component normal to the segment 0, the tangential one free).  Unlike a pinned point,
    a support of finite length has a continuum limit (a point constraint fades under refinement)."""
    prefix: ClassVar[str] = "scene.supports"
    segment: List[Any] = MISSING           # [[x, y], [x, y]], along the material's outer boundary
    kind: str = choice("clamped", ("clamped", "sliding"))

    def check(self):
        _points(f"{self.prefix}.segment", self.segment, float)
        if len(self.segment) != 2:
            self.fail("segment", "must be two points [[x, y], [x, y]]", self.segment)
        (x0, y0), (x1, y1) = self.segment
        if (x0, y0) == (x1, y1) or (x0 != x1 and y0 != y1):
            self.fail("segment", "must be a horizontal or vertical segment of positive length "
                      "(the outer boundary of a cell grid is)", self.segment)

    def fixed_components(self) -> tuple[int, ...]:
        """The displacement components held: both, or the one normal to the segment."""
        if self.kind == "clamped":
            return (0, 1)
        return (0,) if self.segment[0][0] == self.segment[1][0] else (1,)


def _segment_distance(a, b) -> float:
    """Distance between two segments (points if of zero length) in the plane."""
    def point_segment(p, s):
        (x0, y0), (x1, y1) = s
        dx, dy = x1 - x0, y1 - y0
        L2 = dx * dx + dy * dy
        t = 0.0 if L2 == 0 else min(1.0, max(0.0, ((p[0] - x0) * dx + (p[1] - y0) * dy) / L2))
        return math.hypot(p[0] - x0 - t * dx, p[1] - y0 - t * dy)

    def cross(o, p, q):
        return (p[0] - o[0]) * (q[1] - o[1]) - (p[1] - o[1]) * (q[0] - o[0])

    (p0, p1), (q0, q1) = a, b
    d1, d2, d3, d4 = cross(p0, p1, q0), cross(p0, p1, q1), cross(q0, q1, p0), cross(q0, q1, p1)
    if (d1 * d2 < 0) and (d3 * d4 < 0):
        return 0.0  # proper crossing
    return min(point_segment(p0, b), point_segment(p1, b), point_segment(q0, a), point_segment(q1, a))


def _rank(rows: list[list[float]], tol: float) -> tuple[int, list[list[float]]]:
    """Rank of a small matrix with 3 columns by Gaussian elimination, and a basis of its null space."""
    m = [list(r) for r in rows]
    pivots, r = [], 0
    for c in range(3):
        best = max(range(r, len(m)), key=lambda i: abs(m[i][c]), default=None)
        if best is None or abs(m[best][c]) <= tol:
            continue
        m[r], m[best] = m[best], m[r]
        m[r] = [v / m[r][c] for v in m[r]]
        for i in range(len(m)):
            if i != r and m[i][c]:
                m[i] = [vi - m[i][c] * vr for vi, vr in zip(m[i], m[r])]
        pivots.append(c)
        r += 1
    null = []
    for free in (c for c in range(3) if c not in pivots):
        v = [0.0, 0.0, 0.0]
        v[free] = 1.0
        for i, c in enumerate(pivots):
            v[c] = -m[i][free]
        null.append(v)
    return r, null


@dataclass
class SceneConfig(Schema):
    """A cell grid: tokens P (porous), S (solid), . (empty), listed top row first.

    The scene specification: the structure as data, what `conf/scene/<name>.yaml` holds.  Its fields
    (each with its default and range in docs/reference/settings.md): `name`, `cells`, `cell_size` (or
    `x_breaks`, `y_breaks`), the actuated `groups` (`GroupConfig`), the `supports` (`SupportConfig`)
    and `pinned` points that hold the body, the `tracked` material points a task reads, the design's
    box (`radii_init`, `radii_bounds`, `corner_box`, `locked_nodes`), shape matching's `central_pore`,
    digital MNIST's `colours`, and `round_pore_corners`, `contact` and `fidelity`.  Every field is
    checked on construction, and `spec()` refuses a well-formed scene that cannot be a physical set-up
    (a body nothing holds, a group off the outer boundary, cells in pieces), naming the field.

    Examples:
        >>> strip = SceneConfig(name="strip", cells="PP\\nPP", tracked={"tip": [10, 5]},
        ...     groups=[GroupConfig(name="pull", segment=[[10, 0], [10, 10]], actuation=0, direction=[1, 0])],
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
    x_breaks: Optional[List[float]] = None     # cell boundaries, overriding cell_size
    y_breaks: Optional[List[float]] = None     # as x_breaks, for the rows
    groups: List[GroupConfig] = field(default_factory=list)  # actuated boundary segments (docs/reference/scenes.md)
    pinned: List[Any] = field(default_factory=list)          # [[x, y], ...]
    supports: List[SupportConfig] = field(default_factory=list)  # segments that hold the body
    tracked: Dict[str, Any] = field(default_factory=dict)    # name -> [x, y] (a material point)
    radii_init: float = bounded(0.5, "(0, 1)", doc="the pores' initial radii, a fraction of the cell")
    radii_bounds: List[float] = bounded(spec="(0, 1)", factory=lambda: [0.1, 0.9],
                                        doc="0 closes a pore, 1 cuts a cell apart: both degenerate")
    corner_box: float = bounded(0.0, "[0, inf)", doc="half-width of the box interior nodes move in")
    locked_nodes: List[Any] = field(default_factory=list)    # grid nodes [[i, j], ...] that never move
    central_pore: List[Any] = field(default_factory=list)    # ring of grid nodes [[i, j], ...], counter-clockwise
    central_radii_init: float = bounded(0.8, "(0, 1)", doc="the central pore's initial radii")
    colours: bool = False  # a colour field on the material (digital MNIST's display)
    # the pore walls meet tangent at the pore corners (each corner's radius derived from its neighbours',
    # 3 design radii per side), not at an angle: no re-entrant corner, so no singular stress there for
    # refinement to chase; false: the paper's pores, a radius per corner
    round_pore_corners: bool = False
    # contact=auto (the commands' default) turns the pores' self-contact on for a scene that says so: one
    # whose pores close under its task's actuations, where without contact they pass through themselves
    contact: bool = False
    # the discretisation its runs use where the command names none (fidelity=scene, the default): a
    # mapping of fidelity.ctrl_per_patch and/or fidelity.quad_points; empty: the paper's 5 x 5
    fidelity: Dict[str, int] = field(default_factory=dict)

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
        """The geometry's own description of this scene (nma.geometry.scene); cells bottom row first."""
        pair = lambda v: (float(v[0]), float(v[1]))  # noqa: E731
        return SceneSpec(
            name=self.name, x_breaks=tuple(self.breaks("x")), y_breaks=tuple(self.breaks("y")),
            cells=tuple(reversed(self.rows())),
            groups=tuple(Group(g.name, (pair(g.segment[0]), pair(g.segment[1])), g.actuation, pair(g.direction))
                         for g in self.groups),
            pinned=tuple(pair(p) for p in self.pinned),
            tracked={k: pair(v) for k, v in self.tracked.items()},
            radii_init=self.radii_init, radii_bounds=pair(self.radii_bounds), corner_box=self.corner_box,
            locked_nodes=tuple((int(i), int(j)) for i, j in self.locked_nodes),
            central_pore=tuple((int(i), int(j)) for i, j in self.central_pore),
            central_radii_init=self.central_radii_init, colours=self.colours,
            round_pore_corners=self.round_pore_corners,
            supports=tuple(Support((pair(t.segment[0]), pair(t.segment[1])), t.fixed_components())
                           for t in self.supports))

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
        unknown = set(self.fidelity) - {"ctrl_per_patch", "quad_points"}
        if unknown:
            self.fail("fidelity", f"may set ctrl_per_patch and quad_points only, not {sorted(unknown)}", self.fidelity)
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
        half_cell = 0.5 * min(min(b1 - b0 for b0, b1 in zip(b, b[1:])) for b in (self.breaks("x"), self.breaks("y")))
        if self.corner_box >= half_cell:
            # below half a cell, neighbouring nodes can never meet; cells stay convex by the trainer's projection
            self.fail("corner_box", f"must be < half the smallest cell ({half_cell:g})", self.corner_box)
        n_act = 1 + max((g.actuation for g in self.groups), default=-1)
        used = {g.actuation for g in self.groups}
        if used != set(range(n_act)):
            self.fail("groups", f"actuation indices must be 0..{n_act - 1} without gaps", sorted(used))
        _points("scene.pinned", self.pinned, float)
        _points("scene.tracked", list(self.tracked.values()), float)
        _points("scene.locked_nodes", self.locked_nodes, int)
        _points("scene.central_pore", self.central_pore, int)
        self._check_one_piece()
        self._check_in_material()
        for path, name, segment in ([("groups", f"of group {g.name}", g.segment) for g in self.groups]
                                    + [(f"supports[{k}]", "", s.segment) for k, s in enumerate(self.supports)]):
            self._check_on_boundary(path, name, segment)
        self._check_no_contradiction()
        self._check_held()

    # -- what makes a well-formed scene physically wrong: refused before any work

    def _filled(self, i: int, j: int) -> bool:
        """Whether cell (column i, row j from the bottom) holds material (False outside the grid)."""
        rows = self.rows()[::-1]
        return 0 <= j < len(rows) and 0 <= i < len(rows[0]) and rows[j][i] != "."

    def _tol(self) -> float:
        return 1e-9 * max(abs(v) for v in self.breaks("x") + self.breaks("y") + [1.0])

    def _check_one_piece(self):
        """Cells joined through shared edges (a corner alone is a hinge of one control point)."""
        nx, ny = len(self.rows()[0]), len(self.rows())
        filled = {(i, j) for i in range(nx) for j in range(ny) if self._filled(i, j)}
        if not filled:
            self.fail("cells", "holds no material (every cell is '.')", self.cells)
        seen, todo = set(), [min(filled)]
        while todo:
            i, j = todo.pop()
            if (i, j) in seen:
                continue
            seen.add((i, j))
            todo += [c for c in ((i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)) if c in filled]
        if seen != filled:
            apart = sorted((ny - j, i + 1) for i, j in filled - seen)
            self.fail("cells", "must be one piece (cells joined through shared edges); the cells at (row, column) "
                      f"{apart[:6]}{' ...' if len(apart) > 6 else ''}, counted from the top left from 1, are apart "
                      "from the rest")

    def _check_in_material(self):
        """Tracked and pinned points lie on the cells' material (in or on a cell that is not '.'); whether a
        tracked point falls in a pore is known only with the design (the discretisation says so)."""
        tol, xb, yb = self._tol(), self.breaks("x"), self.breaks("y")

        def cells_at(v, breaks):  # the cell indices whose closed interval holds v
            return [k for k, (b0, b1) in enumerate(zip(breaks, breaks[1:])) if b0 - tol <= v <= b1 + tol]

        for path, points in (("tracked", self.tracked.items()), ("pinned", ((None, p) for p in self.pinned))):
            for name, (x, y) in points:
                if not any(self._filled(i, j) for i in cells_at(x, xb) for j in cells_at(y, yb)):
                    what = f"point {name} at {[x, y]}" if name else f"point {[x, y]}"
                    self.fail(path, f"{what} lies on no material: the cells span x {xb[0]:g} to {xb[-1]:g}, y "
                              f"{yb[0]:g} to {yb[-1]:g}, and '.' cells are empty")

    def _boundary_problem(self, vertical: bool, line: float, lo: float, hi: float) -> str | None:
        """Why the piece [lo, hi] of the grid line x = line (vertical) or y = line is not outer boundary
        (material on exactly one side all along; a point: beside at least one boundary edge), or None."""
        tol = self._tol()
        breaks, across = (self.breaks("y"), self.breaks("x")) if vertical else (self.breaks("x"), self.breaks("y"))
        k = next((k for k, b in enumerate(across) if abs(b - line) <= tol), None)
        if k is None:
            return "it runs along no cell boundary"
        if lo < breaks[0] - tol or hi > breaks[-1] + tol:
            return f"it reaches beyond the cells ({breaks[0]:g} to {breaks[-1]:g})"
        on_edge = False
        for n, (b0, b1) in enumerate(zip(breaks, breaks[1:])):
            if not ((min(hi, b1) - max(lo, b0) > tol) if hi > lo else (b0 - tol <= lo <= b1 + tol)):
                continue
            sides = [self._filled(k - 1, n), self._filled(k, n)] if vertical else [self._filled(n, k - 1), self._filled(n, k)]
            if hi > lo and sides[0] == sides[1]:
                return (f"between {b0:g} and {b1:g} it has "
                        f"{'material on both sides' if sides[0] else 'no material on either side'}")
            on_edge |= sides[0] != sides[1]
        return None if on_edge else "the point is on no boundary edge"

    def _check_on_boundary(self, path: str, name: str, segment):
        """A held or moved segment must lie on the material's outer boundary: material on one side only."""
        (x0, y0), (x1, y1) = segment
        where = " ".join(filter(None, [name, str([list(p) for p in segment]), "must lie on the material's outer boundary"]))
        if x0 != x1 and y0 != y1:
            self.fail(path, f"{where}, which is horizontal and vertical lines only")
        if (x0, y0) == (x1, y1):  # a point actuator: on a boundary edge either way
            problems = [self._boundary_problem(True, x0, y0, y0), self._boundary_problem(False, y0, x0, x0)]
            problem = None if None in problems else problems[0]
        elif x0 == x1:
            problem = self._boundary_problem(True, x0, min(y0, y1), max(y0, y1))
        else:
            problem = self._boundary_problem(False, y0, min(x0, x1), max(x0, x1))
        if problem:
            self.fail(path, f"{where}; {problem}")

    def _check_no_contradiction(self):
        """Two segments that share a point must not prescribe one displacement component two ways there.
        Per component: None (free), 0 (held), or (actuation, coefficient) (moved by d[actuation])."""
        zero = lambda a, c: 0 if c == 0 else (a, c)
        held = ([(f"group {g.name}", g.segment, [zero(g.actuation, c) for c in g.direction]) for g in self.groups]
                + [(f"scene.supports[{k}]", s.segment, [0 if c in s.fixed_components() else None for c in (0, 1)])
                   for k, s in enumerate(self.supports)])
        for a in range(len(held)):
            for b in range(a + 1, len(held)):
                (na, sa, ma), (nb, sb, mb) = held[a], held[b]
                clash = any(x is not None and y is not None and x != y for x, y in zip(ma, mb))
                if clash and _segment_distance(sa, sb) <= self._tol():
                    raise ConfigError(f"scene.{'groups' if na.startswith('group') else 'supports'}: {na} and {nb} "
                                      "touch but prescribe different motions where they meet")

    def _check_held(self):
        """The Dirichlet conditions must stop every rigid motion u = t + theta (-y, x); else the stiffness
        is singular.  Each held component at a point is one row [t_x, t_y, theta] of a 3-column system."""
        rows = []
        for p in self.pinned:
            rows += [[1.0, 0.0, -p[1]], [0.0, 1.0, p[0]]]
        for g in self.groups:  # a moved segment holds its points to the actuation
            for p in g.segment:
                rows += [[1.0, 0.0, -p[1]], [0.0, 1.0, p[0]]]
        for s in self.supports:
            for p in s.segment:
                rows += [[1.0, 0.0, -p[1]] if c == 0 else [0.0, 1.0, p[0]] for c in s.fixed_components()]
        rank, free = _rank(rows, 1e-12)
        if rank == 3:
            return
        motions = []
        for t_x, t_y, theta in free:
            if abs(theta) < 1e-12:
                motions.append(f"moving along ({t_x + 0.0:g}, {t_y + 0.0:g})")
            else:
                motions.append(f"rotating about ({-t_y / theta + 0.0:g}, {t_x / theta + 0.0:g})")
        self.fail("pinned", "with scene.groups and scene.supports leaves the body free to move (a singular "
                  f"stiffness): nothing stops it {' or '.join(motions)}; pin two points (scene.pinned) or hold "
                  "a segment (scene.supports, or an actuated group)")
