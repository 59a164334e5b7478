"""The generic trainer: any registered task, the encoder and the geometry, optimised jointly.

One step reads as the data flow of the design:

    t = task.sample(key_step)   # the global batch (the same on every rank); this rank's shard
    d = encoder(theta, t)       # actuations, d_max * tanh
    X = scene.reference(phi)    # differentiable design map
    u = equilibrium(X, d)       # Newton forward, adjoint backward
    loss = task.loss(task.observe(phi, X, u, mat), t)  # + w * inversion_penalty(X, u)
    grads -> sum over ranks -> mean over converged samples -> optax update -> project phi to its box

w is trainer.inversion_penalty.  A sample whose solve does not converge is left out of the mean
(and counted in the log); a step in which no sample converges stops the run with the solver's
error.  Its evaluations are nma.train.evaluation's; its checkpoints (saved, resumed, started from)
nma.train.resume's.
"""

from __future__ import annotations

import contextlib
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.flatten_util import ravel_pytree

from ..errors import TrainingError
from ..mechanics.energy import inversion_penalty

if TYPE_CHECKING:  # the settings' types, for the reader: the trainer reads their fields only
    from ..schema import OptimConfig, TrainerConfig
from ..solver.status import Status, failure
from .evaluation import Evaluation, TrainerEvaluation
from .optimizer import FAILED_STEP_ADVICE, diagnose, make_optimizer, nonfinite_groups
from .mpi import World
from .resume import TrainerCheckpoints

log = logging.getLogger(__name__)


