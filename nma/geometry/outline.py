"""The material's boundary as closed curves, for fabrication (nma.export) and for what a maker
checks.

A scene is a union of m x m quadratic B-spline patches (m = 5: the design nets; any m: an analysis
discretisation, reference or deformed); an edge that belongs to one patch only lies on the boundary.
Chained at their end points, the boundary edges form closed loops: the outer boundary and one loop
per pore.  Each edge is a quadratic B-spline on m - 2 spans (open knots, uniform or graded: the
discretisation's `fidelity.grading`), so a loop is exactly one quadratic B-spline with double knots
where edges join (C0 there), and every span is exactly one quadratic Bezier segment.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import TYPE_CHECKING

import numpy as np

from .bspline import basis_matrix, gauss_legendre_01, span_breaks, span_points, span_weights

if TYPE_CHECKING:
    from .mesh import Mesh


def spans(loop: np.ndarray) -> int:
    """Knot spans per edge of a loop (n_edges, m, 2): m - 2."""
    return loop.shape[1] - 2


def boundary_edges(mesh: Mesh) -> list[np.ndarray]:
    """Point indices (m,) of each boundary edge, running counter-clockwise around its own patch."""
    m = mesh.fidelity.ctrl_per_patch
    grid = mesh.patch_points.reshape(-1, m, m)  # [patch, i along s, j along t]
    # bottom, right, top, left
    sides = [grid[:, :, 0], grid[:, -1, :], grid[:, ::-1, -1], grid[:, 0, ::-1]]
    count: dict[tuple, list] = {}
    for side in sides:
        for edge in side:
            if len(set(edge.tolist())) == 1:
                continue  # collapsed to a point
            key = min(tuple(edge), tuple(edge[::-1]))
            count.setdefault(key, []).append(edge)
    return [found[0] for found in count.values() if len(found) == 1]


def chain(edges: list[np.ndarray]) -> list[list[np.ndarray]]:
    """The boundary edges grouped into closed loops, each edge oriented to follow the one before."""
    at: dict[int, list[int]] = {}
    for k, e in enumerate(edges):
        for end in (e[0], e[-1]):
            at.setdefault(int(end), []).append(k)
    if any(len(v) != 2 for v in at.values()):
        bad = [p for p, v in at.items() if len(v) != 2]
        raise ValueError(
            f"the boundary is not a set of simple closed curves (points {bad[:5]} join "
            f"{[len(at[p]) for p in bad[:5]]} boundary edges)"
        )
    unused, loops = set(range(len(edges))), []
    while unused:
        k = min(unused)
        unused.remove(k)
        loop = [edges[k]]
        while True:
            end = int(loop[-1][-1])
            nxt = [j for j in at[end] if j in unused]
            if not nxt:
                break
            j = nxt[0]
            unused.remove(j)
            loop.append(edges[j] if edges[j][0] == end else edges[j][::-1])
        if loop[-1][-1] != loop[0][0]:
            raise ValueError("a boundary loop does not close")
        loops.append(loop)
    return loops


@dataclass(frozen=True)
class Outline:
    """Closed boundary loops of a design, each (n_edges, m, 2) edge control polygons, chained.
    loops[0] is the outer boundary (counter-clockwise); the others are pores (clockwise).
    `grading`: the edges' knots (bspline.span_breaks)."""

    loops: tuple[np.ndarray, ...]
    grading: float = 1.0

    @classmethod
    def of(cls, mesh: Mesh, points) -> "Outline":
        """The outline of the control points `points` (n_points, 2) of `mesh`."""
        return cls.deformed(oriented_loops(mesh, points), points, mesh.fidelity.grading)

    @classmethod
    def deformed(cls, loops: list[np.ndarray], points, grading: float = 1.0) -> "Outline":
        """The outline at control points `points` (a deformed state) of loops of point indices that
        `oriented_loops` ordered and oriented on the reference: the outer boundary stays loops[0]
        and a pore stays a pore even where the deformation turned it inside out."""
        points = np.asarray(points, float)
        return cls(tuple(points[loop] for loop in loops), grading)

    def scaled(self, factor: float) -> "Outline":
        return Outline(tuple(lp * factor for lp in self.loops), self.grading)

    @property
    def outer(self) -> np.ndarray:
        return self.loops[0]

    @property
    def pores(self) -> tuple[np.ndarray, ...]:
        return self.loops[1:]

    def polylines(self, per_span: int = 16) -> list[np.ndarray]:
        """Each loop through `per_span` points per knot span (its edges' joins once)."""
        return [sample_loop(lp, per_span, self.grading) for lp in self.loops]

    def polygon(self, per_span: int = 16):
        """A shapely Polygon (outer boundary with the pores as holes) through `per_span` points per
        span."""
        from shapely.geometry import Polygon

        lines = self.polylines(per_span)
        return Polygon(lines[0], holes=lines[1:])

    def enclosed_areas(self) -> np.ndarray:
        """Signed area inside each loop, exactly (Green's theorem; the integrand is a cubic per
        span)."""
        return np.asarray([float(enclosed_area(loop, self.grading)) for loop in self.loops])

    @property
    def area(self) -> float:
        """The material's area: the outer boundary's minus the pores' (exact)."""
        return float(np.sum(self.enclosed_areas()))

    @cached_property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax): the control polygons' box, which holds every curve."""
        pts = np.concatenate([lp.reshape(-1, 2) for lp in self.loops])
        return (*pts.min(axis=0), *pts.max(axis=0))


