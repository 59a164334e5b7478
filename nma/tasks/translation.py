"""Translation (paper Sec. 4.1): move the pointer to any target in a box with two horizontal
actuations."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .schemas import TranslationTask
from .base import Task


class Translation(Task):
    metric_name = "mean_pointer_error"
    metric_unit = "length units (cell = 5)"
    metric_dimension = "length"

    def __init__(
        self, start, half_width: float, d_max: float, eval_grid: int, point: str = "pointer"
    ):
        self.name = "translation"
        self.start = jnp.asarray(start)
        self.half_width, self.d_max, self.point = half_width, d_max, point
        g = np.linspace(-half_width, half_width, eval_grid)
        self._eval = jnp.asarray(np.stack(np.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2))

    def sample(self, key, n):
        return jax.random.uniform(key, (n, 2), minval=-self.half_width, maxval=self.half_width)

    def observe(self, sim, geom, X, u, mat):
        return sim.tracked(X, u)[self.point]

    def targets(self, t):
        return self.start + t

    def metric(self, out, t):
        return jnp.linalg.norm(out - self.targets(t), axis=-1)

    def eval_set(self):
        return self._eval

    metric_label = "distance of the pointer to its target"
    sweep_fps = 8.0

    def describe(self, t):
        return "target ({:+.2f}, {:+.2f})".format(*np.asarray(t))

    def coordinates(self, ts):
        return np.asarray(ts), ["target offset x [length units]", "target offset y [length units]"]

    def frozen_floor(self):
        """The initial design and its two horizontal actuators are mirror-symmetric about the
        pointer's row, so with the geometry frozen the pointer moves sideways only: at best the
        vertical offset of each target stays."""
        return (
            float(np.mean(np.abs(np.asarray(self._eval)[:, 1]))),
            "the pointer of the mirror-symmetric initial design moves sideways only",
        )

    def sweep(self, n):
        """Once round the circle inscribed in the target box."""
        phi = jnp.linspace(0.0, 2.0 * jnp.pi, n, endpoint=False)
        return self.half_width * jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)


def translation(cfg: TranslationTask, sim) -> Translation:
    X = sim.reference_points(sim.init_params())
    start = sim.disc.tracked_points(X)["pointer"]
    return Translation(start, cfg.box_half_width, cfg.d_max, cfg.eval_grid)
