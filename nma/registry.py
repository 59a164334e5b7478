"""Name -> factory registries for the components chosen in YAML (tasks, models, linear solvers)."""
from __future__ import annotations

from typing import Callable, Generic, TypeVar

from .errors import ConfigError

T = TypeVar("T")


class Registry(Generic[T]):
    def __init__(self, kind: str):
        self.kind = kind
        self._items: dict[str, Callable[..., T]] = {}

    def register(self, name: str):
        def deco(factory):
            if name in self._items:
                raise ValueError(f"{self.kind} {name!r} is registered twice")
            self._items[name] = factory
            return factory
        return deco

    def get(self, name: str) -> Callable[..., T]:
        if name not in self._items:
            raise ConfigError(f"{self.kind} must be one of {sorted(self._items)}, got {name!r}")
        return self._items[name]



TASKS: Registry = Registry("task.name")
MODELS: Registry = Registry("model.name")
LINEAR_SOLVERS: Registry = Registry("solver.linear")

PLUGIN_GROUP = "nma.tasks"  # entry points of installed packages whose modules register tasks


def load_plugins() -> None:
    """Import the module of every `nma.tasks` entry point of an installed package: a task written outside
    nma registers itself there (its factory in TASKS, its schema in nma.schema.TASK_SCHEMAS)."""
    from importlib.metadata import entry_points

    for ep in entry_points(group=PLUGIN_GROUP):
        try:
            ep.load()
        except Exception as exc:
            raise ConfigError(f"the {PLUGIN_GROUP} entry point {ep.name} = {ep.value} does not import: "
                              f"{type(exc).__name__}: {exc}") from None
