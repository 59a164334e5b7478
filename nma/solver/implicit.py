"""Equilibrium as a differentiable function: Newton forward, adjoint backward (custom_vjp).

At the solution the free residual vanishes, R_f(u_f*; X, d, mat) = 0, so for a cotangent u_bar_f of
the free displacements the adjoint is  lambda = K_ff^-1 u_bar_f  and
(X, d, mat)_bar = -lambda^T dR_f/d(X, d, mat); the Dirichlet part of u (A d) is differentiated by
JAX.

Two drivers of the same Newton iteration (nma.solver.newton):
- traced (a traceable backend, `dense`): one `lax.while_loop`; a batch runs in lockstep under vmap.
- host (SuperLU, PARDISO): the loop runs in Python around jitted halves of an iteration
  (nma.solver.host), a batch's samples on a thread pool (nma.solver.batch); inside a traced program
  it is one `pure_callback` per batch.  Saddles (nma.solver.saddles) and warm starts
  (nma.solver.warm) are the host driver's.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from .batch import HostBatches
from .equations import Equations, compiled, pullback, tangents_at
from .host import HostNewton
from .newton import newton_solve, result
from .options import NewtonOptions
from .starts import setup
from .status import Equilibrium, Status


def make_equilibrium(eqs: Equations, backend, opts: NewtonOptions, workers: int = 0):
    """Return (equilibrium, warm starts): equilibrium(X, d, mat) -> Equilibrium (u (n_points, 2),
    NewtonInfo), differentiable in X, d, mat; the WarmStarts it keeps (None where it keeps none:
    warm starts off, or a traced backend, whose batch runs in lockstep from rest)."""
    warm = None
    # one program where a caller does not trace it (an eager call's ops compile one program each)
    state = compiled(eqs, ("state",), lambda: jax.jit(partial(_state, eqs)))
    if backend.traceable:
        solve_free = _traced_solve(eqs, backend, opts)
    else:
        batches = HostBatches(HostNewton(eqs, backend, opts), workers)
        solve_free, warm = _host_solve(batches), batches.warm

    def equilibrium(X, d, mat):
        u_free, info = solve_free(X, d, mat)
        return Equilibrium(state(u_free, info, d), info)

    return equilibrium, warm


def _state(eqs: Equations, u_free, info, d):
    """Every control point's displacement (n_points, 2) of a solve's free dofs.  A failed solve's
    state is at the load it reached (a failed solve is a cold one: its load path scales the
    prescribed displacements from zero); where nothing was solved (load 0) it is rest, whatever d
    holds (a non-finite d)."""
    reached = jnp.where(info.status == Status.CONVERGED, 1.0, info.load)
    return eqs.full(u_free, eqs.A @ jnp.where(reached > 0, reached * d, 0.0))


def _traced_solve(eqs, backend, opts):
    @jax.custom_vjp
    def solve_free(X, d, mat):
        return newton_solve(eqs, backend, opts, X, d, mat)

    def fwd(X, d, mat):
        u_free, info = newton_solve(eqs, backend, opts, X, d, mat)
        return (u_free, info), (X, d, mat, u_free)

    def bwd(res, cotangents):
        X, d, mat, u_free = res
        adjoint = backend.adjoint_solve(tangents_at(eqs, X, d, mat, u_free), cotangents[0])
        # nothing flows back (a failed sample a loss masks out): zero, not a singular tangent's NaN
        adjoint = jnp.where(jnp.any(cotangents[0] != 0), adjoint, jnp.zeros_like(adjoint))
        return pullback(eqs, X, d, mat, u_free, adjoint)

    solve_free.defvjp(fwd, bwd)
    return solve_free


def _host_solve(batches: HostBatches):
    eqs, opts = batches.newton.eqs, batches.newton.opts

    def call(X, d, mat, keep):
        solved = jax.eval_shape(lambda X, d, mat: result(setup(eqs, opts, X, d, mat)[1]), X, d, mat)
        shapes = (*solved, jax.ShapeDtypeStruct((), jnp.int64))  # u_free, info, workspace token
        return jax.pure_callback(
            partial(batches.forward_batch, keep=keep),
            shapes,
            X,
            d,
            mat,
            vmap_method="broadcast_all",
        )

    @jax.custom_vjp
    def solve_free(X, d, mat):
        u_free, info, _ = call(X, d, mat, False)
        return u_free, info

    def fwd(X, d, mat):
        u_free, info, token = call(X, d, mat, True)
        return (u_free, info), (X, d, mat, u_free, token)

    def bwd(res, cotangents):
        X, d, mat, u_free, token = res
        out = (
            jax.ShapeDtypeStruct(X.shape, X.dtype),
            jax.ShapeDtypeStruct(d.shape, d.dtype),
            jax.ShapeDtypeStruct(mat.shape, mat.dtype),
        )
        return jax.pure_callback(
            batches.backward_batch,
            out,
            X,
            d,
            mat,
            u_free,
            cotangents[0],
            token,
            vmap_method="broadcast_all",
        )

    solve_free.defvjp(fwd, bwd)
    return solve_free
