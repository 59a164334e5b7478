"""Equilibrium as a differentiable function: Newton forward, adjoint backward (custom_vjp).

At the solution the free residual vanishes, R_f(u_f*; X, d, mat) = 0, so for a cotangent u_bar_f of
the free displacements the adjoint is  lambda = K_ff^-1 u_bar_f  and
(X, d, mat)_bar = -lambda^T dR_f/d(X, d, mat); the Dirichlet part of u (A d) is differentiated by JAX.

Two drivers of the same Newton iteration (nma.solver.newton):
- traced (a traceable backend, `dense`): one `lax.while_loop`; a batch runs in lockstep under vmap.
- host (SuperLU, PARDISO): the loop runs in Python around jitted halves of an iteration, so the
  compiled kernels hold no host callback (they go to JAX's persistent compilation cache), and a
  batch's samples run concurrently on `workers` threads (XLA and the factorisations release the
  GIL).  Inside a traced program the host driver is one `pure_callback` per batch; each sample keeps
  its workspace (its last factor) until its adjoint, which then costs back-substitutions only.
  A batch's cold solves of one design share their first iteration, the tangent at rest and its
  factor (AtRest): it does not depend on the actuation.
  With solver.escape_saddles (PARDISO: its LDL^T factorisation reports inertia), each converged load
  step and the final state are checked for negative eigenvalues; a saddle is left along its most
  unstable mode and Newton goes on to a stable equilibrium (if leaving fails, the solve is redone
  without, so the option never costs convergence).
  With solver.warm_start, a solve starts from the kept equilibrium nearest in actuation (WarmStarts)
  and is redone from rest where that is not quick; audits compare warm answers with cold ones.
Per-sample results do not depend on the number of threads: samples share nothing but read-only data.
"""
from __future__ import annotations

import itertools
import threading
from collections import Counter, OrderedDict
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..mechanics.energy import energy_force_tangents, quadrature
from .newton import (CONVERGED, ITERATION_LIMIT, RUNNING, Equations, Equilibrium, advance, hold, leave_saddle,
                     linearise, newton_solve, result, setup)
from .options import NewtonOptions
from ..runtime import available_cores

CONTACT_SLOTS = 512  # contact blocks a solve's linearisations have room for at first (a rotation at 11 x 2 at its
                     # largest angle: 169 near of 28,512); more near: 4x as many (kernels compiled once per room)
KEPT_WORKSPACES = 256  # factors awaiting an adjoint; beyond this the oldest go (their adjoint refactorises)
MAX_SADDLE_CHECKS = 16  # converged load steps checked for stability per solve (escape_saddles)
SHIFT_BISECTIONS = 6  # bisections (in log shift) bracketing a saddle's lowest eigenvalue to a factor 10^(1/64)
INVERSE_ITERATIONS = 10  # block inverse iterations for a saddle's most unstable modes
SADDLE_BLOCK = 4  # modes sought at once (the lowest eigenvalues of a symmetric structure come in near pairs)


SAME_EQUILIBRIUM = 1e-6  # an audited warm solve whose displacements differ from the cold one's by more
                         # (max norm, relative to the cold one's largest) reached another equilibrium
MIN_AUDITS, MAX_OTHER_EQUILIBRIA = 8, 0.1  # warm starts stop once more than this fraction of audits differ
KEPT_OTHER_EQUILIBRIA = 100  # audits that found another equilibrium, recorded (difference, energies)


class Start(NamedTuple):
    """Where a warm solve starts: a kept equilibrium's free displacements and prescribed ones, and the
    reference points of the design it was solved on (with contact its walls must not cross on the way
    to this design's)."""
    u_free: np.ndarray
    u_D: np.ndarray
    X: np.ndarray
    audit: bool  # also solve cold, and take the cold answer where they differ


