"""Train one experiment: python -m nma.run [task=rotation_double] [trainer.steps=200] [logger=none]

The whole config is checked against the schema (nma/schema/) before any work; exit codes as in
nma.cli.  Under `mpiexec -n N` every rank runs this; rank 0 picks the run directory before Hydra
starts and broadcasts it, and only rank 0 writes (config, log, checkpoints, fields, figures,
metrics, wandb).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from . import cli, signals, sweep
from .config import CONF_DIR
from .errors import TrainingError
from .resolve import describe_model, model_record
from .schema import TrainConfig, register
from .sweep import FAILED_JOB
from .train.runs import (
    absent_means,
    check_init_from,
    check_run_dir,
    chosen_fidelity,
    fidelity_record,
    fingerprint,
    make_trainer,
    validate,
)

log = logging.getLogger("nma.run")
register()


def train(s: TrainConfig, run_dir: Path, config: dict, stop=None) -> dict:
    """Train, write the run's figures, fields and metrics.json; the final evaluation's record."""
    from .train import artefacts
    from .train.mpi import World
    from .units import Units, run_record

    world = World()
    trainer = make_trainer(s, run_dir, config, world)
    sim, task, logger = trainer.sim, trainer.task, trainer.logger
    X_before = sim.reference_points(trainer.state["params"]["geom"])
    log.info(
        "%s: %d dofs, %d ranks, batch %d, geometry %s",
        task.name,
        sim.disc.boundary.n_dofs,
        world.size,
        s.trainer.batch_size,
        "frozen" if s.trainer.freeze_geometry else "learned",
    )
    if model_record(s)["nearly_incompressible"]:
        log.info("material.nu = %g is nearly incompressible: %s", s.material.nu, describe_model(s))
    on_eval = None
    if s.trainer.fields == "all":  # fields/step_<n>/ at every evaluation
        on_eval = lambda ev: artefacts.write_eval_fields(
            run_dir / "fields" / f"step_{ev.record['step']:07d}",
            sim,
            ev,
            s.trainer.fields_samples,
            task,
        )
    evaluation = trainer.fit(on_eval, stop)
    logger.finish()
    if not world.is_root:
        return {}
    figures = artefacts.write_figures(
        run_dir / "figures", trainer, evaluation, X_before, s.trainer.animation_frames, s.part.scale
    )
    if s.trainer.fields == "final":
        artefacts.write_eval_fields(
            run_dir / "fields", sim, evaluation, s.trainer.fields_samples, task
        )
    at_rest, floor = task.rest_metric(sim, trainer.mat), task.frozen_floor()
    metrics = artefacts.write_metrics(
        run_dir,
        task,
        evaluation,
        trainer.history,
        {
            "freeze_geometry": s.trainer.freeze_geometry,
            "ranks": world.size,
            "batch_size": s.trainer.batch_size,
            "steps": s.trainer.steps,
            "no_actuation": at_rest,
            "fidelity": fidelity_record(sim.disc, s.fidelity),
            "model": model_record(s),
            "frozen_floor": None if floor is None else floor[0],
            "skipped_updates": sum(h.get("skipped_update", 0) for h in trainer.history),
            "failed_steps": sum(h.get("failed_step", 0) for h in trainer.history),
            **run_record(Units.of(s.part, s.material), sim, trainer.mat, task, evaluation),
        },
    )
    r = evaluation.record
    stretches = json.loads(metrics.read_text()).get("stretch_range")
    if (
        stretches
        and not s.material.stretches[0] <= stretches[0] <= stretches[1] <= s.material.stretches[1]
    ):
        log.warning(
            "the evaluation's states stretch the material over principal stretches %.3g to %.3g, "
            "beyond "
            "material.stretches=%s where its law was checked stable (and a fitted law has its "
            "data)",
            *stretches,
            s.material.stretches,
        )
    failed, n = r["failed_solves"], len(r["per_sample"])
    over = (
        f" over all {n} samples, {failed} of whose solves failed"
        if failed
        else f" over all {n} samples"
    )
    log.info(
        "final %s = %.4g %s%s after %d steps; %sthe initial design at rest, no actuation: %.4g",
        task.metric_name,
        r[task.metric_name],
        task.metric_unit,
        over,
        trainer.state["step"],
        ""
        if floor is None or s.trainer.freeze_geometry
        else f"the initial design with its geometry frozen can do no better than {floor[0]:.4g} "
        f"({floor[1]}); ",
        at_rest,
    )
    log.info(
        "run directory %s: figures in %s (%s), metrics in %s",
        run_dir,
        figures,
        ", ".join(sorted(p.name for p in figures.iterdir())),
        metrics,
    )
    if task.next_step(run_dir):
        log.info("next, from this run: %s", task.next_step(run_dir))
    if failed == n:  # everything is written; the metric is that of states nobody reached
        raise TrainingError(failed_solves(r))
    if failed:
        log.warning(failed_solves(r))
    if r["invalid_states"]:
        from .geometry.validity import describe

        log.warning(
            "%s. They are marked in figures/deformed.png and listed in metrics.json "
            "(invalid_samples).",
            describe(r, r["invalid_samples"], s.contact.enabled),
        )
    return r


def failed_solves(record: dict) -> str:
    """What an evaluation's failed solves were and how the metric scored them, in a line."""
    failed, n = record["failed_solves"], len(record["per_sample"])
    why = [
        f"{k} {what}"
        for k, what in [
            (
                record["stopped_inverting"],
                "stopped at Newton's element bound (solver.element_bound), where the material "
                "would invert between Gauss points",
            ),
            (failed - record["stopped_inverting"], "did not converge"),
        ]
        if k
    ]
    others = (
        f"; over the other {n - failed} alone it is {record['over_converged']:.4g}"
        if failed < n
        else "; none converged"
    )
    return (
        f"{failed} of the final evaluation's {n} solves failed ({'; '.join(why)}): the metric "
        "scores each at the "
        f"worse of the state it reached and no actuation{others}. metrics.json lists them "
        "(failed_samples)."
    )


