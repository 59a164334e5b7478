"""Newton driven from Python around jitted halves of an iteration (host linear backends: SuperLU,
PARDISO): the compiled kernels hold no host callback (they go to JAX's persistent compilation
cache). One sample at a time here; nma.solver.batch runs a batch's samples on a thread pool.  A
batch's cold solves of one design share their first iteration, the tangent at rest and its factor
(AtRest): it does not depend on the actuation."""

from __future__ import annotations

import threading
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from . import saddles
from .equations import Equations, compiled, energy_at, pullback, tangents_at
from .newton import advance, hold, leave_saddle, linearise, result
from .options import NewtonOptions
from .starts import continue_in_time, setup
from .status import Status
from .warm import Audit, Start, WarmStarts

# contact blocks a solve's linearisations have room for at first (the near ones of the scenes'
# largest actuations); more near: 4x as many (kernels compiled once per room)
CONTACT_SLOTS = 512


class AtRest:
    """A design's linearisation at rest, shared by a batch's solves of that design.  Every cold
    solve begins by linearising at rest and factorising that tangent, which depend on the design
    only (not on the actuation), so a batch does both once per design; a warm solve's tolerance
    comes from the same tangent.  The factor is one solver handle, so its back-substitutions take
    turns."""

    def __init__(self, backend, lin, factorise: bool):
        self.parts = (lin.energy, lin.g, lin.kel)  # potential, free residual, element tangents
        self._backend, self._ws, self.inertia = backend, None, None
        if factorise:
            self._ws = backend.workspace()
            self._ws.factorise(lin.kel, 0.0)  # a cold start's first iteration: no diagonal shift
            self.inertia = backend.inertia(self._ws)
        self._lock = threading.Lock()

    @property
    def kel(self):
        return self.parts[2]

    @property
    def factorised(self) -> bool:
        return self._ws is not None

    def solve(self, b) -> np.ndarray:
        with self._lock:
            return self._ws.solve(b)

    def release(self) -> None:
        if self._ws is not None:
            self._backend.release(self._ws)


class Kernels:
    """The jitted halves of Newton's iterations and the adjoint's tangent, for Equations with a
    given number of contact slots: one dispatch and one wait per iteration, each kernel ending with
    the next linearisation (a step that fell short of where it linearised: `relinearise` too)."""

    @classmethod
    def of(cls, eqs: Equations, opts: NewtonOptions, room: int | None) -> "Kernels":
        """The kernels of `eqs` under `opts` with room for `room` contact blocks (None: no
        contact), built once per discretisation's content (nma.solver.equations.compiled): shared
        by every HostNewton on it or on an equal one (the Simulators built on one scene and
        fidelity, and their Dynamics' steps), so that each is traced once."""
        return compiled(
            eqs, ("newton", opts, room), lambda: cls(eqs.with_contact_slots(room), opts)
        )

    def __init__(self, eqs: Equations, opts: NewtonOptions):
        self.start = jax.jit(partial(_start, eqs, opts))
        self.start_warm = jax.jit(partial(_start_warm, eqs, opts))
        self.start_at_rest = jax.jit(partial(_start_at_rest, eqs, opts))
        self.start_step = jax.jit(partial(_start_step, eqs, opts))
        self.step = jax.jit(partial(advance, eqs, opts))
        self.relinearise = jax.jit(partial(linearise, eqs, opts))
        self.leave = jax.jit(partial(leave_saddle, eqs, opts))
        self.tangents = jax.jit(partial(tangents_at, eqs))
        self.hold = jax.jit(partial(hold, opts))
        self.energy = jax.jit(partial(energy_at, eqs))
        self.pullback = jax.jit(partial(pullback, eqs))


