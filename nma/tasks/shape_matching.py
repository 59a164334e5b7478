"""Pore shape matching (paper Sec. 4.2): deform the central pore into any shape asked of it.

Targets are closed curves r(t) = exp(f(cos t, sin t)) with f a Gaussian process drawn through random
Fourier features (Rahimi & Recht 2007): f(u) = sqrt(2/F) sum_i w_i cos(omega_i . u + phi_i),
omega ~ N(0, I)/lengthscale and phi ~ U(0, 2 pi) fixed by a dataset seed, w ~ N(0, I) fresh per
sample.  Each curve is resampled by arc length to as many points as the pore boundary has, running
counter-clockwise like the pore and starting at its lowest x + y, then centred and scaled to unit
mean radius; that normalised curve is both the task descriptor and the network's input.

Loss (the authors' code): centre both shapes and scale them to unit mean radius; for each of the N
cyclic re-indexings of the target take the rotation that best aligns the shapes (2D Procrustes, in
closed form with arctan2) and the mean L1 distance |dx| + |dy| per point; the loss is the smallest.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .schemas import ShapeMatchingTask
from .base import Task

CURVE_SAMPLES = 1000  # angles at which a target curve is traced before arc-length resampling


def normalise(points: jnp.ndarray) -> jnp.ndarray:
    """Centred at the mean point and scaled to unit mean distance from it."""
    c = points - jnp.mean(points, axis=-2, keepdims=True)
    return c / jnp.mean(jnp.linalg.norm(c, axis=-1), axis=-1)[..., None, None]


def rotate(points: jnp.ndarray, theta) -> jnp.ndarray:
    """Points (..., N, 2) turned by theta (...) about the origin."""
    c, s = jnp.cos(theta)[..., None], jnp.sin(theta)[..., None]
    return jnp.stack(
        [c * points[..., 0] - s * points[..., 1], s * points[..., 0] + c * points[..., 1]], axis=-1
    )


def aligned(observed: jnp.ndarray, target: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """For each cyclic re-indexing k of the normalised target: the rotation theta_k (N,) that best
    turns the normalised observed shape onto it, and the mean L1 point distance after it (N,)."""
    a, b = normalise(observed), normalise(target)
    shifts = jax.vmap(lambda k: jnp.roll(b, -k, axis=0))(jnp.arange(b.shape[0]))  # (N, N, 2)
    cross = jnp.sum(a[:, 0] * shifts[..., 1] - a[:, 1] * shifts[..., 0], axis=-1)
    dot = jnp.sum(a[:, 0] * shifts[..., 0] + a[:, 1] * shifts[..., 1], axis=-1)
    theta = jnp.arctan2(cross, dot)  # minimises sum |R a - b_k|^2
    rotated = rotate(jnp.broadcast_to(a, shifts.shape), theta)
    return theta, jnp.mean(jnp.sum(jnp.abs(rotated - shifts), axis=-1), axis=-1)


def shape_distance(observed: jnp.ndarray, target: jnp.ndarray) -> jnp.ndarray:
    """Smallest mean L1 distance over re-indexings and rotations, in units of the mean radius."""
    return jnp.min(aligned(observed, target)[1])


def fit_onto(observed: jnp.ndarray, target: jnp.ndarray) -> jnp.ndarray:
    """The target scaled, rotated, re-indexed and centred onto the observed shape (for drawing)."""
    theta, distance = aligned(observed, target)
    k = jnp.argmin(distance)
    centre = jnp.mean(observed, axis=0)
    radius = jnp.mean(jnp.linalg.norm(observed - centre, axis=-1))
    return centre + radius * rotate(jnp.roll(normalise(target), -k, axis=0), -theta[k])


def resample(polyline: jnp.ndarray, n: int) -> jnp.ndarray:
    """n points at equal arc length along a closed polyline (its last point equal to its first),
    starting at its first point."""
    length = jnp.concatenate(
        [jnp.zeros(1), jnp.cumsum(jnp.linalg.norm(jnp.diff(polyline, axis=0), axis=-1))]
    )
    s = jnp.linspace(0.0, length[-1], n + 1)[:-1]
    return jnp.stack([jnp.interp(s, length, polyline[:, k]) for k in range(2)], axis=-1)


def signed_area(points: jnp.ndarray) -> jnp.ndarray:
    """Shoelace area: positive for a counter-clockwise polygon."""
    x, y = points[..., 0], points[..., 1]
    return 0.5 * jnp.sum(x * jnp.roll(y, -1, axis=-1) - jnp.roll(x, -1, axis=-1) * y, axis=-1)


class ShapeMatching(Task):
    metric_name = "shape_error"
    metric_unit = "mean pore radii"
    outline = True

    def __init__(self, cfg: ShapeMatchingTask, boundary, n_points: int):
        self.name, self.d_max, self.n_points = cfg.name, cfg.d_max, n_points
        self._idx, self._w = (jnp.asarray(a) for a in boundary)
        rng = np.random.default_rng(cfg.dataset_seed)
        self.omega = jnp.asarray(rng.normal(size=(cfg.features, 2)) / cfg.lengthscale)
        self.phi = jnp.asarray(rng.uniform(0.0, 2.0 * np.pi, cfg.features))
        self._eval = self.sample(jax.random.PRNGKey(cfg.eval_seed), cfg.eval_targets)

    def curve(self, weights: jnp.ndarray) -> jnp.ndarray:
        """(n_points, 2) one target: the curve of Fourier weights (F,), resampled by arc length,
        started at its lowest x + y, normalised."""
        t = jnp.linspace(0.0, 2.0 * jnp.pi, CURVE_SAMPLES)
        u = jnp.stack([jnp.cos(t), jnp.sin(t)], axis=-1)
        f = jnp.sqrt(2.0 / len(weights)) * jnp.cos(u @ self.omega.T + self.phi) @ weights
        pts = resample(jnp.exp(f)[:, None] * u, self.n_points)
        return normalise(jnp.roll(pts, -jnp.argmin(pts[:, 0] + pts[:, 1]), axis=0))

    def sample(self, key, n):
        weights = jax.random.normal(key, (n, self.omega.shape[0]))
        return jax.vmap(self.curve)(weights).reshape(n, -1)

    def observe(self, sim, geom, X, u, mat):
        x = X + u
        return jnp.einsum("nk,nkd->nd", self._w, x[self._idx])

    def targets(self, t):
        return t.reshape(*t.shape[:-1], self.n_points, 2)

    def loss(self, out, t):
        return shape_distance(out, self.targets(t))

    def metric(self, out, t):
        return shape_distance(out, self.targets(t))

    def eval_set(self):
        return self._eval

    metric_label = "shape error (best shift, scale, rotation, start)"

    def describe(self, t):
        return "held-out target"

    def shown_target(self, out, t):
        return fit_onto(out, self.targets(t))


def shape_matching(cfg: ShapeMatchingTask, sim) -> ShapeMatching:
    boundary = sim.disc.pore_boundary()
    return ShapeMatching(cfg, boundary, len(boundary[0]))