class WarmStarts:
    """The equilibria kept as starting points of later solves: the last `size` converged ones, each
    with its actuation.  A solve starts from the one nearest in actuation, where that is nearer than
    rest.  Nothing here depends on threads: a batch takes its starts before it runs, and keeps its
    results and records its audits after, in sample order.

    A structure with several equilibria under one actuation (a near-mechanism, a buckled wall) can
    reach another from a warm start than from rest.  Every `audit_every`-th warm solve is therefore
    also solved cold; where the two differ the cold answer is taken, and once more than `max_other`
    of at least MIN_AUDITS audits differed, warm starts stop for the rest of the run (`stopped` says
    why).  `clear()` (the trainer's, at every checkpoint) drops what is kept, so that a run resumed there
    solves exactly as one not interrupted; the audits' tallies (`verdict`) go on over the run and into
    the checkpoint (`restore`).  (Counted anew at every checkpoint, as they were, a stage that
    checkpoints every 10 steps never reached MIN_AUDITS: 3 of 14 audits differed and warm starts went
    on.)  `stats` and `other_equilibria` count everything since the simulator was built (they decide
    nothing)."""

    def __init__(self, size: int, audit_every: int, max_other: float = MAX_OTHER_EQUILIBRIA):
        self.size, self.audit_every, self.max_other = size, audit_every, max_other
        self.other_equilibria: list[dict] = []
        self.stats = {"warm_solves": 0, "warm_converged": 0, "warm_iterations": 0, "cold_solves": 0,
                      "cold_iterations": 0, "audits": 0, "audits_same": 0, "audits_within_1e-8": 0,
                      "audit_largest_difference": 0.0, "stops": 0}
        self._lock = threading.Lock()
        self._audits = self._other = 0
        self.enabled, self.stopped = True, ""
        self.clear()

    def clear(self) -> None:
        """Nothing kept (the audits' tallies, and so whether warm starts are on, stay)."""
        self._kept: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []  # (d, u_D, u_free, X)
        self._taken = 0

    @property
    def verdict(self) -> tuple[int, int]:
        """(audits, of them on another equilibrium) over the run: what decides whether warm starts stop."""
        return self._audits, self._other

    def restore(self, audits: int, other: int) -> None:
        """A checkpoint's tallies: a resumed run goes on as the run it continues (stopped where it was)."""
        self._audits, self._other = int(audits), int(other)
        self.enabled, self.stopped = True, ""
        self._judge(count=False)

    def _judge(self, count: bool = True) -> None:
        if self.enabled and self._audits >= MIN_AUDITS and self._other > self.max_other * self._audits:
            self.enabled, self._kept = False, []
            self.stats["stops"] += int(count)
            self.stopped = (f"{self._other} of {self._audits} audited warm solves reached another equilibrium "
                            f"than the cold solve: this design has several under one actuation")

    def start(self, d: np.ndarray) -> Start | None:
        """The start of a solve at actuation d: the kept equilibrium nearest to it, None where nothing
        kept is nearer than rest (or warm starts are off)."""
        if not (self.enabled and self._kept):
            return None
        dist = [np.linalg.norm(d - kept[0]) for kept in self._kept]
        i = int(np.argmin(dist))
        if not dist[i] < np.linalg.norm(d):
            return None
        self._taken += 1
        _, u_D, u_free, X = self._kept[i]
        return Start(u_free, u_D, X, self.audit_every > 0 and self._taken % self.audit_every == 0)

    def keep(self, d, u_D, u_free, X) -> None:
        if self.enabled:
            self._kept.append((np.array(d), np.array(u_D), np.array(u_free), np.array(X)))
            del self._kept[:-self.size]

    def record(self, **counts) -> None:
        with self._lock:  # a batch's samples report from several threads
            for k, v in counts.items():
                self.stats[k] += v

    def audited(self, audit: "Audit") -> None:
        """Record an audit, and stop warm starts where too many found another equilibrium."""
        st, same = self.stats, audit.same
        st["audits"] += 1
        st["audits_same"] += int(same)
        st["audits_within_1e-8"] += int(audit.difference <= 1e-8)
        st["audit_largest_difference"] = max(st["audit_largest_difference"], audit.difference)
        if not same and len(self.other_equilibria) < KEPT_OTHER_EQUILIBRIA:
            self.other_equilibria.append(audit._asdict())
        self._audits += 1
        self._other += int(not same)
        self._judge()

    @contextmanager
    def paused(self):
        """Cold solves only (a run's final evaluation, whose metric is the cold solves', and sim.solve)."""
        enabled, self.enabled = self.enabled, False
        try:
            yield
        finally:
            self.enabled = enabled and not self.stopped


