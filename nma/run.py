"""Train one experiment: python -m nma.run [task=rotation_double] [trainer.steps=200] [logger=none]

The whole config is checked against the schema (nma/schema.py) before any work; exit codes as in
nma/cli.py.  Under `mpiexec -n N` every rank runs this; rank 0 picks the run directory before Hydra
starts and broadcasts it, and only rank 0 writes (config, log, checkpoints, fields, figures,
metrics, wandb).
"""
from __future__ import annotations

import dataclasses
import logging
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from . import cli
from .config import CONF_DIR
from .schema import TrainConfig, build, register

log = logging.getLogger("nma.run")
register()


def validate(cfg: DictConfig) -> TrainConfig:
    """The composed config as checked settings, resolved (fidelity=auto: the measured setting it picks);
    ConfigError names the field and its allowed range. Nothing is built: only the registries are
    consulted for the component names."""
    from . import models, tasks  # noqa: F401  (register components)
    from .fidelity import resolve
    from .registry import LINEAR_SOLVERS, MODELS, TASKS
    from .solver import linear  # noqa: F401

    settings = build(TrainConfig, cfg)
    TASKS.get(settings.task.name)
    MODELS.get(settings.model.name)
    LINEAR_SOLVERS.get(settings.solver.linear)
    return dataclasses.replace(settings, fidelity=resolve(settings.fidelity, settings.scene))


def load_run(run_dir) -> tuple[TrainConfig, dict, Path]:
    """A training run directory's checked settings, its newest checkpointed parameters ({"net",
    "geom"}) and that checkpoint's path: where exporting or re-evaluating a trained design starts."""
    from omegaconf import OmegaConf

    from .errors import ConfigError
    from .schema import TASK_SCHEMAS
    from .train import checkpoint

    run = Path(run_dir)
    saved = run / ".hydra" / "config.yaml"
    if not saved.is_file():
        raise ConfigError(f"run={run} is not a training run directory (it has no .hydra/config.yaml)")
    cfg = OmegaConf.load(saved)
    name = OmegaConf.select(cfg, "task.name")
    if name not in TASK_SCHEMAS:
        raise ConfigError(f"run={run}: its config names task {name!r}, not one of {sorted(TASK_SCHEMAS)}")
    settings = validate(OmegaConf.merge({"task": OmegaConf.structured(TASK_SCHEMAS[name])}, cfg))
    found = checkpoint.load_latest(run / "checkpoints")
    if found is None:
        raise ConfigError(f"run={run} holds no checkpoint yet (checkpoints/step_*.msgpack)")
    path, raw = found
    return settings, raw["params"], path


def check_run_dir(run_dir: Path, resume: str, what: str = "hydra.run.dir") -> None:
    """One run per directory: a new run (trainer.resume=false) does not start in a directory that holds
    a run already (its checkpoints would mix with the new run's, its metrics and figures be replaced)."""
    from .errors import ConfigError
    from .train import checkpoint

    held = [p.name for p in (run_dir / "checkpoints", run_dir / "metrics.json")
            if p.exists() and (p.is_file() or checkpoint.latest(p))]
    if resume == "false" and held:
        raise ConfigError(f"{what}={run_dir} holds a run already ({', '.join(held)}): continue it with "
                          "trainer.resume=true, or start the new run in another directory (without "
                          "hydra.run.dir or hydra.sweep.dir each run gets a new one)")


def check_init_from(path: Path, s: TrainConfig) -> None:
    """trainer.init_from names a run of the same scene with a checkpoint: a design carries over only to
    the scene it was learned on."""
    from omegaconf import OmegaConf

    from .errors import ConfigError
    from .train import checkpoint

    if not path.is_dir():
        raise ConfigError(f"trainer.init_from={path} is not a directory (a training run's directory)")
    if checkpoint.latest(path / "checkpoints") is None:
        raise ConfigError(f"trainer.init_from={path} holds no checkpoint (checkpoints/step_*.msgpack)")
    saved = path / ".hydra" / "config.yaml"
    scene = OmegaConf.select(OmegaConf.load(saved), "scene.name") if saved.is_file() else None
    if scene is not None and scene != s.scene.name:
        raise ConfigError(f"trainer.init_from={path} is a run on scene {scene}; this run's scene is "
                          f"{s.scene.name}, and a design carries over only to the scene it was learned on")


