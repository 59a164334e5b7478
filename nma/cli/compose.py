"""A command line's config composed exactly as Hydra will compose it, and a composition error as
the one line that says what to change."""

from __future__ import annotations

import copy
import difflib
import re
from pathlib import Path

from ..config import CONF_DIR
from ..errors import ConfigError
from ..schema import explain, register

PACKAGE = Path(__file__).parent.parent  # nma/: where Hydra reads a relative --config-path


def compose(
    config_name: str,
    overrides: list[str],
    config_dir: str | None = None,
    config_path: str | None = None,
):
    """The composed config of one job, with its `hydra` node (run directory and so on);
    `config_dir`: Hydra's --config-dir, a directory of configs searched besides conf/;
    `config_path`: Hydra's --config-path, the primary config directory in place of conf/
    (relative: to the nma package, as Hydra reads it)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    register()
    if config_dir is not None:
        mine = Path(config_dir)
        if not mine.is_dir():
            raise ConfigError(f"--config-dir {config_dir} is not a directory")
        _refuse_clashes(mine, f"--config-dir {config_dir}")
        overrides = [*overrides, f"hydra.searchpath=[file://{mine.absolute()}]"]
    for override in overrides:  # Hydra passes over a search path that does not exist
        if override.startswith(("hydra.searchpath=", "+hydra.searchpath=")):
            for entry in re.findall(r"file://([^,\]\s'\"]+)", override):
                if not Path(entry).is_dir():
                    raise ConfigError(f"hydra.searchpath names {entry}, which is not a directory")
                _refuse_clashes(Path(entry), f"hydra.searchpath entry {entry}")
    # an absolute --config-path wins over the package's directory
    primary = CONF_DIR if config_path is None else PACKAGE / config_path
    if not primary.is_dir():
        raise ConfigError(f"--config-path {config_path} is not a directory ({primary})")
    with initialize_config_dir(config_dir=str(primary.resolve()), version_base="1.3"):
        return hydra_compose(config_name, overrides=overrides, return_hydra_config=True)


def _refuse_clashes(mine: Path, what: str) -> None:
    """A directory of the user's configs may not hold a file of a shipped config's name: Hydra
    reads conf/ first, so the shipped file would be used in place of the user's, without a word."""
    clashes = sorted(
        str(p.relative_to(mine))
        for p in mine.rglob("*.yaml")
        if (CONF_DIR / p.relative_to(mine)).is_file()
    )
    if clashes:
        raise ConfigError(
            f"{what}: {', '.join(clashes)} has the name of a config nma ships "
            "(conf/), which would be read in its place: give yours a name of its own"
        )


def without_hydra(cfg):
    from omegaconf import open_dict, read_write

    cfg = copy.deepcopy(cfg)
    with read_write(cfg), open_dict(cfg):
        cfg.pop("hydra", None)
    return cfg


def bad_input(exc: Exception, overrides: list[str] = ()) -> str:
    """The one line of a composition or validation error; anything else is not bad input:
    re-raised."""
    from hydra.errors import HydraException, OverrideParseException
    from omegaconf.errors import OmegaConfBaseException

    if isinstance(exc, ConfigError):
        return str(exc)
    if isinstance(exc, OverrideParseException):  # name the override that does not parse
        from hydra.core.override_parser.overrides_parser import OverridesParser

        for o in overrides:
            try:
                OverridesParser.create().parse_overrides([o])
            except OverrideParseException:
                return (
                    f"the command-line override {o!r} does not parse: a list is [a, b], a "
                    f"string with spaces or commas is quoted ('a b'), a sweep is a,b under "
                    f"--multirun"
                )
    if isinstance(exc, (HydraException, OmegaConfBaseException)):
        return _one_line(exc)
    if isinstance(exc, AssertionError) and "NoneType" in str(exc):
        # omegaconf: a field of a group left at null
        for o in overrides:
            key = o.lstrip("+").split("=")[0]
            group = key.split(".")[0]
            if "." in key and not any(x.lstrip("+").startswith(group + "=") for x in overrides):
                from ..config import options

                choices = options(group)
                return (
                    f"{key} needs {group}= chosen first ({group}={choices[0]} {key}=...; one "
                    f"of {choices}): left unchosen, the command picks it (nma.evaluate: the "
                    f"run's own)"
                )
    raise exc


def _one_line(exc: BaseException) -> str:
    from hydra.errors import MissingConfigException

    if isinstance(exc, MissingConfigException) and exc.missing_cfg_file:
        group, _, name = str(exc.missing_cfg_file).rpartition("/")
        options = [o for o in (exc.options or []) if not o.endswith("_schema")]
        task_file = CONF_DIR / "task" / f"{name}.yaml"
        if group == "scene" and task_file.is_file():
            # scene defaults to the task's option name; a task posed in YAML may be named otherwise
            import yaml

            own = (yaml.safe_load(task_file.read_text()) or {}).get("name")
            which = f"scene={own}" if own in options else f"scene=<one of {options}>"
            return (
                f"task={name} names no scene of its own name (scene={name} is unknown): give "
                f"its scene, {which}"
            )
        schemas = []
        if group:
            from hydra.core.config_store import ConfigStore

            try:
                schemas = sorted(
                    o.removesuffix(".yaml")
                    for o in ConfigStore.instance().list(group)
                    if "_schema" in o
                )
            except OSError:  # a group with no schema in the store
                schemas = []
        if group and (name.endswith("_schema") or difflib.get_close_matches(name, schemas, 1, 0.8)):
            # a config file's defaults list names a schema (or one misspelt)
            return (
                f"the schema {name} in a {group} file's defaults list is unknown; choose one "
                f"of {schemas}"
            )
        if group:
            from ..registry import broken_plugins

            broken = broken_plugins() if group == "task" else ""
            return f"{group}={name} is unknown; choose one of {options}{broken}"
    return explain(exc)
