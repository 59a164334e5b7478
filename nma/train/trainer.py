"""The generic trainer: any registered task, the encoder and the geometry, optimised jointly.

One step reads as the data flow of the design:
    t = task.sample(key_step)        the global batch (same on every rank); this rank takes its shard
    d = encoder(theta, t)            actuations, d_max * tanh
    X = scene.reference(phi)         differentiable design map
    u = equilibrium(X, d)            Newton forward, adjoint backward
    loss = task.loss(task.observe(u), t)
    grads -> sum over ranks -> mean over converged samples -> optax update -> project phi to its box
A sample whose solve does not converge is left out of the mean (and counted in the log); a step in
which no sample converges stops the run with the solver's error.
"""
from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.flatten_util import ravel_pytree

from ..solver.newton import CONVERGED, SolverError
from . import checkpoint
from .mpi import World

log = logging.getLogger(__name__)
GEOMETRY_GROUPS = ("radii", "corners", "pore_radii", "colours")


@dataclass(frozen=True)
class TrainerConfig:
    steps: int = 100
    batch_size: int = 8
    eval_every: int = 25
    checkpoint_every: int = 25
    resume: bool = False
    freeze_geometry: bool = False
    seed: int = 0
    fields_samples: int = 9
    progress: bool = True

    def __post_init__(self):
        for name in ("steps", "batch_size", "eval_every", "checkpoint_every"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"trainer.{name} must be >= 1, got {getattr(self, name)}")
        if not 2 <= self.fields_samples <= 64:
            raise ValueError(f"trainer.fields_samples must be in [2, 64], got {self.fields_samples}")
        if self.seed < 0:
            raise ValueError(f"trainer.seed must be >= 0, got {self.seed}")


@dataclass(frozen=True)
class OptimConfig:
    lr: float = 1e-3
    lr_scale: dict = field(default_factory=dict)
    schedule: str = "constant"      # or "cosine": decays to final_fraction * lr over the run
    final_fraction: float = 0.1

    def __post_init__(self):
        if not self.lr > 0:
            raise ValueError(f"optim.lr must be > 0, got {self.lr}")
        if self.schedule not in ("constant", "cosine"):
            raise ValueError(f"optim.schedule must be constant or cosine, got {self.schedule!r}")
        if not 0 <= self.final_fraction <= 1:
            raise ValueError(f"optim.final_fraction must be in [0, 1], got {self.final_fraction}")
        for k, v in self.lr_scale.items():
            if k not in GEOMETRY_GROUPS:
                raise ValueError(f"optim.lr_scale.{k} is unknown; allowed {list(GEOMETRY_GROUPS)}")
            if not v >= 0:
                raise ValueError(f"optim.lr_scale.{k} must be >= 0 (0 freezes the group), got {v}")


def make_optimizer(ocfg: OptimConfig, geometry_keys, freeze_geometry: bool, steps: int):
    """Adam per parameter group; a frozen group (scale 0 or the geometry-frozen baseline) gets no update."""
    def lr(scale):
        if ocfg.schedule == "cosine":
            return optax.cosine_decay_schedule(ocfg.lr * scale, steps, alpha=ocfg.final_fraction)
        return ocfg.lr * scale

    transforms = {"network": optax.adam(lr(1.0))}
    for k in geometry_keys:
        scale = 0.0 if freeze_geometry else float(ocfg.lr_scale.get(k, 1.0))
        transforms[k] = optax.adam(lr(scale)) if scale > 0 else optax.set_to_zero()
    labels = {"net": "network", "geom": {k: k for k in geometry_keys}}
    return optax.multi_transform(transforms, labels)


