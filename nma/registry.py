"""Name -> factory registries for the components chosen in YAML (tasks, models, linear solvers,
Newton's correctors).

A factory is registered with its function, or declared by its import path ("module:attribute") and
imported when first asked for: the config layer learns every task's name and schema without
importing the task's code (and JAX with it).
"""

from __future__ import annotations

from importlib import import_module
from typing import Callable, Generic, TypeVar

from .errors import ConfigError

T = TypeVar("T")


class Registry(Generic[T]):
    def __init__(self, kind: str):
        self.kind = kind
        self._items: dict[str, Callable[..., T] | str] = {}
        # name -> the schema of its settings, where the component has one
        self.schemas: dict[str, type] = {}

    def register(self, name: str, schema: type | None = None):
        """Decorator: `factory` under `name`, and `schema` (its settings' dataclass) beside it."""

        def deco(factory):
            self.declare(name, factory, schema)
            return factory

        return deco

    def declare(
        self, name: str, factory: Callable[..., T] | str, schema: type | None = None
    ) -> None:
        """`factory` a callable, or the path "module:attribute" of one, imported on first use."""
        if name in self._items:
            raise ValueError(f"{self.kind} {name!r} is registered twice")
        if isinstance(factory, str) and factory.count(":") != 1:
            raise ValueError(
                f"{self.kind} {name!r}: a factory's path is 'module:attribute', got {factory!r}"
            )
        self._items[name] = factory
        if schema is not None:
            self.schemas[name] = schema

    def get(self, name: str) -> Callable[..., T]:
        if name not in self._items:
            raise ConfigError(
                f"{self.kind} must be one of {sorted(self._items)}, got {name!r}{broken_plugins()}"
            )
        factory = self._items[name]
        if isinstance(factory, str):
            module, _, attribute = factory.partition(":")
            try:
                factory = getattr(import_module(module), attribute)
            except (ImportError, AttributeError) as exc:
                raise ConfigError(
                    f"{self.kind} {name} is declared as {self._items[name]!r}, which does not "
                    f"import: {type(exc).__name__}: {exc}"
                ) from None
            self._items[name] = factory
        return factory

    def names(self) -> list[str]:
        """Every registered name, in order of registration."""
        return list(self._items)


TASKS: Registry = Registry("task.name")
MODELS: Registry = Registry("model.name")
LINEAR_SOLVERS: Registry = Registry("solver.linear")
CORRECTORS: Registry = Registry("solver.corrector")  # nma.solver.correctors

PLUGIN_GROUP = "nma.tasks"  # entry points of installed packages whose modules register tasks
# entry point -> why it did not import (its tasks are unavailable)
BROKEN_PLUGINS: dict[str, str] = {}
_plugins_loaded = False


def load_plugins() -> None:
    """Import the module of every `nma.tasks` entry point of an installed package, once: a task
    written outside nma registers itself there, its factory with its schema (`@TASKS.register(name,
    schema=...)`). One that does not import (or exits) is named in a warning and in BROKEN_PLUGINS,
    and the commands go on without its tasks."""
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    load_entry_points(PLUGIN_GROUP, "tasks", BROKEN_PLUGINS)


def load_entry_points(group: str, what: str, broken: dict[str, str]) -> None:
    """Import every entry point of `group`; one that does not import (or exits) is recorded in
    `broken` and named in a warning saying that its `what` are unavailable."""
    import sys
    from importlib.metadata import entry_points

    for ep in entry_points(group=group):
        try:
            ep.load()
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # SystemExit too: a plugin never ends the command
            broken[f"{ep.name} = {ep.value}"] = why = f"{type(exc).__name__}: {exc}"
            print(
                f"warning: the {group} entry point {ep.name} = {ep.value} does not import "
                f"({why}); its {what} are unavailable",
                file=sys.stderr,
                flush=True,
            )


def broken_plugins() -> str:
    """The entry points that did not import, for a message that lists the tasks there are ("" if
    none)."""
    if not BROKEN_PLUGINS:
        return ""
    return (
        f" (the {PLUGIN_GROUP} entry points that did not import: "
        + "; ".join(f"{k}: {v}" for k, v in BROKEN_PLUGINS.items())
        + ")"
    )
