"""Between the schemas and Hydra / OmegaConf: a checked instance from a mapping, unknown keys
refused, OmegaConf's errors in one line, the schemas in Hydra's ConfigStore."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from ..errors import ConfigError
from ..geometry.scene import SceneSpec
from .commands import EvaluateConfig, ExportConfig, FitConfig, SimulateConfig, TrainConfig
from .periodic import PeriodicSceneConfig
from .physics import MaterialConfig
from .scene import SceneConfig
from ..settings import _kind
from ..tasks.schemas import TASK_SCHEMAS


def build(schema: type, values: Any = None):
    """A checked schema instance from a mapping (or an OmegaConf node); errors name the field."""
    from omegaconf import OmegaConf

    if isinstance(values, schema):
        return values
    try:
        node = OmegaConf.merge(OmegaConf.structured(schema), values or {})
        check_keys(node, getattr(schema, "prefix", ""))
        return OmegaConf.to_object(node)
    except ConfigError:
        raise
    except Exception as exc:  # OmegaConf's type / unknown-key / missing-value errors
        raise ConfigError(explain(exc, getattr(schema, "prefix", ""))) from None


def scene_config(cfg: Any) -> SceneConfig:
    """A checked SceneConfig from itself or a mapping (cells as one string or a list of rows); a
    periodic one (`periodic: true`) is a PeriodicSceneConfig."""
    if isinstance(cfg, Mapping) and not isinstance(cfg.get("cells", ""), str):
        cfg = {**cfg, "cells": "\n".join(cfg["cells"])}
    periodic = isinstance(cfg, Mapping) and bool(cfg.get("periodic", False))
    return build(PeriodicSceneConfig if periodic else SceneConfig, cfg)


def scene_from_config(cfg: Any) -> SceneSpec:
    """The SceneSpec of a checked SceneConfig or of a mapping (checked here), cells top row
    first."""
    return scene_config(cfg).spec()


def check_keys(node, path: str = "") -> None:
    """Reject keys a schema does not declare (Hydra's `+group.key=...` can add them)."""
    import dataclasses

    from omegaconf import DictConfig, ListConfig, OmegaConf

    if isinstance(node, DictConfig):
        kind = OmegaConf.get_type(node)
        if dataclasses.is_dataclass(kind):
            known = {f.name for f in dataclasses.fields(kind)}
            for key in node.keys():
                if key not in known:
                    raise ConfigError(
                        f"{path + '.' if path else ''}{key} is not a known setting; "
                        f"{kind.__name__} has {sorted(known)}"
                    )
        for key in node.keys():
            if not OmegaConf.is_missing(node, key):
                check_keys(node[key], f"{path + '.' if path else ''}{key}")
    elif isinstance(node, ListConfig):
        for i in range(len(node)):
            if not OmegaConf.is_missing(node, i):
                check_keys(node[i], f"{path}[{i}]")


def explain(exc: BaseException, prefix: str = "") -> str:
    """One line for a Hydra or OmegaConf error: the field, the value and what is allowed."""
    from omegaconf.errors import ConfigKeyError, MissingMandatoryValue, ValidationError

    cause = exc
    # Hydra wraps the error of a config file it composes (e.g. one from --config-dir): find the
    # field's
    while (cause.__cause__ or cause.__context__) is not None and not getattr(
        cause, "full_key", None
    ):
        cause = cause.__cause__ or cause.__context__
    where = re.match(r"In '([^']+)':", str(exc))
    if where and cause is not exc:
        return f"{explain(cause, prefix)} (in the config file {where[1]}.yaml)"
    key = getattr(cause, "full_key", None) or ""
    key = f"{prefix}.{key}" if prefix and key and not key.startswith(prefix) else key
    first = str(cause).strip().splitlines()[0] if str(cause).strip() else type(cause).__name__
    if isinstance(cause, MissingMandatoryValue):
        return f"{key} is required and has no value"
    if (
        isinstance(cause, ConfigKeyError)
        or "not in struct" in first
        or re.search(r"Key '.*' not in", first)
    ):
        return f"{key} is not a known setting ({first})"
    if isinstance(cause, ValidationError):
        m = re.match(r"Value '(.*)' of type '(\w+)' could not be converted to (\w+)", first)
        if "is not a ListConfig" in first:
            return f"{key} must be a list such as [1.0, 2.0], got a single {first.split()[3]}"
        if m:
            return (
                f"{key} must be "
                f"{_kind({'Integer': int, 'Float': float, 'Boolean': bool}.get(m[3], m[3]))}, "
                f"got {m[1]!r}"
            )
        return f"{key}: {first}"
    return first if not key else f"{key}: {first}"


def register() -> None:
    """Put the schemas into Hydra's ConfigStore (idempotent)."""
    from hydra.core.config_store import ConfigStore

    from ..mechanics.laws import builtin, law_names
    from ..registry import load_plugins

    load_plugins()  # tasks from outside nma bring their schemas
    cs = ConfigStore.instance()
    cs.store(name="train_schema", node=TrainConfig)
    cs.store(name="simulate_schema", node=SimulateConfig)
    cs.store(name="export_schema", node=ExportConfig)
    cs.store(name="evaluate_schema", node=EvaluateConfig)
    cs.store(name="fit_schema", node=FitConfig)
    # a periodic scene's file names it in its defaults (conf/scene/square_array.yaml)
    cs.store(group="scene", name="periodic_scene_schema", node=PeriodicSceneConfig)
    for name in law_names():  # a law from an installed package: material=<name> needs no file
        if not builtin(name):  # checked with the rest of the command's settings
            cs.store(group="material", name=name, node=MaterialConfig.fields_of_law(name))
    for name, schema in TASK_SCHEMAS.items():
        # a spec task has no defaults to build an instance from: its class is the node
        cs.store(
            group="task",
            name=f"{name}_schema",
            node=schema if name == "spec" else schema(name=name),
        )