class Trainer:
    def __init__(self, task, sim, model, mat, tcfg: TrainerConfig, ocfg: OptimConfig, run_dir: Path,
                 logger=None, world: World | None = None):
        self.task, self.sim, self.model, self.mat = task, sim, model, mat
        self.cfg, self.run_dir = tcfg, Path(run_dir)
        self.world = world or World()
        self.logger = logger
        self.shard = self.world.shard(tcfg.batch_size)
        key = jax.random.PRNGKey(tcfg.seed)
        self.data_key, init_key = jax.random.split(key)
        t0 = task.sample(init_key, 1)
        geom = sim.init_params()
        strong = lambda tree: jax.tree_util.tree_map(lambda a: jnp.array(a, dtype=a.dtype), tree)
        self.bounds = sim.disc.design.bounds()
        params = strong({"net": model.init(init_key, task.net_input(t0)), "geom": geom})  # no weak types: one compile
        self.tx = make_optimizer(ocfg, list(geom), tcfg.freeze_geometry, tcfg.steps)
        self.state = {"params": params, "opt_state": self.tx.init(params), "step": 0}
        self.history: list[dict] = []
        self._grad = jax.jit(jax.value_and_grad(self._loss_sum, has_aux=True))
        self._update = jax.jit(self._apply)
        self._evaluate = jax.jit(self._forward)

    # -- the differentiable path -------------------------------------------------------------------
    def _forward(self, params, ts):
        X = self.sim.reference_points(params["geom"])
        d = self.model.apply(params["net"], self.task.net_input(ts))
        u, info = self.sim.equilibrium_batch(X, d, self.mat)
        out = jax.vmap(self.task.observe, in_axes=(None, None, 0))(self.sim, X, u)
        return X, d, u, out, info

    def _loss_sum(self, params, ts):
        _, d, _, out, info = self._forward(params, ts)
        ok = info.status == CONVERGED
        losses = jax.vmap(self.task.loss)(out, ts)
        return jnp.sum(jnp.where(ok, losses, 0.0)), (ok, losses, info)

    def _apply(self, params, opt_state, grads):
        updates, opt_state = self.tx.update(grads, opt_state, params)
        params = optax.apply_updates(params, updates)
        geom = {k: jnp.clip(v, *self.bounds[k]) for k, v in params["geom"].items()}  # project to the box
        return {**params, "geom": geom}, opt_state

    # -- one step, data-parallel ----------------------------------------------------------------------
    def step(self) -> dict:
        t0 = time.perf_counter()
        step = self.state["step"]
        ts = self.task.sample(jax.random.fold_in(self.data_key, step), self.cfg.batch_size)[self.shard]
        (loss_sum, (ok, _, info)), grads = self._grad(self.state["params"], ts)
        flat, unravel = ravel_pytree(grads)
        local = np.concatenate([np.asarray(flat), [float(loss_sum), float(np.sum(ok))]])
        total = self.world.allreduce_sum(local)
        n_ok = int(round(total[-1]))
        if n_ok == 0:
            bad = int(np.flatnonzero(~np.asarray(ok))[0]) if not np.all(ok) else 0
            raise SolverError(jax.tree_util.tree_map(lambda a: np.asarray(a)[bad], info),
                              f"step {step}: no sample of the batch converged; ")
        mean_grads = unravel(jnp.asarray(total[:-2] / n_ok))
        params, opt_state = self._update(self.state["params"], self.state["opt_state"], mean_grads)
        self.state = {"params": params, "opt_state": opt_state, "step": step + 1}
        return {"step": step + 1, "loss": float(total[-2] / n_ok), "failed_solves": self.cfg.batch_size - n_ok,
                "seconds": time.perf_counter() - t0}

    def evaluate(self) -> dict:
        ts = self.task.eval_set()
        X, d, u, out, info = self._evaluate(self.state["params"], ts)
        ok = np.asarray(info.status) == CONVERGED
        metric = np.asarray(jax.vmap(self.task.metric)(out, ts))
        value = float(np.mean(metric[ok])) if ok.any() else float("nan")
        return {"step": self.state["step"], self.task.metric_name: value, "failed_solves": int((~ok).sum()),
                "per_sample": metric.tolist(), "_solution": (X, d, u, out, ts, ok)}

    # -- the loop ---------------------------------------------------------------------------------------
    def checkpoint_dir(self) -> Path:
        return self.run_dir / "checkpoints"

    def _payload(self):
        return {**self.state, "history": json.dumps(self.history)}

    def save(self):
        if self.world.is_root:
            checkpoint.save(self.checkpoint_dir(), self.state["step"], self._payload())

    def try_resume(self) -> bool:
        found = self.world.bcast(checkpoint.latest(self.checkpoint_dir()) if self.world.is_root else None)
        if not found:
            return False
        restored = checkpoint.restore(found[1], self._payload())
        self.history = json.loads(restored.pop("history"))
        step = int(restored.pop("step"))
        self.state = {**jax.tree_util.tree_map(jnp.asarray, restored), "step": step}
        log.info("resumed from %s at step %d", found[1], self.state["step"])
        return True

    def fit(self, on_eval=None) -> dict:
        if self.cfg.resume:
            self.try_resume()
        bar = None
        if self.cfg.progress and self.world.is_root:
            from tqdm.auto import tqdm
            bar = tqdm(total=self.cfg.steps, initial=self.state["step"], desc=self.task.name, unit="step")
        last_eval = None
        while self.state["step"] < self.cfg.steps:
            rec = self.step()
            step = rec["step"]
            if step % self.cfg.eval_every == 0 or step == self.cfg.steps:
                if self.world.is_root:
                    ev = self.evaluate()
                    rec[self.task.metric_name] = ev[self.task.metric_name]
                    last_eval = ev
                    if on_eval:
                        on_eval(ev)
            self.history.append(rec)
            if self.logger:
                self.logger.log(rec, step)
            if bar:
                bar.update(1)
                bar.set_postfix(loss=f"{rec['loss']:.4f}", s_per_step=f"{rec['seconds']:.2f}")
            if step % self.cfg.checkpoint_every == 0 or step == self.cfg.steps:
                self.save()
        if bar:
            bar.close()
        if self.world.is_root and last_eval is None:
            last_eval = self.evaluate()
        return last_eval