class Trainer(TrainerEvaluation, TrainerCheckpoints):
    def __init__(
        self,
        task,
        sim,
        model,
        mat,
        tcfg: TrainerConfig,
        ocfg: OptimConfig,
        run_dir: Path,
        logger=None,
        world: World | None = None,
        fingerprint: dict | None = None,
        exact_init: bool = False,
        absent: dict | None = None,
        features=None,
    ):
        self.task, self.sim, self.model, self.mat = task, sim, model, mat
        self.cfg, self.ocfg, self.run_dir = tcfg, ocfg, Path(run_dir)
        self.fingerprint = fingerprint or {}
        self.absent = absent or {}  # what a setting missing from a checkpoint's fingerprint means
        # nma.geometry.features.Ligaments: reported at each evaluation; with a bound, enforced
        self.features = features
        self.world = world or World()
        self.logger = logger
        self.shard = self.world.shard(tcfg.batch_size)
        key = jax.random.PRNGKey(tcfg.seed)
        self.data_key, init_key = jax.random.split(key)
        t0 = task.sample(init_key, 1)
        geom = sim.init_params()
        strong = lambda tree: jax.tree_util.tree_map(lambda a: jnp.array(a, dtype=a.dtype), tree)
        # no weak types: one compile
        params = strong({"net": model.init(init_key, task.net_input(t0)), "geom": geom})
        self.tx = make_optimizer(
            ocfg,
            list(geom),
            tcfg.freeze_geometry,
            tcfg.steps,
            tcfg.max_nonfinite_steps,
            task.frozen_geometry,
        )
        if tcfg.init_from:
            params = self._init_from(Path(tcfg.init_from), params, exact_init)
        self.state = {"params": params, "opt_state": self.tx.init(params), "step": 0}
        self.history: list[dict] = []
        self._warm_stop_said = False
        # the warning that training solves stop at the element bound, once a run
        self._inverts_said = False
        self._failed_in_a_row = 0  # steps in a row in which no sample of the batch converged
        self._grad = jax.jit(jax.value_and_grad(self._loss_sum, has_aux=True))
        self._update = jax.jit(self._apply)
        self._evaluate = jax.jit(self._forward)
        self._at_rest = jax.jit(self._observe_at_rest)

    # -- the differentiable path -------------------------------------------------------------------
    def _forward(self, params, ts):
        X = self.sim.reference_points(params["geom"])
        d = self.model.apply(params["net"], self.task.net_input(ts))
        u, info = self.task.solve(self.sim, X, d, self.mat)
        # one at a time: an evaluation set may be large, an observation (the colour display) is not
        # small, and a branch in one runs only where taken (lax.map with a batch_size vmaps, and
        # computes both)
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
            status = jnp.where(
                jnp.all(jnp.isfinite(d), axis=-1), Status.CONVERGED, Status.NONFINITE_INPUT
            )
            return jnp.sum(losses), (status == Status.CONVERGED, losses, status, None)
        X, d, u, out, info = self._forward(params, ts)
        ok = info.status == Status.CONVERGED
        losses = jax.vmap(self.task.loss)(out, ts)
        # steer away from states that invert between Gauss points
        if self.cfg.inversion_penalty > 0 and not self.task.solved_outside:
            margin = self.cfg.inversion_margin
            one = lambda ui: inversion_penalty(self.sim.disc.mesh, X, ui, margin)
            # a trajectory's: summed over its states
            penalty = jax.vmap(
                lambda ui: (
                    jnp.sum(jax.vmap(one)(self.task.states(ui))) if self.task.in_time else one(ui)
                )
            )(u)
            losses = losses + self.cfg.inversion_penalty * penalty
        if (
            self.features is not None
            and self.features.bound is not None
            and self.cfg.feature_penalty > 0
        ):
            # one design: the same in each sample
            losses = losses + self.cfg.feature_penalty * self.features.penalty(X)
        return jnp.sum(jnp.where(ok, losses, 0.0)), (ok, losses, info.status, info)

    def _apply(self, params, opt_state, grads):
        updates, opt_state = self.tx.update(grads, opt_state, params)
        new = optax.apply_updates(params, updates)
        # into the box, cells convex
        geom = self.sim.disc.design.project(new["geom"], params["geom"])
        return {**new, "geom": geom}, opt_state

    # -- one step, data-parallel
    # ----------------------------------------------------------------------
    def step(self) -> dict:
        t0 = time.perf_counter()
        step = self.state["step"]
        ts = self.task.sample(jax.random.fold_in(self.data_key, step), self.cfg.batch_size)[
            self.shard
        ]
        (loss_sum, (ok, _, status, info)), grads = self._grad(self.state["params"], ts)
        flat, unravel = ravel_pytree(grads)
        status = np.asarray(status)
        total = self.world.allreduce_record(
            {
                "grads": flat,
                "loss": float(loss_sum),
                "converged": np.sum(ok),
                "nonfinite": np.sum(status == Status.NONFINITE_INPUT),
                "inverts": np.sum(status == Status.INVERTS),
            }
        )
        n_ok, n_nonfinite, n_inverts = (
            int(round(float(total[k]))) for k in ("converged", "nonfinite", "inverts")
        )
        if n_nonfinite:
            raise TrainingError(
                diagnose(
                    self.state["params"],
                    self.ocfg,
                    step,
                    f"{n_nonfinite} of the batch's "
                    "actuations or the geometry are not finite, so nothing could be solved",
                )
            )
        if n_ok == 0:
            return self._skip_failed_step(step, info, t0)
        self._failed_in_a_row = 0
        if self.sim.warm_starts_stopped() and not self._warm_stop_said:
            log.warning(
                "step %d: warm starts stopped: %s; solves start from rest for the rest of the run",
                step + 1,
                self.sim.warm_starts_stopped(),
            )
            self._warm_stop_said = True
        if n_inverts and self.cfg.inversion_penalty == 0 and not self._inverts_said:
            log.warning(
                "step %d: %d training solves stopped where the material would invert between "
                "Gauss points "
                "(solver.element_bound); they give no gradient, so nothing steers the design away "
                "from them: trainer.inversion_penalty does (docs/explanation/physical-states.md)",
                step + 1,
                n_inverts,
            )
            self._inverts_said = True
        mean_grads = unravel(jnp.asarray(total["grads"] / n_ok))
        params, opt_state = self._update(self.state["params"], self.state["opt_state"], mean_grads)
        self.state = {"params": params, "opt_state": opt_state, "step": step + 1}
        rec = {
            "step": step + 1,
            "loss": float(total["loss"] / n_ok),
            "failed_solves": self.cfg.batch_size - n_ok,
            "seconds": time.perf_counter() - t0,
        }
        if n_inverts:  # of the failed solves, those the element bound stopped
            rec["stopped_inverting"] = n_inverts
        skipped = int(opt_state.notfinite_count)
        if skipped:  # optax.apply_if_finite left the parameters as they were
            rec["skipped_update"] = 1
            groups = nonfinite_groups(mean_grads)
            log.warning(
                "step %d: loss %s, non-finite gradient in %s: update skipped (%d in a row, %d in "
                "all)",
                step + 1,
                rec["loss"],
                groups or "none",
                skipped,
                int(opt_state.total_notfinite),
            )
            if skipped >= self.cfg.max_nonfinite_steps:
                raise TrainingError(
                    diagnose(
                        self.state["params"],
                        self.ocfg,
                        step + 1,
                        f"the loss or gradient was "
                        f"not finite for {skipped} steps in a row (in {groups or 'the loss'})",
                    )
                )
        return rec

    def _skip_failed_step(self, step: int, info, t0: float) -> dict:
        """A step in which no sample of the batch converged has no gradient: it is skipped (the
        parameters and the optimiser's state stay as they were) and counted;
        trainer.max_failed_steps of them in a row stop the run, saying why the last batch's first
        sample failed."""
        self._failed_in_a_row += 1
        first = jax.tree_util.tree_map(lambda a: np.asarray(a)[0], info)  # every sample failed
        if self._failed_in_a_row >= self.cfg.max_failed_steps:
            err = failure(
                first,
                f"step {step + 1}: no sample of the batch converged in {self._failed_in_a_row} "
                f"steps in a row (trainer.max_failed_steps); the last batch's first: ",
            )
            raise type(err)(
                f"{err}. {FAILED_STEP_ADVICE.get(int(first.status), FAILED_STEP_ADVICE[None])}",
                err.info,
            )
        log.warning(
            "step %d: no sample of the batch converged (the first: %s); step skipped (%d in a row "
            "of trainer.max_failed_steps %d)",
            step + 1,
            failure(first),
            self._failed_in_a_row,
            self.cfg.max_failed_steps,
        )
        self.state = {**self.state, "step": step + 1}
        return {
            "step": step + 1,
            "loss": None,
            "failed_solves": self.cfg.batch_size,
            "failed_step": 1,
            "seconds": time.perf_counter() - t0,
        }

    # -- the loop
    # ---------------------------------------------------------------------------------------
    def fit(self, on_eval=None, stop=None) -> Evaluation:
        """Train to trainer.steps (resuming first if asked), evaluating and checkpointing on
        schedule; the last evaluation.  `stop()` (nma.signals.stop_on_signals), asked after every
        step, returns a signal's number to stop there: the step is checkpointed, then Stopped is
        raised."""
        if self.cfg.resume != "false" and not self.try_resume():
            log.info(
                "trainer.resume=%s: no checkpoint in %s yet; starting at step 0",
                self.cfg.resume,
                self.checkpoint_dir(),
            )
        bar, quiet = None, contextlib.nullcontext()
        if self.cfg.progress and self.world.is_root:
            from tqdm.auto import tqdm
            from tqdm.contrib.logging import logging_redirect_tqdm

            bar = tqdm(
                total=self.cfg.steps, initial=self.state["step"], desc=self.task.name, unit="step"
            )
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
                    ev = (
                        self.final_evaluation()
                        if step == self.cfg.steps
                        else self.evaluate(self.eval_subset())
                    )
                    r = ev.record
                    rec[self.task.metric_name] = r[self.task.metric_name]
                    rec["invalid_states"] = r["invalid_states"]
                    rec["eval_samples"] = len(r["per_sample"])
                    last_eval = ev
                    log.info(
                        "step %d: %s = %.4g %s on %d samples of the evaluation set (%d failed "
                        "solves, %d of %d "
                        "states not physical)",
                        step,
                        self.task.metric_name,
                        r[self.task.metric_name],
                        self.task.metric_unit,
                        len(r["per_sample"]),
                        r["failed_solves"],
                        r["invalid_states"],
                        r["checked_states"],
                    )
                    if r.get("ligaments_below_min_feature"):
                        log.warning(
                            "step %d: ligaments below trainer.min_feature = %g mm: %d (the "
                            "narrowest %.4g mm)",
                            step,
                            r["min_feature"],
                            len(r["ligaments_below_min_feature"]),
                            r["min_ligament_mm"],
                        )
                    if on_eval:
                        on_eval(ev)
            self.history.append(rec)
            if self.logger:
                self.logger.log(rec, step)
            if bar:
                bar.update(1)
                bar.set_postfix(
                    loss="skipped" if rec["loss"] is None else f"{rec['loss']:.4f}",
                    s_per_step=f"{rec['seconds']:.2f}",
                )
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
