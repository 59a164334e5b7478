"""Trajectories: implicit time stepping on the host, each step a Newton solve with the static solver's
safeguards, and the discrete adjoint sweep backwards through the steps, as one differentiable function.

Forward: the run is split into `steps` intervals of dt; an interval whose step does not converge (a
load-step cut below solver.min_increment, the element bound, the iteration limit) is redone in 2, 4,
... equal steps, up to 2^max_cuts: the static solver's load-step cuts become time-step cuts.  A step
that still fails ends the trajectory and says at which time, after how many intervals and why; its
later states hold the last one reached.  Interval k runs from k dt to (k + 1) dt: the states and the
steps are known by these indices, never by comparing times.  Each step starts Newton at the
previous state, so its predictor is the linearised response to the step's boundary motion and
inertia; its first linearisation is the last step's final one with the Inertia swapped
(nma.solver.newton.continue_in_time), not another pass over the elements.

Backward: the states at the start of every step are kept (3 vectors of 2 n_points floats a step,
u, v, a, plus the step's free displacements); nothing else.  The adjoint of a step needs the factor of
K(u_{n+1}) + B at the converged state, which Newton never factorised (its last factor is of the
iterate before), so the backward sweep factorises it: the neighbouring step's factor is too far from it
for iterative refinement to converge in a few back-substitutions.
"""
from __future__ import annotations

import itertools
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError, SolverError
from ..solver.batch import split_samples, stack_samples
from ..solver.host import HostNewton
from ..solver.status import Status
from .checks import check_dynamics, check_run, checked_function
from .schemes import Scheme
from .stepping import StepKernels

KEPT_TRAJECTORIES = 256  # forward records awaiting their adjoint; the oldest go beyond this


class TrajectoryInfo(NamedTuple):
    """How a trajectory went: status (a Status: CONVERGED when every step did, else the failed
    step's), the time it reached (the failed step's start, else the end), its time steps (cut
    intervals count each of their steps), the intervals that were cut, Newton's iterations over all
    steps, and the intervals completed: the states at k dt, k = 0..intervals, are solved (all
    `steps` + 1 of them where it converged), the later ones hold the last."""
    status: jnp.ndarray
    time: jnp.ndarray
    steps: jnp.ndarray
    cuts: jnp.ndarray
    iterations: jnp.ndarray
    intervals: jnp.ndarray


class _Step(NamedTuple):
    t: float           # the step's start
    dt: float
    z: tuple           # (u, v, a) at its start, flat, every dof
    u_free: np.ndarray  # its solution's free dofs
    d: np.ndarray      # the actuation at its end
    k: int             # the interval it belongs to (from k dt to (k + 1) dt)
    j: int             # its place in that interval (0: it starts at k dt)