def validate_in(cfg: DictConfig, run_dir: Path):
    """The checked settings of a run in `run_dir`, and the checkpoint a resumed run continues from
    ((path, raw state) or None): a run resumed there keeps the setting fidelity=auto chose for it
    (its checkpoint records it), whatever fronts were measured since.  A setting given that cannot
    take effect, and a trainer.min_feature no design can meet, are refused (nma.schema.effect)."""
    from .schema.effect import check_train
    from .train import checkpoint

    found = None
    if str(cfg.trainer.get("resume", "false")).lower() != "false":
        found = checkpoint.load_latest(run_dir / "checkpoints", warn=False)
    settings = validate(cfg, chosen_fidelity(found[1]) if found else None)
    check_train(settings)
    return settings, found


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")
def hydra_main(cfg: DictConfig) -> None:
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from .train.mpi import World

    hydra_cfg = hydra.core.hydra_config.HydraConfig.get()
    run_dir, in_sweep = Path(hydra_cfg.runtime.output_dir), hydra_cfg.mode == RunMode.MULTIRUN
    world = World()
    try:
        with cli.exit_codes(world.rank, None if in_sweep else run_dir):
            if world.is_root:
                cli.hold_run_dir(run_dir, "this job's directory")
            settings = validate_in(cfg, run_dir)[0]
            with signals.stop_on_signals(settings.trainer.stop_grace) as stop:
                train(settings, run_dir, OmegaConf.to_container(cfg, resolve=True), stop)
    except SystemExit as exit_:
        if not (in_sweep and 0 < int(exit_.code or 0) < 128):  # a signal stops the sweep too
            raise
        # one failed job is recorded (the sweep's summary lists it) and the sweep goes on
        if world.is_root:
            record = {"exit_code": exit_.code, "error": getattr(exit_, "message", "")}
            (run_dir / FAILED_JOB).write_text(json.dumps(record, indent=1))


def main() -> None:
    from .train import checkpoint
    from .train.mpi import World

    world = World()
    built: set[str] = set()  # the scenes and fidelities a sweep's jobs were discretised at

    def check(cfg, hydra_cfg, multirun: bool):
        # the job's directory (a sweep's: its subdirectory), before Hydra records its config there
        run_dir = cli.job_dir(hydra_cfg, multirun)
        settings, found = validate_in(cfg, run_dir)
        # what only the discretisation finds (a tracked point in a pore), for every job at once
        if multirun:
            key = repr((settings.scene, settings.fidelity))
            if key not in built:
                from .discretise import discretise
                from .schema import scene_from_config

                discretise(scene_from_config(settings.scene), settings.fidelity)
                built.add(key)
        world.shard(settings.trainer.batch_size)  # a batch must split evenly over the MPI ranks
        if settings.trainer.init_from:
            check_init_from(Path(settings.trainer.init_from), settings)
        check_run_dir(
            run_dir,
            settings.trainer.resume,
            "a sweep job's directory" if multirun else "hydra.run.dir",
        )
        if settings.trainer.resume == "true":  # does the checkpoint fit?
            if found:
                checkpoint.check_fingerprint(
                    found[0],
                    found[1],
                    fingerprint(settings),
                    absent_means(settings),
                    dataclasses.asdict(type(settings.optim)()),
                )

    hydra_cfg = cli.preflight("config", check, sys.argv[1:], world.rank)
    if world.size > 1:
        if hydra_cfg is not None and not {"--multirun", "-m"} & set(sys.argv[1:]):
            # one run directory for all ranks, picked by rank 0 from its composed config (follows
            # the task)
            sys.argv.append(
                f"hydra.run.dir={world.bcast(str(hydra_cfg.run.dir) if world.is_root else None)}"
            )
        if not world.is_root:
            sys.argv += [
                "hydra.output_subdir=null",
                "hydra/job_logging=disabled",
                "hydra/hydra_logging=disabled",
                "trainer.progress=false",
            ]
    hydra_main()
    if sweep.last["failed"]:  # any launcher's: each job records its failure in its directory
        cli.say(
            f"{len(sweep.last['failed'])} of the sweep's {sweep.last['jobs']} jobs failed (job "
            f"{', '.join(sweep.last['failed'])}): each job's {FAILED_JOB} says why, and "
            f"{sweep.last['summary']} lists them",
            world.rank,
        )
        sys.exit(cli.FAILED)


if __name__ == "__main__":
    main()
