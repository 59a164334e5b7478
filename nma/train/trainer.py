"""The generic trainer: any registered task, the encoder and the geometry, optimised jointly.

One step reads as the data flow of the design:
    t = task.sample(key_step)        the global batch (same on every rank); this rank takes its shard
    d = encoder(theta, t)            actuations, d_max * tanh
    X = scene.reference(phi)         differentiable design map
    u = equilibrium(X, d)            Newton forward, adjoint backward
    loss = task.loss(task.observe(phi, X, u, mat), t)  [+ w * inversion_penalty(X, u): trainer.inversion_penalty]
    grads -> sum over ranks -> mean over converged samples -> optax update -> project phi to its box
A sample whose solve does not converge is left out of the mean (and counted in the log); a step in
which no sample converges stops the run with the solver's error.
"""
from __future__ import annotations

import contextlib
import json
import logging
import signal
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.flatten_util import ravel_pytree

from ..errors import ConfigError, Stopped, TrainingError
from ..geometry.validity import StateChecker
from ..mechanics.energy import inversion_penalty
if TYPE_CHECKING:  # the settings' types, for the reader: the trainer reads their fields only
    from ..schema import OptimConfig, TrainerConfig
from ..solver.status import Status, failure
from . import checkpoint
from .optimizer import FAILED_STEP_ADVICE, diagnose, make_optimizer, nonfinite_groups
from .mpi import World

log = logging.getLogger(__name__)


@dataclass
class Evaluation:
    """One evaluation at the current parameters: what metrics.json records of it, and the solved states
    that the figures and the HDF5 fields draw."""
    record: dict       # step, the task's metric (mean over every sample) and extra metrics, failed_solves,
                       # failed_samples (their per_sample values: Task.failed_score), over_converged (the mean
                       # over the others, or None), validity summary, invalid_samples, per_sample, eval_actuations
    X: Any             # (n_points, 2) reference control points
    d: Any             # (n, n_actuations) actuations
    u: Any             # (n, n_points, 2) displacements
    out: Any           # the task's observations of each state
    ts: Any            # the descriptors
    ok: np.ndarray     # (n,) converged
    validity: list     # each converged state's Validity; None where the solve failed
    motion: Any = None  # a task in time: each sample's trajectory (u is the state it shows)


