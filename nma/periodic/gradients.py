"""Gradients of a periodic cell's effective response with respect to the design and the material,
by implicit differentiation of its reduced equations at a converged state.

At an equilibrium z* of the reduced equations r(z; X, mat) = dE/dz = 0 (under fixed prescribed
components of F_bar), a quantity q(z*, X, mat) changes with the design parameters theta as
    dq/dtheta = dq/dtheta|_z - lambda^T dr/dtheta|_z,   K lambda = dq/dz,
K the reduced Hessian at z* (the path's own: on a buckled branch, the branch the path chose).  The
design enters through the reference points X(theta) and the affine field's origin.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla

from ..mechanics.energy import quadrature, strain_energy
from .problem import PeriodicProblem

QUANTITIES = ("stress", "free")  # an average stress component; a free component of F_bar


def _quantity(p: PeriodicProblem, kind: str, component: int):
    """q(z, Fp, ctx): the average first Piola-Kirchhoff stress's `component` (0..3), or F_bar's
    `component` where it is free."""
    if kind == "stress":

        def q(z, Fp, ctx):
            def energy(Fv):
                u = p._u_of(z[: p.nw], Fv, ctx)
                return strain_energy(p.solid, quadrature(p.solid, ctx[0]), u, ctx[2])

            return jax.grad(energy)(p.F(z, Fp))[component] / p.cell.area

        return q
    if kind == "free":
        where = np.flatnonzero(p.free == component)
        if not len(where):
            raise ValueError(f"F_bar's component {component} is not free under load {p.load.name}")
        return lambda z, Fp, ctx: z[p.nw + int(where[0])]
    raise ValueError(f"quantity must be one of {list(QUANTITIES)}, got {kind!r}")


def _compile(p: PeriodicProblem, q):
    """q with dq/dz, and the adjoint's total derivative, compiled: they take (params, mat, z, Fp)
    and (params, mat, z, Fp, lambda)."""

    def context(params, mat):
        X = p.cell.disc.reference_points(params)
        return (X, p.cell.pin_position(X), mat)

    def residual(z, Fp, ctx):
        quad = quadrature(p.solid, ctx[0])
        return jax.grad(lambda z: strain_energy(p.solid, quad, p.u(z, Fp, ctx), ctx[2]))(z)

    def total(params, mat, z, Fp, lam):
        ctx = context(params, mat)
        return q(z, Fp, ctx) - jnp.dot(lam, residual(z, Fp, ctx))

    value_and_dz = jax.jit(
        lambda params, mat, z, Fp: jax.value_and_grad(q)(z, Fp, context(params, mat))
    )
    return value_and_dz, jax.jit(jax.grad(total, argnums=(0, 1)))


def response_gradient(p: PeriodicProblem, z, Fp, params, kind: str = "stress", component: int = 0):
    """d q / d (params, mat) at the converged state z (under prescribed components Fp) of the
    problem p built on the design `params` (the cell's reference_points(params)) and its material:
    q the average stress's `component` (kind "stress") or F_bar's free `component` ("free", the
    lateral stretch of a uniaxial load).  Returns (q, d q / d params (a dict like params), d q / d
    mat)."""
    key = ("gradient", kind, component, tuple(p.free.tolist()))
    if key not in p.cell.compiled:
        p.cell.compiled[key] = _compile(p, _quantity(p, kind, component))
    value_and_dz, adjoint = p.cell.compiled[key]
    z, Fp, mat = jnp.asarray(z), jnp.asarray(Fp), p.ctx[2]
    value, dq_dz = value_and_dz(params, mat, z, Fp)
    K = p.linearise(np.asarray(z), np.asarray(Fp))[2]
    lam = jnp.asarray(spla.splu(K.tocsc()).solve(np.asarray(dq_dz)))
    d_params, d_mat = adjoint(params, mat, z, Fp, lam)
    return float(value), d_params, np.asarray(d_mat)


def path_gradient(cell, load, path, k: int, params=None, kind="stress", component=0, mat=None):
    """response_gradient at the path's output point k (nma.periodic.follow's PathResult, followed
    on the design `params` and material `mat`, None: the cell's initial ones)."""
    params = cell.disc.init_params() if params is None else params
    mat = cell.material_params if mat is None else mat
    p = PeriodicProblem(cell, cell.reference_points(params), mat, load)
    return response_gradient(p, path.z[k], load.at(path.t[k]), params, kind, component)