def fingerprint(s: TrainConfig) -> dict:
    """The settings that shape the parameters, the optimiser state or the data: a checkpoint written
    under other values must not be continued silently."""
    asdict = dataclasses.asdict
    trainer = {"batch_size": s.trainer.batch_size, "seed": s.trainer.seed, "freeze_geometry": s.trainer.freeze_geometry}
    if s.optim.schedule != "constant":
        trainer["steps"] = s.trainer.steps  # the schedule's length
    return {"task": asdict(s.task), "scene": asdict(s.scene), "model": asdict(s.model),
            "fidelity": asdict(s.fidelity), "material": asdict(s.material), "optim": asdict(s.optim),
            "trainer": trainer, **({"contact": asdict(s.contact)} if s.contact.enabled else {})}


def fidelity_record(disc) -> dict:
    """The discretisation a run used, and with fidelity=auto which measured setting that was and why."""
    from .fidelity import choice_of

    choice = choice_of(disc.fidelity, disc.spec.name)
    return {"ctrl_per_patch": disc.fidelity.ctrl_per_patch, "quad_points": disc.fidelity.quad_points,
            "dofs": disc.n_dofs, "auto": None if choice is None else choice.record(), "contact": disc.contact is not None}


def make_trainer(s: TrainConfig, run_dir: Path, config: dict | None = None, world=None, exact_init: bool = False):
    """The simulator, task, network, logger and trainer of checked, resolved settings (JAX set up first);
    with `exact_init` every parameter restored from trainer.init_from must fit (re-evaluating a run)."""
    from .runtime import configure_jax

    configure_jax()
    from .geometry.discretise import discretise
    from .geometry.scene import scene_from_config
    from .mechanics.material import material
    from .registry import MODELS, TASKS
    from .simulator import Simulator
    from .solver.implicit import available_cores
    from .train.logger import make_logger
    from .train.mpi import World
    from .train.trainer import Trainer

    world = world or World()
    # solver.workers 0: this machine's cores, shared among the MPI ranks running on it
    workers = s.solver.workers or max(1, available_cores() // world.local_size)
    sim = Simulator(discretise(scene_from_config(s.scene), s.fidelity, s.contact.settings()), s.solver.linear, s.solver.newton(), workers)
    task = TASKS.get(s.task.name)(s.task, sim)
    hidden = task.hidden(s.task.hidden if s.model.hidden is None else s.model.hidden)
    model = MODELS.get(s.model.name)(hidden=hidden, n_out=sim.n_actuations, d_max=task.d_max,
                                     out_bias=s.model.out_bias)
    logger = make_logger(s.logger, run_dir, config or {}, run_dir.name, world.is_root)
    return Trainer(task, sim, model, material(s.material.E, s.material.nu), s.trainer, s.optim, run_dir,
                   logger, world, fingerprint(s), exact_init)


def train(s: TrainConfig, run_dir: Path, config: dict, stop=None) -> dict:
    """Train, write the run's figures, fields and metrics.json; the final evaluation's record."""
    from .train import artefacts
    from .train.mpi import World

    world = World()
    trainer = make_trainer(s, run_dir, config, world)
    sim, task, logger = trainer.sim, trainer.task, trainer.logger
    X_before = sim.reference_points(trainer.state["params"]["geom"])
    log.info("%s: %d dofs, %d ranks, batch %d, geometry %s", task.name, sim.disc.n_dofs, world.size,
             s.trainer.batch_size, "frozen" if s.trainer.freeze_geometry else "learned")
    on_eval = None
    if s.trainer.fields == "all":  # fields/step_<n>/ at every evaluation
        on_eval = lambda ev: artefacts.write_eval_fields(  # noqa: E731
            run_dir / "fields" / f"step_{ev.record['step']:07d}", sim, ev, s.trainer.fields_samples)
    evaluation = trainer.fit(on_eval, stop)
    logger.finish()
    if not world.is_root:
        return {}
    X_after = sim.reference_points(trainer.state["params"]["geom"])
    figures = run_dir / "figures"
    figures.mkdir(exist_ok=True)
    artefacts.figure_designs(figures / "design.png", sim, X_before, X_after)
    geom = trainer.state["params"]["geom"]
    if getattr(task, "display", None) is not None:  # a colour display: draw what it shows
        artefacts.figure_display(figures / "deformed.png", task, evaluation, geom)
        artefacts.figure_colour_map(figures / "colours.png", sim, task, geom)
    else:
        artefacts.figure_deformed(figures / "deformed.png", sim, task, evaluation)
    artefacts.figure_curves(figures / "curves.png", task, trainer.history)
    if task.coordinates(task.eval_set()) is not None or task.outline:
        artefacts.figure_errors(figures / "errors.png", task, evaluation)
    if s.trainer.animation_frames:
        sweep = trainer.evaluate(task.sweep(s.trainer.animation_frames))
        artefacts.animation_sweep(figures / "sweep.gif", sim, task, sweep, geom, task.sweep_fps)
    if task.outline:
        artefacts.figure_shapes(figures / "shapes.png", task, evaluation)
    if s.trainer.fields == "final":
        artefacts.write_eval_fields(run_dir / "fields", sim, evaluation, s.trainer.fields_samples)
    at_rest, floor = task.rest_metric(sim), task.frozen_floor()
    metrics = artefacts.write_metrics(run_dir, task, evaluation, trainer.history,
                                      {"freeze_geometry": s.trainer.freeze_geometry, "ranks": world.size,
                                       "batch_size": s.trainer.batch_size, "steps": s.trainer.steps,
                                       "no_actuation": at_rest, "fidelity": fidelity_record(sim.disc),
                                       "frozen_floor": None if floor is None else floor[0],
                                       "skipped_updates": sum(h.get("skipped_update", 0) for h in trainer.history)})
    log.info("final %s = %.4g %s after %d steps; %sthe initial design at rest, no actuation: %.4g",
             task.metric_name, evaluation.record[task.metric_name], task.metric_unit, trainer.state["step"],
             "" if floor is None or s.trainer.freeze_geometry else
             f"the initial design with its geometry frozen can do no better than {floor[0]:.4g} ({floor[1]}); ",
             at_rest)
    log.info("run directory %s: figures in %s (%s), metrics in %s", run_dir, figures,
             ", ".join(sorted(p.name for p in figures.iterdir())), metrics)
    if evaluation.record["invalid_states"]:
        from .geometry.validity import describe

        log.warning("%s. They are marked in figures/deformed.png and listed in metrics.json (invalid_samples).",
                    describe(evaluation.record, evaluation.record["invalid_samples"]))
    return evaluation.record


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")
def hydra_main(cfg: DictConfig) -> None:
    from omegaconf import OmegaConf

    from .train.mpi import World

    run_dir = Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir)
    with cli.exit_codes(World().rank, run_dir), cli.stop_on_signals() as stop:
        train(validate(cfg), run_dir, OmegaConf.to_container(cfg, resolve=True), stop)


