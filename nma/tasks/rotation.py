"""Rotation (paper Sec. 4.1, Figs. 5-6): rotate the centre square's stick by theta about the
centre."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .schemas import RotationTask
from .base import Task


class Rotation(Task):
    metric_name = "mean_angle_error_deg"
    metric_unit = "degrees"

    def __init__(self, name, centre, points, theta_range, d_max, eval_angles):
        self.name = name
        self.centre = jnp.asarray(centre)
        # (2, 2) reference positions of left and right ends
        self.points = jnp.asarray(points)
        self.lo, self.hi = theta_range
        self.d_max = d_max
        self._eval = jnp.linspace(self.lo, self.hi, eval_angles)[:, None]

    def sample(self, key, n):
        return jax.random.uniform(key, (n, 1), minval=self.lo, maxval=self.hi)

    def observe(self, sim, geom, X, u, mat):
        tracked = sim.tracked(X, u)
        return jnp.stack([tracked["left"], tracked["right"]])

    def targets(self, t):
        th = t[..., 0]
        c, s = jnp.cos(th), jnp.sin(th)
        R = jnp.stack([jnp.stack([c, -s], -1), jnp.stack([s, c], -1)], -2)  # (..., 2, 2)
        return self.centre + jnp.einsum("...ij,pj->...pi", R, self.points - self.centre)

    def metric(self, out, t):
        v = out[..., 1, :] - out[..., 0, :]
        angle = jnp.arctan2(v[..., 1], v[..., 0])
        err = jnp.angle(jnp.exp(1j * (angle - t[..., 0])))  # wrapped to (-pi, pi]
        return jnp.degrees(jnp.abs(err))

    def eval_set(self):
        return self._eval

    metric_label = "error of the stick's angle"
    sweep_fps = 8.0

    def describe(self, t):
        return f"target angle {float(np.degrees(t[0])):+.1f}°"

    def coordinates(self, ts):
        return np.degrees(np.asarray(ts)), ["target angle [degrees]"]

    def frozen_floor(self):
        """The initial design and its actuators are mirror-symmetric about both axes through the
        centre, so with the geometry frozen the stick cannot turn: the error is the target angle
        itself."""
        return (
            float(np.mean(np.degrees(np.abs(np.asarray(self._eval))))),
            "the mirror-symmetric initial design cannot turn the stick",
        )

    def sweep(self, n):
        """From the smallest angle to the largest and back."""
        up = jnp.linspace(self.lo, self.hi, (n + 1) // 2 + 1)
        return jnp.concatenate([up, up[-2:0:-1]])[:n, None]


def _rotation(name):
    def build(cfg: RotationTask, sim) -> Rotation:
        X = sim.reference_points(sim.init_params())
        tracked = sim.disc.tracked_points(X)
        centre = 0.5 * (tracked["left"] + tracked["right"])
        return Rotation(
            name,
            centre,
            jnp.stack([tracked["left"], tracked["right"]]),
            tuple(cfg.theta_range),
            cfg.d_max,
            cfg.eval_angles,
        )

    return build


rotation_single = _rotation("rotation_single")
rotation_double = _rotation("rotation_double")
