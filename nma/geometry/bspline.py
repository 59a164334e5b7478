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
    """Bezier-element tables of one patch: every knot span is an element with 9 basis functions.

    Returns (local_index, values, grads, weights):
      local_index (S*S, 9)   patch-local control point index i * n_ctrl + j of each element function
      values      (S*S, Q, 9)   N at the Q = quad^2 Gauss points of each element
      grads       (S*S, Q, 9, 2) dN/dxi, dN/deta (parametric, patch coordinates in [0, 1]^2)
      weights     (S*S, Q)   Gauss weights times the span area
    """
    spans = n_ctrl - DEGREE
    h = 1.0 / spans
    gx, gw = gauss_legendre_01(quad)
    local, vals, grads, wts = [], [], [], []
    for si in range(spans):
        xi = (si + gx) * h
        Bx, dBx = basis_matrix(xi, n_ctrl)[:, si:si + 3], basis_matrix(xi, n_ctrl, 1)[:, si:si + 3]
        for sj in range(spans):
            eta = (sj + gx) * h
            By, dBy = basis_matrix(eta, n_ctrl)[:, sj:sj + 3], basis_matrix(eta, n_ctrl, 1)[:, sj:sj + 3]
            # quadrature point (p, q) -> row p * quad + q ; function (a, b) -> column a * 3 + b
            v = np.einsum("pa,qb->pqab", Bx, By).reshape(quad * quad, 9)
            dxi = np.einsum("pa,qb->pqab", dBx, By).reshape(quad * quad, 9)
            deta = np.einsum("pa,qb->pqab", Bx, dBy).reshape(quad * quad, 9)
            local.append([(si + a) * n_ctrl + (sj + b) for a in range(3) for b in range(3)])
            vals.append(v)
            grads.append(np.stack([dxi, deta], axis=-1))
            wts.append(np.outer(gw, gw).reshape(-1) * h * h)
    return (np.array(local), np.array(vals), np.array(grads), np.array(wts))
