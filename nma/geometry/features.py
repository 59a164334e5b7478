"""The narrowest ligament of a design (the material between two boundary curves: pore and pore, or
pore and outer boundary), as a differentiable function of the reference control points: what a
printer or a mould must resolve, measured during training so that a minimum feature size can be
enforced.

Each boundary loop (nma.geometry.outline: the outer boundary, then one loop per pore) is sampled at
fixed parameter values, so every sample is a fixed linear combination of control points, and
consecutive samples make a closed polyline.  The width between two loops is the distance between
their polylines: the least distance from a vertex of one to a segment of the other, which is what
shapely measures on the same polylines (nma.export.fabrication_report).  The search for the closest
vertex-segment pair of each pair of loops runs without gradients; that pair's distance is then
computed again differentiably, so the gradient is that of the exact minimum: it flows to the control
points of the two curves at the ligament (where two pairs of curves tie, jnp.min shares it; within a
pair, a tie is broken by the first vertex found). The training penalty (`Ligaments.penalty`) uses
every vertex's nearest segment of each other loop, so it pushes a too narrow ligament along its
whole length.

Resolution: a polyline's vertices lie on its curve, and a chord over parameter length h of a
quadratic span deviates from the curve by at most h^2 / 8 times C'' 's component normal to the chord
(C'' is constant on a span).  So a measured width is within e_a + e_b of the true distance between
the curves a and b, e a loop's largest such deviation (`Ligaments.resolution`, reported as
min_ligament_resolution): about 0.005 length units on the paper scenes' random designs at 24 samples
per edge.  Straight spans are exact (square pores: so are their corners, which lie at edge joins,
always sampled).  Distances between far-apart parts of one loop are not measured: in the cell scenes
a loop that comes close to itself encloses a narrow slot of void, not a ligament of material.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from .bspline import basis_matrix, span_points, span_widths
from .outline import loop_basis, oriented_loops, spans

# about 0.2 length units apart on a paper cell's side (5 units): see `resolution`
SAMPLES_PER_EDGE = 24
_CHUNK = 256  # vertices searched at once: the search holds (chunk, samples) distances


def _point_segment(p, a, b):
    """Distance from points p (..., 2) to segments a-b (..., 2), differentiable (a segment may be a
    point)."""
    e = b - a
    ee = jnp.sum(e * e, axis=-1)
    t = jnp.clip(jnp.sum((p - a) * e, axis=-1) / jnp.where(ee > 0, ee, 1.0), 0.0, 1.0)
    gap = p - (a + t[..., None] * e)
    d2 = jnp.sum(gap * gap, axis=-1)
    return jnp.sqrt(jnp.where(d2 > 0, d2, 1.0)) * (d2 > 0), a + t[..., None] * e


@dataclass(frozen=True, eq=False)
class Ligaments:
    """The boundary loops of a mesh sampled for the ligament widths; `scale` (mm per unit,
    part.scale) where the scene's units are physical, and `bound` (scene units) where training
    enforces a minimum width (trainer.min_feature / part.scale: nma.train.trainer adds
    feature_penalty x `penalty` to its loss)."""

    # point indices (n_edges, m) per loop, loops[0] the outer boundary
    loops: tuple[np.ndarray, ...]
    grading: float
    per_span: int  # samples per knot span
    bound: float | None = None
    scale: float | None = None

    @classmethod
    def of(
        cls,
        mesh,
        points,
        bound: float | None = None,
        scale: float | None = None,
        per_edge: int = SAMPLES_PER_EDGE,
    ) -> "Ligaments":
        """The loops of `mesh` (oriented at control points `points`), `per_edge` samples per edge or
        more (a whole number per knot span)."""
        loops = tuple(oriented_loops(mesh, np.asarray(points)))
        return cls(
            loops,
            mesh.fidelity.grading,
            max(1, math.ceil(per_edge / spans(loops[0]))),
            bound,
            scale,
        )

    def names(self) -> list[str]:
        return ["outer boundary"] + [f"pore {k}" for k in range(1, len(self.loops))]

    @cached_property
    def _tables(self):
        """Each sample's control points and weights (N, m), its loop (N,) and the next sample of its
        loop."""
        index, weight, loop, after, start = [], [], [], [], 0
        for k, lp in enumerate(self.loops):
            B = loop_basis(lp.shape[1], self.per_span, self.grading)  # (per edge, m)
            n = len(lp) * len(B)
            index.append(np.repeat(lp, len(B), axis=0))
            weight.append(np.tile(B, (len(lp), 1)))
            loop.append(np.full(n, k))
            after.append(start + (np.arange(n) + 1) % n)
            start += n
        return tuple(np.concatenate(a) for a in (index, weight, loop, after))

    @property
    def pairs(self) -> np.ndarray:
        """(n_pairs, 2) the loop pairs measured: every two loops."""
        return np.asarray(np.triu_indices(len(self.loops), k=1)).T.reshape(-1, 2)

    def samples(self, X) -> jnp.ndarray:
        """(N, 2) the polylines' vertices at control points X (n_points, 2), linear in X."""
        index, weight, _, _ = self._tables
        return jnp.einsum("nk,nkd->nd", jnp.asarray(weight), jnp.asarray(X)[index])

    def _nearest(self, P):
        """For each vertex of the polylines P and each loop, the start of the loop's segment nearest
        to it and its distance (inf for the vertex's own loop), found without gradients: two (N,
        n_loops)."""
        _, _, loop, after = self._tables
        n, L, loop = len(loop), len(self.loops), jnp.asarray(loop)
        P = jax.lax.stop_gradient(P)
        pad = -n % _CHUNK
        rows = np.concatenate([np.arange(n), np.zeros(pad, int)]).reshape(-1, _CHUNK)
        real = np.concatenate([np.ones(n, bool), np.zeros(pad, bool)]).reshape(-1, _CHUNK)
        a, b, j = P, P[after], jnp.arange(n)

        def chunk(args):
            i, ok = args
            d, _ = _point_segment(P[i][:, None], a[None], b[None])  # (chunk, N)
            d = jnp.where((loop[i][:, None] != loop[None]) & ok[:, None], d, jnp.inf)
            low = jax.ops.segment_min(d.T, loop, num_segments=L)  # (L, chunk)
            at = jax.ops.segment_min(
                jnp.where(d.T <= low[loop], j[:, None], n), loop, num_segments=L
            )
            return low.T, at.T

        low, seg = jax.lax.map(chunk, (jnp.asarray(rows), jnp.asarray(real)))
        return low.reshape(-1, L)[:n], jnp.clip(seg.reshape(-1, L)[:n], 0, n - 1)

    def _closest(self, P):
        """For each loop pair, its closest (vertex, segment start) of the polylines P: two
        (n_pairs,)."""
        loop = jnp.asarray(self._tables[2])
        n, L = len(loop), len(self.loops)
        low, seg = self._nearest(P)
        # (L from, L to): vertices of one, segments of the other
        best = jax.ops.segment_min(low, loop, num_segments=L)
        vert = jax.ops.segment_min(
            jnp.where(low <= best[loop], jnp.arange(n)[:, None], n), loop, num_segments=L
        )
        p, q = self.pairs.T
        forward = best[p, q] <= best[q, p]
        i = jnp.clip(jnp.where(forward, vert[p, q], vert[q, p]), 0, n - 1)
        return i, seg[i, jnp.where(forward, q, p)]

    @cached_property
    def _search(self):
        return jax.jit(self._closest)

    def pair_widths(self, X) -> jnp.ndarray:
        """(n_pairs,) the width between each two loops (`pairs`), in the scene's units,
        differentiable in X."""
        P = self.samples(X)
        i, s = self._closest(P)
        return _point_segment(P[i], P[s], P[jnp.asarray(self._tables[3])[s]])[0]

    def width(self, X) -> jnp.ndarray:
        """The narrowest ligament of the design at control points X, in the scene's units (inf
        without pores)."""
        return jnp.min(self.pair_widths(X), initial=jnp.inf)

    def penalty(self, X) -> jnp.ndarray:
        """The integral along every boundary curve of (max(0, bound - d) / bound)^2 ds / bound, d
        the distance to each other curve: zero where every ligament holds the bound; it pushes a too
        narrow ligament along its whole length, not at its narrowest point alone, and it is unitless
        (a weight means the same in any scene units and at any sampling)."""
        _, _, loop, after = self._tables
        before = np.argsort(after)
        P = self.samples(X)
        _, seg = self._nearest(P)  # (N, n_loops)
        d = _point_segment(P[:, None], P[seg], P[jnp.asarray(after)[seg]])[0]
        own = loop[:, None] == np.arange(len(self.loops))[None]
        short = jnp.where(own, 0.0, jnp.maximum(self.bound - d, 0.0) / self.bound)
        step = lambda k: jnp.linalg.norm(P[k] - P, axis=-1)
        ds = 0.5 * (step(after) + step(before)) / self.bound  # each vertex's share of its curve
        return jnp.sum(short * short * ds[:, None])

    def resolution(self, X) -> np.ndarray:
        """(n_loops,) each polyline's largest deviation from its curve: over a chord of parameter
        length h, h^2 / 8 times C'' 's component normal to the chord (C'' is constant on a quadratic
        span)."""
        out = []
        for lp in self.loops:
            m, k = lp.shape[1], self.per_span
            # each chord's middle
            mid = span_points(m, (np.arange(k) + 0.5) / k, self.grading).ravel()
            at = lambda order: np.einsum(
                "sk,ekd->esd", basis_matrix(mid, m, order, self.grading), np.asarray(X)[lp]
            )
            d1, d2 = at(1), at(2)
            cross = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
            normal = np.abs(cross) / np.maximum(np.linalg.norm(d1, axis=-1), 1e-300)
            h = np.repeat(span_widths(m, self.grading), k) / k
            out.append(float(np.max(normal * h**2 / 8.0)))
        return np.asarray(out)

    def report(self, X) -> dict:
        """What metrics.json records of the design at control points X: the narrowest ligament
        (scene units; in mm with a scale), between which curves and where, the measure's resolution,
        and with a bound, the loop pairs narrower than it."""
        X = np.asarray(X)
        if len(self.loops) < 2:
            return {"min_ligament": None}
        P = self.samples(X)
        i, s = (np.asarray(v) for v in self._search(P))
        w, foot = (
            np.asarray(v) for v in _point_segment(P[i], P[s], P[jnp.asarray(self._tables[3])[s]])
        )
        k, names, err = int(np.argmin(w)), self.names(), self.resolution(X)
        a, b = self.pairs[k]
        out = {
            "min_ligament": float(w[k]),
            "min_ligament_between": [names[a], names[b]],
            "min_ligament_at": (0.5 * (np.asarray(P[i[k]]) + foot[k])).tolist(),
            "min_ligament_resolution": float(err[a] + err[b]),
        }
        if self.scale is not None:
            out["min_ligament_mm"] = float(w[k]) * self.scale
        if self.bound is not None:
            unit = self.scale or 1.0  # mm where the scale is known (trainer.min_feature needs it)
            out["min_feature"] = self.bound * unit
            out["ligaments_below_min_feature"] = [
                [names[a], names[b], float(w[n]) * unit]
                for n, (a, b) in enumerate(self.pairs)
                if w[n] < self.bound
            ]
        return out
