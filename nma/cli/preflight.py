"""Every job of a command line checked before Hydra starts (`preflight`): composed as Hydra will
compose it, checked against the schema and the command's own rules, and its run directory held."""

from __future__ import annotations

import itertools
import signal
import sys
from pathlib import Path
from typing import Callable

from ..errors import ConfigError
from ..sweep import checking, job_overrides
from .compose import bad_input, compose, without_hydra
from .exits import BAD_INPUT, SYSTEM, os_error, say
from .rundirs import RUN_LOCK, hold_run_dir, writable_dir


def preflight(config_name: str, check: Callable, argv: list[str], rank: int = 0):
    """Check every job's config with check(cfg, hydra_cfg, multirun); exit 2 with one line on the
    first error.  Returns the first job's `hydra` node (run directory, ...), or None when Hydra is
    asked for help or info only."""
    from hydra._internal.utils import get_args_parser

    from ..runtime import before_jax_starts

    before_jax_starts()  # the checks below may start JAX's backend
    args, _ = get_args_parser().parse_known_args(argv)
    if (
        args.help
        or args.hydra_help
        or args.info
        or args.cfg
        or args.shell_completion
        or args.experimental_rerun
    ):
        return None  # Hydra answers these itself
    config_name = args.config_name or config_name
    first, bad = None, {}  # bad: message -> the jobs it holds for
    subdirs: dict[str, int] = {}  # a sweep's job directories (below its sweep dir) -> first job
    try:
        jobs = job_overrides(args.overrides, args.multirun)
        varying = [i for i in range(len(jobs[0])) if any(job[i] != jobs[0][i] for job in jobs)]
        for num, overrides in checking(jobs, args.multirun, rank):  # says how far a sweep got
            try:
                # a sweep's job numbers, as Hydra's basic sweeper gives them: its directory resolves
                job = [*overrides, f"hydra.job.num={num}"] if args.multirun else overrides
                cfg = compose(config_name, job, args.config_dir, args.config_path)
                subdir = str(cfg.hydra.sweep.subdir) if args.multirun else None
                if args.multirun and subdirs.setdefault(subdir, num) != num:
                    raise ConfigError(
                        f"hydra.sweep.subdir={subdir} is the directory of job "
                        f"{subdirs[subdir]} and of job {num}: each job needs its "
                        f"own (the default, ${{hydra.job.num}}, gives each its number)"
                    )
                check(without_hydra(cfg), cfg.hydra, args.multirun)
                if not args.multirun:
                    try:
                        writable_dir(Path(cfg.hydra.run.dir), _run_dir_name(cfg))
                    except PermissionError as exc:  # the system refuses: nothing has run
                        say(os_error(exc), rank)
                        sys.exit(SYSTEM)
                    if rank == 0:  # before Hydra writes there (a sweep's jobs take theirs later)
                        cfg = hold_dated_dir(cfg, overrides, config_name, args) or cfg
                        hold_run_dir(Path(cfg.hydra.run.dir), _run_dir_name(cfg))
                first = first if first is not None else cfg.hydra
            except Exception as exc:  # composition and validation errors only: nothing has run
                message = bad_input(exc, overrides)
                bad.setdefault(message, []).append(" ".join(overrides[i] for i in varying))
    except KeyboardInterrupt:
        say("interrupted (Ctrl-C)", rank)
        sys.exit(128 + signal.SIGINT)
    except Exception as exc:  # the command line itself does not parse
        say(bad_input(exc, args.overrides), rank)
        sys.exit(BAD_INPUT)
    if bad:  # every bad job of a sweep at once, each message once
        for message, where in bad.items():
            say(
                message
                if not args.multirun
                else f"{message} (in {len(where)} of {len(jobs)} jobs, e.g. "
                f"{where[0] or 'every job'})",
                rank,
            )
        sys.exit(BAD_INPUT)
    return first


def hold_dated_dir(cfg, overrides: list[str], config_name: str, args):
    """Where the run directory is the command's dated default (no hydra.run.dir given): the first
    of it, <it>_2, <it>_3, ... that is empty and not in use, held, and named on the command line so
    that Hydra writes there (its own clock may have moved on): two commands started in one second
    each get one.  The config with that directory, or None where the user named the directory."""
    from omegaconf import OmegaConf

    run = OmegaConf.to_container(cfg.hydra.run, resolve=False)
    dated = "${now:" in str(run.get("dir", ""))
    if not dated or any(o.lstrip("+").startswith("hydra.run.dir=") for o in overrides):
        return None
    base = chosen = Path(cfg.hydra.run.dir)
    for n in itertools.count(2):
        if not (chosen.is_dir() and any(p.name != RUN_LOCK for p in chosen.iterdir())):
            try:
                hold_run_dir(chosen)
                break
            except ConfigError:  # another process holds it
                pass
        chosen = base.with_name(f"{base.name}_{n}")
    sys.argv.append(f"hydra.run.dir={chosen}")
    if chosen == base:  # the config says this directory already: no second composition
        return cfg
    return compose(
        config_name, [*overrides, f"hydra.run.dir={chosen}"], args.config_dir, args.config_path
    )


def _run_dir_name(cfg) -> str:
    """How a command's run directory is named to its user: hydra.run.dir, or where a command on a
    run (nma.evaluate, nma.export: run=<dir>) writes inside it."""
    run, where = cfg.get("run"), Path(cfg.hydra.run.dir)
    if isinstance(run, str) and where.parent == Path(run):
        return f"run={run}: its {where.name}/ directory"
    return "hydra.run.dir"
