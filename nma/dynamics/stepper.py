"""One sample's time steps: what the step controllers (nma.dynamics.controllers) step with, forward
and again in the backward pass.

A step from the state z = (u, v, a) at t0 (flat, every dof) to t0 + h is one Newton solve of the
static potential with the step's Inertia (nma.dynamics.schemes), started at the state, then the
scheme's explicit update of v and a.  Newton begins from `previous`, the last step's
linearisation at its converged end (nma.solver.starts.continue_in_time), or afresh at the state
where that is None: a step started afresh is the same computation whenever it is redone from the
same state, which is how the backward pass gets back the steps it did not keep.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from ..solver.status import Status


class Step(NamedTuple):
    """An accepted time step: all the backward pass needs of it."""

    t: float  # its start
    dt: float  # its length: the actuation is taken at t + dt
    z: tuple  # (u, v, a) at its start, flat, every dof
    u_free: np.ndarray  # its solution's free dofs
    d: np.ndarray  # the actuation at its end
    k: int  # the interval it belongs to (from k dt to (k + 1) dt)
    j: int  # its place in that interval (0: it starts at k dt)


class Stepper:
    """The time steps of one sample (X, coeffs, mat) of a Dynamics, in the linear workspace `ws`."""

    def __init__(self, dyn, X, coeffs, mat, ws):
        self.dyn, self.ws = dyn, ws
        self.X, self.coeffs, self.mat = (jnp.asarray(a) for a in (X, coeffs, mat))
        self.kernels, self.scheme = dyn.kernels, dyn.scheme
        self.dt, self.times, self.free = dyn.dt, dyn.times, dyn.free
        self.design = self.kernels.design(self.X, self.mat)

    def start(self):
        """The state at t = 0, the Dynamics' start's (nma.dynamics.initial)."""
        return self.dyn.initial.state(self)

    def step(self, z, t0: float, h: float, k: int, j: int, previous):
        """The step from z at t0 to t0 + h, the j-th of interval k: (Step, NewtonInfo, its end's
        linearisation, the state at its end), or (None, NewtonInfo, None, None) where Newton did not
        converge."""
        kk, dyn = self.kernels, self.dyn
        d1 = kk.actuation(self.coeffs, t0 + h)
        u, v, a = (jnp.asarray(x) for x in z)
        inertia = kk.inertia(*self.design, self.mat, u, v, a, h)
        # numpy's gathers: JAX's eager ones dispatch a program each (about 1 ms)
        z_u = np.asarray(z[0])
        start = (jnp.asarray(z_u[dyn.free]), jnp.asarray(z_u[dyn.dirichlet]), None, self.X)
        u_free, info, end = dyn.newton.time_step(
            self.X, d1, self.mat, self.ws, start, inertia, previous
        )
        if int(info.status) != Status.CONVERGED:
            return None, info, None, None
        step = Step(t0, h, z, np.asarray(u_free), np.asarray(d1), k, j)
        u1 = np.asarray(kk.full(u_free, d1))
        return step, info, end, (u1, *self.update(step, u1))

    def whole(self, z, k: int, previous):
        """One step over all of interval k (Stepper.step's answer)."""
        return self.step(z, float(self.times[k]), self.dt, k, 0, previous)

    def known(self, z, k: int, z_next) -> Step:
        """The one step over interval k from z whose end z_next is known: its record, no solve."""
        t = float(self.times[k])
        d1 = self.kernels.actuation(self.coeffs, t + self.dt)
        return Step(t, self.dt, z, z_next[0][self.free], np.asarray(d1), k, 0)

    def update(self, step: Step, u1):
        """(v, a) at the step's end, its displacement u1."""
        out = self.kernels.update(jnp.asarray(u1), *(jnp.asarray(x) for x in step.z), step.dt)
        return tuple(np.asarray(a) for a in out)

    def error(self, z, z1, h: float, rtol: float, atol: float) -> float:
        """The step's local error estimate in u (Scheme.local_error) over the free dofs, relative
        to atol + rtol x the largest displacement at either end: a step is accurate enough at 1 or
        less."""
        e = np.asarray(self.scheme.local_error(z[2], z1[2], h))[self.free]
        scale = atol + rtol * max(np.max(np.abs(z[0])), np.max(np.abs(z1[0])))
        return float(np.max(np.abs(e)) / scale)