class Trainer:
    def __init__(self, task, sim, model, mat, tcfg: TrainerConfig, ocfg: OptimConfig, run_dir: Path,
                 logger=None, world: World | None = None, fingerprint: dict | None = None, exact_init: bool = False,
                 absent: dict | None = None, features=None):
        self.task, self.sim, self.model, self.mat = task, sim, model, mat
        self.cfg, self.ocfg, self.run_dir = tcfg, ocfg, Path(run_dir)
        self.fingerprint = fingerprint or {}
        self.absent = absent or {}  # what a setting missing from a checkpoint's fingerprint means
        self.features = features  # nma.geometry.features.Ligaments: reported at each evaluation; with a bound, enforced
        self.world = world or World()
        self.logger = logger
        self.shard = self.world.shard(tcfg.batch_size)
        key = jax.random.PRNGKey(tcfg.seed)
        self.data_key, init_key = jax.random.split(key)
        t0 = task.sample(init_key, 1)
        geom = sim.init_params()
        strong = lambda tree: jax.tree_util.tree_map(lambda a: jnp.array(a, dtype=a.dtype), tree)
        params = strong({"net": model.init(init_key, task.net_input(t0)), "geom": geom})  # no weak types: one compile
        self.tx = make_optimizer(ocfg, list(geom), tcfg.freeze_geometry, tcfg.steps, tcfg.max_nonfinite_steps,
                                 task.frozen_geometry)
        if tcfg.init_from:
            params = self._init_from(Path(tcfg.init_from), params, exact_init)
        self.state = {"params": params, "opt_state": self.tx.init(params), "step": 0}
        self.history: list[dict] = []
        self._warm_stop_said = False
        self._inverts_said = False  # the warning that training solves stop at the element bound, once a run
        self._failed_in_a_row = 0  # steps in a row in which no sample of the batch converged
        self._grad = jax.jit(jax.value_and_grad(self._loss_sum, has_aux=True))
        self._update = jax.jit(self._apply)
        self._evaluate = jax.jit(self._forward)
        self._at_rest = jax.jit(self._observe_at_rest)

    @staticmethod
    def _init_from(run: Path, params, exact: bool = False):
        """This run's parameters, with the geometry (and the network, where its shapes fit) of another
        run's newest checkpoint: how a phase starts from the one before it.  Its geometry must fit (a
        design carries over only to its own scene); with `exact` (re-evaluating the run itself) every
        parameter must, or the checkpoint is not of this config: ConfigError either way."""
        found = checkpoint.load_latest(run / "checkpoints", what=f"run={run}" if exact else f"trainer.init_from={run}")
        if found is None:
            raise ConfigError(f"trainer.init_from: {run} holds no checkpoint")
        path, raw = found
        geom, taken = dict(params["geom"]), []
        saved = raw["params"].get("geom", {})
        for k, v in saved.items():
            if k in geom and np.shape(v) == geom[k].shape:
                geom[k] = jnp.asarray(v, geom[k].dtype)
                taken.append(k)
        net, net_error = params["net"], None
        try:
            net = jax.tree_util.tree_map(jnp.asarray, checkpoint.restore(raw["params"]["net"], net))
            taken.append("network")
        except (ValueError, KeyError, TypeError) as exc:
            # another architecture (the lookup table before the network): keep the fresh network
            net_error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        missing = [k for k in geom if k not in taken]
        if (geom and len(missing) == len(geom)) or (exact and (missing or net_error)):
            what = [f"geometry {k} (checkpoint {np.shape(saved[k]) if k in saved else 'none'}, this run "
                    f"{tuple(geom[k].shape)})" for k in missing] + ([f"the network ({net_error})"] if net_error else [])
            raise ConfigError(f"checkpoint {path} does not fit this run's config: {'; '.join(what)}. "
                              "It was written for another scene or model")
        log.info("initialised %s from %s", ", ".join(taken) or "nothing", path)
        return {"net": net, "geom": geom}

    # -- the differentiable path -------------------------------------------------------------------
    def _forward(self, params, ts):
        X = self.sim.reference_points(params["geom"])
        d = self.model.apply(params["net"], self.task.net_input(ts))
        u, info = self.task.solve(self.sim, X, d, self.mat)
        # one at a time: an evaluation set may be large, an observation (the colour display) is not small,
        # and a branch in one runs only where taken (lax.map with a batch_size vmaps, and computes both)
        observe = lambda ui: self.task.observe(self.sim, params["geom"], X, ui, self.mat)
        out = jax.lax.map(observe, u)
        return X, d, u, out, info

    def _observe_at_rest(self, params):
        """What the task reads off the design with no actuation: nothing moves."""
        X = self.sim.reference_points(params["geom"])
        return self.task.observe(self.sim, params["geom"], X, self.task.at_rest(X), self.mat)

    def _loss_sum(self, params, ts):
        if self.task.supervised:  # regress the actuations onto given ones; nothing to solve
            d = self.model.apply(params["net"], self.task.net_input(ts))
            losses = jnp.mean((d - self.task.actuation_targets(ts)) ** 2, axis=-1)
            status = jnp.where(jnp.all(jnp.isfinite(d), axis=-1), Status.CONVERGED, Status.NONFINITE_INPUT)
            return jnp.sum(losses), (status == Status.CONVERGED, losses, status, None)
        X, d, u, out, info = self._forward(params, ts)
        ok = info.status == Status.CONVERGED
        losses = jax.vmap(self.task.loss)(out, ts)
        if self.cfg.inversion_penalty > 0:  # steer away from states that invert between Gauss points
            margin = self.cfg.inversion_margin
            one = lambda ui: inversion_penalty(self.sim.disc.mesh, X, ui, margin)  # noqa: E731
            # a trajectory's: summed over its states
            penalty = jax.vmap(lambda ui: jnp.sum(jax.vmap(one)(self.task.states(ui))) if self.task.in_time else one(ui))(u)
            losses = losses + self.cfg.inversion_penalty * penalty
        if self.features is not None and self.features.bound is not None and self.cfg.feature_penalty > 0:
            losses = losses + self.cfg.feature_penalty * self.features.penalty(X)  # one design: the same in each sample
        return jnp.sum(jnp.where(ok, losses, 0.0)), (ok, losses, info.status, info)

    def _apply(self, params, opt_state, grads):
        updates, opt_state = self.tx.update(grads, opt_state, params)
        new = optax.apply_updates(params, updates)
        geom = self.sim.disc.design.project(new["geom"], params["geom"])  # into the box, cells convex
        return {**new, "geom": geom}, opt_state

    # -- one step, data-parallel ----------------------------------------------------------------------
    def step(self) -> dict:
        t0 = time.perf_counter()
        step = self.state["step"]
        ts = self.task.sample(jax.random.fold_in(self.data_key, step), self.cfg.batch_size)[self.shard]
        (loss_sum, (ok, _, status, info)), grads = self._grad(self.state["params"], ts)
        flat, unravel = ravel_pytree(grads)
        status = np.asarray(status)
        total = self.world.allreduce_record({"grads": flat, "loss": float(loss_sum), "converged": np.sum(ok),
                                             "nonfinite": np.sum(status == Status.NONFINITE_INPUT),
                                             "inverts": np.sum(status == Status.INVERTS)})
        n_ok, n_nonfinite, n_inverts = (int(round(float(total[k]))) for k in ("converged", "nonfinite", "inverts"))
        if n_nonfinite:
            raise TrainingError(diagnose(self.state["params"], self.ocfg, step, f"{n_nonfinite} of the batch's "
                                         "actuations or the geometry are not finite, so nothing could be solved"))
        if n_ok == 0:
            return self._skip_failed_step(step, info, t0)
        self._failed_in_a_row = 0
        if self.sim.warm_starts_stopped() and not self._warm_stop_said:
            log.warning("step %d: warm starts stopped: %s; solves start from rest for the rest of the run",
                        step + 1, self.sim.warm_starts_stopped())
            self._warm_stop_said = True
        if n_inverts and self.cfg.inversion_penalty == 0 and not self._inverts_said:
            log.warning("step %d: %d training solves stopped where the material would invert between Gauss points "
                        "(solver.element_bound); they give no gradient, so nothing steers the design away from "
                        "them: trainer.inversion_penalty does (docs/explanation/physical-states.md)", step + 1, n_inverts)
            self._inverts_said = True
        mean_grads = unravel(jnp.asarray(total["grads"] / n_ok))
        params, opt_state = self._update(self.state["params"], self.state["opt_state"], mean_grads)
        self.state = {"params": params, "opt_state": opt_state, "step": step + 1}
        rec = {"step": step + 1, "loss": float(total["loss"] / n_ok), "failed_solves": self.cfg.batch_size - n_ok,
               "seconds": time.perf_counter() - t0}
        if n_inverts:  # of the failed solves, those the element bound stopped
            rec["stopped_inverting"] = n_inverts
        skipped = int(opt_state.notfinite_count)
        if skipped:  # optax.apply_if_finite left the parameters as they were
            rec["skipped_update"] = 1
            groups = nonfinite_groups(mean_grads)
            log.warning("step %d: loss %s, non-finite gradient in %s: update skipped (%d in a row, %d in all)",
                        step + 1, rec["loss"], groups or "none", skipped, int(opt_state.total_notfinite))
            if skipped >= self.cfg.max_nonfinite_steps:
                raise TrainingError(diagnose(self.state["params"], self.ocfg, step + 1, f"the loss or gradient was "
                                             f"not finite for {skipped} steps in a row (in {groups or 'the loss'})"))
        return rec

    def _skip_failed_step(self, step: int, info, t0: float) -> dict:
        """A step in which no sample of the batch converged has no gradient: it is skipped (the parameters
        and the optimiser's state stay as they were) and counted; trainer.max_failed_steps of them in a
        row stop the run, saying why the last batch's first sample failed."""
        self._failed_in_a_row += 1
        first = jax.tree_util.tree_map(lambda a: np.asarray(a)[0], info)  # every sample failed
        if self._failed_in_a_row >= self.cfg.max_failed_steps:
            err = failure(first, f"step {step + 1}: no sample of the batch converged in {self._failed_in_a_row} "
                                 f"steps in a row (trainer.max_failed_steps); the last batch's first: ")
            raise type(err)(f"{err}. {FAILED_STEP_ADVICE.get(int(first.status), FAILED_STEP_ADVICE[None])}", err.info)
        log.warning("step %d: no sample of the batch converged (the first: %s); step skipped (%d in a row of "
                    "trainer.max_failed_steps %d)", step + 1, failure(first), self._failed_in_a_row,
                    self.cfg.max_failed_steps)
        self.state = {**self.state, "step": step + 1}
        return {"step": step + 1, "loss": None, "failed_solves": self.cfg.batch_size, "failed_step": 1,
                "seconds": time.perf_counter() - t0}

    def eval_subset(self):
        """The evaluation samples of an evaluation before the last: trainer.eval_subset of them, evenly
        spaced through the task's evaluation set (all of it where that is no larger)."""
        ts = self.task.eval_set()
        n = len(jax.tree_util.tree_leaves(ts)[0])
        if self.cfg.eval_subset is None or self.cfg.eval_subset >= n:
            return ts
        idx = np.linspace(0, n - 1, self.cfg.eval_subset).round().astype(int)
        return jax.tree_util.tree_map(lambda a: a[idx], ts)

    def evaluate(self, ts=None) -> Evaluation:
        """The metric on the task's evaluation set (or on descriptors `ts`) at the current parameters."""
        ts = self.task.eval_set() if ts is None else ts
        X, d, u, out, info = self._evaluate(self.state["params"], ts)
        status = np.asarray(info.status)
        ok = status == Status.CONVERGED
        rest = None if ok.all() else self._at_rest(self.state["params"])
        metric = self.task.scored(self.task.metric, out, ts, ok, rest)
        extras = {k: float(np.mean(self.task.scored(fn, out, ts, ok, rest)))
                  for k, fn in self.task.sample_metrics().items()}
        # is every converged state a physical object? (no inverted material, no wall through a wall)
        states, checked = self.task.check_states(StateChecker(self.sim.disc.mesh, np.asarray(X)), u, ok)
        invalid = {str(i): v.problems() for i, v in enumerate(states) if v is not None and not v.valid}
        record = {"step": self.state["step"], self.task.metric_name: self.task.aggregate(metric), **extras,
                  "failed_solves": int((~ok).sum()), "failed_samples": np.flatnonzero(~ok).tolist(),
                  "over_converged": self.task.aggregate(metric[ok]) if ok.any() else None,
                  "stopped_inverting": int((status == Status.INVERTS).sum()),  # of the failed, those the element bound stopped
                  **checked, "invalid_samples": invalid,
                  "per_sample": metric.tolist(), "eval_actuations": np.asarray(d).tolist(),
                  **(self.features.report(X) if self.features is not None else {})}
        if self.sim.solver_record() is not None:  # how the run's solves started, and whether warm starts held
            record["warm_starts"] = self.sim.solver_record()
        return Evaluation(record, X, d, self.task.shown(u), out, ts, ok, states, u if self.task.in_time else None)

    # -- the loop ---------------------------------------------------------------------------------------
    def _stop_if_asked(self, stop, saved: bool) -> None:
        signum = stop()
        if self.world.size > 1:  # every rank stops after the same step (a signal may reach only some)
            signum = signum or (signal.SIGTERM if self.world.allreduce_sum(np.array([float(signum)]))[0] else 0)
        if not signum:
            return
        if not saved:
            self.save()
        step = self.state["step"]
        raise Stopped(f"stopped by {signal.Signals(signum).name} after step {step} of {self.cfg.steps}; checkpoint "
                      f"{checkpoint.path_of(self.checkpoint_dir(), step)} saved: continue with trainer.resume=true "
                      f"in the same run directory", signum)

    def checkpoint_dir(self) -> Path:
        return self.run_dir / "checkpoints"

    def _payload(self, warm_audits=()):
        return {**self.state, "history": json.dumps(self.history), "config": json.dumps(self.fingerprint),
                "warm_audits": json.dumps(list(warm_audits))}

    def _warm_audits(self) -> list[list[int]]:
        """Every rank's solver state for a checkpoint (Simulator.checkpoint_state), [] without any."""
        tallies = self.sim.checkpoint_state()
        if tallies is None:
            return []
        mine = np.zeros((self.world.size, 2))
        mine[self.world.rank] = tallies
        return np.rint(self.world.allreduce_sum(mine.ravel())).astype(int).reshape(-1, 2).tolist()

    def save(self):
        warm_audits = self._warm_audits()
        if self.world.is_root:
            checkpoint.save(self.checkpoint_dir(), self.state["step"], self._payload(warm_audits))

    def try_resume(self) -> bool:
        """Continue from the newest readable checkpoint whose config fingerprint matches this run's
        (or any, with trainer.resume=force); a corrupt newest checkpoint is reported and skipped."""
        found = checkpoint.load_latest(self.checkpoint_dir(), warn=self.world.is_root)
        if found is None:
            return False
        path, raw = found
        if self.cfg.resume != "force":
            checkpoint.check_fingerprint(path, raw, self.fingerprint, self.absent, asdict(type(self.ocfg)()))
        raw.setdefault("warm_audits", "[]")  # a checkpoint from before the tallies were kept
        try:
            restored = checkpoint.restore(raw, self._payload())
        except Exception as exc:  # structure or shapes differ: only reachable with resume=force
            raise ConfigError(f"trainer.resume=force: checkpoint {path} does not fit this run's parameters "
                              f"({str(exc).splitlines()[0]})") from None
        self.history = json.loads(restored.pop("history"))
        restored.pop("config")
        warm_audits = json.loads(restored.pop("warm_audits"))
        if len(warm_audits) == self.world.size:
            self.sim.restore_checkpoint_state(warm_audits[self.world.rank])
        step = int(restored.pop("step"))
        self.state = {**jax.tree_util.tree_map(jnp.asarray, restored), "step": step}
        log.info("resumed from %s at step %d", path, self.state["step"])
        return True

    def fit(self, on_eval=None, stop=None) -> Evaluation:
        """Train to trainer.steps (resuming first if asked), evaluating and checkpointing on schedule;
        the last evaluation.  `stop()` (nma.signals.stop_on_signals), asked after every step, returns a
        signal's number to stop there: the step is checkpointed, then Stopped is raised."""
        if self.cfg.resume != "false" and not self.try_resume():
            log.info("trainer.resume=%s: no checkpoint in %s yet; starting at step 0", self.cfg.resume,
                     self.checkpoint_dir())
        bar, quiet = None, contextlib.nullcontext()
        if self.cfg.progress and self.world.is_root:
            from tqdm.auto import tqdm
            from tqdm.contrib.logging import logging_redirect_tqdm

            bar = tqdm(total=self.cfg.steps, initial=self.state["step"], desc=self.task.name, unit="step")
            quiet = logging_redirect_tqdm()  # log lines above the bar, not through it
        with quiet:
            return self._loop(bar, on_eval, stop)

    def _loop(self, bar, on_eval, stop) -> Evaluation:
        last_eval = None
        while self.state["step"] < self.cfg.steps:
            rec = self.step()
            step = rec["step"]
            if step % self.cfg.eval_every == 0 or step == self.cfg.steps:
                if self.world.is_root:
                    ev = self.final_evaluation() if step == self.cfg.steps else self.evaluate(self.eval_subset())
                    r = ev.record
                    rec[self.task.metric_name] = r[self.task.metric_name]
                    rec["invalid_states"] = r["invalid_states"]
                    rec["eval_samples"] = len(r["per_sample"])
                    last_eval = ev
                    log.info("step %d: %s = %.4g %s on %d samples of the evaluation set (%d failed solves, %d of %d "
                             "states not physical)", step, self.task.metric_name, r[self.task.metric_name],
                             self.task.metric_unit, len(r["per_sample"]), r["failed_solves"], r["invalid_states"],
                             r["checked_states"])
                    if r.get("ligaments_below_min_feature"):
                        log.warning("step %d: ligaments below trainer.min_feature = %g mm: %d (the narrowest %.4g mm)",
                                    step, r["min_feature"], len(r["ligaments_below_min_feature"]), r["min_ligament_mm"])
                    if on_eval:
                        on_eval(ev)
            self.history.append(rec)
            if self.logger:
                self.logger.log(rec, step)
            if bar:
                bar.update(1)
                bar.set_postfix(loss="skipped" if rec["loss"] is None else f"{rec['loss']:.4f}",
                                s_per_step=f"{rec['seconds']:.2f}")
            saved = step % self.cfg.checkpoint_every == 0 or step == self.cfg.steps
            if saved:
                self.save()
            if stop is not None:
                self._stop_if_asked(stop, saved)
        if bar:
            bar.close()
        if self.world.is_root and last_eval is None:
            last_eval = self.final_evaluation()
        return last_eval

    def final_evaluation(self, ts=None) -> Evaluation:
        """The run's metric: every evaluation sample (or the descriptors `ts`), each solved from rest (warm
        starts paused), so that it means what a cold solve of the design means, however training started
        its solves."""
        with self.sim.cold_solves():
            return self.evaluate(ts)
