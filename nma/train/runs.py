"""A training run's directory and what builds it: the checked settings of a run (validate), a
finished run's settings and newest checkpoint (load_run), the rules a new run's directory keeps (one
run per directory; trainer.init_from a run of the same scene), the fingerprint a checkpoint records,
and the trainer of checked settings (make_trainer).  The commands (nma.run, nma.evaluate,
nma.export) call these."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from ..schema import TrainConfig, build


def validate(cfg: DictConfig, chosen: tuple[int, int] | None = None) -> TrainConfig:
    """The composed config as checked settings, resolved (fidelity=auto: the measured setting it
    picks, or the `chosen` one a trained run's checkpoint records); ConfigError names the field and
    its allowed range. Nothing is built: only the registries are consulted for the component
    names."""
    from .. import models, tasks  # noqa: F401  (register components)
    from ..registry import LINEAR_SOLVERS, MODELS, TASKS
    from ..resolve import resolve
    from ..solver import linear  # noqa: F401

    settings = build(TrainConfig, cfg)
    TASKS.get(settings.task.factory)
    MODELS.get(settings.model.name)
    LINEAR_SOLVERS.get(settings.solver.linear)
    return resolve(settings, chosen)


def load_run(run_dir, material: dict | None = None) -> tuple[TrainConfig, dict, Path]:
    """A training run directory's checked settings, its newest checkpointed parameters ({"net",
    "geom"}) and that checkpoint's path: where exporting or re-evaluating a trained design starts.
    `material`: the material settings to solve with in place of the run's (the part as it is
    made)."""
    from ..errors import ConfigError
    from ..schema import task_schema
    from ..schema.periodic import PeriodicSceneConfig
    from . import checkpoint

    run = Path(run_dir)
    saved = run / ".hydra" / "config.yaml"
    if not saved.is_file():
        raise ConfigError(
            f"run={run} is not a training run directory (it has no .hydra/config.yaml)"
        )
    from ..cli import holder_of
    from ..mechanics.laws import law_of

    holder = holder_of(run)
    if holder:  # its newest checkpoint would change while it is read, and again after
        raise ConfigError(
            f"run={run} is still training ({holder}): wait for it to end, or copy the run "
            f"directory and name the copy"
        )
    try:
        cfg = OmegaConf.load(saved)
    except Exception as exc:  # YAML or OmegaConf errors of a damaged file
        raise ConfigError(
            f"run={run}: {saved} does not read ({type(exc).__name__}: {str(exc).splitlines()[0]})"
        ) from None
    if (
        not isinstance(cfg, Mapping)
        or not isinstance(cfg.get("task"), Mapping)
        or "trainer" not in cfg
    ):
        raise ConfigError(
            f"run={run} is not a training run directory (its .hydra/config.yaml holds no task and "
            f"trainer: another command's)"
        )
    # a run trained before Newton's element bound was the default: its states are re-solved as it
    # found them
    if "element_bound" not in cfg.get("solver", {}):
        cfg.solver = {**(cfg.get("solver") or {}), "element_bound": False}
    # a saved config without material.volumetric solved with the paper's volume term
    m = cfg.get("material") or {}
    if "volumetric" not in m and law_of(m.get("law", "neo_hookean")).volume_term:
        cfg.material = {**m, "volumetric": "bulk"}
    try:
        schema = task_schema(OmegaConf.to_container(cfg.get("task") or {}))
    except ConfigError as exc:
        raise ConfigError(f"run={run}: {exc}") from None
    found = checkpoint.load_latest(run / "checkpoints", what=f"run={run}")
    if found is None:
        raise ConfigError(f"run={run} holds no checkpoint yet (checkpoints/step_*.msgpack)")
    path, raw = found
    if material is not None:  # the settings the run left to auto are chosen again, by this material
        cfg.material = material
    # a periodic scene's own settings (porosity) are its schema's
    scene = {"scene": PeriodicSceneConfig} if (cfg.get("scene") or {}).get("periodic") else {}
    nodes = {k: OmegaConf.structured(v) for k, v in {"task": schema, **scene}.items()}
    settings = validate(OmegaConf.merge(nodes, cfg), chosen_fidelity(raw))
    # what the design is and what it is asked: the run's files must still say what its checkpoint
    # trained a material given is not the run's
    groups = [g for g in DESIGN_GROUPS if material is None or g != "material"]
    trained = checkpoint.recorded(raw, groups)
    if trained is not None:
        now = {
            k: v
            for k, v in checkpoint.flatten(json.loads(json.dumps(fingerprint(settings))))
            if k.split(".")[0] in groups
        }
        changed, diff = checkpoint.differences(trained, now, absent_means(settings))
        if changed:
            raise ConfigError(
                f"run={run}: its files no longer say what checkpoint {path.name} trained ("
                + "; ".join(diff)
                + "): a config or dataset changed after training; restore it, or "
                "train anew"
            )
    return settings, raw["params"], path


# the fingerprint's groups a trained design is checked by
DESIGN_GROUPS = ("task", "scene", "model", "material")


def chosen_fidelity(raw: dict) -> tuple[int, int] | None:
    """The (control points, Gauss points) fidelity=auto chose for a run, as its checkpoint's
    fingerprint records them (None where the run did not use auto): a run is re-evaluated and
    exported at the setting it trained at, whatever fronts were measured since."""
    from ..schema import Fidelity

    # what a record's absence means
    defaults = {f.name: f.default for f in dataclasses.fields(Fidelity)}
    recorded = {**defaults, **(json.loads(raw.get("config") or "{}").get("fidelity") or {})}
    if recorded["tolerance"] is None:
        return None
    return int(recorded["ctrl_per_patch"]), int(recorded["quad_points"])


def check_run_dir(run_dir: Path, resume: str, what: str = "hydra.run.dir") -> None:
    """One run per directory: a new run (trainer.resume=false) does not start in a directory that
    holds a run already (its checkpoints would mix with the new run's, its metrics and figures be
    replaced)."""
    from ..errors import ConfigError
    from . import checkpoint

    saved = run_dir / ".hydra" / "config.yaml"
    if saved.is_file() and "task" not in _top_keys(saved):
        raise ConfigError(
            f"{what}={run_dir} holds another command's output ({saved.relative_to(run_dir)} is "
            "not a training run's): a run there would replace its record; give this run another "
            "directory"
        )
    held = [
        p.name
        for p in (run_dir / "checkpoints", run_dir / "metrics.json")
        if p.exists() and (p.is_file() or checkpoint.latest(p))
    ]
    elsewhere = (
        "start the new run in another directory (without hydra.run.dir or hydra.sweep.dir "
        "each run gets a new one)"
    )
    if resume == "false" and held:
        raise ConfigError(
            f"{what}={run_dir} holds a run already ({', '.join(held)}): "
            + ("continue it with trainer.resume=true, or " if "checkpoints" in held else "")
            + elsewhere
        )
    if resume != "false" and held == ["metrics.json"]:  # a finished run whose checkpoints are gone
        raise ConfigError(
            f"{what}={run_dir} holds a run's metrics.json but no checkpoint to continue from "
            f"(checkpoints/step_*.msgpack): trainer.resume={resume} would start it again; "
            f"{elsewhere}"
        )


def _top_keys(path: Path) -> list[str]:
    """The top-level keys of a YAML file (none where it does not read as a mapping)."""
    import yaml

    try:
        body = yaml.safe_load(path.read_text())
    except (OSError, ValueError, yaml.YAMLError):
        return []
    return list(body) if isinstance(body, dict) else []


def check_init_from(path: Path, s: TrainConfig) -> None:
    """trainer.init_from names a run of the same scene with a checkpoint: a design carries over only
    to the scene it was learned on."""
    from omegaconf import OmegaConf

    from ..errors import ConfigError
    from . import checkpoint

    if not path.is_dir():
        raise ConfigError(
            f"trainer.init_from={path} is not a directory (a training run's directory)"
        )
    if checkpoint.latest(path / "checkpoints") is None:
        raise ConfigError(
            f"trainer.init_from={path} holds no checkpoint (checkpoints/step_*.msgpack)"
        )
    saved = path / ".hydra" / "config.yaml"
    scene = OmegaConf.select(OmegaConf.load(saved), "scene.name") if saved.is_file() else None
    if scene is not None and scene != s.scene.name:
        raise ConfigError(
            f"trainer.init_from={path} is a run on scene {scene}; this run's scene is "
            f"{s.scene.name}, and a design carries over only to the scene it was learned on"
        )


# What the absence of a setting from a checkpoint's record means: how runs trained before the
# setting existed or before its default changed.  These are recorded always; every other setting
# only where it differs from its schema default, its absence meaning that default, so a new setting
# needs no rule (a changed default needs its old value here).
ABSENT_MEANS = {
    "solver.element_bound": False,
    "material.formulation": "displacement",
    "material.volumetric": "bulk",
    "trainer.inversion_penalty": 0.0,
    "contact.enabled": False,
}


def _shaping(s: TrainConfig) -> dict:
    """The settings that shape the parameters, the optimiser state or the data, by group."""
    asdict = dataclasses.asdict
    trainer = {
        "batch_size": s.trainer.batch_size,
        "seed": s.trainer.seed,
        "freeze_geometry": s.trainer.freeze_geometry,
        "inversion_penalty": s.trainer.inversion_penalty,
    }
    if s.optim.schedule != "constant":
        trainer["steps"] = s.trainer.steps  # the schedule's length
    if s.trainer.inversion_penalty > 0:
        trainer["inversion_margin"] = s.trainer.inversion_margin
    # the bound in the scene's units is min_feature / part.scale
    if s.trainer.min_feature is not None:
        trainer.update(
            min_feature=s.trainer.min_feature,
            feature_penalty=s.trainer.feature_penalty,
            part_scale=s.part.scale,
        )
    task = asdict(s.task)
    if getattr(s.task, "dataset", None):  # the descriptors themselves, not only the file's name
        task["dataset_sha256"] = _sha256(Path(s.task.dataset))
    # resolved below (the scene's volumetric: as the material's)
    scene = asdict(s.scene)
    scene = {k: v for k, v in scene.items() if k not in ("contact", "fidelity", "volumetric")}
    return {
        "task": task,
        "scene": scene,
        "model": asdict(s.model),
        "fidelity": asdict(s.fidelity),
        # what describes the material (name, source, fit, unit) or checks it (stretches) changes no
        # solve; volumetric=auto: a law without a volume term, which has none to record
        "material": {
            k: v
            for k, v in asdict(s.material).items()
            if k not in ("name", "source", "fit", "unit", "stretches") and v != "auto"
        },
        "optim": asdict(s.optim),
        "trainer": trainer,
        "contact": asdict(s.contact) if s.contact.enabled else {"enabled": False},
        "solver": {"element_bound": s.solver.element_bound},
    }


def _flat(tree: dict) -> dict:
    from . import checkpoint

    return dict(checkpoint.flatten(json.loads(json.dumps(tree, default=dataclasses.asdict))))


def absent_means(s: TrainConfig) -> dict:
    """What each setting of the fingerprint means where a checkpoint's record lacks it: its schema
    default, or ABSENT_MEANS's value."""
    defaults = {}
    for group in (
        "task",
        "scene",
        "model",
        "fidelity",
        "material",
        "optim",
        "trainer",
        "contact",
        "solver",
    ):
        for f in dataclasses.fields(getattr(s, group)):
            if f.default is not dataclasses.MISSING:
                defaults[f"{group}.{f.name}"] = f.default
            elif f.default_factory is not dataclasses.MISSING:
                defaults[f"{group}.{f.name}"] = f.default_factory()
    return {**_flat(_nest(defaults)), **ABSENT_MEANS}


