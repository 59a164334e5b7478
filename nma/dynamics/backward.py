"""The discrete adjoint through time, one step at a time from the last, and the trajectory as one
differentiable function of (X, coeffs, mat).

A step's adjoint needs the factor of K(u_{n+1}) + B at its converged state, which Newton never
factorised (its last factor is of the iterate before), so the sweep factorises it: the neighbouring
step's factor is too far from it for iterative refinement to converge in a few back-substitutions.
The design enters a step only through its quadrature and its mass and damping blocks, the same in
every step, so the sweep sums their cotangents and pulls the sum back to X once, at its end.  What
the forward pass keeps, and how the sweep gets each step back, is the adjoint's
(nma.dynamics.adjoints); the accepted steps are fixed, and no gradient flows through their choice.
"""

from __future__ import annotations

import itertools
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


class TrajectoryInfo(NamedTuple):
    """How a trajectory went: status (a Status: CONVERGED when every step did, else the failed
    step's), the time it reached (the failed step's start, else the end), its time steps, the
    intervals stepped in more than one (cut, or adaptive steps), Newton's iterations over all
    steps tried, the intervals completed (the states at k dt, k = 0..intervals, are solved: all
    `steps` + 1 of them where it converged, the later ones hold the last) and the steps tried and
    not accepted."""

    status: jnp.ndarray
    time: jnp.ndarray
    steps: jnp.ndarray
    cuts: jnp.ndarray
    iterations: jnp.ndarray
    intervals: jnp.ndarray
    rejected: jnp.ndarray


class Sweep:
    """The adjoint sweep of one sample: `step(s)` for every accepted step, the last first, then
    `result()`: (X_bar, coeffs_bar, mat_bar)."""

    def __init__(self, dyn, stepper, u_bar, v_bar, intervals: int, z0):
        self.dyn, self.stepper, self.z0 = dyn, stepper, z0  # z0: the state at t = 0
        self.u_bar, self.v_bar = (np.asarray(a).reshape(dyn.steps + 1, -1) for a in (u_bar, v_bar))
        self.design_bar = jax.tree_util.tree_map(jnp.zeros_like, stepper.design)
        self.mat_bar = np.zeros(stepper.mat.shape)
        self.c_bar = np.zeros(stepper.coeffs.shape)
        # the last state solved, at interval m's start, holds for the states after it too (a
        # trajectory that failed in interval m): their cotangents are its own
        m = intervals
        self.zb = [self.u_bar[m:].sum(axis=0), self.v_bar[m:].sum(axis=0), np.zeros(dyn.n)]
        self._blocks = {}  # dt -> the scheme's inertia and damping blocks B

    def factorised(self, step, ws):
        """ws with the factor of K(u_{n+1}) + B at the step's end: the part of its adjoint that
        does not wait for the cotangents, so that it can be computed while the step after it is
        swept (`sweep_back`)."""
        dyn, s = self.dyn, self.stepper
        d1, uf1 = jnp.asarray(step.d), jnp.asarray(step.u_free)
        kel = dyn.newton.linearised(
            lambda kk: kk.tangents(s.X, d1, s.mat, uf1), tangents=lambda kel: kel
        )
        if step.dt not in self._blocks:  # the same in every step of a length
            self._blocks[step.dt] = dyn.scheme.blocks(*s.design[1:], step.dt)
        # K(u_{n+1}) + B differs from the neighbouring step's too much to refine from its factor
        ws.factorise_for_adjoint(kel._replace(elements=kel.elements + self._blocks[step.dt]))
        return ws

    def step(self, step, factor) -> None:
        """The step's adjoint, `factor` the workspace `factorised` left its matrix's factor in."""
        dyn, s, k, zb = self.dyn, self.stepper, self.dyn.kernels, self.zb
        mat, design = s.mat, s.design
        u, v, a = (jnp.asarray(x) for x in step.z)
        d1, uf1 = jnp.asarray(step.d), jnp.asarray(step.u_free)
        u1 = k.full(uf1, d1)
        un_b, u_b, v_b, a_b = k.update_vjp(
            u1, u, v, a, step.dt, jnp.asarray(zb[1]), jnp.asarray(zb[2])
        )
        u1_bar = zb[0] + np.asarray(un_b)
        rhs = u1_bar[dyn.free]
        lam = factor.solve(rhs) if np.linalg.norm(rhs) else np.zeros_like(rhs)
        self.design_bar, mb, ub, vb, ab, uDb = k.pullback(
            design,
            mat,
            u,
            v,
            a,
            uf1,
            jnp.asarray(np.asarray(u1)[dyn.dirichlet]),
            step.dt,
            jnp.asarray(lam),
            self.design_bar,
        )
        d_bar = dyn.A.T @ (np.asarray(uDb) + u1_bar[dyn.dirichlet])
        self.c_bar += np.asarray(k.actuation_vjp(s.coeffs, step.t + step.dt, jnp.asarray(d_bar)))
        self.mat_bar += np.asarray(mb)
        self.zb = [
            np.asarray(u_b) + np.asarray(ub),
            np.asarray(v_b) + np.asarray(vb),
            np.asarray(a_b) + np.asarray(ab),
        ]
        if step.j == 0:  # back at its interval's start, a grid time: its state's cotangents
            self.zb[0] += self.u_bar[step.k]
            self.zb[1] += self.v_bar[step.k]

    def result(self):
        dyn, s, k = self.dyn, self.stepper, self.dyn.kernels
        # the state at t = 0 holds the actuation there: u_D(0) = A d(coeffs, 0); and the start's
        # own dependence on the design, material and actuation (nma.dynamics.initial)
        d_bar = dyn.A.T @ self.zb[0][dyn.dirichlet]
        X_0, design_0, mat_0, d_bar = dyn.initial.pullback(s, self.z0, self.zb, d_bar)
        if design_0 is not None:
            self.design_bar = jax.tree_util.tree_map(jnp.add, self.design_bar, design_0)
        if mat_0 is not None:
            self.mat_bar += np.asarray(mat_0)
        self.c_bar += np.asarray(k.actuation_vjp(s.coeffs, 0.0, jnp.asarray(d_bar)))
        X_b, mat_b = k.design_vjp(s.X, s.mat, self.design_bar)
        X_b = np.asarray(X_b) if X_0 is None else np.asarray(X_b) + np.asarray(X_0)
        return X_b, self.c_bar, self.mat_bar + np.asarray(mat_b)


