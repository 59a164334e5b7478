"""The colour display of digital MNIST (nma.tasks.digital_mnist): the colour material points of a
scene, which move with the deformation, and the seven windows fixed in space that read them, each
window's score the mean over its grid of samples of the softmax-weighted colour of the material
there."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.bspline import DESIGN_CTRL, basis_matrix


NEAREST_PATCHES = 6  # patches a window sample reads its colour from (ColourDisplay)
# the most the patches it does not read may weigh, relative to its nearest point
EXCLUDED_WEIGHT = 1e-13


def _padded(rows: list[np.ndarray]) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Index lists of different lengths as one array, padded with index 0, and where each entry is
    real."""
    width = max(len(r) for r in rows)
    return (
        jnp.asarray(np.stack([np.pad(r, (0, width - len(r))) for r in rows])),
        jnp.asarray(np.stack([np.arange(width) < len(r) for r in rows])),
    )


def _box_distance(points, lo, hi) -> jnp.ndarray:
    """Distance from points (..., 2) to the axis-aligned boxes from lo to hi (..., 2); 0 inside."""
    gap = jnp.maximum(jnp.maximum(lo - points, points - hi), 0.0)
    return jnp.sqrt(jnp.sum(gap**2, axis=-1))


def window_points(windows, samples: int) -> np.ndarray:
    """(W, samples^2, 2) grid points of each window [x0, x1, y0, y1], edges included."""
    out = []
    for x0, x1, y0, y1 in windows:
        gx, gy = np.meshgrid(
            np.linspace(x0, x1, samples), np.linspace(y0, y1, samples), indexing="ij"
        )
        out.append(np.stack([gx.ravel(), gy.ravel()], axis=-1))
    return np.asarray(out)


