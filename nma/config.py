"""Where the configs live, and plain (non-Hydra) loading of one config group option.

`load("scene", "translation")` is the option's YAML merged onto its schema (nma/schema/) and
checked, as a plain dict: what Hydra would compose for that group, without Hydra.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from omegaconf import OmegaConf

from . import schema
from .errors import ConfigError
from .schema.periodic import LoadConfig, PeriodicSceneConfig

CONF_DIR = Path(__file__).resolve().parent.parent / "conf"
GROUP_SCHEMAS = {
    "scene": schema.SceneConfig,
    "fidelity": schema.Fidelity,
    "solver": schema.SolverConfig,
    "contact": schema.ContactConfig,
    "material": schema.MaterialConfig,
    "model": schema.ModelConfig,
    "optim": schema.OptimConfig,
    "trainer": schema.TrainerConfig,
    "logger": schema.LoggerConfig,
    "dynamics": schema.DynamicsConfig,
    "load": LoadConfig,
}


def options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


def groups_help(*groups: str) -> str:
    """The config groups a command takes, each with its options: a line each of its --help
    (`${nma_groups:scene,fidelity}` in a command's hydra.help.template)."""
    return "\n".join(f"{group}: {', '.join(options(group))}" for group in groups)


OmegaConf.register_new_resolver("nma_groups", groups_help, replace=True)


def load(group: str, name: str) -> dict:
    path = CONF_DIR / group / f"{name}.yaml"
    if not path.exists():
        raise ConfigError(f"{group}={name!r} is unknown; choose one of {options(group)}")
    body = yaml.safe_load(path.read_text()) or {}
    defaults = body.pop("defaults", None)
    if group == "task":
        body.setdefault("name", name)
    kind = schema.task_schema(body, defaults) if group == "task" else GROUP_SCHEMAS[group]
    if group == "scene" and body.get("periodic"):
        kind = PeriodicSceneConfig
    return OmegaConf.to_container(OmegaConf.structured(schema.build(kind, body)))
