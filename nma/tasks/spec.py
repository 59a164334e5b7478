"""A task posed in YAML (`task=<file>` with `defaults: [spec_schema]`; the schema: nma.schema.SpecTask).

A small, closed vocabulary: the task observes tracked points of its scene and sets them one of three
goals, each a function of a descriptor t drawn from a box:
- `move`: every point to its rest position + t (t in 2D): the paper's translation is
  `points: [pointer]`, `low: [-1.5, -1.5]`, `high: [1.5, 1.5]`;
- `rotate`: two points about their rest midpoint by t radians: the paper's rotations are
  `points: [left, right]`;
- `distance`: the distance between two points to its rest value + t.
The loss is the mean absolute (l1) or squared (l2) error of the points (or of the distance); the metric
is what a reader asks of the goal: the distance of the points to their targets, the error of the
angle of the line through the two points (degrees), or the error of their distance.  Everything a
figure needs follows from the goal and the box.
"""
from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np

from .schemas import SpecTask as SpecConfig
from .base import Task


class SpecTask(Task):
    sweep_fps = 8.0

    def __init__(self, cfg: SpecConfig, rest: jnp.ndarray):
        self.name, self.d_max, self.goal = cfg.name, cfg.d_max, cfg.goal
        self.point_names = list(cfg.points)
        self.rest = jnp.asarray(rest)                                    # (k, 2) the points at rest
        self.centre = jnp.mean(self.rest, axis=0)
        self.low, self.high = jnp.asarray(cfg.low), jnp.asarray(cfg.high)
        self.l2 = cfg.loss == "l2"
        axes = [np.asarray(jnp.linspace(lo, hi, cfg.eval_points)) for lo, hi in zip(cfg.low, cfg.high)]
        # the grid with the first dimension fastest (as the translation task's eval grid)
        self._eval = jnp.asarray([p[::-1] for p in itertools.product(*axes[::-1])])
        self.metric_name, self.metric_unit, self._label = {
            "move": (f"mean_{self.point_names[0] if len(self.point_names) == 1 else 'point'}_error", "length units",
                     f"distance of {', '.join(self.point_names)} to the target"),
            "rotate": ("mean_angle_error_deg", "degrees", f"error of the angle of {self.point_names[0]}-"
                       f"{self.point_names[-1]}"),
            "distance": ("mean_distance_error", "length units", f"error of the distance {self.point_names[0]}-"
                         f"{self.point_names[-1]}"),
        }[self.goal]

    @property
    def metric_label(self):
        return self._label

    # -- the protocol ----------------------------------------------------------------------------------
    def sample(self, key, n):
        return jax.random.uniform(key, (n, len(self.low)), minval=self.low, maxval=self.high)

    def observe(self, sim, geom, X, u):
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
        return jnp.linalg.norm(self.rest[1] - self.rest[0]) + t[..., 0]  # distance: a length

    def _error(self, out, t):
        if self.goal == "distance":
            return jnp.linalg.norm(out[..., 1, :] - out[..., 0, :], axis=-1) - self.targets(t)
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
            return jnp.degrees(jnp.abs(jnp.angle(jnp.exp(1j * (angle - t[..., 0])))))  # wrapped to (-pi, pi]
        return jnp.abs(self._error(out, t))

    # -- what figures need, from the goal and the box ----------------------------------------------------
    def shown_target(self, out, t):
        if self.goal != "distance":
            return self.targets(t)
        mid, v = 0.5 * (out[0] + out[1]), out[1] - out[0]  # the reached points moved along their line
        half = 0.5 * self.targets(t) * v / jnp.linalg.norm(v)
        return jnp.stack([mid - half, mid + half])

    def describe(self, t):
        t = np.asarray(t)
        if self.goal == "move":
            return "target offset ({:+.2f}, {:+.2f})".format(*t)
        return f"target angle {np.degrees(t[0]):+.1f}°" if self.goal == "rotate" else f"distance change {t[0]:+.2f}"

    def coordinates(self, ts):
        ts = np.asarray(ts)
        if self.goal == "move":
            return ts, ["target offset x [length units]", "target offset y [length units]"]
        if self.goal == "rotate":
            return np.degrees(ts), ["target angle [degrees]"]
        return ts, ["change of distance [length units]"]

    def sweep(self, n):
        if self.goal == "move":  # once round the ellipse inscribed in the box
            phi = jnp.linspace(0.0, 2.0 * jnp.pi, n, endpoint=False)
            mid, half = 0.5 * (self.low + self.high), 0.5 * (self.high - self.low)
            return mid + half * jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)
        up = jnp.linspace(self.low[0], self.high[0], (n + 1) // 2 + 1)  # from low to high and back
        return jnp.concatenate([up, up[-2:0:-1]])[:n, None]


def spec(cfg: SpecConfig, sim) -> SpecTask:
    X = sim.reference_points(sim.init_params())
    tracked = sim.disc.tracked_points(X)
    return SpecTask(cfg, jnp.stack([tracked[p] for p in cfg.points]))