class Audit(NamedTuple):
    """A warm solve also solved cold: the displacements' relative difference (max norm, relative to the
    cold one's largest), and where they differ, the two equilibria's energies."""
    difference: float
    energy_warm: float | None = None
    energy_cold: float | None = None

    @property
    def same(self) -> bool:
        return self.difference <= SAME_EQUILIBRIUM


class AtRest:
    """A design's linearisation at rest, shared by a batch's solves of that design.  Every cold solve
    begins by linearising at rest and factorising that tangent, which depend on the design only (not on
    the actuation), so a batch does both once per design; a warm solve's tolerance comes from the same
    tangent.  The factor is one solver handle, so its back-substitutions take turns."""

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
    """The jitted halves of Newton's iterations and the adjoint's tangent, for Equations with a given
    number of contact slots: one dispatch and one wait per iteration, each kernel ending with the next
    linearisation."""

    def __init__(self, eqs: Equations, opts: NewtonOptions):
        self.start = jax.jit(partial(_start, eqs, opts))
        self.start_warm = jax.jit(partial(_start_warm, eqs, opts))
        self.start_at_rest = jax.jit(partial(_start_at_rest, eqs, opts))
        self.step = jax.jit(partial(_step, eqs, opts))
        self.leave = jax.jit(partial(leave_saddle, eqs, opts))
        self.tangents = jax.jit(partial(tangents_at, eqs))


def tangents_at(eqs: Equations, X, d, mat, u_free):
    """The Tangents at a converged state (the adjoint's matrix)."""
    return energy_force_tangents(eqs.disc, quadrature(eqs.disc, X), eqs.full(u_free, eqs.A @ d), mat,
                                 capacity=eqs.contact_slots)[2]


def energy_at(eqs: Equations, X, d, mat, u_free):
    """The potential energy of a state at full load."""
    return eqs.potential(quadrature(eqs.disc, X), u_free, eqs.A @ d, 1.0, mat)


def pullback(eqs: Equations, X, d, mat, u_free, adjoint):
    """(X, d, mat)_bar = -adjoint^T dR_f/d(X, d, mat) at fixed free displacements."""
    def residual(X, d, mat):
        return eqs.residual(quadrature(eqs.disc, X), u_free, eqs.A @ d, 1.0, mat)

    return jax.vjp(residual, X, d, mat)[1](-adjoint)