class Dynamics:
    """Time stepping of a Simulator's scene under an actuation waveform (nma.dynamics.waveform).

    Args:
        sim: The Simulator (any linear backend: each step's Newton is driven from the host).
        scheme: `newmark` or `generalised_alpha` (rho_inf its spectral radius at infinite frequency).
        dt: The time step; steps: how many (the trajectory's states are at k dt, k = 0..steps).
        density: Mass per unit area (the model's units).
        alpha, beta: Rayleigh damping C = alpha M + beta K_0.
        waveform: f(coeffs, t) -> actuations at time t, traceable (nma.dynamics.waveform.Fourier).
        max_cuts: An interval may be redone in up to 2^max_cuts steps.
        v0: Initial velocity (n_points, 2) or None (rest); undamped only (its initial acceleration is 0).
    """

    def __init__(self, sim, scheme: str = "newmark", rho_inf: float = 1.0, dt: float = 1.0, steps: int = 100,
                 density: float = 1.0, alpha: float = 0.0, beta: float = 0.0, waveform=None, max_cuts: int = 4,
                 v0=None, workers: int | None = None):
        check_dynamics(sim, scheme, rho_inf, dt, steps, density, alpha, beta, waveform, max_cuts, v0,
                       workers)
        if np.any(np.asarray(sim.equations.f_ext)):
            raise ConfigError("dynamics starts at rest: a scene with a dead load would start out of balance")
        if v0 is not None and (alpha or beta):
            raise ConfigError("dynamics: an initial velocity needs no damping (alpha = beta = 0), so that the "
                              "initial acceleration is 0")
        self.sim, self.eqs = sim, sim.equations
        self.scheme = Scheme.of(scheme, rho_inf)
        self.dt, self.steps, self.max_cuts = float(dt), int(steps), int(max_cuts)
        self.waveform = waveform
        self.kernels = StepKernels(self.eqs, self.scheme, density, alpha, beta, waveform)
        self.newton = HostNewton(self.eqs, sim.backend, sim.options)
        self.free, self.dirichlet = np.asarray(self.eqs.free), np.asarray(self.eqs.dirichlet)
        self.A = np.asarray(self.eqs.A)
        self.n = 2 * sim.disc.mesh.n_points
        self.v0 = np.zeros(self.n) if v0 is None else np.asarray(v0, float).reshape(-1)
        self.workers = workers or sim.workers
        self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix="nma-dynamics") if self.workers > 1 else None
        self._kept: dict[int, list] = {}
        self._tokens = itertools.count(1)
        self._lock = threading.Lock()
        self.function = checked_function(self, _differentiable(self))

    @classmethod
    def from_settings(cls, sim, s, density: float, waveform, X, mat, workers: int | None = None,
                      omega_1: float | None = None) -> "Dynamics":
        """From a DynamicsConfig `s` (nma.schema.physics): dt null takes a 20th of the lowest natural period
        at rest, and a damping ratio becomes alpha = zeta omega, beta = zeta / omega at its frequency (the
        lowest natural one where none is given; `omega_1`: that one, where the caller has it)."""
        from .modes import natural_frequencies

        needed = s.dt is None or (s.damping_ratio is not None and s.damping_frequency is None)
        if omega_1 is None and needed:
            omega_1 = float(natural_frequencies(sim, X, mat, density, count=1)[0])
        dt = s.dt if s.dt is not None else 2.0 * np.pi / omega_1 / 20.0
        alpha, beta = s.alpha, s.beta
        if s.damping_ratio is not None:
            omega = s.damping_frequency or omega_1
            alpha, beta = s.damping_ratio * omega, s.damping_ratio / omega
        return cls(sim, s.scheme, s.rho_inf, dt, s.steps, density, alpha, beta, waveform, s.max_cuts, workers=workers)

    @property
    def times(self) -> np.ndarray:
        return self.dt * np.arange(self.steps + 1)

    # -- one sample, forward
    def run(self, X, coeffs, mat):
        """(u (steps + 1, n_points, 2), v (same), TrajectoryInfo, the steps kept for the adjoint)."""
        X, coeffs, mat = check_run(self, "Dynamics.run", X, coeffs, mat, finite=False)
        k = self.kernels
        X, coeffs, mat = (jnp.asarray(a) for a in (X, coeffs, mat))
        design = k.design(X, mat)
        ws = self.sim.backend.workspace()
        z = (np.asarray(k.full(jnp.zeros(len(self.free)), k.actuation(coeffs, 0.0))), self.v0, np.zeros(self.n))
        us, vs, kept = [z[0]], [z[1]], []
        status, substeps, cuts, iterations, previous = Status.CONVERGED, 0, 0, 0, None
        t, intervals = float(self.times[-1]), self.steps
        try:
            for i in range(self.steps):  # interval i: times[i] to times[i + 1], states by index
                done, failed, its, previous = self._interval(X, coeffs, mat, design, z, i, ws,
                                                             previous)
                iterations += its
                if failed is not None:  # (NewtonInfo, the time of the step that failed)
                    status, t, intervals = int(failed[0].status), failed[1], i
                    break
                kept.extend(done)
                substeps += len(done)
                cuts += len(done) > 1
                last = done[-1]
                u1 = np.asarray(k.full(jnp.asarray(last.u_free), jnp.asarray(last.d)))
                z = (u1, *self._next(last, u1))
                us.append(z[0])
                vs.append(z[1])
        finally:
            self.sim.backend.release(ws)
        while len(us) < self.steps + 1:  # after a failed step: the last state reached
            us.append(us[-1])
            vs.append(vs[-1])
        shape = (self.steps + 1, -1, 2)
        info = TrajectoryInfo(np.int32(status), np.float64(t), np.int32(substeps), np.int32(cuts),
                              np.int32(iterations), np.int32(intervals))
        return np.stack(us).reshape(shape), np.stack(vs).reshape(shape), info, kept

    def _next(self, step: _Step, u1):
        return tuple(np.asarray(a) for a in self.kernels.update(jnp.asarray(u1), *(jnp.asarray(x) for x in step.z),
                                                                 step.dt))

    def _interval(self, X, coeffs, mat, design, z, i, ws, previous):
        """The steps of interval i, from times[i] to times[i + 1] (in 1, 2, 4, ... equal steps),
        from the state z that the step `previous` (HostNewton.time_step) ended at: (steps, None,
        iterations, the last step's end), or where even the finest fails (None, (NewtonInfo, time),
        iterations, None)."""
        k, iterations, t = self.kernels, 0, float(self.times[i])
        for level in range(self.max_cuts + 1):
            n = 2 ** level
            h, zz, done, end = self.dt / n, z, [], previous
            for j in range(n):
                t0 = t + j * h
                d1 = k.actuation(coeffs, t0 + h)
                u, v, a = (jnp.asarray(x) for x in zz)
                inertia = k.inertia(*design, mat, u, v, a, h)
                start = (u[self.free], u[self.dirichlet], None, X)
                u_free, info, end = self.newton.time_step(X, d1, mat, ws, start, inertia, end)
                iterations += int(info.iterations)
                if int(info.status) != Status.CONVERGED:
                    failed = (info, t0)
                    break
                step = _Step(t0, h, zz, np.asarray(u_free), np.asarray(d1), i, j)
                done.append(step)
                u1 = np.asarray(k.full(u_free, d1))
                zz = (u1, *self._next(step, u1))
            else:
                return done, None, iterations, end
        return None, failed, iterations, None

    # -- one sample, backward
    def adjoint(self, kept: list, X, coeffs, mat, u_bar, v_bar):
        """(X_bar, coeffs_bar, mat_bar) for cotangents of the states at the steps' times."""
        k = self.kernels
        X, coeffs, mat = (jnp.asarray(a) for a in (X, coeffs, mat))
        design = k.design(X, mat)
        design_bar = jax.tree_util.tree_map(jnp.zeros_like, design)
        M, C = design[1:]
        u_bar, v_bar = (np.asarray(a).reshape(self.steps + 1, -1) for a in (u_bar, v_bar))
        mat_bar, c_bar = np.zeros(mat.shape), np.zeros(coeffs.shape)
        # the last state solved, at interval m's start, holds for the states after it too (a
        # trajectory that failed in interval m): their cotangents are its own
        m = kept[-1].k + 1 if kept else 0
        zb = [u_bar[m:].sum(axis=0), v_bar[m:].sum(axis=0), np.zeros(self.n)]
        ws = self.sim.backend.workspace()
        try:
            for step in reversed(kept):
                u, v, a = (jnp.asarray(x) for x in step.z)
                d1, uf1 = jnp.asarray(step.d), jnp.asarray(step.u_free)
                u1 = k.full(uf1, d1)
                un_b, u_b, v_b, a_b = k.update_vjp(u1, u, v, a, step.dt, jnp.asarray(zb[1]), jnp.asarray(zb[2]))
                u1_bar = zb[0] + np.asarray(un_b)
                B = self.scheme.blocks(M, C, step.dt)
                kel = self.newton.linearised(lambda kk: kk.tangents(X, d1, mat, uf1), tangents=lambda kel: kel)
                # K(u_{n+1}) + B differs from the neighbouring step's too much to refine from its factor
                lam = ws.adjoint(kel._replace(elements=kel.elements + B), u1_bar[self.free], refine=False)
                design_bar, mb, ub, vb, ab, uDb = k.pullback(design, mat, u, v, a, uf1, u1[self.dirichlet], step.dt,
                                                             jnp.asarray(lam), design_bar)
                d_bar = self.A.T @ (np.asarray(uDb) + u1_bar[self.dirichlet])
                c_bar += np.asarray(k.actuation_vjp(coeffs, step.t + step.dt, jnp.asarray(d_bar)))
                mat_bar += np.asarray(mb)
                zb = [np.asarray(u_b) + np.asarray(ub), np.asarray(v_b) + np.asarray(vb), np.asarray(a_b) + np.asarray(ab)]
                if step.j == 0:  # back at its interval's start, a grid time: its state's cotangents
                    zb[0] += u_bar[step.k]
                    zb[1] += v_bar[step.k]
        finally:
            self.sim.backend.release(ws)
        X_b, mat_b = k.design_vjp(X, mat, design_bar)
        return np.asarray(X_b), c_bar, mat_bar + np.asarray(mat_b)

    # -- batches (pure_callback's broadcast_all)
    def _map(self, fn, items):
        return list(self._pool.map(fn, items)) if self._pool and len(items) > 1 else [fn(i) for i in items]

    def forward_batch(self, X, coeffs, mat, keep: bool):
        lead = np.shape(coeffs)[:-1]
        Xs, cs, ms = (split_samples(a, lead) for a in (X, coeffs, mat))

        def one(i):
            u, v, info, kept = self.run(Xs[i], cs[i], ms[i])
            token = 0
            if keep:
                token = next(self._tokens)
                with self._lock:
                    self._kept[token] = kept
                    while len(self._kept) > KEPT_TRAJECTORIES:
                        self._kept.pop(next(iter(self._kept)))
            return u, v, info, np.int64(token)

        return stack_samples(self._map(one, range(len(cs))), lead)

    def backward_batch(self, X, coeffs, mat, u_bar, v_bar, token):
        lead = np.shape(coeffs)[:-1]
        Xs, cs, ms, ub, vb, tokens = (split_samples(a, lead) for a in (X, coeffs, mat, u_bar, v_bar, token))

        def one(i):
            with self._lock:
                kept = self._kept.get(int(tokens[i]))
            if kept is None:
                raise SolverError("dynamics: a trajectory's adjoint was asked after its forward record was dropped")
            return self.adjoint(kept, Xs[i], cs[i], ms[i], ub[i], vb[i])

        out = self._map(one, range(len(cs)))
        with self._lock:
            for t in set(tokens.tolist()):
                self._kept.pop(int(t), None)
        return stack_samples(out, lead)