def main() -> None:
    from .train import checkpoint
    from .train.mpi import World

    world = World()

    def check(cfg, hydra_cfg, multirun: bool):
        settings = validate(cfg)
        world.shard(settings.trainer.batch_size)  # a batch must split evenly over the MPI ranks
        if settings.trainer.init_from:
            check_init_from(Path(settings.trainer.init_from), settings)
        # the job's directory (a sweep's: its subdirectory), before Hydra records its config there
        run_dir = Path(hydra_cfg.sweep.dir) / str(hydra_cfg.sweep.subdir) if multirun else Path(hydra_cfg.run.dir)
        check_run_dir(run_dir, settings.trainer.resume, "a sweep job's directory" if multirun else "hydra.run.dir")
        if settings.trainer.resume == "true":  # does the checkpoint fit?
            found = checkpoint.load_latest(run_dir / "checkpoints", warn=False)
            if found:
                checkpoint.check_fingerprint(found[0], found[1], fingerprint(settings))

    hydra_cfg = cli.preflight("config", check, sys.argv[1:], world.rank)
    if world.size > 1:
        if hydra_cfg is not None and not {"--multirun", "-m"} & set(sys.argv[1:]):
            # one run directory for all ranks, picked by rank 0 from its composed config (follows the task)
            sys.argv.append(f"hydra.run.dir={world.bcast(str(hydra_cfg.run.dir) if world.is_root else None)}")
        if not world.is_root:
            sys.argv += ["hydra.output_subdir=null", "hydra/job_logging=disabled",
                         "hydra/hydra_logging=disabled", "trainer.progress=false"]
    hydra_main()


if __name__ == "__main__":
    main()
