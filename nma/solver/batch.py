"""A batch of host solves (any leading batch shape: what pure_callback's broadcast_all hands over)
on a thread pool of `workers` threads (XLA and the factorisations release the GIL).  Each sample
keeps its workspace (its last factor) until its adjoint, which then costs back-substitutions only.
Warm starts are taken before a batch runs and kept after, in sample order, so per-sample results do
not depend on the number of threads."""

from __future__ import annotations

import itertools
import threading
from collections import Counter, OrderedDict
from concurrent.futures import ThreadPoolExecutor

import jax
import numpy as np

from ..runtime import available_cores
from .host import AtRest, HostNewton
from .status import Status

# factors awaiting an adjoint; beyond this the oldest go (their adjoint refactorises)
KEPT_WORKSPACES = 256


class HostBatches:
    """Batches of a HostNewton's solves and adjoints on a thread pool."""

    def __init__(self, newton: HostNewton, workers: int = 0):
        self.newton, self.backend = newton, newton.backend
        self.workers = workers or available_cores()
        self._A = np.asarray(newton.eqs.A)
        self._pool = (
            ThreadPoolExecutor(self.workers, thread_name_prefix="nma-newton")
            if self.workers > 1
            else None
        )
        self._kept: OrderedDict[int, object] = OrderedDict()
        self._tokens = itertools.count(1)
        self._lock = threading.Lock()

    @property
    def warm(self):
        return self.newton.warm

    def _map(self, fn, items):
        return (
            list(self._pool.map(fn, items))
            if self._pool and len(items) > 1
            else [fn(i) for i in items]
        )

    def forward_batch(self, X, d, mat, keep: bool):
        with self.backend.clock.time("forward_batches"):
            return self._forward_batch(X, d, mat, keep)

    def backward_batch(self, *args):
        with self.backend.clock.time("backward_batches"):
            return self._backward_batch(*args)

    def _forward_batch(self, X, d, mat, keep: bool):
        lead = np.shape(d)[:-1]
        Xs, ds, mats = (split_samples(a, lead) for a in (X, d, mat))

        # the starts are taken before the batch runs, its results kept and its audits recorded
        # after, in sample order: what warm starts do does not depend on the threads
        starts = [self.warm.start(d) if self.warm else None for d in ds]
        audits = [None] * len(ds)
        rests = self._at_rest(Xs, ds, mats, starts)

        def one(i):
            ws = self.backend.workspace()
            u, info, audits[i] = self.newton.solve(Xs[i], ds[i], mats[i], ws, starts[i], rests[i])
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
                if int(info.status) == Status.CONVERGED:
                    self.warm.keep(d, self._A @ d, u, X)
        return stack_samples(solved, lead)

    def _at_rest(self, Xs, ds, mats, starts) -> list[AtRest | None]:
        """Each sample's design linearised at rest, once per design of the batch, where the design
        has a warm solve (its tolerance) or two cold ones or more (then also factorised: their first
        iteration). Every cold solve of such a design starts from it."""
        keys = [(Xs[i].tobytes(), mats[i].tobytes()) for i in range(len(ds))]
        cold = Counter(k for k, start in zip(keys, starts) if start is None)
        warm = {k for k, start in zip(keys, starts) if start is not None}
        rests = {}
        for i, k in enumerate(keys):
            if k not in rests and (cold[k] > 1 or k in warm):
                with self.backend.clock.time("newton_kernels"):
                    lin = jax.block_until_ready(
                        self.newton.linearised(lambda k: k.start(Xs[i], ds[i], mats[i]))[2]
                    )
                # else every solve of it ends at once (NONFINITE_INPUT)
                finite = all(np.all(np.isfinite(K)) for K in lin.kel[:2])
                rests[k] = AtRest(self.backend, lin, factorise=cold[k] > 1 and finite)
        return [rests.get(k) for k in keys]

    def _backward_batch(self, X, d, mat, u_free, u_bar, token):
        lead = np.shape(d)[:-1]
        Xs, ds, mats, us, bars, tokens = (
            split_samples(a, lead) for a in (X, d, mat, u_free, u_bar, token)
        )
        with self._lock:  # one workspace per token, even if a token comes more than once (jacrev)
            kept = {int(t): self._kept.pop(int(t), None) for t in set(tokens.tolist())}
        spaces = {t: ws or self.backend.workspace() for t, ws in kept.items()}

        def one(i):
            # nothing flows back (a failed sample a loss masks out): no adjoint to solve, nor a
            # singular tangent's NaN
            if not np.any(bars[i]):
                return tuple(np.zeros_like(a) for a in (Xs[i], ds[i], mats[i]))
            return jax.tree_util.tree_map(
                np.asarray,
                self.newton.adjoint(Xs[i], ds[i], mats[i], us[i], bars[i], spaces[int(tokens[i])]),
            )

        out = self._map(one, range(len(ds)))
        for ws in spaces.values():
            self.backend.release(ws)
        return stack_samples(out, lead)


def stack_samples(samples: list, lead: tuple):
    """Per-sample result trees as one tree with batch dimensions `lead`."""
    return jax.tree_util.tree_map(
        lambda *xs: np.stack(xs).reshape(lead + np.shape(xs[0])), *samples
    )


def split_samples(a, lead: tuple) -> np.ndarray:
    """A callback argument with batch dimensions `lead` as a flat list of samples."""
    a = np.asarray(a)
    return a.reshape((int(np.prod(lead)),) + a.shape[len(lead) :])
