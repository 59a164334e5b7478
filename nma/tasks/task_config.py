"""TaskConfig: the settings every task has, the base of each task's schema (nma.tasks.schemas)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, List

from omegaconf import MISSING

from ..settings import Schema, bounded


@dataclass
class TaskConfig(Schema):
    prefix: ClassVar[str] = "task"
    name: str = MISSING
    d_max: float = bounded(4.0, "(0, 5]", doc="actuations are d_max * tanh(network output)")
    hidden: List[int] = bounded(
        spec="[1, 100000]",
        factory=lambda: [30, 30, 30],
        doc="the encoder's hidden widths for this task (authors' code: 3 x 30)",
    )

    @property
    def factory(self) -> str:
        """The name the task is registered under (nma.registry.TASKS)."""
        return self.name
