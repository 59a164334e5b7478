"""The one config schema: every group's fields, defaults, types and allowed ranges.

Each config group is a dataclass registered in Hydra's ConfigStore; the YAML files under conf/ only
select a group option and override values.  A field's allowed range lives next to its default
(`bounded(default, "(0, 1)")`, `choice(default, options)`), and every dataclass checks its fields on
construction, so a config is checked the same way whether Hydra composes it or Python builds it:

    Fidelity(5, 1)  ->  ConfigError: fidelity.quad_points must be an integer in [2, 10], got 1

This package imports no JAX: the commands validate a composed config before any heavy import or
work.
"""

from __future__ import annotations

from .commands import EvaluateConfig, ExportConfig, OutputConfig, SimulateConfig, TrainConfig
from .compose import build, check_keys, explain, register, scene_config, scene_from_config
from ..settings import Schema, bounded, choice
from .physics import (
    ContactConfig,
    DynamicsConfig,
    Fidelity,
    MaterialConfig,
    PartConfig,
    SolverConfig,
)
from .scene import GroupConfig, SceneConfig, SupportConfig
from ..tasks.schemas import (
    TASK_SCHEMAS,
    DigitalMNISTTask,
    RotationTask,
    ShapeMatchingTask,
    SpecTask,
    TaskConfig,
    TranslationTask,
    task_schema,
)
from .training import LoggerConfig, LrScale, ModelConfig, OptimConfig, TrainerConfig

__all__ = [
    "EvaluateConfig",
    "ExportConfig",
    "OutputConfig",
    "SimulateConfig",
    "TrainConfig",
    "build",
    "check_keys",
    "explain",
    "register",
    "scene_config",
    "scene_from_config",
    "Schema",
    "bounded",
    "choice",
    "ContactConfig",
    "DynamicsConfig",
    "Fidelity",
    "MaterialConfig",
    "PartConfig",
    "SolverConfig",
    "GroupConfig",
    "SceneConfig",
    "SupportConfig",
    "TASK_SCHEMAS",
    "DigitalMNISTTask",
    "RotationTask",
    "ShapeMatchingTask",
    "SpecTask",
    "TaskConfig",
    "task_schema",
    "TranslationTask",
    "LoggerConfig",
    "LrScale",
    "ModelConfig",
    "OptimConfig",
    "TrainerConfig",
]