class HostNewton:
    """Newton driven from Python around jitted halves of an iteration; batches on a thread pool."""

    def __init__(self, eqs: Equations, backend, opts: NewtonOptions, workers: int = 0):
        self.eqs, self.backend, self.opts = eqs, backend, opts
        self.workers = workers or available_cores()
        self._kernels: dict[int | None, Kernels] = {}  # for each room for contact blocks (None: no contact)
        self.warm = WarmStarts(opts.warm_pool, opts.warm_audit) if opts.warm_start else None
        self._A = np.asarray(eqs.A)
        self._hold = jax.jit(partial(hold, opts))
        self._energy = jax.jit(partial(energy_at, eqs))
        self._pullback = jax.jit(partial(pullback, eqs))
        self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix="nma-newton") if self.workers > 1 else None
        self._kept: OrderedDict[int, object] = OrderedDict()
        self._tokens = itertools.count(1)
        self._lock = threading.Lock()

    def _linearised(self, call, slots: int | None = None, tangents=lambda out: out[-1].kel):
        """call(Kernels) with room for `slots` contact blocks, again with 4x as much until its `tangents`
        hold every near one (the energy and force are exact either way; only the tangent needs the
        room).  Each solve starts with CONTACT_SLOTS and its linearisations carry their room, so that
        what a solve computes depends on its input only, not on the solves before it."""
        slots = slots or CONTACT_SLOTS
        while True:
            room = min(slots, self.eqs.disc.contact.n_blocks) if self.eqs.disc.contact else None
            with self._lock:
                kernels = self._kernels.get(room) or self._kernels.setdefault(
                    room, Kernels(self.eqs.with_contact_slots(room), self.opts))
            out = call(kernels)
            kel = tangents(out)
            if bool(kel.complete):
                return out
            while slots < int(kel.near):
                slots *= 4

    def _map(self, fn, items):
        return list(self._pool.map(fn, items)) if self._pool and len(items) > 1 else [fn(i) for i in items]

    # -- one sample
    def solve(self, X, d, mat, ws, start: Start | None = None, rest: AtRest | None = None):
        """One sample's equilibrium, and its Audit where it had one: from `start` (WarmStarts; rest, this
        design's linearisation at rest, sets the cold tolerance) where given and it converges within
        warm_iters iterations, else from rest (with `rest`'s factor where it has one).  An audited warm
        solve is also solved from rest, and the cold answer taken where they differ."""
        if start is not None:
            escape = self.opts.escape_saddles and self.backend.reports_inertia
            warm = (start.u_free, start.u_D, rest.kel, start.X)
            u, info = self._solve(X, d, mat, ws, escape, warm, self.opts.warm_iters)
            converged = int(info.status) == CONVERGED
            self.warm.record(warm_solves=1, warm_converged=int(converged), warm_iterations=int(info.iterations))
            if converged and not start.audit:
                return u, info, None
            if converged:
                cold, cold_info = self._cold(X, d, mat, ws, rest)
                if int(cold_info.status) != CONVERGED:
                    return u, info, None
                u, cold = np.asarray(u), np.asarray(cold)
                audit = Audit(float(np.max(np.abs(u - cold)) / max(np.max(np.abs(cold)), 1e-300)))
                if audit.same:
                    return u, info, audit
                energy = lambda v: float(self._energy(X, d, mat, v))  # noqa: E731
                return cold, cold_info, audit._replace(energy_warm=energy(u), energy_cold=energy(cold))
        return (*self._cold(X, d, mat, ws, rest), None)

    def _cold(self, X, d, mat, ws, rest: AtRest | None = None):
        if not (self.opts.escape_saddles and self.backend.reports_inertia):
            u, info = self._solve(X, d, mat, ws, False, rest=rest)
        else:
            u, info = self._solve(X, d, mat, ws, True, rest=rest)
            if int(info.status) != CONVERGED:  # leaving a saddle must not cost the solve: take the first stationary point
                u, info = self._solve(X, d, mat, ws, False, rest=rest)
        if self.warm is not None:
            self.warm.record(cold_solves=1, cold_iterations=int(info.iterations))
        return u, info

    def _solve(self, X, d, mat, ws, escape: bool, start=None, budget=None, rest: AtRest | None = None):
        kernels = partial(self.backend.clock.time, "newton_kernels")  # dispatch and wait (XLA runs async)
        checked = set()  # converged load steps whose stability was checked (each once)
        with kernels():
            if start is not None:
                p, s, lin = self._linearised(lambda k: k.start_warm(X, d, mat, *start))
            elif rest is not None:
                p, s, lin = self._linearised(lambda k: k.start_at_rest(X, d, mat, rest.parts))
            else:
                p, s, lin = self._linearised(lambda k: k.start(X, d, mat))
        # the first iteration's factor, where the batch factorised it for this design
        shared = rest if start is None and rest is not None and rest.factorised else None
        while True:
            with kernels():
                status, next_status, shift, predictor, steps, it = jax.device_get(
                    (s.status, lin.state.status, lin.state.shift, lin.state.predictor, lin.state.steps, s.it))
            # a converged state (a load step's, seen at the predictor that follows it, or the final one)
            # whose Hessian has negative eigenvalues is a saddle: leave it along its unstable mode
            at_converged = next_status == CONVERGED or (next_status == RUNNING and predictor)
            check = escape and at_converged and int(steps) not in checked and len(checked) < MAX_SADDLE_CHECKS
            if status != RUNNING:  # lin (of a state that ended) is not used
                break
            if budget is not None and next_status == RUNNING and it >= budget:  # a warm start that is not quick
                s = self._hold(lin)._replace(status=jnp.asarray(ITERATION_LIMIT))
                break
            if next_status != RUNNING and not check:
                s = self._hold(lin)
                break
            factor, shared = shared or ws, None
            # a converged state's factor is of K itself (its inertia; the adjoint's), else of the step's K + shift I
            if factor is ws:
                ws.factorise(lin.kel, 0.0 if next_status != RUNNING or check else float(shift))
            if check:
                checked.add(int(steps))
                negative = factor.inertia if factor is not ws else self.backend.inertia(ws)
                left = self._leave_saddle(p, lin, ws) if negative else None
                if left is not None:
                    lin = left
                    continue
                if next_status != RUNNING:
                    s = self._hold(lin)
                    break
                if factor is ws and float(shift):  # the predictor that follows is solved with the kept shift
                    ws.factorise(lin.kel, float(shift))
            du = factor.solve(lin.rhs)
            with kernels():
                s, lin = self._linearised(lambda k, lin=lin: k.step(p, lin, du), lin.kel.which.shape[-1])
        self.backend.count("newton_solves")
        self.backend.count("newton_iterations", int(s.it))
        return result(s)

    def _leave_saddle(self, p, lin, ws):
        """Find the saddle's most unstable mode and step along it.  Soft stable modes of thin walls can
        lie nearer zero than the unstable ones, so the search is shifted: the inertia of K + sigma I
        counts the eigenvalues below -sigma, and bisection on it (in log sigma) brackets the lowest
        eigenvalue, -sigma_hi < lambda_min <= -sigma_lo; inverse iteration with the (positive definite)
        factor of K + sigma_hi I then amplifies the lowest modes most, and Rayleigh-Ritz on a block of
        them gives the direction of most negative curvature. None if the energy does not fall along it."""
        with self.backend.clock.time("saddles"):
            kel = jax.device_get(lin.kel)
            unstable = lambda sigma: ws.factorise(kel, sigma) or self.backend.inertia(ws)
            lo, hi = 0.0, 1e-9 * float(lin.state.k_ref)
            while unstable(hi):
                lo, hi = hi, 10.0 * hi
                if hi > float(lin.state.k_ref):
                    return None
            for _ in range(SHIFT_BISECTIONS):
                mid = np.sqrt(lo * hi) if lo > 0 else 0.1 * hi
                lo, hi = (mid, hi) if unstable(mid) else (lo, mid)
            if not (lo > 0 or unstable(0.0)):
                return None
            ws.factorise(kel, hi)
            A = self.backend.pattern.matrix(kel)
            V = np.random.default_rng(0).standard_normal((A.shape[0], SADDLE_BLOCK))  # reproducible
            for _ in range(INVERSE_ITERATIONS):
                V = np.linalg.qr(ws.solve(V))[0]
            KV = np.column_stack([self.backend.matvec(A, V[:, j]) for j in range(SADDLE_BLOCK)])
            theta, Y = np.linalg.eigh(0.5 * (V.T @ KV + KV.T @ V))
            v, curvature = V @ Y[:, 0], float(theta[0])
            if not curvature < 0:
                return None
            left, ok = self._linearised(lambda k: k.leave(p, lin, jnp.asarray(v), curvature), lin.kel.which.shape[-1],
                                        lambda out: out[0].kel)
            if not bool(ok):
                return None
            self.backend.count("saddles_left")
            return left

    def adjoint(self, X, d, mat, u_free, u_bar, ws):
        kernels = partial(self.backend.clock.time, "adjoint_kernels")
        with kernels():
            kel = jax.block_until_ready(self._linearised(lambda k: k.tangents(X, d, mat, u_free),
                                                         tangents=lambda kel: kel))
        lam = ws.adjoint(kel, u_bar)
        with kernels():
            return jax.block_until_ready(self._pullback(X, d, mat, u_free, jnp.asarray(lam)))

    # -- batches (any leading batch shape; what pure_callback's broadcast_all hands over)
    def forward_batch(self, X, d, mat, keep: bool):
        with self.backend.clock.time("forward_batches"):
            return self._forward_batch(X, d, mat, keep)

    def backward_batch(self, *args):
        with self.backend.clock.time("backward_batches"):
            return self._backward_batch(*args)

    def _forward_batch(self, X, d, mat, keep: bool):
        lead = np.shape(d)[:-1]
        Xs, ds, mats = (_samples(a, lead) for a in (X, d, mat))

        # the starts are taken before the batch runs, its results kept and its audits recorded after, in
        # sample order: what warm starts do does not depend on the threads
        starts = [self.warm.start(d) if self.warm else None for d in ds]
        audits = [None] * len(ds)
        rests = self._at_rest(Xs, ds, mats, starts)

        def one(i):
            ws = self.backend.workspace()
            u, info, audits[i] = self.solve(Xs[i], ds[i], mats[i], ws, starts[i], rests[i])
            token = 0
            if keep:
                token = next(self._tokens)
                with self._lock:
                    self._kept[token] = ws
                    while len(self._kept) > KEPT_WORKSPACES:
                        self.backend.release(self._kept.popitem(last=False)[1])
            else:
                self.backend.release(ws)
            return np.asarray(u), jax.tree_util.tree_map(np.asarray, info), np.int64(token)

        try:
            solved = self._map(one, range(len(ds)))
        finally:
            for rest in {id(r): r for r in rests if r is not None}.values():
                rest.release()
        if self.warm is not None:
            for X, d, (u, info, _), audit in zip(Xs, ds, solved, audits):
                if audit is not None:
                    self.warm.audited(audit)
                if int(info.status) == CONVERGED:
                    self.warm.keep(d, self._A @ d, u, X)
        return _stack(solved, lead)

    def _at_rest(self, Xs, ds, mats, starts) -> list[AtRest | None]:
        """Each sample's design linearised at rest, once per design of the batch, where the design has a
        warm solve (its tolerance) or two cold ones or more (then also factorised: their first iteration).
        Every cold solve of such a design starts from it."""
        keys = [(Xs[i].tobytes(), mats[i].tobytes()) for i in range(len(ds))]
        cold = Counter(k for k, start in zip(keys, starts) if start is None)
        warm = {k for k, start in zip(keys, starts) if start is not None}
        rests = {}
        for i, k in enumerate(keys):
            if k not in rests and (cold[k] > 1 or k in warm):
                with self.backend.clock.time("newton_kernels"):
                    lin = jax.block_until_ready(self._linearised(lambda k: k.start(Xs[i], ds[i], mats[i]))[2])
                finite = all(np.all(np.isfinite(K)) for K in lin.kel[:2])  # else every solve of it ends at once (NONFINITE_INPUT)
                rests[k] = AtRest(self.backend, lin, factorise=cold[k] > 1 and finite)
        return [rests.get(k) for k in keys]

    def _backward_batch(self, X, d, mat, u_free, u_bar, token):
        lead = np.shape(d)[:-1]
        Xs, ds, mats, us, bars, tokens = (_samples(a, lead) for a in (X, d, mat, u_free, u_bar, token))
        with self._lock:  # one workspace per token, even if a token comes more than once (jacrev)
            kept = {int(t): self._kept.pop(int(t), None) for t in set(tokens.tolist())}
        spaces = {t: ws or self.backend.workspace() for t, ws in kept.items()}

        def one(i):
            return jax.tree_util.tree_map(
                np.asarray, self.adjoint(Xs[i], ds[i], mats[i], us[i], bars[i], spaces[int(tokens[i])]))

        out = self._map(one, range(len(ds)))
        for ws in spaces.values():
            self.backend.release(ws)
        return _stack(out, lead)


