"""The trainer's evaluation: its metric on the task's evaluation set at the current parameters, with
every converged state checked for a physical object (nma.geometry.validity)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from ..geometry.validity import StateChecker
from ..solver.status import Status


@dataclass
class Evaluation:
    """One evaluation at the current parameters: what metrics.json records of it, and the solved
    states that the figures and the HDF5 fields draw."""

    # step, the task's metric (mean over every sample) and extra metrics, failed_solves,
    # failed_samples (their per_sample values: Task.failed_score), over_converged (the mean
    # over the others, or None), validity summary, invalid_samples, per_sample, eval_actuations
    record: dict
    X: Any  # (n_points, 2) reference control points
    d: Any  # (n, n_actuations) actuations
    u: Any  # (n, n_points, 2) displacements
    out: Any  # the task's observations of each state
    ts: Any  # the descriptors
    ok: np.ndarray  # (n,) converged
    validity: list  # each converged state's Validity; None where the solve failed
    motion: Any = None  # a task in time: each sample's trajectory (u is the state it shows)


class TrainerEvaluation:
    """The evaluations of nma.train.trainer.Trainer, a part of it: they read its task, simulator,
    state and settings."""

    def eval_subset(self):
        """The evaluation samples of an evaluation before the last: trainer.eval_subset of them,
        evenly spaced through the task's evaluation set (all of it where that is no larger)."""
        ts = self.task.eval_set()
        n = len(jax.tree_util.tree_leaves(ts)[0])
        if self.cfg.eval_subset is None or self.cfg.eval_subset >= n:
            return ts
        idx = np.linspace(0, n - 1, self.cfg.eval_subset).round().astype(int)
        return jax.tree_util.tree_map(lambda a: a[idx], ts)

    def evaluate(self, ts=None) -> Evaluation:
        """The metric on the task's evaluation set (or on descriptors `ts`) at the current
        parameters."""
        ts = self.task.eval_set() if ts is None else ts
        X, d, u, out, info = self._evaluate(self.state["params"], ts)
        status = np.asarray(info.status)
        ok = status == Status.CONVERGED
        rest = None if ok.all() else self._at_rest(self.state["params"])
        metric = self.task.scored(self.task.metric, out, ts, ok, rest)
        extras = {
            k: float(np.mean(self.task.scored(fn, out, ts, ok, rest)))
            for k, fn in self.task.sample_metrics().items()
        }
        # is every converged state a physical object? (no inverted material, no wall through a wall)
        states, checked = self.task.check_states(
            StateChecker(self.sim.disc.mesh, np.asarray(X)), u, ok
        )
        invalid = {
            str(i): v.problems() for i, v in enumerate(states) if v is not None and not v.valid
        }
        record = {
            "step": self.state["step"],
            self.task.metric_name: self.task.aggregate(metric),
            **extras,
            "failed_solves": int((~ok).sum()),
            "failed_samples": np.flatnonzero(~ok).tolist(),
            "over_converged": self.task.aggregate(metric[ok]) if ok.any() else None,
            "stopped_inverting": int(
                (status == Status.INVERTS).sum()
            ),  # of the failed, those the element bound stopped
            **checked,
            "invalid_samples": invalid,
            "per_sample": metric.tolist(),
            "eval_actuations": np.asarray(d).tolist(),
            **(self.features.report(X) if self.features is not None else {}),
        }
        # how the run's solves started, and whether warm starts held
        if self.sim.solver_record() is not None:
            record["warm_starts"] = self.sim.solver_record()
        return Evaluation(
            record, X, d, self.task.shown(u), out, ts, ok, states, u if self.task.in_time else None
        )

    def final_evaluation(self, ts=None) -> Evaluation:
        """The run's metric: every evaluation sample (or the descriptors `ts`), each solved from
        rest (warm starts paused), so that it means what a cold solve of the design means, however
        training started its solves."""
        with self.sim.cold_solves():
            return self.evaluate(ts)
