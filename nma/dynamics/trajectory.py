"""Trajectories: implicit time stepping on the host, each step a Newton solve with the static
solver's safeguards, and the discrete adjoint swept backwards through the steps, as one
differentiable function.  Three parts, each chosen by name (nma.dynamics.options):

- the scheme (nma.dynamics.schemes): the integrator of one step;
- the step controller (nma.dynamics.controllers): how each output interval, from k dt to
  (k + 1) dt, is covered by steps.  The states are reported at k dt, k = 0 .. steps, known by
  their index, never by comparing times;
- the adjoint (nma.dynamics.adjoints): what the forward pass keeps for the backward one.

Each step starts Newton at the previous state, so its predictor is the linearised response to the
step's boundary motion and inertia; its first linearisation is the last step's final one with the
Inertia swapped (nma.solver.starts.continue_in_time), not another pass over the elements, except
where the controller or the adjoint starts it afresh (nma.dynamics.stepper).  An interval the
controller cannot step ends the trajectory, which says at which time, after how many intervals and
why; its later states hold the last one reached.
"""

from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

from ..errors import ConfigError
from ..solver.batch import split_samples, stack_samples
from ..solver.host import HostNewton
from ..solver.status import Status
from .adjoints import Adjoint
from .backward import Sweep, TrajectoryInfo, differentiable, sweep_back
from .checks import check_dynamics, check_run, checked_function
from .controllers import Controller
from .initial import Initial
from .options import ADJOINTS, CONTROLLERS, DEFAULTS, DynamicsOptions
from .schemes import Scheme
from .stepper import Stepper
from .stepping import StepKernels

__all__ = ["Dynamics", "Trace", "TrajectoryInfo"]


class Trace(NamedTuple):
    """What a forward pass leaves for the adjoint besides u and v."""

    a: np.ndarray  # (steps + 1, n_points, 2): the accelerations at k dt
    counts: np.ndarray  # (steps,): each interval's accepted steps (0 past a failure)
    control: np.ndarray  # (steps,): what the controller carried into each interval


