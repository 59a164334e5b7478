"""The pores' walls, between which self-contact acts (nma.mechanics.contact): the wall segments and
their vertices, the arc lengths along each pore's wall, which vertex faces which chord, point-chord
distances, and the broad phase that visits only the segment pairs whose boxes are near.

Each pore's wall is cut into its quadratic Bezier segments (one per knot span of a boundary edge),
each sampled at `per_span` + 1 vertices; every two segments of the same pore that are not neighbours
are a pair that may touch (a contact block).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..geometry.bspline import basis_matrix, span_points
from .options import ContactSettings


@dataclass(frozen=True, eq=False)
class ContactModel:
    """The static tables of a scene's contact: which control points carry each wall segment, where
    its vertices are, and which segment pairs may touch."""

    settings: ContactSettings
    d_hat: float  # activation distance (length)
    segments: np.ndarray  # (Ns, 3) point index of the 3 control points of each wall segment
    vertex_basis: np.ndarray  # (Ns, k + 1, 3) weights of those points at the segment's vertices
    pairs: np.ndarray  # (Ec, 2) segments that may touch (same pore, not neighbours)
    # (Ns,) the first segment of each segment's pore (segments run along each pore)
    loop_start: np.ndarray
    loop_end: np.ndarray  # (Ns,) one past the last segment of each segment's pore

    @property
    def n_blocks(self) -> int:
        return len(self.pairs)

    @property
    def pores(self) -> int:
        return len(np.unique(self.loop_start))

    @property
    def block_points(self) -> np.ndarray:
        """(Ec, 9) control points of each contact block: the two segments' 6, the last repeated
        (zero rows)."""
        pts = self.segments[self.pairs].reshape(-1, 6)
        return np.concatenate([pts, np.repeat(pts[:, -1:], 3, axis=1)], axis=1)


def build(
    loops: list[np.ndarray], points: np.ndarray, settings: ContactSettings, grading: float = 1.0
) -> ContactModel | None:
    """The contact model of the pore loops (each (n_edges, m) point indices, chained;
    nma.geometry.outline) at the reference control points `points`; None for a scene without pores
    (or with pores too coarse to have a pair of segments that are not neighbours)."""
    if not loops:
        return None
    m = loops[0].shape[1]
    spans, k = m - 2, settings.per_span
    s = np.arange(k + 1) / k
    at = span_points(m, s, grading)
    segments, basis, pairs, start, end = [], [], [], [], []
    for loop in loops:
        first = len(segments)
        for edge in loop:
            for j in range(spans):
                segments.append(edge[j : j + 3])
                basis.append(basis_matrix(at[j], m, grading=grading)[:, j : j + 3])
        n = len(segments) - first
        start += [first] * n
        end += [first + n] * n
        i, j = np.triu_indices(n, 2)
        keep = (j - i) != n - 1  # the loop closes: the last segment neighbours the first
        pairs.append(first + np.stack([i[keep], j[keep]], axis=1))
    pairs = np.concatenate(pairs)
    if not len(pairs):
        return None
    segments, basis, start = np.asarray(segments, np.int64), np.asarray(basis), np.asarray(start)
    walls = np.einsum("svc,scd->svd", basis, points[segments])  # every wall vertex
    extents = [np.ptp(walls[start == a].reshape(-1, 2), axis=0).max() for a in np.unique(start)]
    d_hat = settings.distance * float(np.median(extents))
    model = ContactModel(settings, d_hat, segments, basis, pairs, start, np.asarray(end))
    gap = smallest_gap(model, points, points)
    if gap <= d_hat:
        raise ConfigError(
            f"contact.distance = {settings.distance:g} puts the contact distance at {d_hat:.3g} "
            f"({settings.distance:g} of the median pore's extent), but two walls of a pore face "
            f"each other {gap:.3g} apart at rest; lower contact.distance"
        )
    return model


def smallest_gap(model: ContactModel, x, X) -> float:
    """The smallest distance between a wall vertex and a chord it faces at control points x, the
    walls' arc lengths those of the reference X (the terms of the model; below d_hat the barrier
    acts)."""
    walls = reference_walls(model, jnp.asarray(X))
    own, other = _faces(model, jnp.arange(model.n_blocks))
    v = vertices(model, jnp.asarray(x))
    d2 = _d2_pairs(v[own], v[other], jnp)
    return float(jnp.sqrt(jnp.min(jnp.where(_facing(model, walls, own, other), d2, jnp.inf))))


def vertices(model: ContactModel, x: jnp.ndarray) -> jnp.ndarray:
    """(Ns, k + 1, 2) the wall vertices at control points x (n_points, 2)."""
    return jnp.einsum("svc,scd->svd", jnp.asarray(model.vertex_basis), x[model.segments])


class Walls(NamedTuple):
    """The pores' walls in the reference configuration (of the design being solved)."""

    weights: jnp.ndarray  # (Ns, k + 1) arc length of each vertex (trapezoid rule on the polyline)
    arcs: jnp.ndarray  # (Ns, k + 1) arc-length position of each vertex along its pore's wall
    perimeter: jnp.ndarray  # (Ns,) the length of each segment's pore wall


