"""Equilibrium as a differentiable function: Newton forward, adjoint backward (custom_vjp).

At the solution the free residual vanishes, R_f(u_f*; X, d, mat) = 0, so for an output cotangent
u_bar the adjoint is  lambda = K_ff^-1 u_bar_f  and  (X, d, mat)_bar = -lambda^T dR_f/d(X, d, mat),
plus the direct term A^T u_bar_D of the points that sit on actuated boundaries.
"""
from __future__ import annotations

import jax

from ..mechanics.energy import force_and_tangents, quadrature
from .newton import Equations, NewtonOptions, newton_solve


def make_equilibrium(eqs: Equations, backend, opts: NewtonOptions):
    """Return equilibrium(X, d, mat) -> (u (n_points, 2), NewtonInfo), differentiable in X, d, mat."""

    def forward(X, d, mat):
        u_free, info = newton_solve(eqs, backend, opts, X, d, mat)
        return eqs.full(u_free, 1.0, eqs.A @ d), info, u_free

    @jax.custom_vjp
    def equilibrium(X, d, mat):
        u, info, _ = forward(X, d, mat)
        return u, info

    def fwd(X, d, mat):
        u, info, u_free = forward(X, d, mat)
        return (u, info), (X, d, mat, u_free, u)

    def bwd(res, cotangents):
        X, d, mat, u_free, u = res
        u_bar = cotangents[0].reshape(-1)
        quad = quadrature(eqs.disc, X)
        _, kel = force_and_tangents(eqs.disc, quad, u, mat)
        adjoint = backend.adjoint_solve(kel, u_bar[eqs.free])

        def residual(X, d, mat):
            return eqs.residual(quadrature(eqs.disc, X), u_free, 1.0, eqs.A @ d, mat)

        _, pullback = jax.vjp(residual, X, d, mat)
        X_bar, d_bar, mat_bar = pullback(-adjoint)
        d_bar = d_bar + eqs.A.T @ u_bar[eqs.dirichlet]
        return X_bar, d_bar, mat_bar

    equilibrium.defvjp(fwd, bwd)
    return equilibrium
