"""Where a trajectory starts (dynamics.start, nma.dynamics.options.STARTS), and the start's part of
the gradient.

- rest: u = 0 but the prescribed dofs at the actuation's value at t = 0, v = 0 (v0 where given).
  A dead load (scene.gravity, a traction) is applied at once at t = 0: the state is out of balance,
  and its acceleration is the one the dead load gives there, M_ff a_f = (f_ext - f(u))_f (the
  prescribed dofs' 0), so that the first step is the scheme's consistent one; without a dead load,
  a = 0.  Under a suddenly applied weight the body falls and oscillates about its sagged state.
- static: the static equilibrium under the dead load and the actuation's value at t = 0 (the static
  solver's Newton, from rest), v = 0 (v0 where given), a = 0: in balance, so nothing moves unless
  the actuation does.

The gradient: rest's a depends on the design (the mass and the dead load's nodal forces follow the
reference areas), on the material (through f(u) where the actuation at t = 0 is not 0) and on the
actuation at t = 0.  It is the implicit function of R0 = M_ff a_f + f(u)_f - f_ext,f = 0: with
lambda = M_ff^-1 a_bar_f, (design, mat, u_D)_bar = -lambda^T dR0/d(design, mat, u_D).  static's u
is the equilibrium's, whose implicit derivative is the static adjoint's at its tangent
(HostNewton.adjoint); its a = 0 holds whatever the design, so passes nothing back.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SolverError
from ..mechanics.energy import Tangents, strain_energy
from ..solver.equations import Equations
from ..solver.status import Status


def has_dead_load(eqs: Equations) -> bool:
    """Whether the scene carries a dead load: a body force (scene.gravity) or a traction."""
    return eqs.body is not None or bool(np.any(np.asarray(eqs.f_ext)))


class Initial:
    """The start `kind` (rest, static) of a Dynamics' trajectories: `state` forward, `pullback`
    in the backward pass."""

    def __init__(self, dyn, kind: str):
        self.dyn, self.kind, self.eqs = dyn, kind, dyn.eqs
        self.dead = has_dead_load(self.eqs)
        self._force = jax.jit(partial(_out_of_balance, self.eqs))
        self._force_vjp = jax.jit(partial(_balance_vjp, self.eqs))

    def state(self, stepper):
        """(u, v, a) at t = 0, flat, every dof, of the stepper's sample."""
        k, dyn = stepper.kernels, self.dyn
        d0 = k.actuation(stepper.coeffs, 0.0)
        # a non-finite input: at rest, whose first step ends the trajectory (NONFINITE_INPUT)
        finite = all(np.all(np.isfinite(np.asarray(x))) for x in (stepper.X, d0, stepper.mat))
        if self.kind == "static" and finite:
            u0 = k.full(jnp.asarray(self.equilibrium(stepper, d0)), d0)
            return np.asarray(u0), dyn.v0, np.zeros(dyn.n)
        u0 = k.full(jnp.zeros(len(dyn.free)), d0)
        a0 = np.zeros(dyn.n)
        if self.dead and finite:
            force = self._force(stepper.design, stepper.mat, u0)
            a0[dyn.free] = self._mass_solve(stepper.design[1], np.asarray(force))
        return np.asarray(u0), dyn.v0, a0

    def equilibrium(self, stepper, d0) -> np.ndarray:
        """The static equilibrium's free dofs at actuation d0; SolverError, saying why, where the
        static solve does not converge."""
        dyn = self.dyn
        ws = dyn.sim.backend.workspace()
        try:
            u, info, _ = dyn.newton.solve(stepper.X, d0, stepper.mat, ws)
        finally:
            dyn.sim.backend.release(ws)
        if int(info.status) != Status.CONVERGED:
            raise SolverError(
                f"dynamics.start=static: the static equilibrium at t = 0 (actuation "
                f"{np.round(np.asarray(d0), 6).tolist()}) did not converge: "
                f"{Status.describe(info.status)}; start from rest (dynamics.start=rest) or lighten "
                f"the dead load"
            )
        return np.asarray(u)

    def pullback(self, stepper, z0, zb, d_bar):
        """The start's cotangents from those (zb) of its state z0 = (u, v, a) at t = 0 (flat, every
        dof; None: solved again), d_bar the actuation at t = 0's so far: (X_bar, design_bar,
        mat_bar, d_bar), None for a part it passes nothing to."""
        dyn, k = self.dyn, stepper.kernels
        X_bar, design_bar, mat_bar = None, None, None
        if z0 is None and (self.kind == "static" or self.dead):  # an adjoint that did not keep it
            z0 = self.state(stepper)
        d0 = k.actuation(stepper.coeffs, 0.0)
        if self.kind == "static":
            u_bar = np.asarray(zb[0])[dyn.free]
            if np.any(u_bar):
                u_free = jnp.asarray(np.asarray(z0[0])[dyn.free])
                ws = dyn.sim.backend.workspace()
                try:
                    X_bar, db, mat_bar = dyn.newton.adjoint(
                        stepper.X, d0, stepper.mat, u_free, u_bar, ws
                    )
                finally:
                    dyn.sim.backend.release(ws)
                d_bar = d_bar + np.asarray(db)
        elif self.dead:
            a_bar = np.asarray(zb[2])[dyn.free]
            if np.any(a_bar):
                lam = self._mass_solve(stepper.design[1], a_bar)
                u0 = k.full(jnp.zeros(len(dyn.free)), d0)
                design_bar, mat_bar, uD_bar = self._force_vjp(
                    stepper.design,
                    stepper.mat,
                    jnp.asarray(z0[2]),
                    u0[dyn.dirichlet],
                    jnp.asarray(lam),
                )
                d_bar = d_bar + dyn.A.T @ np.asarray(uD_bar)
        return X_bar, design_bar, mat_bar, d_bar

    def _mass_solve(self, M, rhs) -> np.ndarray:
        """M_ff^-1 rhs (free rows) by the scene's linear solver, in a workspace of its own."""
        backend = self.dyn.sim.backend
        none = jnp.zeros((0, 18, 18), M.dtype)
        kel = Tangents(M, none, jnp.zeros(0, jnp.int32), jnp.asarray(0))
        ws = backend.workspace()
        try:
            return np.asarray(ws.adjoint(kel, rhs, refine=False))
        finally:
            backend.release(ws)


def _internal(eqs, quad, mat, u):
    return jax.grad(lambda w: strain_energy(eqs.solid, quad, w.reshape(-1, 2), mat))(u)


def _out_of_balance(eqs, design, mat, u):
    """(f_ext - f(u))_f at t = 0: what the mass accelerates there."""
    quad = design[0]
    return (eqs.external_force(quad) - _internal(eqs, quad, mat, u))[eqs.free]


def _balance_vjp(eqs, design, mat, a, u_D, lam):
    """-lambda^T dR0/d(design, mat, u_D), R0 = (M a + f(u) - f_ext)_f, u = (0, u_D)."""

    def residual(design, mat, u_D):
        quad, M = design[0], design[1]
        edofs = eqs.edofs[: eqs.elements]
        Ma = jnp.zeros_like(a).at[edofs].add(jnp.einsum("eab,eb->ea", M, a[edofs]))
        u = eqs.full(jnp.zeros(len(eqs.free), a.dtype), u_D).reshape(-1)
        return (Ma + _internal(eqs, quad, mat, u) - eqs.external_force(quad))[eqs.free]

    return jax.vjp(residual, design, mat, u_D)[1](-lam)