def reference_walls(model: ContactModel, X: jnp.ndarray) -> Walls:
    """Arc lengths along the pores' walls at the reference control points X."""
    chord = jnp.linalg.norm(jnp.diff(vertices(model, X), axis=1), axis=-1)  # (Ns, k)
    pad = jnp.zeros_like(chord[:, :1])
    weights = 0.5 * (jnp.concatenate([chord, pad], 1) + jnp.concatenate([pad, chord], 1))
    # along all segments
    total = jnp.concatenate([jnp.zeros(1, X.dtype), jnp.cumsum(chord.sum(axis=1))])
    first = total[model.loop_start]
    arcs = (total[:-1] - first)[:, None] + jnp.concatenate([pad, jnp.cumsum(chord, axis=1)], 1)
    return Walls(weights, arcs, total[model.loop_end] - first)


# terms of a vertex and a chord closer than this many d_hat along the wall are left out
EXCLUDED_ARC = 3.0


def _facing(model: ContactModel, walls: Walls, own, other) -> jnp.ndarray:
    """(b, 2, k + 1, k) whether each term's vertex and chord face each other: further apart along
    their wall than EXCLUDED_ARC * d_hat (in the reference).  Closer, they are one piece of wall: on
    a smooth wall their distance is about their arc length, so at rest the barrier would act on a
    wall with nothing touching (segments grow short at fine fidelity and small radii, while d_hat
    stays)."""
    sv = walls.arcs[own][..., :, None]  # (b, 2, k + 1, 1)
    P = walls.perimeter[own][..., None, None]

    def along(c):  # the shorter way round the wall
        gap = jnp.abs(sv - c)
        return jnp.minimum(gap, P - gap)

    ends = walls.arcs[other]
    return (
        jnp.minimum(along(ends[..., None, :-1]), along(ends[..., None, 1:]))
        > EXCLUDED_ARC * model.d_hat
    )


def _point_chord_d2(p, a, b, xp=jnp):
    """Squared distance from points p to chords [a, b] (broadcast)."""
    e = b - a
    t = xp.clip(xp.sum((p - a) * e, -1) / xp.maximum(xp.sum(e * e, -1), 1e-300), 0.0, 1.0)
    r = p - a - t[..., None] * e
    return xp.sum(r * r, -1)


def _d2_pairs(va, vb, xp=np):
    """(..., k + 1, k) squared distances from the vertices of va to the chords of vb (..., k + 1,
    2)."""
    return _point_chord_d2(va[..., :, None, :], vb[..., None, :-1, :], vb[..., None, 1:, :], xp)


# -- broad phase: a block's terms are computed only where its two segments' boxes are near
# ---------------


def _box_gaps(model: ContactModel, v: jnp.ndarray) -> jnp.ndarray:
    """(Ec,) distance between the boxes of each block's two segments' vertices: no vertex of one is
    closer to a chord of the other (chords lie in the box of their ends)."""
    lo, hi = v.min(axis=1), v.max(axis=1)  # (Ns, 2)
    A, B = model.pairs[:, 0], model.pairs[:, 1]
    apart = jnp.maximum(jnp.maximum(lo[B] - hi[A], lo[A] - hi[B]), 0.0)
    return jnp.sqrt(jnp.sum(apart * apart, -1))


# blocks per chunk of the broad phase's loop: the work grows with the near blocks only
NEAR_CHUNK = 32


def _over_near(model: ContactModel, near: jnp.ndarray, step, init):
    """Fold step(acc, blocks) over the blocks where `near` holds, a fixed-size chunk of block
    indices at a time (padded with -1, which step must ignore): a jitted program needs fixed shapes,
    and the near blocks are few while the pores are open (none: no work).  Forward only (not
    differentiated)."""
    n = model.n_blocks
    size = min(n, NEAR_CHUNK)
    chunks = -(-n // size)
    idx = jnp.nonzero(near, size=chunks * size, fill_value=-1)[0]
    count = -(-jnp.sum(near) // size)
    return jax.lax.fori_loop(
        0, count, lambda i, acc: step(acc, jax.lax.dynamic_slice(idx, (i * size,), (size,))), init
    )


def _faces(model: ContactModel, blocks):
    """Each gathered block's two sides: the segments whose vertices (own) face the chords
    (other)."""
    pairs = jnp.asarray(model.pairs)[jnp.maximum(blocks, 0)]  # (b, 2)
    return pairs, jnp.flip(pairs, -1)
