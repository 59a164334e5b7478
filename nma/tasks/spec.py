"""A task posed in YAML (`task=<file>` with `defaults: [spec_schema]`; the schema:
nma.tasks.schemas.SpecTask).

A small, closed vocabulary: the task observes tracked points of its scene, or the boundary of one of
its pores, and sets them one of four goals, each a function of a descriptor t:
- `move`: every point to its rest position + t (t in 2D): the paper's translation is
  `points: [pointer]`, `low: [-1.5, -1.5]`, `high: [1.5, 1.5]`;
- `rotate`: two points about their rest midpoint by t radians: the paper's rotations are
  `points: [left, right]`;
- `distance`: the distance between two points to its rest value + t;
- `pore_area`: the area inside the pore of cell `pore` to its rest area x (1 + t): open or close a
  pore on demand.  The area is exact (Green's theorem on the quadratic Bezier segments of the pore's
  wall);
- `force`: the force the actuation of group `group` pushes with (the energy's conjugate of that
  actuation: the derivative of the equilibrium's strain energy with respect to it, summed over every
  group it drives) to t: press with a given force.
t comes from a box (`low`, `high`: uniform in training, an evenly spaced grid in evaluation), from
named `cases` or from a `dataset` file (in training each with equal chance; in evaluation all).
The loss is the mean absolute (l1) or squared (l2) error of the points (or of the distance, or of
the area ratio); the metric is what a reader asks of the goal: the distance of the points to their
targets, the error of the angle of the line through the two points (degrees), the error of their
distance, or the error of the pore's area in % of its rest area.  Everything a figure needs follows
from the goal and the descriptors.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..geometry.outline import loop_basis, oriented_loops, sample_loop
from .base import Task
from .schemas import SpecTask as SpecConfig

# boundary points per knot span of a pore's wall: even, so every span's midpoint is one
PER_SPAN = 4
# a descriptor entry past this (a length, a relative change, an angle or a force) is beyond any
# set-up a scene can make; near float64's limit it would overflow once squared in a loss
DESCRIPTOR_MAX = 1e6


def descriptors(cfg: SpecConfig) -> np.ndarray | None:
    """The finite set of descriptors (n, dim) of named cases or of a dataset file (CSV, one per row,
    '#' comments), None for a box; ConfigError naming the field for a file that cannot be read or
    rows that do not fit the goal."""
    if cfg.cases:
        return np.asarray(list(cfg.cases.values()), float).reshape(len(cfg.cases), cfg.dim)
    if not cfg.dataset:
        return None
    path = Path(cfg.dataset)
    try:
        rows = np.loadtxt(path, delimiter=",", ndmin=2, comments="#")
    except (OSError, ValueError) as exc:
        raise ConfigError(
            f"task.dataset {path} cannot be read as CSV numbers (one descriptor per row): {exc}"
        ) from None
    if rows.shape[0] == 0 or rows.shape[1] != cfg.dim or not np.all(np.isfinite(rows)):
        raise ConfigError(
            f"task.dataset {path} must hold finite rows of {cfg.dim} value{'s' * (cfg.dim > 1)} "
            f"for goal {cfg.goal}, got an array of shape {rows.shape}"
        )
    for k, row in enumerate(rows):
        cfg.check_values(f"dataset (row {k + 1} of {path})", list(row))
    return rows


def wall_points(wall: jnp.ndarray, grading: float = 1.0) -> jnp.ndarray:
    """The points of a pore's wall, its control points (n_edges, m, 2), at PER_SPAN even steps per
    span (as outline.sample_loop, traceable)."""
    return jnp.einsum("nk,ekd->end", loop_basis(wall.shape[1], PER_SPAN, grading), wall).reshape(
        -1, 2
    )


def wall_area(points: jnp.ndarray) -> jnp.ndarray:
    """The signed area inside a closed curve given by its points at PER_SPAN even steps per
    quadratic span, exactly: each span is the Bezier segment through its start, midpoint and end,
    whose area contribution (1/2 of the integral of x dy - y dx) is (P0xP1 + P1xP2) / 3 + P0xP2 /
    6."""
    start = points[..., ::PER_SPAN, :]
    mid = points[..., PER_SPAN // 2 :: PER_SPAN, :]
    end = jnp.roll(start, -1, axis=-2)
    ctrl = 2.0 * mid - 0.5 * (start + end)
    cross = lambda a, b: a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return jnp.sum((cross(start, ctrl) + cross(ctrl, end)) / 3.0 + cross(start, end) / 6.0, axis=-1)


class SpecTask(Task):
    sweep_fps = 8.0

    def __init__(
        self,
        cfg: SpecConfig,
        rest: jnp.ndarray,
        pore_loop: np.ndarray | None = None,
        actuation: int | None = None,
    ):
        """`rest`: the observed points at rest, (k, 2) tracked points or the pore's wall;
        `pore_loop`: the pore's wall as point indices (n_edges, m), for goal pore_area; `actuation`:
        the group's actuation
        index, for goal force."""
        self.name, self.d_max, self.goal = cfg.name, cfg.d_max, cfg.goal
        self.point_names = list(cfg.points)
        self.rest = jnp.asarray(rest)
        self.centre = jnp.mean(self.rest, axis=0)
        self.l2 = cfg.loss == "l2"
        self.pore_loop, self.outline = pore_loop, pore_loop is not None
        self.actuation, self.group_name = actuation, cfg.group
        self.rest_area = wall_area(self.rest) if self.outline else None
        self.cases = descriptors(cfg)
        self.case_names = list(cfg.cases)
        if self.cases is None:
            self.low, self.high = jnp.asarray(cfg.low), jnp.asarray(cfg.high)
            axes = [
                np.asarray(jnp.linspace(lo, hi, cfg.eval_points))
                for lo, hi in zip(cfg.low, cfg.high)
            ]
            # the grid with the first dimension fastest (as the translation task's eval grid)
            self._eval = jnp.asarray([p[::-1] for p in itertools.product(*axes[::-1])])
        else:
            self._eval = jnp.asarray(self.cases)
            self.sweep_fps = 1.0  # separate cases, not a continuous path
        where = (
            "task.cases"
            if cfg.cases
            else f"task.dataset {cfg.dataset}"
            if cfg.dataset
            else "task.low/high"
        )
        if float(jnp.max(jnp.abs(self._eval))) > DESCRIPTOR_MAX:
            raise ConfigError(
                f"{where} asks for {float(jnp.max(jnp.abs(self._eval))):g}: a descriptor's "
                "entries must "
                f"be within [-{DESCRIPTOR_MAX:g}, {DESCRIPTOR_MAX:g}], beyond any set-up a scene "
                "can make"
            )
        if self.goal == "distance":  # a target distance below zero is no distance
            apart, lowest = (
                float(jnp.linalg.norm(self.rest[1] - self.rest[0])),
                float(jnp.min(self._eval)),
            )
            if apart + lowest <= 0:
                raise ConfigError(
                    f"{where} asks for a distance change of {lowest:g}, but "
                    f"{', '.join(cfg.points)} "
                    f"are {apart:g} apart at rest: each change must be above {-apart:g}"
                )
        first, last = (self.point_names or ["", ""])[0], (self.point_names or ["", ""])[-1]
        self.metric_name, self.metric_unit, self._label = {
            "move": (
                f"mean_{first if len(self.point_names) == 1 else 'point'}_error",
                "length units",
                f"distance of {', '.join(self.point_names)} to the target",
            ),
            "rotate": ("mean_angle_error_deg", "degrees", f"error of the angle of {first}-{last}"),
            "distance": (
                "mean_distance_error",
                "length units",
                f"error of the distance {first}-{last}",
            ),
            "pore_area": (
                "mean_pore_area_error_pct",
                "% of the rest area",
                f"area error of pore {list(cfg.pore or [])}",
            ),
            "force": (
                "mean_force_error",
                "force units (E x length)",
                f"force error on group {cfg.group}",
            ),
        }[self.goal]
        self.metric_dimension = {"move": "length", "distance": "length", "force": "force"}.get(
            self.goal
        )

    @property
    def metric_label(self):
        return self._label

    # -- the protocol
    # ----------------------------------------------------------------------------------
    def sample(self, key, n):
        if self.cases is not None:  # each case (or row) with equal chance
            return self._eval[jax.random.randint(key, (n,), 0, len(self._eval))]
        return jax.random.uniform(key, (n, len(self.low)), minval=self.low, maxval=self.high)

    def observe(self, sim, geom, X, u, mat):
        if self.actuation is not None:  # dW/dd of the group's actuation
            return jnp.reshape(sim.actuation_forces(X, u, mat)[self.actuation], (1,))
        if self.outline:
            return wall_points((X + u)[self.pore_loop], sim.disc.mesh.fidelity.grading)
        tracked = sim.tracked(X, u)
        return jnp.stack([tracked[p] for p in self.point_names])

    def eval_set(self):
        return self._eval

    def targets(self, t):
        if self.goal == "move":
            return self.rest + t[..., None, :]
        if self.goal == "rotate":
            c, s = jnp.cos(t[..., 0]), jnp.sin(t[..., 0])
            R = jnp.stack([jnp.stack([c, -s], -1), jnp.stack([s, c], -1)], -2)
            return self.centre + jnp.einsum("...ij,pj->...pi", R, self.rest - self.centre)
        if self.goal == "pore_area":
            return 1.0 + t[..., 0]  # the area as a multiple of the rest area
        if self.goal == "force":
            return t
        return jnp.linalg.norm(self.rest[1] - self.rest[0]) + t[..., 0]  # distance: a length

    def _error(self, out, t):
        if self.goal == "distance":
            return jnp.linalg.norm(out[..., 1, :] - out[..., 0, :], axis=-1) - self.targets(t)
        if self.goal == "pore_area":
            return wall_area(out) / self.rest_area - self.targets(t)
        return out - self.targets(t)

    def loss(self, out, t):
        e = self._error(out, t)
        return jnp.mean(e * e) if self.l2 else jnp.mean(jnp.abs(e))

    def metric(self, out, t):
        if self.goal == "move":
            return jnp.mean(jnp.linalg.norm(out - self.targets(t), axis=-1), axis=-1)
        if self.goal == "rotate":
            v = out[..., 1, :] - out[..., 0, :]
            rest = self.rest[1] - self.rest[0]
            angle = jnp.arctan2(v[..., 1], v[..., 0]) - jnp.arctan2(rest[1], rest[0])
            # wrapped to (-pi, pi]
            return jnp.degrees(jnp.abs(jnp.angle(jnp.exp(1j * (angle - t[..., 0])))))
        if self.goal == "pore_area":
            return 100.0 * jnp.abs(self._error(out, t))
        if self.goal == "force":
            return jnp.abs(out[..., 0] - t[..., 0])
        return jnp.abs(self._error(out, t))

    # -- what figures need, from the goal and the descriptors
    # -----------------------------------------
    def shown_target(self, out, t):
        # the reached wall scaled about its centre to the target's area
        if self.goal == "pore_area":
            centre = jnp.mean(out, axis=-2, keepdims=True)
            return centre + (out - centre) * jnp.sqrt(
                self.targets(t) * self.rest_area / wall_area(out)
            )
        if self.goal != "distance":
            return self.targets(t)
        # the reached points moved along their line
        mid, v = 0.5 * (out[0] + out[1]), out[1] - out[0]
        half = 0.5 * self.targets(t) * v / jnp.linalg.norm(v)
        return jnp.stack([mid - half, mid + half])

    def describe(self, t):
        t = np.asarray(t)
        name = next(
            (
                f"{n}: "
                for n, c in zip(self.case_names, self.cases if self.case_names else [])
                if np.array_equal(c, t)
            ),
            "",
        )
        if self.goal == "move":
            return name + "target offset ({:+.2f}, {:+.2f})".format(*t)
        if self.goal == "rotate":
            return name + f"target angle {np.degrees(t[0]):+.1f}°"
        if self.goal == "pore_area":
            return name + f"pore area x {1.0 + t[0]:.2f}"
        if self.goal == "force":
            return name + f"force {t[0]:+.3g}"
        return name + f"distance change {t[0]:+.2f}"

    def coordinates(self, ts):
        ts = np.asarray(ts)
        if self.goal == "move":
            return ts, ["target offset x [length units]", "target offset y [length units]"]
        if self.goal == "rotate":
            return np.degrees(ts), ["target angle [degrees]"]
        if self.goal == "pore_area":
            return ts, ["relative change of the pore's area"]
        if self.goal == "force":
            return ts, [f"target force of group {self.group_name}'s actuation [E x length]"]
        return ts, ["change of distance [length units]"]

    def sweep(self, n):
        if self.cases is not None:  # every case (row) in turn, as many as fit
            return self._eval[jnp.arange(n) % len(self._eval)]
        if self.goal == "move":  # once round the ellipse inscribed in the box
            phi = jnp.linspace(0.0, 2.0 * jnp.pi, n, endpoint=False)
            mid, half = 0.5 * (self.low + self.high), 0.5 * (self.high - self.low)
            return mid + half * jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)
        up = jnp.linspace(self.low[0], self.high[0], (n + 1) // 2 + 1)  # from low to high and back
        return jnp.concatenate([up, up[-2:0:-1]])[:n, None]


def pore_wall(disc, X: np.ndarray, cell) -> np.ndarray:
    """The wall of the pore inside `cell` [column, row] (from the bottom left) as point indices
    (n_edges, m): the pore loop that holds the cell's centre."""
    import shapely

    spec = disc.spec
    i, j = cell
    centre = shapely.Point(
        0.5 * (spec.x_breaks[i] + spec.x_breaks[i + 1]),
        0.5 * (spec.y_breaks[j] + spec.y_breaks[j + 1]),
    )
    for loop in oriented_loops(disc.mesh, X)[1:]:
        if shapely.Polygon(sample_loop(X[loop], PER_SPAN, disc.mesh.fidelity.grading)).contains(
            centre
        ):
            return loop
    raise ConfigError(
        f"task.pore {list(cell)}: no pore of scene {spec.name} surrounds the centre of that cell"
    )


def spec(cfg: SpecConfig, sim) -> SpecTask:
    X = sim.reference_points(sim.init_params())
    if cfg.goal == "force":
        group = next((g for g in getattr(sim.disc.spec, "groups", ()) if g.name == cfg.group), None)
        if group is None:
            raise ConfigError(
                f"task.group {cfg.group!r} is not an actuated group of scene {sim.disc.spec.name}"
            )
        return SpecTask(cfg, jnp.zeros((1,)), actuation=group.actuation)
    if cfg.goal == "pore_area":
        loop = pore_wall(sim.disc, np.asarray(X), cfg.pore)
        return SpecTask(cfg, wall_points(X[loop], sim.disc.mesh.fidelity.grading), loop)
    tracked = sim.disc.tracked_points(X)
    return SpecTask(cfg, jnp.stack([tracked[p] for p in cfg.points]))
