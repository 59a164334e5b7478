"""The trainer's checkpoints: saved on schedule and on a stop, resumed from, and a phase started
from another run's (the files themselves: nma.train.checkpoint)."""

from __future__ import annotations

import json
import logging
import signal
from dataclasses import asdict
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError, Stopped
from . import checkpoint

log = logging.getLogger("nma.train.trainer")  # the trainer's messages, under its one name


class TrainerCheckpoints:
    """The checkpoints of nma.train.trainer.Trainer, a part of it: they read and write its state and
    history, and read its settings and world."""

    @staticmethod
    def _init_from(run: Path, params, exact: bool = False):
        """This run's parameters, with the geometry (and the network, where its shapes fit) of
        another run's newest checkpoint: how a phase starts from the one before it.  Its geometry
        must fit (a design carries over only to its own scene); with `exact` (re-evaluating the run
        itself) every parameter must, or the checkpoint is not of this config: ConfigError either
        way."""
        found = checkpoint.load_latest(
            run / "checkpoints", what=f"run={run}" if exact else f"trainer.init_from={run}"
        )
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
            what = [
                f"geometry {k} (checkpoint {np.shape(saved[k]) if k in saved else 'none'}, this "
                f"run {tuple(geom[k].shape)})"
                for k in missing
            ] + ([f"the network ({net_error})"] if net_error else [])
            raise ConfigError(
                f"checkpoint {path} does not fit this run's config: {'; '.join(what)}. "
                "It was written for another scene or model"
            )
        log.info("initialised %s from %s", ", ".join(taken) or "nothing", path)
        return {"net": net, "geom": geom}

    def _stop_if_asked(self, stop, saved: bool) -> None:
        signum = stop()
        # every rank stops after the same step (a signal may reach only some)
        if self.world.size > 1:
            signum = signum or (
                signal.SIGTERM if self.world.allreduce_sum(np.array([float(signum)]))[0] else 0
            )
        if not signum:
            return
        if not saved:
            self.save()
        step = self.state["step"]
        raise Stopped(
            f"stopped by {signal.Signals(signum).name} after step {step} of {self.cfg.steps}; "
            f"checkpoint {checkpoint.path_of(self.checkpoint_dir(), step)} saved: continue with "
            "trainer.resume=true "
            f"in the same run directory",
            signum,
        )

    def checkpoint_dir(self) -> Path:
        return self.run_dir / "checkpoints"

    def _payload(self, warm_audits=()):
        return {
            **self.state,
            "history": json.dumps(self.history),
            "config": json.dumps(self.fingerprint),
            "warm_audits": json.dumps(list(warm_audits)),
        }

    def _warm_audits(self) -> list[list[int]]:
        """Every rank's solver state for a checkpoint (Simulator.checkpoint_state), [] without
        any."""
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
            checkpoint.check_fingerprint(
                path, raw, self.fingerprint, self.absent, asdict(type(self.ocfg)())
            )
        raw.setdefault("warm_audits", "[]")  # a checkpoint from before the tallies were kept
        try:
            restored = checkpoint.restore(raw, self._payload())
        except Exception as exc:  # structure or shapes differ: only reachable with resume=force
            raise ConfigError(
                f"trainer.resume=force: checkpoint {path} does not fit this run's parameters "
                f"({str(exc).splitlines()[0]})"
            ) from None
        self.history = json.loads(restored.pop("history"))
        restored.pop("config")
        warm_audits = json.loads(restored.pop("warm_audits"))
        if len(warm_audits) == self.world.size:
            self.sim.restore_checkpoint_state(warm_audits[self.world.rank])
        step = int(restored.pop("step"))
        self.state = {**jax.tree_util.tree_map(jnp.asarray, restored), "step": step}
        log.info("resumed from %s at step %d", path, self.state["step"])
        return True