def fingerprint(s: TrainConfig) -> dict:
    """The settings that shape the parameters, the optimiser state or the data, as a checkpoint
    records them: each where it differs from what its absence means (absent_means), those of
    ABSENT_MEANS always. A checkpoint written under other values must not be continued silently."""
    absent = absent_means(s)
    return _nest(
        {
            k: v
            for k, v in _flat(_shaping(s)).items()
            if k in ABSENT_MEANS or k not in absent or v != absent[k]
        }
    )


def _nest(flat: dict) -> dict:
    """{"a.b": 1} as {"a": {"b": 1}}."""
    tree: dict = {}
    for key, value in flat.items():
        *parents, leaf = key.split(".")
        node = tree
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return tree


def _sha256(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None  # a missing file is refused with the task's settings; an unreadable one, read


def fidelity_record(disc, fidelity) -> dict:
    """The discretisation a run used, and where its `fidelity` setting was fidelity=auto, which
    measured setting that was and why."""
    from ..fidelity import choice_of

    choice = choice_of(fidelity, disc.spec)
    return {
        "ctrl_per_patch": disc.mesh.fidelity.ctrl_per_patch,
        "quad_points": disc.mesh.fidelity.quad_points,
        "grading": disc.mesh.fidelity.grading,
        "inversion_barrier": disc.mesh.fidelity.inversion_barrier,
        "dofs": disc.boundary.n_dofs,
        "auto": None if choice is None else choice.record(),
        "contact": disc.contact is not None,
    }


def make_trainer(
    s: TrainConfig, run_dir: Path, config: dict | None = None, world=None, exact_init: bool = False
):
    """The simulator, task, network, logger and trainer of checked, resolved settings (JAX set up
    first); with `exact_init` every parameter restored from trainer.init_from must fit
    (re-evaluating a run)."""
    from ..runtime import available_cores, configure_jax

    configure_jax()
    from ..geometry.features import Ligaments
    from ..registry import MODELS, TASKS
    from ..resolve import material_params
    from ..periodic.front import cell_of
    from ..simulator import Simulator
    from .logger import make_logger
    from .mpi import World
    from .trainer import Trainer

    world = world or World()
    # solver.workers 0: this machine's cores, shared among the MPI ranks running on it
    workers = s.solver.workers or max(1, available_cores() // world.local_size)
    periodic = getattr(s.task, "periodic", False)  # a periodic task: its scene's cell
    sim = cell_of(s) if periodic else Simulator.from_settings(s, workers)
    task = TASKS.get(s.task.factory)(s.task, sim)
    sim = task.simulator(sim)
    hidden = task.hidden(s.task.hidden if s.model.hidden is None else s.model.hidden)
    if task.in_time:  # its trajectories: the run's dynamics, the material's density
        task.attach(sim, s.dynamics, s.material.density)
    model = MODELS.get(s.model.name)(
        hidden=hidden, n_out=task.n_outputs(sim), d_max=task.d_max, out_bias=s.model.out_bias
    )
    logger = make_logger(s.logger, run_dir, config or {}, run_dir.name, world.is_root)
    # the narrowest ligament: reported for every design, and with trainer.min_feature bounded
    bound = None if s.trainer.min_feature is None else s.trainer.min_feature / s.part.scale
    features = Ligaments.of(
        sim.disc.mesh, sim.reference_points(sim.init_params()), bound, s.part.scale
    )
    return Trainer(
        task,
        sim,
        model,
        material_params(s.material),
        s.trainer,
        s.optim,
        run_dir,
        logger,
        world,
        fingerprint(s),
        exact_init,
        absent_means(s),
        features,
    )