class Dynamics:
    """Time stepping of a Simulator's scene under an actuation waveform (nma.dynamics.waveform).
    The defaults are the config's (nma.dynamics.options.DynamicsOptions, the `dynamics` settings);
    `Simulator.dynamics` builds one from those settings.

    Args:
        sim: The Simulator (any linear backend: each step's Newton is driven from the host).
        scheme: A name in nma.dynamics.options.SCHEMES: `newmark` or `generalised_alpha` (rho_inf
            its spectral radius at infinite frequency).
        dt: The time step, the interval between the states reported; None: a 20th of the lowest
            natural period at rest of the scene's initial design (one modal solve).
        steps: Intervals: the trajectory's states are at k dt, k = 0..steps.
        density: Mass per unit area (the model's units).
        alpha, beta: Rayleigh damping C = alpha M + beta K_0.
        waveform: f(coeffs, t) -> actuations at time t, traceable (nma.dynamics.waveform.Fourier).
        max_cuts: The shortest step is dt / 2^max_cuts (controllers cuts and adaptive).
        v0: Initial velocity (n_points, 2) or None (0); undamped only (damping would take a part of
            the initial acceleration).
        workers: Threads solving a batch's samples at once (None: the simulator's).
        controller: A name in nma.dynamics.options.CONTROLLERS (`fixed`, `cuts`, `adaptive`) or a
            Controller; rtol and atol are adaptive's tolerances.
        adjoint: A name in nma.dynamics.options.ADJOINTS (`store_all`, `checkpointed`) or an
            Adjoint; checkpoints: checkpointed's kept states (None: ceil(sqrt(steps)) apart).
        start: Where each trajectory starts (nma.dynamics.initial): `rest` (u = 0 but the
            actuation's value at t = 0, v = 0; a dead load, scene.gravity or a traction, applied at
            once at t = 0) or `static` (the static equilibrium under the dead load and the
            actuation's value at t = 0, v = 0).
    """

    def __init__(
        self,
        sim,
        scheme: str = DEFAULTS.scheme,
        rho_inf: float = DEFAULTS.rho_inf,
        dt: float | None = DEFAULTS.dt,
        steps: int = DEFAULTS.steps,
        density: float = 1.0,
        alpha: float = DEFAULTS.alpha,
        beta: float = DEFAULTS.beta,
        waveform=None,
        max_cuts: int = DEFAULTS.max_cuts,
        v0=None,
        workers: int | None = None,
        controller: str | Controller = DEFAULTS.controller,
        rtol: float = DEFAULTS.rtol,
        atol: float = DEFAULTS.atol,
        adjoint: str | Adjoint = DEFAULTS.adjoint,
        checkpoints: int | None = DEFAULTS.checkpoints,
        start: str = DEFAULTS.start,
    ):
        parts = {"controller": controller, "adjoint": adjoint}
        named = {k: p if isinstance(p, str) else type(p).__name__ for k, p in parts.items()}
        options = DynamicsOptions(
            scheme,
            rho_inf,
            dt,
            steps,
            alpha,
            beta,
            max_cuts,
            named["controller"],
            rtol,
            atol,
            named["adjoint"],
            checkpoints,
            start,
        )
        check_dynamics(sim, options, density, waveform, v0, workers, parts)
        if v0 is not None and (alpha or beta):
            raise ConfigError(
                "dynamics: an initial velocity needs no damping (alpha = beta = 0): the "
                "initial acceleration leaves the damping force out"
            )
        if dt is None:
            from .settings import lowest_frequency, time_step

            X0 = sim.reference_points(sim.init_params())
            dt = time_step(None, lowest_frequency(sim, X0, sim.material_params, density))
            options = dataclasses.replace(options, dt=dt)
        self.options = options
        self.sim, self.eqs = sim, sim.equations
        self.scheme = Scheme.of(scheme, rho_inf)
        self.dt, self.steps, self.max_cuts = float(dt), int(steps), int(max_cuts)
        self.controller = (
            CONTROLLERS.get(controller)(options) if isinstance(controller, str) else controller
        )
        self.adjoint = ADJOINTS.get(adjoint)(options) if isinstance(adjoint, str) else adjoint
        self.waveform = waveform
        self.initial = Initial(self, start)
        self.kernels = StepKernels.of(self.eqs, self.scheme, density, alpha, beta, waveform)
        self.newton = HostNewton(self.eqs, sim.backend, sim.options)
        self.free, self.dirichlet = np.asarray(self.eqs.free), np.asarray(self.eqs.dirichlet)
        self.A = np.asarray(self.eqs.A)
        self.n = 2 * sim.disc.mesh.n_points
        self.v0 = np.zeros(self.n) if v0 is None else np.asarray(v0, float).reshape(-1)
        self.workers = workers or sim.workers
        self._pool = (
            ThreadPoolExecutor(self.workers, thread_name_prefix="nma-dynamics")
            if self.workers > 1
            else None
        )
        self.function = checked_function(self, differentiable(self))

    @classmethod
    def from_settings(
        cls,
        sim,
        s,
        density: float,
        waveform,
        X=None,
        mat=None,
        workers: int | None = None,
        omega_1: float | None = None,
        v0=None,
    ) -> "Dynamics":
        """From a DynamicsConfig `s` (nma.schema.physics; Simulator.dynamics takes a mapping of
        its fields too): dt null takes a 20th of the lowest natural period at rest, and a damping
        ratio becomes alpha = zeta omega, beta = zeta / omega at its frequency (the lowest
        natural one where none is given).  That frequency is of the design X under the material
        mat (the scene's initial design and material where None); `omega_1`: that one, where the
        caller has it (no modal solve)."""
        from .settings import resolve

        s = resolve(sim, s, density, X, mat, omega_1)
        return cls(
            sim,
            s.scheme,
            s.rho_inf,
            s.dt,
            s.steps,
            density,
            s.alpha,
            s.beta,
            waveform,
            s.max_cuts,
            v0,
            workers,
            s.controller,
            s.rtol,
            s.atol,
            s.adjoint,
            s.checkpoints,
            s.start,
        )

    @property
    def times(self) -> np.ndarray:
        """The output times k dt, k = 0 .. steps."""
        return self.dt * np.arange(self.steps + 1)

    # -- one sample, forward
    def run(self, X, coeffs, mat):
        """(u (steps + 1, n_points, 2), v (same), TrajectoryInfo, the Trace the adjoint needs)."""
        X, coeffs, mat = check_run(self, "Dynamics.run", X, coeffs, mat, finite=False)
        ws = self.sim.backend.workspace()
        stepper = Stepper(self, X, coeffs, mat, ws)
        z = stepper.start()
        states = [z]
        counts, control = np.zeros(self.steps, np.int32), np.zeros(self.steps)
        status, substeps, cuts, iterations, rejected, previous = Status.CONVERGED, 0, 0, 0, 0, None
        t, intervals, state = float(self.times[-1]), self.steps, self.controller.start(self.dt)
        try:
            for i in range(self.steps):  # interval i: times[i] to times[i + 1], states by index
                control[i] = state
                if self.adjoint.restarts(i, self.steps):
                    previous = None
                out = self.controller.interval(stepper, z, i, state, previous)
                iterations += out.iterations
                rejected += out.rejected
                if out.failed is not None:  # (NewtonInfo, the start of the step that failed)
                    status, t, intervals = int(out.failed[0].status), out.failed[1], i
                    break
                counts[i] = len(out.steps)
                substeps += len(out.steps)
                cuts += len(out.steps) > 1
                z, previous, state = out.z, out.end, out.state
                states.append(z)
        finally:
            self.sim.backend.release(ws)
        states += [states[-1]] * (self.steps + 1 - len(states))  # after a failed step: the last
        u, v, a = (np.stack(x).reshape(self.steps + 1, -1, 2) for x in zip(*states))
        info = TrajectoryInfo(
            np.int32(status),
            np.float64(t),
            np.int32(substeps),
            np.int32(cuts),
            np.int32(iterations),
            np.int32(intervals),
            np.int32(rejected),
        )
        return u, v, info, Trace(a, counts, control)

    # -- one sample, backward
    def backward(
        self, X, coeffs, mat, kept, counts, control, intervals: int, u_bar, v_bar, ahead=True
    ):
        """(X_bar, coeffs_bar, mat_bar) for cotangents u_bar, v_bar of the states at k dt, from what
        the adjoint kept: `kept` = (u, v, a) at its kept output times, each interval's step count
        and controller state, and the intervals the trajectory completed.  `ahead`: each step's
        factor computed beside the step after it (nma.dynamics.backward.sweep_back)."""
        ws = self.sim.backend.workspace()
        try:
            stepper = Stepper(self, X, coeffs, mat, ws)
            index = self.adjoint.kept(self.steps)
            index = range(self.steps + 1) if index is None else index
            states = {
                int(k): tuple(np.asarray(x[i]).reshape(-1) for x in kept)
                for i, k in enumerate(index)
            }
            sweep = Sweep(self, stepper, u_bar, v_bar, int(intervals), states.get(0))
            steps = self.adjoint.steps_back(self, stepper, states, counts, control, int(intervals))
            sweep_back(sweep, steps, self.sim.backend, ahead)
            return sweep.result()
        finally:
            self.sim.backend.release(ws)

    # -- batches (pure_callback's broadcast_all)
    def _map(self, fn, items):
        if self._pool and len(items) > 1:
            return list(self._pool.map(fn, items))
        return [fn(i) for i in items]

    def forward_batch(self, X, coeffs, mat):
        lead = np.shape(coeffs)[:-1]
        Xs, cs, ms = (split_samples(a, lead) for a in (X, coeffs, mat))

        def one(i):
            u, v, info, trace = self.run(Xs[i], cs[i], ms[i])
            return u, v, info, *trace

        return stack_samples(self._map(one, range(len(cs))), lead)

    def backward_batch(self, X, coeffs, mat, u, v, a, counts, control, intervals, u_bar, v_bar):
        lead = np.shape(coeffs)[:-1]
        args = (X, coeffs, mat, u, v, a, counts, control, intervals, u_bar, v_bar)
        Xs, cs, ms, us, vs, as_, ns, cts, ms_, ub, vb = (split_samples(x, lead) for x in args)

        # a batch's samples on the pool hold the cores already: no factor computed ahead
        ahead = not (self._pool and len(cs) > 1)

        def one(i):
            kept = (us[i], vs[i], as_[i])
            return self.backward(
                Xs[i], cs[i], ms[i], kept, ns[i], cts[i], ms_[i], ub[i], vb[i], ahead
            )

        return stack_samples(self._map(one, range(len(cs))), lead)
