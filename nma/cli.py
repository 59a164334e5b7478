"""What every command shares: config checks before any work, and exit codes a script can rely on.

    0  success
    2  bad input (config or data), reported before any work, as one line naming the field
    1  a solve or a training step that failed for a stated reason
    anything unexpected keeps its traceback (Hydra prints it) and is never reported as bad input

`preflight` composes the command line's config exactly as Hydra will (every job of a --multirun
sweep), checks it against the schema, and exits 2 on the first error, before Hydra creates a run
directory.  Under MPI every rank checks and exits, and rank 0 alone prints.
"""
from __future__ import annotations

import copy
import itertools
import math
import sys
from contextlib import contextmanager
from typing import Callable

from .config import CONF_DIR
from .errors import ConfigError, SolverError, TrainingError
from .schema import explain, register

BAD_INPUT, FAILED = 2, 1
MAX_SWEEP_CHECKS = 256


def _say(message: str, rank: int = 0) -> None:
    if rank == 0:
        print(f"error: {message}", file=sys.stderr, flush=True)


def _one_line(exc: BaseException) -> str:
    from hydra.errors import MissingConfigException

    if isinstance(exc, MissingConfigException) and exc.missing_cfg_file:
        group, _, name = str(exc.missing_cfg_file).rpartition("/")
        options = [o for o in (exc.options or []) if not o.endswith("_schema")]
        if group:
            return f"{group}={name} is unknown; choose one of {options}"
    return explain(exc)


def job_overrides(overrides: list[str], multirun: bool) -> list[list[str]]:
    """The override list of every job Hydra's basic sweeper would launch (one without --multirun)."""
    if not multirun:
        return [overrides]
    from hydra.core.override_parser.overrides_parser import OverridesParser

    choices = []
    for o in OverridesParser.create().parse_overrides(overrides):
        if o.is_sweep_override():
            key = o.get_key_element()
            choices.append([f"{key}={v}" for v in o.sweep_string_iterator()])
        else:
            choices.append([o.input_line])
    return [list(job) for job in itertools.islice(itertools.product(*choices), MAX_SWEEP_CHECKS)]


def compose(config_name: str, overrides: list[str]):
    """The composed config of one job, with its `hydra` node (run directory and so on)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    register()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return hydra_compose(config_name, overrides=overrides, return_hydra_config=True)


def without_hydra(cfg):
    from omegaconf import open_dict, read_write

    cfg = copy.deepcopy(cfg)
    with read_write(cfg), open_dict(cfg):
        cfg.pop("hydra", None)
    return cfg


def preflight(config_name: str, check: Callable, argv: list[str], rank: int = 0):
    """Check every job's config with check(cfg, hydra_cfg, multirun); exit 2 with one line on the
    first error.  Returns the first job's `hydra` node (run directory, ...), or None when Hydra is
    asked for help or info only."""
    from hydra._internal.utils import get_args_parser

    args, _ = get_args_parser().parse_known_args(argv)
    if args.help or args.hydra_help or args.info or args.cfg or args.shell_completion \
            or args.config_path or args.config_dir or args.config_name or args.experimental_rerun:
        return None  # Hydra answers these itself
    first = None
    try:
        for overrides in job_overrides(args.overrides, args.multirun):
            cfg = compose(config_name, overrides)
            check(without_hydra(cfg), cfg.hydra, args.multirun)
            first = first if first is not None else cfg.hydra
    except Exception as exc:  # composition and validation errors only reach here: nothing has run
        from hydra.errors import HydraException
        from omegaconf.errors import OmegaConfBaseException

        if not isinstance(exc, (ConfigError, HydraException, OmegaConfBaseException)):
            raise
        _say(_one_line(exc) if not isinstance(exc, ConfigError) else str(exc), rank)
        sys.exit(BAD_INPUT)
    return first


@contextmanager
def exit_codes(rank: int = 0):
    """Inside a command's task function: bad input -> 2, a stated failure -> 1, one line each."""
    try:
        yield
    except ConfigError as err:
        _say(str(err), rank)
        sys.exit(BAD_INPUT)
    except (SolverError, TrainingError) as err:
        _say(str(err), rank)
        sys.exit(FAILED)


def json_safe(value):
    """Non-finite floats as null (JSON has no NaN or Infinity)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value