def sweep_back(sweep: Sweep, steps, backend, ahead: bool) -> None:
    """Every step of `steps` (the last first) through `sweep`.  With `ahead`, each step's factor
    is computed in a second thread while the step after it is swept: a step's tangent and
    factorisation do not wait for its cotangents, so they run beside the next one's pullback on
    the cores that one sample leaves idle (the same computations: the same gradient)."""
    spaces = [backend.workspace(), backend.workspace()]  # the factor in use, the one coming
    try:
        if not ahead:
            for step in steps:
                sweep.step(step, sweep.factorised(step, spaces[0]))
            return
        with ThreadPoolExecutor(1, thread_name_prefix="nma-adjoint") as pool:
            steps, ring = iter(steps), itertools.cycle(spaces)
            current = next(steps, None)
            coming = None if current is None else pool.submit(sweep.factorised, current, next(ring))
            while current is not None:
                following = next(steps, None)  # may solve steps again (checkpointed)
                factor = coming.result()
                if following is not None:
                    coming = pool.submit(sweep.factorised, following, next(ring))
                sweep.step(current, factor)
                current = following
    finally:
        for ws in spaces:
            backend.release(ws)


def differentiable(dyn):
    """trajectory(X, coeffs, mat) -> (u, v, TrajectoryInfo), differentiable in X, coeffs and mat (u
    and v at the output times k dt; vmap batches it over samples).  Its residuals hold what the
    adjoint keeps (nma.dynamics.adjoints), as arrays."""
    kept = dyn.adjoint.kept(dyn.steps)

    def call(X, coeffs, mat):
        m, n = dyn.steps + 1, dyn.n // 2
        state = jax.ShapeDtypeStruct((m, n, 2), X.dtype)
        kinds = (jnp.int32, X.dtype, jnp.int32, jnp.int32, jnp.int32, jnp.int32, jnp.int32)
        info = TrajectoryInfo(*(jax.ShapeDtypeStruct((), t) for t in kinds))
        per = (
            jax.ShapeDtypeStruct((dyn.steps,), jnp.int32),
            jax.ShapeDtypeStruct((dyn.steps,), X.dtype),
        )
        return jax.pure_callback(
            dyn.forward_batch,
            (state, state, info, state, *per),
            X,
            coeffs,
            mat,
            vmap_method="broadcast_all",
        )

    @jax.custom_vjp
    def trajectory(X, coeffs, mat):
        return call(X, coeffs, mat)[:3]

    def fwd(X, coeffs, mat):
        u, v, info, a, counts, control = call(X, coeffs, mat)
        states = (u, v, a) if kept is None else (u[kept], v[kept], a[kept])
        return (u, v, info), (X, coeffs, mat, *states, counts, control, info.intervals)

    def bwd(res, cotangents):
        out = tuple(jax.ShapeDtypeStruct(a.shape, a.dtype) for a in res[:3])
        return jax.pure_callback(
            dyn.backward_batch, out, *res, cotangents[0], cotangents[1], vmap_method="broadcast_all"
        )

    trajectory.defvjp(fwd, bwd)
    return trajectory