def _start(eqs, opts, X, d, mat):
    p, s = setup(eqs, opts, X, d, mat)
    return p, s, linearise(eqs, opts, p, s)


def _start_at_rest(eqs, opts, X, d, mat, at_rest):
    p, s = setup(eqs, opts, X, d, mat)
    return p, s, linearise(eqs, opts, p, s, at_rest)


def _start_warm(eqs, opts, X, d, mat, u0, u_D0, kel_rest, X0):
    p, s = setup(eqs, opts, X, d, mat, (u0, u_D0, kel_rest, X0))
    return p, s, linearise(eqs, opts, p, s)


def _step(eqs, opts, p, lin, du):
    s = advance(eqs, opts, p, lin, du)
    return s, linearise(eqs, opts, p, s)


def _stack(samples: list, lead: tuple):
    """Per-sample result trees as one tree with batch dimensions `lead`."""
    return jax.tree_util.tree_map(lambda *xs: np.stack(xs).reshape(lead + np.shape(xs[0])), *samples)


def _samples(a, lead: tuple) -> np.ndarray:
    """A callback argument with batch dimensions `lead` as a flat list of samples."""
    a = np.asarray(a)
    return a.reshape((int(np.prod(lead)),) + a.shape[len(lead):])


def make_equilibrium(eqs: Equations, backend, opts: NewtonOptions, workers: int = 0):
    """Return (equilibrium, warm starts): equilibrium(X, d, mat) -> Equilibrium (u (n_points, 2),
    NewtonInfo), differentiable in X, d, mat; the WarmStarts it keeps (None where it keeps none: warm
    starts off, or a traced backend, whose batch runs in lockstep from rest)."""
    warm = None
    if backend.traceable:
        solve_free = _traced_solve(eqs, backend, opts)
    else:
        newton = HostNewton(eqs, backend, opts, workers)
        solve_free, warm = _host_solve(newton), newton.warm

    def equilibrium(X, d, mat):
        u_free, info = solve_free(X, d, mat)
        # a failed solve's state is at the load it reached (a failed solve is a cold one: its load path
        # scales the prescribed displacements from zero)
        reached = jnp.where(info.status == CONVERGED, 1.0, info.load)
        return Equilibrium(eqs.full(u_free, eqs.A @ (reached * d)), info)

    return equilibrium, warm


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
        return pullback(eqs, X, d, mat, u_free, adjoint)

    solve_free.defvjp(fwd, bwd)
    return solve_free