class HostNewton:
    """Newton driven from Python around jitted halves of an iteration, one sample at a time (any
    number of threads may each solve one: samples share nothing but read-only data); warm starts
    where the options ask for them."""

    def __init__(self, eqs: Equations, backend, opts: NewtonOptions):
        self.eqs, self.backend, self.opts = eqs, backend, opts
        self.warm = WarmStarts(opts.warm_pool, opts.warm_audit) if opts.warm_start else None
        # what needs no contact room: the equations' own (every block)
        self._kernels = Kernels.of(eqs, opts, None)

    def linearised(self, call, slots: int | None = None, tangents=lambda out: out[-1].kel):
        """call(Kernels) with room for `slots` contact blocks, again with 4x as much until its
        `tangents` hold every near one (the energy and force are exact either way; only the tangent
        needs the room).  Each solve starts with CONTACT_SLOTS and its linearisations carry their
        room, so that what a solve computes depends on its input only, not on the solves before
        it."""
        slots = slots or CONTACT_SLOTS
        while True:
            room = min(slots, self.eqs.solid.contact.n_blocks) if self.eqs.solid.contact else None
            out = call(Kernels.of(self.eqs, self.opts, room))
            kel = tangents(out)
            if bool(kel.complete):
                return out
            while slots < int(kel.near):
                slots *= 4

    # -- one sample
    def solve(self, X, d, mat, ws, start: Start | None = None, rest: AtRest | None = None):
        """One sample's equilibrium, and its Audit where it had one: from `start` (WarmStarts; rest,
        this design's linearisation at rest, sets the cold tolerance) where given and it converges
        within warm_iters iterations, else from rest (with `rest`'s factor where it has one).  An
        audited warm solve is also solved from rest, and the cold answer taken where they differ."""
        if start is not None:
            escape = self.opts.escape_saddles and self.backend.reports_inertia
            warm = (start.u_free, start.u_D, rest.kel, start.X)
            u, info = self._solve(X, d, mat, ws, escape, warm, self.opts.warm_iters)
            converged = int(info.status) == Status.CONVERGED
            self.warm.record(
                warm_solves=1, warm_converged=int(converged), warm_iterations=int(info.iterations)
            )
            if converged and not start.audit:
                return u, info, None
            if converged:
                cold, cold_info = self._cold(X, d, mat, ws, rest)
                if int(cold_info.status) != Status.CONVERGED:
                    return u, info, None
                u, cold = np.asarray(u), np.asarray(cold)
                audit = Audit(float(np.max(np.abs(u - cold)) / max(np.max(np.abs(cold)), 1e-300)))
                if audit.same:
                    return u, info, audit
                energy = lambda v: float(self._kernels.energy(X, d, mat, v))
                return (
                    cold,
                    cold_info,
                    audit._replace(energy_warm=energy(u), energy_cold=energy(cold)),
                )
        return (*self._cold(X, d, mat, ws, rest), None)

    def _cold(self, X, d, mat, ws, rest: AtRest | None = None):
        if not (self.opts.escape_saddles and self.backend.reports_inertia):
            u, info = self._solve(X, d, mat, ws, False, rest=rest)
        else:
            u, info = self._solve(X, d, mat, ws, True, rest=rest)
            # leaving a saddle must not cost the solve: take the first stationary point
            if int(info.status) != Status.CONVERGED:
                u, info = self._solve(X, d, mat, ws, False, rest=rest)
        if self.warm is not None:
            self.warm.record(cold_solves=1, cold_iterations=int(info.iterations))
        return u, info

    def time_step(self, X, d, mat, ws, start, inertia, previous=None):
        """One implicit time step (nma.dynamics): Newton from `start` = (u_free, u_D, kel_rest, X)
        of the previous state, its potential with the step's Inertia.  `previous`: the last step's
        (Problem, Linearised) at its converged end, which must be `start` under the same X and mat
        (they are then taken from it): this step begins from that linearisation (its elastic part is
        this step's; only the Inertia changes).  Returns (u_free, NewtonInfo, this step's (Problem,
        Linearised) at its end)."""
        kernels = partial(self.backend.clock.time, "newton_kernels")
        with kernels():
            if previous is None:
                p, s, lin = self.linearised(lambda k: k.start_warm(X, d, mat, *start, inertia))
            else:
                p, s, lin = self.linearised(
                    lambda k: k.start_step(*previous, d, inertia), previous[1].kel.which.shape[-1]
                )
        s, lin = self._iterate(p, s, lin, ws, False)
        return (*result(s), (p, lin))

    def _solve(
        self, X, d, mat, ws, escape: bool, start=None, budget=None, rest: AtRest | None = None
    ):
        with self.backend.clock.time("newton_kernels"):  # dispatch and wait (XLA runs async)
            if start is not None:
                p, s, lin = self.linearised(lambda k: k.start_warm(X, d, mat, *start))
            elif rest is not None:
                p, s, lin = self.linearised(lambda k: k.start_at_rest(X, d, mat, rest.parts))
            else:
                p, s, lin = self.linearised(lambda k: k.start(X, d, mat))
        # the first iteration's factor, where the batch factorised it for this design
        shared = rest if start is None and rest is not None and rest.factorised else None
        return result(self._iterate(p, s, lin, ws, escape, budget, shared)[0])

    def _iterate(self, p, s, lin, ws, escape: bool, budget=None, shared: AtRest | None = None):
        """Newton's iterations from a started solve to its end: (the final state, its last
        linearisation)."""
        # dispatch and wait (XLA runs async)
        kernels = partial(self.backend.clock.time, "newton_kernels")
        checked = set()  # converged load steps whose stability was checked (each once)
        speculate = True  # whether the next step linearises at its full length first
        while True:
            with kernels():
                status, next_status, shift, predictor, steps, it = jax.device_get(
                    (
                        s.status,
                        lin.state.status,
                        lin.state.shift,
                        lin.state.predictor,
                        lin.state.steps,
                        s.it,
                    )
                )
            # a converged state (a load step's, seen at the predictor that follows it, or the final
            # one) whose Hessian has negative eigenvalues is a saddle: leave it along its unstable
            # mode
            at_converged = next_status == Status.CONVERGED or (
                next_status == Status.RUNNING and predictor
            )
            check = (
                escape
                and at_converged
                and int(steps) not in checked
                and len(checked) < saddles.MAX_SADDLE_CHECKS
            )
            if status != Status.RUNNING:  # lin (of a state that ended) is not used
                break
            # a warm start that is not quick
            if budget is not None and next_status == Status.RUNNING and it >= budget:
                s = self._kernels.hold(lin)._replace(status=jnp.asarray(Status.ITERATION_LIMIT))
                break
            if next_status != Status.RUNNING and not check:
                s = self._kernels.hold(lin)
                break
            factor, shared = shared or ws, None
            # a converged state's factor is of K itself (its inertia; the adjoint's), else of the
            # step's K + shift I
            if factor is ws:
                ws.factorise(
                    lin.kel, 0.0 if next_status != Status.RUNNING or check else float(shift)
                )
            if check:
                checked.add(int(steps))
                negative = factor.inertia if factor is not ws else self.backend.inertia(ws)
                left = saddles.leave(self, p, lin, ws) if negative else None
                if left is not None:
                    lin = left
                    continue
                if next_status != Status.RUNNING:
                    s = self._kernels.hold(lin)
                    break
                # the predictor that follows is solved with the kept shift
                if factor is ws and float(shift):
                    ws.factorise(lin.kel, float(shift))
            du = factor.solve(lin.rhs)
            with kernels():
                s, lin, speculate = self.linearised(
                    lambda k, lin=lin: _advanced(k, p, lin, du, speculate),
                    lin.kel.which.shape[-1],
                    lambda out: out[1].kel,
                )
        self.backend.count("newton_solves")
        self.backend.count("newton_iterations", int(s.it))
        return s, lin

    def adjoint(self, X, d, mat, u_free, u_bar, ws):
        kernels = partial(self.backend.clock.time, "adjoint_kernels")
        with kernels():
            kel = jax.block_until_ready(
                self.linearised(lambda k: k.tangents(X, d, mat, u_free), tangents=lambda kel: kel)
            )
        lam = ws.adjoint(kel, u_bar)
        with kernels():
            return jax.block_until_ready(
                self._kernels.pullback(X, d, mat, u_free, jnp.asarray(lam))
            )


