"""Train one experiment: python -m nma.run [task=rotation_double] [trainer.steps=200] [logger=none]

Under `mpiexec -n N` every rank runs this; rank 0 picks the run directory before Hydra starts and
broadcasts it, and only rank 0 writes (config, log, checkpoints, fields, figures, metrics, wandb).
"""
from __future__ import annotations

import logging
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from .config import CONF_DIR

log = logging.getLogger("nma.run")


def validate(cfg: DictConfig):
    """Turn the composed config into checked settings before any work; raise ValueError naming the field."""
    from .geometry.discretise import Fidelity
    from .geometry.scene import scene_from_config
    from .mechanics.material import check_material
    from .registry import LINEAR_SOLVERS, MODELS, TASKS
    from .solver.newton import NewtonOptions
    from .train.trainer import OptimConfig, TrainerConfig
    from . import models, tasks  # noqa: F401  (register components)
    from .solver import linear  # noqa: F401

    check_material(float(cfg.material.E), float(cfg.material.nu))
    TASKS.get(cfg.task.name)
    MODELS.get(cfg.model.name)
    LINEAR_SOLVERS.get(cfg.solver.linear)
    if cfg.task.name != cfg.scene.name:
        raise ValueError(f"scene {cfg.scene.name!r} does not fit task {cfg.task.name!r}")
    spec = scene_from_config(OmegaConf.to_container(cfg.scene))
    fidelity = Fidelity(**OmegaConf.to_container(cfg.fidelity))
    solver = dict(OmegaConf.to_container(cfg.solver))
    options = NewtonOptions.from_config(solver)
    optim = OptimConfig(float(cfg.optim.lr), dict(OmegaConf.to_container(cfg.optim.lr_scale)),
                        str(cfg.optim.get("schedule", "constant")), float(cfg.optim.get("final_fraction", 0.1)))
    trainer = TrainerConfig(**OmegaConf.to_container(cfg.trainer))
    return spec, fidelity, solver["linear"], options, optim, trainer


def train(cfg: DictConfig, run_dir: Path) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    from .geometry.discretise import discretise
    from .mechanics.material import material
    from .registry import MODELS, TASKS
    from .simulator import Simulator
    from .train import artefacts
    from .train.logger import make_logger
    from .train.mpi import World
    from .train.trainer import Trainer

    spec, fidelity, linear, options, optim, tcfg = validate(cfg)
    world = World()
    sim = Simulator(discretise(spec, fidelity), linear, options)
    task = TASKS.get(cfg.task.name)(cfg.task, sim)
    model = MODELS.get(cfg.model.name)(hidden=list(cfg.model.hidden), n_out=sim.n_actuations,
                                       d_max=task.d_max, out_bias=bool(cfg.model.out_bias))
    logger = make_logger(cfg.logger, run_dir, OmegaConf.to_container(cfg, resolve=True),
                         run_dir.name, world.is_root)
    trainer = Trainer(task, sim, model, material(cfg.material.E, cfg.material.nu), tcfg, optim, run_dir,
                      logger, world)
    X_before = sim.reference_points(trainer.state["params"]["geom"])
    log.info("%s: %d dofs, %d ranks, batch %d, geometry %s", task.name, sim.disc.n_dofs, world.size,
             tcfg.batch_size, "frozen" if tcfg.freeze_geometry else "learned")
    evaluation = trainer.fit()
    logger.finish()
    if not world.is_root:
        return {}
    X_after = sim.reference_points(trainer.state["params"]["geom"])
    figures = run_dir / "figures"
    figures.mkdir(exist_ok=True)
    artefacts.figure_designs(figures / "design.png", sim, X_before, X_after)
    artefacts.figure_deformed(figures / "deformed.png", sim, task, evaluation)
    artefacts.figure_curves(figures / "curves.png", task, trainer.history)
    artefacts.write_eval_fields(run_dir, sim, evaluation, tcfg.fields_samples)
    artefacts.write_metrics(run_dir, task, evaluation, trainer.history,
                            {"freeze_geometry": tcfg.freeze_geometry, "ranks": world.size,
                             "batch_size": tcfg.batch_size, "steps": tcfg.steps})
    log.info("final %s = %.4g %s", task.metric_name, evaluation[task.metric_name], task.metric_unit)
    return evaluation


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")
def hydra_main(cfg: DictConfig) -> None:
    run_dir = Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir)
    try:
        train(cfg, run_dir)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)


def _mpi_argv() -> None:
    """Under MPI: one run directory for all ranks, chosen by rank 0; ranks > 0 write nothing."""
    from .train.mpi import World

    world = World()
    if world.size == 1:
        return
    if not any(a.startswith("hydra.run.dir=") for a in sys.argv[1:]):
        import time
        task = next((a.split("=", 1)[1] for a in sys.argv[1:] if a.startswith("task=")), "translation")
        stamp = time.strftime("%Y-%m-%d_%H-%M-%S") if world.is_root else None
        sys.argv.append(f"hydra.run.dir=outputs/runs/{task}/{world.bcast(stamp)}_mpi{world.size}")
    if not world.is_root:
        sys.argv += ["hydra.output_subdir=null", "hydra/job_logging=disabled", "hydra/hydra_logging=disabled",
                     "trainer.progress=false"]


def main() -> None:
    _mpi_argv()
    hydra_main()


if __name__ == "__main__":
    main()