def _differentiable(dyn: Dynamics):
    """trajectory(X, coeffs, mat) -> (u, v, TrajectoryInfo), differentiable in X, coeffs and mat (u and v
    at the steps' times; vmap batches it over samples)."""
    def call(X, coeffs, mat, keep):
        m = dyn.steps + 1
        state = jax.ShapeDtypeStruct((m, dyn.n // 2, 2), X.dtype)
        kinds = (jnp.int32, X.dtype, jnp.int32, jnp.int32, jnp.int32, jnp.int32)
        info = TrajectoryInfo(*(jax.ShapeDtypeStruct((), t) for t in kinds))
        shapes = (state, state, info, jax.ShapeDtypeStruct((), jnp.int64))
        return jax.pure_callback(lambda *a: dyn.forward_batch(*a, keep=keep), shapes, X, coeffs, mat,
                                 vmap_method="broadcast_all")

    @jax.custom_vjp
    def trajectory(X, coeffs, mat):
        return call(X, coeffs, mat, False)[:3]

    def fwd(X, coeffs, mat):
        u, v, info, token = call(X, coeffs, mat, True)
        return (u, v, info), (X, coeffs, mat, token)

    def bwd(res, cotangents):
        X, coeffs, mat, token = res
        out = tuple(jax.ShapeDtypeStruct(a.shape, a.dtype) for a in (X, coeffs, mat))
        return jax.pure_callback(dyn.backward_batch, out, X, coeffs, mat, cotangents[0], cotangents[1], token,
                                 vmap_method="broadcast_all")

    trajectory.defvjp(fwd, bwd)
    return trajectory
