"""Quadratic B-spline bases on open knot vectors, uniform or graded, sampled once per
discretisation.

Everything here is plain numpy: the tables are constants of a scene's discretisation, computed
once and closed over by the jitted mechanics.  scipy's BSpline evaluates the basis (no
hand-written Cox-de Boor recursion).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.interpolate import BSpline


DEGREE = 2
DESIGN_CTRL = 5  # the design net of every patch: 5 x 5 control points, 3 x 3 knot spans


@lru_cache(maxsize=None)
def span_breaks(n_ctrl: int, grading: float = 1.0) -> np.ndarray:
    """The distinct knots 0 = b_0 < ... < b_S = 1 of a patch side with n_ctrl control points (S =
    n_ctrl - 2 knot spans).  grading 1: uniform.  grading g > 1 (n_ctrl = 3k + 2): the design knots
    1/3 and 2/3 stay, the middle third keeps its k uniform spans, and in the outer thirds the knots
    go as (i / k)^g from the patch's ends, so elements shrink towards every patch corner (where the
    ends of supports and actuated segments sit, the stress singularities that a uniform mesh
    resolves at a low order) and are symmetric, so that patches of either orientation still meet
    knot to knot."""
    spans = n_ctrl - DEGREE
    if grading == 1.0:
        return _frozen(np.linspace(0.0, 1.0, spans + 1))
    if spans % 3:
        raise ValueError(
            f"graded knots need 3k + 2 control points (one knot per design span), got {n_ctrl}"
        )
    k = spans // 3
    outer = (np.arange(k + 1) / k) ** grading / 3.0  # 0 .. 1/3, finest at 0
    middle = 1.0 / 3.0 + np.arange(1, k) / (3.0 * k)
    return _frozen(np.concatenate([outer, middle, 1.0 - outer[::-1]]))


def _frozen(a: np.ndarray) -> np.ndarray:
    """A cached table, read-only so that no caller changes it for the next."""
    a.setflags(write=False)
    return a


def knot_vector(n_ctrl: int, grading: float = 1.0) -> np.ndarray:
    """The open knot vector (n_ctrl + 3,): span_breaks with the end knots repeated."""
    return np.concatenate([np.zeros(DEGREE), span_breaks(n_ctrl, grading), np.ones(DEGREE)])


def span_widths(n_ctrl: int, grading: float = 1.0) -> np.ndarray:
    """(S,) the knot spans' lengths in patch coordinates."""
    if grading == 1.0:
        return np.full(n_ctrl - DEGREE, 1.0 / (n_ctrl - DEGREE))
    return np.diff(span_breaks(n_ctrl, grading))


def span_points(n_ctrl: int, local, grading: float = 1.0) -> np.ndarray:
    """(S, len(local)) patch coordinates of the points at `local` in [0, 1] of each knot span
    (uniform knots: (span + local) / S, the arithmetic every table used before grading existed)."""
    local = np.asarray(local, float)[None, :]
    if grading == 1.0:
        return (np.arange(n_ctrl - DEGREE)[:, None] + local) / (n_ctrl - DEGREE)
    return span_breaks(n_ctrl, grading)[:-1, None] + local * span_widths(n_ctrl, grading)[:, None]


def span_weights(n_ctrl: int, weights, grading: float = 1.0) -> np.ndarray:
    """(S * len(weights),) 1D quadrature weights on [0, 1] scaled to each knot span, span-major."""
    weights = np.asarray(weights, float)
    if grading == 1.0:
        return np.tile(weights, n_ctrl - DEGREE) / (n_ctrl - DEGREE)
    return (weights[None, :] * span_widths(n_ctrl, grading)[:, None]).ravel()


def basis_matrix(
    x: np.ndarray, n_ctrl: int, derivative: int = 0, grading: float = 1.0
) -> np.ndarray:
    """B[k, i] = N_i^(derivative)(x_k) for the open quadratic basis with n_ctrl functions (knots:
    span_breaks)."""
    spline = BSpline(knot_vector(n_ctrl, grading), np.eye(n_ctrl), DEGREE, extrapolate=False)
    if derivative:
        spline = spline.derivative(derivative)
    out = spline(np.clip(np.asarray(x, float), 0.0, 1.0 - 1e-14))
    return np.nan_to_num(out)