def _start(eqs, opts, X, d, mat):
    p, s = setup(eqs, opts, X, d, mat)
    return p, s, linearise(eqs, opts, p, s)


def _start_at_rest(eqs, opts, X, d, mat, at_rest):
    p, s = setup(eqs, opts, X, d, mat)
    return p, s, linearise(eqs, opts, p, s, at_rest)


def _start_warm(eqs, opts, X, d, mat, u0, u_D0, kel_rest, X0, inertia=None):
    p, s = setup(eqs, opts, X, d, mat, (u0, u_D0, kel_rest, X0), inertia)
    return p, s, linearise(eqs, opts, p, s)


def _start_step(eqs, opts, p, lin, d, inertia):
    p, s, at = continue_in_time(eqs, opts, p, lin, d, inertia)
    return p, s, linearise(eqs, opts, p, s, at)


def _advanced(kernels: Kernels, p, lin, du, speculate: bool):
    """The step du, the linearisation at its end (the step kernel's where the step landed where it
    linearised, else afresh) and whether the next step speculates (nma.solver.newton.advance)."""
    s, lin, landed, full = kernels.step(p, lin, du, jnp.asarray(speculate))
    landed, full = jax.device_get((landed, full))
    return (s, lin if landed else kernels.relinearise(p, s), bool(full))