def _host_solve(newton: HostNewton):
    eqs, opts = newton.eqs, newton.opts

    def call(X, d, mat, keep):
        solved = jax.eval_shape(lambda X, d, mat: result(setup(eqs, opts, X, d, mat)[1]), X, d, mat)
        shapes = (*solved, jax.ShapeDtypeStruct((), jnp.int64))  # u_free, info, workspace token
        return jax.pure_callback(partial(newton.forward_batch, keep=keep), shapes, X, d, mat,
                                 vmap_method="broadcast_all")

    @jax.custom_vjp
    def solve_free(X, d, mat):
        u_free, info, _ = call(X, d, mat, False)
        return u_free, info

    def fwd(X, d, mat):
        u_free, info, token = call(X, d, mat, True)
        return (u_free, info), (X, d, mat, u_free, token)

    def bwd(res, cotangents):
        X, d, mat, u_free, token = res
        out = (jax.ShapeDtypeStruct(X.shape, X.dtype), jax.ShapeDtypeStruct(d.shape, d.dtype),
               jax.ShapeDtypeStruct(mat.shape, mat.dtype))
        return jax.pure_callback(newton.backward_batch, out, X, d, mat, u_free, cotangents[0], token,
                                 vmap_method="broadcast_all")

    solve_free.defvjp(fwd, bwd)
    return solve_free