class ColourDisplay:
    """Colour material points of a scene and the seven windows that read them.

    Only material points within `reach` (reference distance) of a window can weigh in its score:
    a window sample always has material within half a sample spacing (the windows lie inside solid
    strips), so at temperature 10 a point 2 units further away weighs less than e^-80 of it, and no
    point moves more than reach / 2 under actuations of at most d_max <= reach / 2.

    A sample's weights, softmax(temperature / distance), fall off so fast that it reads only the
    points of the NEAREST_PATCHES patches nearest it (of its window's candidates, nearest by the
    distance to the box of the patch's deformed control points, which holds all its material: a
    B-spline patch lies in the convex hull of its control points): a tenth of the candidate patches,
    a sixth of the candidate points.  It reads all of those patches' points, also the few beyond
    `reach` that `scores_of` leaves out (which weigh less than e^-80, above).  What the patches left
    out could weigh is bounded by their nearest box; where that exceeds EXCLUDED_WEIGHT of the
    nearest point read, at any sample, the state is read over every candidate point instead
    (`scores_of`)."""

    def __init__(
        self,
        disc,
        windows,
        window_samples: int,
        colour_samples: int,
        temperature: float,
        reach: float,
    ):
        m = disc.mesh.fidelity.ctrl_per_patch
        t = np.linspace(1e-4, 1.0 - 1e-4, colour_samples)
        kron = lambda B: np.einsum("pi,qj->pqij", B, B).reshape(len(t) ** 2, -1)
        # (s^2, m^2)
        self.geometry_basis = jnp.asarray(
            kron(basis_matrix(t, m, grading=disc.mesh.fidelity.grading))
        )
        self.colour_basis = jnp.asarray(kron(basis_matrix(t, DESIGN_CTRL)))  # (s^2, 25)
        self.patch_points = jnp.asarray(disc.mesh.patch_points)
        self.windows = jnp.asarray(window_points(windows, window_samples))  # (W, k, 2)
        self.temperature = temperature
        X0 = np.asarray(self.positions(disc.reference_points(disc.init_params())))
        near = [
            np.flatnonzero(
                np.asarray(_box_distance(X0, np.array([x0, y0]), np.array([x1, y1]))) <= reach
            )
            for x0, x1, y0, y1 in windows
        ]
        self.candidates, self.valid = _padded(near)
        # the same candidates by patch (positions are patch-major, colour_samples^2 points a patch)
        self.n_patches, self.per_patch = int(disc.mesh.patch_points.shape[0]), colour_samples**2
        self.window_patches, self.window_patches_valid = _padded(
            [np.unique(n // self.per_patch) for n in near]
        )

    def positions(self, points) -> jnp.ndarray:
        """(P * s^2, 2) colour material points for control points `points` (X or X + u)."""
        return jnp.einsum("sk,pkd->psd", self.geometry_basis, points[self.patch_points]).reshape(
            -1, 2
        )

    def colours(self, colour_nets) -> jnp.ndarray:
        """(P * s^2,) colour in [0, 1] at the material points."""
        logits = jnp.einsum(
            "sk,pk->ps", self.colour_basis, colour_nets.reshape(colour_nets.shape[0], -1)
        )
        return jax.nn.sigmoid(logits).reshape(-1)

    def scores(self, points, colour_nets) -> jnp.ndarray:
        """(W,) each window's mean softmax-weighted colour, for deformed control points `points`:
        read from each sample's nearest patches where what the others could weigh is below
        EXCLUDED_WEIGHT, else over every candidate point (under vmap both are computed; nma.train
        maps over samples instead). Its gradient is the gradient of the branch read, computed in
        that branch only: reverse-mode through lax.cond carries both branches' residuals, and every
        candidate point's costs several times the nearest read's gradient."""

        def nearest(points, colour_nets):
            return self.scores_nearest(points, self.positions(points), self.colours(colour_nets))

        def every(points, colour_nets):
            return self.scores_of(self.positions(points), self.colours(colour_nets))

        def read(points, colour_nets):
            pos, col = self.positions(points), self.colours(colour_nets)  # shared by both branches
            scores, left_out = self.scores_nearest(points, pos, col)
            near = left_out <= np.log(EXCLUDED_WEIGHT)
            return jax.lax.cond(near, lambda: scores, lambda: self.scores_of(pos, col)), near

        @jax.custom_vjp
        def scores(points, colour_nets):
            return read(points, colour_nets)[0]

        def forward(points, colour_nets):
            out, near = read(points, colour_nets)
            return out, (points, colour_nets, near)

        def backward(saved, bar):
            points, colour_nets, near = saved
            pullback = lambda f: lambda: jax.vjp(f, points, colour_nets)[1](bar)
            return jax.lax.cond(near, pullback(lambda *a: nearest(*a)[0]), pullback(every))

        scores.defvjp(forward, backward)
        return scores(points, colour_nets)

    def scores_nearest(self, points, pos, col) -> tuple[jnp.ndarray, jnp.ndarray]:
        """(W,) window scores read from each sample's NEAREST_PATCHES nearest patches, and the log
        of the most the patches left out could weigh, relative to the nearest point read (the
        largest over samples)."""
        s2 = self.per_patch
        pos, col = pos.reshape(self.n_patches, s2, 2), col.reshape(self.n_patches, s2)
        # which patches are read: no gradient
        ctrl = jax.lax.stop_gradient(points[self.patch_points])
        lo, hi = ctrl.min(axis=1), ctrl.max(axis=1)
        width = self.window_patches.shape[1]
        k = min(NEAREST_PATCHES, width)

        def window(samples, patches, valid):
            # (samples, width): no point of a patch is nearer than its box
            box = jnp.where(
                valid,
                _box_distance(samples[:, None], lo[patches][None], hi[patches][None]),
                jnp.inf,
            )
            neg, order = jax.lax.top_k(-box, width)  # every candidate patch, nearest box first
            read = patches[order[:, :k]]  # (samples, k)
            d = jnp.sqrt(jnp.sum((pos[read] - samples[:, None, None]) ** 2, axis=-1) + 1e-24)
            logits = jnp.where(
                valid[order[:, :k]][..., None], self.temperature / d, -jnp.inf
            ).reshape(len(samples), -1)
            score = jnp.mean(
                jnp.sum(
                    jax.nn.softmax(logits, axis=-1) * col[read].reshape(len(samples), -1), axis=-1
                )
            )
            if k == width:
                return score, -jnp.inf
            # each patch left out: at most s2 points, none nearer than its box
            # padding weighs 0
            beyond = jnp.where(jnp.isfinite(neg[:, k:]), self.temperature / -neg[:, k:], -jnp.inf)
            left_out = jax.nn.logsumexp(beyond, axis=-1) + np.log(s2) - jnp.max(logits, axis=-1)
            return score, jnp.max(left_out)

        scores, left_out = jax.vmap(window)(
            self.windows, self.window_patches, self.window_patches_valid
        )
        return scores, jnp.max(left_out)

    def scores_of(self, pos, col) -> jnp.ndarray:
        """(W,) window scores of material points at `pos` (n, 2) with colours `col` (n,)."""

        def window(samples, idx, valid):
            d = jnp.sqrt(jnp.sum((samples[:, None, :] - pos[idx][None]) ** 2, axis=-1) + 1e-24)
            logits = jnp.where(valid, self.temperature / d, -jnp.inf)
            return jnp.mean(jax.nn.softmax(logits, axis=-1) @ col[idx])

        return jax.vmap(window)(self.windows, self.candidates, self.valid)