def oriented_loops(mesh: Mesh, points) -> list[np.ndarray]:
    """The boundary loops as point indices (n_edges, m), the outer boundary first and
    counter-clockwise, the pores clockwise (the material on the left), at control points `points`
    (the reference)."""
    points = np.asarray(points, float)
    loops = [np.stack(loop) for loop in chain(boundary_edges(mesh))]
    areas = np.asarray(
        [float(enclosed_area(points[loop], mesh.fidelity.grading)) for loop in loops]
    )
    outer = int(np.argmax(np.abs(areas)))
    order = [outer] + [k for k in range(len(loops)) if k != outer]
    oriented = []
    for k in order:
        ccw = areas[k] > 0
        keep = ccw if k == outer else not ccw
        oriented.append(loops[k] if keep else loops[k][::-1, ::-1])
    return oriented


@lru_cache(maxsize=None)
def _area_tables(m: int, grading: float = 1.0):
    """Basis, derivative and weights at 2 Gauss points per span of an edge with m control points."""
    g, w = gauss_legendre_01(2)
    t = span_points(m, g, grading).ravel()
    return (
        basis_matrix(t, m, grading=grading),
        basis_matrix(t, m, 1, grading),
        span_weights(m, w, grading),
    )


@lru_cache(maxsize=None)
def loop_basis(m: int, per_span: int, grading: float = 1.0) -> np.ndarray:
    """B-spline values (n_spans * per_span, m) at `per_span` even steps through each knot span of an
    edge with m control points, the end excluded (it is the next edge's start)."""
    n = m - 2
    if grading == 1.0:
        return basis_matrix(np.arange(n * per_span) / (n * per_span), m)
    return basis_matrix(
        span_points(m, np.arange(per_span) / per_span, grading).ravel(), m, grading=grading
    )


def enclosed_area(loop: np.ndarray, grading: float = 1.0):
    """Signed area inside a loop (..., n_edges, m, 2), exactly (Green's theorem; a cubic per
    span)."""
    B, dB, w = _area_tables(loop.shape[-2], grading)
    x, dx = np.einsum("nk,...ekd->...end", B, loop), np.einsum("nk,...ekd->...end", dB, loop)
    return 0.5 * np.sum((x[..., 0] * dx[..., 1] - x[..., 1] * dx[..., 0]) * w, axis=(-2, -1))


def sample_loop(loop: np.ndarray, per_span: int, grading: float = 1.0) -> np.ndarray:
    """Points along a loop (..., n_edges, m, 2), `per_span` per knot span, each join once:
    (..., n_edges * spans * per_span, 2)."""
    points = np.einsum("nk,...ekd->...end", loop_basis(loop.shape[-2], per_span, grading), loop)
    return points.reshape(*loop.shape[:-3], -1, 2)


def bezier_segments(loop: np.ndarray, grading: float = 1.0) -> np.ndarray:
    """The loop as quadratic Bezier segments (n_edges * spans, 3, 2), exactly: per span [a, b] the
    end points C(a), C(b) and the control point 2 C(mid) - (C(a) + C(b)) / 2."""
    n, m = spans(loop), loop.shape[1]
    if grading == 1.0:
        a = np.arange(n) / n
        t = np.stack([a, a + 0.5 / n, a + 1.0 / n], axis=1).ravel()
    else:
        t = span_points(m, [0.0, 0.5, 1.0], grading).ravel()
    C = np.einsum("nk,ekd->end", basis_matrix(t, m, grading=grading), loop).reshape(
        len(loop), n, 3, 2
    )
    ends = C[:, :, [0, 2]]
    ctrl = 2.0 * C[:, :, 1] - 0.5 * (ends[:, :, 0] + ends[:, :, 1])
    return np.stack([ends[:, :, 0], ctrl, ends[:, :, 1]], axis=2).reshape(-1, 3, 2)


def loop_spline(loop: np.ndarray, grading: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """One quadratic B-spline through the whole loop: control points ((m - 1) n + 1, 2) and knots
    ((m - 1) n + 4,), with double knots where edges join, so that it equals the edges exactly."""
    n, per = len(loop), spans(loop)
    ctrl = np.concatenate([loop[0]] + [e[1:] for e in loop[1:]])
    breaks = span_breaks(loop.shape[1], grading)
    inner = [
        k + (s / per if grading == 1.0 else breaks[s]) for k in range(n) for s in range(1, per)
    ]
    joins = [float(k) for k in range(1, n) for _ in range(2)]
    knots = np.sort(np.concatenate([[0.0] * 3, inner, joins, [float(n)] * 3]))
    return ctrl, knots
