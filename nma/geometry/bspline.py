"""Quadratic B-spline bases on open-uniform knot vectors, sampled once per discretisation.

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


def open_uniform_knots(n_ctrl: int, degree: int = DEGREE) -> np.ndarray:
    spans = n_ctrl - degree
    inner = np.linspace(0.0, 1.0, spans + 1)
    return np.concatenate([np.zeros(degree), inner, np.ones(degree)])


def basis_matrix(x: np.ndarray, n_ctrl: int, derivative: int = 0) -> np.ndarray:
    """B[k, i] = N_i^(derivative)(x_k) for the open-uniform quadratic basis with n_ctrl functions."""
    spline = BSpline(open_uniform_knots(n_ctrl), np.eye(n_ctrl), DEGREE, extrapolate=False)
    if derivative:
        spline = spline.derivative(derivative)
    out = spline(np.clip(np.asarray(x, float), 0.0, 1.0 - 1e-14))
    return np.nan_to_num(out)


def greville(n_ctrl: int) -> np.ndarray:
    t = open_uniform_knots(n_ctrl)
    return np.array([t[i + 1:i + 1 + DEGREE].mean() for i in range(n_ctrl)])


def refinement_operator(n_ctrl: int) -> np.ndarray:
    """R (n_ctrl, 5): h-refinement (knot insertion) of the 5-point design net, exact for any net.

    The design space is a subspace of the analysis space because the analysis knots nest the design
    knots, so solving B_fine R = B_coarse at n_ctrl distinct points gives the exact operator."""
    x = greville(n_ctrl)
    fine = basis_matrix(x, n_ctrl)
    coarse = basis_matrix(x, DESIGN_CTRL)
    R = np.linalg.solve(fine, coarse)
    R[np.abs(R) < 1e-14] = 0.0
    return R


def gauss_legendre_01(n: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


@lru_cache(maxsize=None)
def element_tables(n_ctrl: int, quad: int):
    """Bezier-element tables of one patch at the quad x quad Gauss points of each knot span: every span
    is an element with 9 basis functions.

    Returns (local_index, values, grads, weights):
      local_index (S*S, 9)   patch-local control point index i * n_ctrl + j of each element function
      values      (S*S, Q, 9)   N at the Q = quad^2 Gauss points of each element
      grads       (S*S, Q, 9, 2) dN/dxi, dN/deta (parametric, patch coordinates in [0, 1]^2)
      weights     (S*S, Q)   Gauss weights times the span area
    """
    return _tables(n_ctrl, *gauss_legendre_01(quad))


CHECK_POINTS = np.linspace(0.0, 1.0, 4)  # per span and direction: where det F of a quadratic map is a
# polynomial of bidegree (3, 3) determined by its values (nma/geometry/validity.py), corners included


@lru_cache(maxsize=None)
def check_tables(n_ctrl: int):
    """element_tables at the 4 x 4 CHECK_POINTS of each element, each weighted by a 16th of its span area."""
    return _tables(n_ctrl, CHECK_POINTS, np.full(len(CHECK_POINTS), 1.0 / len(CHECK_POINTS)))


def _tables(n_ctrl: int, points: np.ndarray, point_weights: np.ndarray):
    """The tables of element_tables at the tensor grid of 1D `points` in [0, 1] of each span."""
    spans = n_ctrl - DEGREE
    h = 1.0 / spans
    k = len(points)
    local, vals, grads, wts = [], [], [], []
    for si in range(spans):
        xi = (si + points) * h
        Bx, dBx = basis_matrix(xi, n_ctrl)[:, si:si + 3], basis_matrix(xi, n_ctrl, 1)[:, si:si + 3]
        for sj in range(spans):
            eta = (sj + points) * h
            By, dBy = basis_matrix(eta, n_ctrl)[:, sj:sj + 3], basis_matrix(eta, n_ctrl, 1)[:, sj:sj + 3]
            # point (p, q) -> row p * k + q ; function (a, b) -> column a * 3 + b
            v = np.einsum("pa,qb->pqab", Bx, By).reshape(k * k, 9)
            dxi = np.einsum("pa,qb->pqab", dBx, By).reshape(k * k, 9)
            deta = np.einsum("pa,qb->pqab", Bx, dBy).reshape(k * k, 9)
            local.append([(si + a) * n_ctrl + (sj + b) for a in range(3) for b in range(3)])
            vals.append(v)
            grads.append(np.stack([dxi, deta], axis=-1))
            wts.append(np.outer(point_weights, point_weights).reshape(-1) * h * h)
    return (np.array(local), np.array(vals), np.array(grads), np.array(wts))