def greville(n_ctrl: int, grading: float = 1.0) -> np.ndarray:
    t = knot_vector(n_ctrl, grading)
    return np.array([t[i + 1 : i + 1 + DEGREE].mean() for i in range(n_ctrl)])


@lru_cache(maxsize=None)
def refinement_operator(n_ctrl: int, grading: float = 1.0) -> np.ndarray:
    """R (n_ctrl, 5): h-refinement (knot insertion) of the 5-point design net, exact for any net.

    The design space is a subspace of the analysis space because the analysis knots nest the design
    knots (1/3 and 2/3 are knots at every grading), so solving B_fine R = B_coarse at n_ctrl
    distinct points gives the exact operator."""
    x = greville(n_ctrl, grading)
    fine = basis_matrix(x, n_ctrl, grading=grading)
    coarse = basis_matrix(x, DESIGN_CTRL)
    R = np.linalg.solve(fine, coarse)
    R[np.abs(R) < 1e-14] = 0.0
    return _frozen(R)


def gauss_legendre_01(n: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


@lru_cache(maxsize=None)
def element_tables(n_ctrl: int, quad: int, grading: float = 1.0):
    """Bezier-element tables of one patch at the quad x quad Gauss points of each knot span: every
    span is an element with 9 basis functions.

    Returns (local_index, values, grads, weights):
      local_index (S*S, 9)   patch-local control point index i * n_ctrl + j of each element function
      values      (S*S, Q, 9)   N at the Q = quad^2 Gauss points of each element
      grads       (S*S, Q, 9, 2) dN/dxi, dN/deta (parametric, patch coordinates in [0, 1]^2)
      weights     (S*S, Q)   Gauss weights times the span area
    """
    return _tables(n_ctrl, grading, *gauss_legendre_01(quad))


# per span and direction: where det F of a quadratic map is a polynomial of bidegree (3, 3)
# determined by its values (nma/geometry/validity.py), corners included
CHECK_POINTS = np.linspace(0.0, 1.0, 4)


@lru_cache(maxsize=None)
def check_tables(n_ctrl: int, grading: float = 1.0):
    """element_tables at the 4 x 4 CHECK_POINTS of each element, each weighted by a 16th of its span
    area."""
    return _tables(
        n_ctrl, grading, CHECK_POINTS, np.full(len(CHECK_POINTS), 1.0 / len(CHECK_POINTS))
    )


def _tables(n_ctrl: int, grading: float, points: np.ndarray, point_weights: np.ndarray):
    """The tables of element_tables at the tensor grid of 1D `points` in [0, 1] of each span."""
    spans = n_ctrl - DEGREE
    h = span_widths(n_ctrl, grading)
    # uniform: (span + point) * h, bit for bit the tables before grading existed
    at = (
        (np.arange(spans)[:, None] + points[None, :]) * h[0]
        if grading == 1.0
        else span_points(n_ctrl, points, grading)
    )
    k = len(points)
    basis = lambda x, d=0: basis_matrix(x, n_ctrl, d, grading)
    local, vals, grads, wts = [], [], [], []
    for si in range(spans):
        xi = at[si]
        Bx, dBx = basis(xi)[:, si : si + 3], basis(xi, 1)[:, si : si + 3]
        for sj in range(spans):
            eta = at[sj]
            By, dBy = basis(eta)[:, sj : sj + 3], basis(eta, 1)[:, sj : sj + 3]
            # point (p, q) -> row p * k + q ; function (a, b) -> column a * 3 + b
            v = np.einsum("pa,qb->pqab", Bx, By).reshape(k * k, 9)
            dxi = np.einsum("pa,qb->pqab", dBx, By).reshape(k * k, 9)
            deta = np.einsum("pa,qb->pqab", Bx, dBy).reshape(k * k, 9)
            local.append([(si + a) * n_ctrl + (sj + b) for a in range(3) for b in range(3)])
            vals.append(v)
            grads.append(np.stack([dxi, deta], axis=-1))
            wts.append(np.outer(point_weights, point_weights).reshape(-1) * h[si] * h[sj])
    return (np.array(local), np.array(vals), np.array(grads), np.array(wts))
