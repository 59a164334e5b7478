"""A periodic cell's effective response as a JAX function of its reference control points, for
training inside jit: `Response(cell, load, steps)(X)` follows the load path of every design of a
batch on the host (nma.periodic.follow, through the bifurcation onto the buckled branch) and returns
the lateral stretch at the path's end, differentiable in X by implicit differentiation at that
state (one adjoint solve, nma.periodic.gradients), with what the path went through.

A path that could not be completed (or whose reduced Hessian is singular at its end) returns its
status as failed and no gradient: the trainer leaves it out of the mean and scores it as a failure.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla

from ..mechanics.energy import quadrature, strain_energy
from ..solver.status import Status
from .cell import PeriodicCell
from .load import MacroLoad
from .path import follow
from .problem import PeriodicProblem


class PathOutput(NamedTuple):
    """A batch's load paths (leading axis: the sample; S the path's output points).

    lateral: (n,) F_bar's lateral stretch at the path's end (differentiable in X).
    strain: (n, S) the nominal axial strain at each output point; poisson: (n, S) the secant
    Poisson's ratio; stress: (n, S) the average nominal stress along the load; valid: (n, S) 1.0
    where the state passed nma.geometry.validity's checks; u: (n, S, n_points, 2) the states;
    status: (n,) a Status as a float (CONVERGED: the whole path); critical: (n,) the strain of the
    bifurcation crossed (NaN: none).

    Only `lateral` carries a gradient: a loss that differentiates strain, poisson, stress, u or
    critical is refused in the backward pass (nma.periodic.gradients.path_gradient differentiates
    a path's stress at any of its points).
    """

    lateral: jnp.ndarray
    strain: jnp.ndarray
    poisson: jnp.ndarray
    stress: jnp.ndarray
    valid: jnp.ndarray
    u: jnp.ndarray
    status: jnp.ndarray
    critical: jnp.ndarray


# outputs a loss may read but not differentiate (their cotangents have no adjoint here)
UNDIFFERENTIATED = ("strain", "poisson", "stress", "u", "critical")


def _refuse_untracked(cotangents: dict) -> None:
    """ValueError naming the first output of UNDIFFERENTIATED whose cotangent is not zero: a
    gradient through it would be silently zero."""
    for name, c in cotangents.items():
        if np.any(np.asarray(c) != 0):
            raise ValueError(
                f"PathOutput.{name} carries no gradient (only lateral does): differentiate a "
                "path's stress with nma.periodic.gradients.path_gradient"
            )


class Response:
    """The response function of one cell under one load, its compiled adjoints kept."""

    def __init__(self, cell: PeriodicCell, load: MacroLoad, steps: int, mat=None):
        if load.lateral is None:
            raise ValueError(f"load {load.name} has no free lateral stretch")
        self.cell, self.load, self.steps = cell, load, int(steps)
        self.mat = np.asarray(cell.material_params if mat is None else mat, float)
        X0 = cell.reference_points()
        self.n_points = int(X0.shape[0])
        self.nz = int(PeriodicProblem(cell, X0, self.mat, load).nz)  # the reduced unknowns
        self._adjoint = None
        self.fn = self._build()

    def __call__(self, X) -> PathOutput:
        return self.fn(X)

    # -- the host side -------------------------------------------------------------------------
    def paths(self, X):
        """Follow the path of each design X[i] (n, n_points, 2); (PathOutput as numpy, the final
        reduced states (n, nz))."""
        X = np.asarray(X, float)
        n, S = X.shape[0], self.steps
        out = {
            "lateral": np.ones(n),
            "strain": np.full((n, S), np.nan),
            "poisson": np.full((n, S), np.nan),
            "stress": np.full((n, S), np.nan),
            "valid": np.zeros((n, S)),
            "u": np.zeros((n, S, self.n_points, 2)),
            "status": np.full(n, float(Status.INCREMENT_TOO_SMALL)),
            "critical": np.full(n, np.nan),
        }
        zs = np.zeros((n, self.nz))
        for i in range(n):
            path = follow(self.cell, self.load, S, mat=self.mat, points=X[i])
            k = len(path.t)
            out["strain"][i, :k] = path.strain_axial
            out["poisson"][i, :k] = path.poisson
            out["stress"][i, :k] = path.P[:, self.load.axial]
            out["valid"][i, :k] = path.valid
            out["u"][i, :k] = path.u.reshape(k, self.n_points, 2)
            if path.critical is not None:
                out["critical"][i] = path.critical["strain"]
            if path.completed and k == S:
                out["lateral"][i] = path.F[-1, self.load.lateral]
                out["status"][i] = float(Status.CONVERGED)
                zs[i] = path.z[-1]
        return PathOutput(**out), zs

    def _compiled(self, p: PeriodicProblem):
        """dq/dz and the adjoint's total derivative in X, q the lateral stretch (a free component
        of F_bar: an entry of the reduced state z)."""
        if self._adjoint is None:
            where = int(np.flatnonzero(p.free == self.load.lateral)[0])

            def residual(z, Fp, X, mat):
                ctx = (X, p.cell.pin_position(X), mat)
                quad = quadrature(p.solid, X)
                return jax.grad(lambda z: strain_energy(p.solid, quad, p.u(z, Fp, ctx), mat))(z)

            def total(X, mat, z, Fp, lam):
                return -jnp.dot(lam, residual(z, Fp, X, mat))

            self._adjoint = (p.nw + where, jax.jit(jax.grad(total)))
        return self._adjoint

    def gradients(self, X, zs, status, ct):
        """sum_i ct[i] d lateral_i / d X_i, (n, n_points, 2); zero for a failed path."""
        X = np.asarray(X, float)
        grads = np.zeros_like(X)
        Fp = self.load.at(1.0)
        for i in np.flatnonzero((np.asarray(status) == Status.CONVERGED) & (np.asarray(ct) != 0)):
            p = PeriodicProblem(self.cell, jnp.asarray(X[i]), self.mat, self.load)
            index, adjoint = self._compiled(p)
            K = p.linearise(zs[i], Fp)[2]
            dq_dz = np.zeros(p.nz)
            dq_dz[index] = 1.0  # q = z[index]: it has no explicit dependence on X
            try:
                lam = spla.splu(K.tocsc()).solve(dq_dz)
            except RuntimeError:  # singular at the state (exactly at a bifurcation): no gradient
                continue
            g = adjoint(jnp.asarray(X[i]), jnp.asarray(self.mat), jnp.asarray(zs[i]), Fp, lam)
            grads[i] = float(ct[i]) * np.asarray(g)
        return grads

    # -- the JAX side ----------------------------------------------------------------------------
    def _build(self):
        def shapes(n):
            f = lambda *s: jax.ShapeDtypeStruct(s, jnp.float64)
            S, P = self.steps, self.n_points
            return PathOutput(f(n), f(n, S), f(n, S), f(n, S), f(n, S), f(n, S, P, 2), f(n), f(n))

        def host(X):
            out, zs = self.paths(X)
            return tuple(np.asarray(a, np.float64) for a in out) + (np.asarray(zs, np.float64),)

        def call(X):
            n = X.shape[0]
            res = jax.pure_callback(
                host, (*shapes(n), jax.ShapeDtypeStruct((n, self.nz), jnp.float64)), X
            )
            return PathOutput(*res[:-1]), res[-1]

        @jax.custom_vjp
        def fn(X):
            return call(X)[0]

        def fwd(X):
            out, zs = call(X)
            return out, (X, zs, out.status)

        def bwd(res, ct):
            X, zs, status = res
            untracked = {k: getattr(ct, k) for k in UNDIFFERENTIATED}

            def host_gradients(X, zs, s, c, untracked):
                _refuse_untracked(untracked)
                return self.gradients(X, zs, s, c).astype(np.float64)

            g = jax.pure_callback(
                host_gradients,
                jax.ShapeDtypeStruct(X.shape, jnp.float64),
                X,
                zs,
                status,
                ct.lateral,
                untracked,
            )
            return (g,)

        fn.defvjp(fwd, bwd)
        return fn
