"""What every command shares: config checks before any work, and exit codes a script can rely on.

    0  success
    2  bad input (config or data), reported before any work where it can be, as one line naming the
       field; a run directory the command created for nothing is removed again
    1  a solve or a training step that failed for a stated reason
    3  the operating system refused (a directory that cannot be written, a disk that is full, ...)
    130, 143  stopped by Ctrl-C or SIGTERM (128 + the signal): training saves a checkpoint first
    anything unexpected keeps its traceback (Hydra prints it) and is never reported as bad input

`preflight` composes the command line's config exactly as Hydra will (every job of a --multirun
sweep, saying how far it got where that takes a while), checks it against the schema, and exits 2
on the first error, before Hydra creates a run directory.  Under MPI every rank checks and exits,
and rank 0 alone prints.
"""
from __future__ import annotations

import copy
import difflib
import itertools
import math
import os
import re
import shutil
import signal
import socket
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

from .config import CONF_DIR
from .errors import ConfigError, SolverError, Stopped, TrainingError
from .schema import explain, register
from .sweep import checking, job_overrides  # noqa: F401  (job_overrides: the jobs a sweep launches)

BAD_INPUT, FAILED, SYSTEM = 2, 1, 3


def say(message: str, rank: int = 0) -> None:
    if rank == 0:
        print(f"error: {message}", file=sys.stderr, flush=True)


def _one_line(exc: BaseException) -> str:
    from hydra.errors import MissingConfigException

    if isinstance(exc, MissingConfigException) and exc.missing_cfg_file:
        group, _, name = str(exc.missing_cfg_file).rpartition("/")
        options = [o for o in (exc.options or []) if not o.endswith("_schema")]
        if group == "scene" and (CONF_DIR / "task" / f"{name}.yaml").is_file():
            # scene defaults to the task's option name; a task posed in YAML may be named otherwise
            import yaml

            own = (yaml.safe_load((CONF_DIR / "task" / f"{name}.yaml").read_text()) or {}).get("name")
            which = f"scene={own}" if own in options else f"scene=<one of {options}>"
            return (f"task={name} names no scene of its own name (scene={name} is unknown): give its "
                    f"scene, {which}")
        schemas = []
        if group:
            from hydra.core.config_store import ConfigStore

            try:
                schemas = sorted(o.removesuffix(".yaml") for o in ConfigStore.instance().list(group) if "_schema" in o)
            except OSError:  # a group with no schema in the store
                schemas = []
        if group and (name.endswith("_schema") or difflib.get_close_matches(name, schemas, 1, 0.8)):
            # a config file's defaults list names a schema (or one misspelt)
            return f"the schema {name} in a {group} file's defaults list is unknown; choose one of {schemas}"
        if group:
            from .registry import broken_plugins

            return f"{group}={name} is unknown; choose one of {options}{broken_plugins() if group == 'task' else ''}"
    return explain(exc)


def compose(config_name: str, overrides: list[str], config_dir: str | None = None, config_path: str | None = None):
    """The composed config of one job, with its `hydra` node (run directory and so on); `config_dir`:
    Hydra's --config-dir, a directory of configs searched besides conf/; `config_path`: Hydra's
    --config-path, the primary config directory in place of conf/ (relative: to the nma package, as
    Hydra reads it)."""
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
    primary = CONF_DIR if config_path is None else Path(__file__).parent / config_path  # an absolute one wins
    if not primary.is_dir():
        raise ConfigError(f"--config-path {config_path} is not a directory ({primary})")
    with initialize_config_dir(config_dir=str(primary.resolve()), version_base="1.3"):
        return hydra_compose(config_name, overrides=overrides, return_hydra_config=True)


def _refuse_clashes(mine: Path, what: str) -> None:
    """A directory of the user's configs may not hold a file of a shipped config's name: Hydra reads
    conf/ first, so the shipped file would be used in place of the user's, without a word."""
    clashes = sorted(str(p.relative_to(mine)) for p in mine.rglob("*.yaml") if (CONF_DIR / p.relative_to(mine)).is_file())
    if clashes:
        raise ConfigError(f"{what}: {', '.join(clashes)} has the name of a config nma ships (conf/), which would be "
                          f"read in its place: give yours a name of its own")


def job_dir(hydra_cfg, multirun: bool) -> Path:
    """The directory a job writes: a sweep's job its subdirectory of the sweep directory, else hydra.run.dir."""
    return Path(hydra_cfg.sweep.dir) / str(hydra_cfg.sweep.subdir) if multirun else Path(hydra_cfg.run.dir)


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

    from .runtime import before_jax_starts

    before_jax_starts()  # the checks below may start JAX's backend
    args, _ = get_args_parser().parse_known_args(argv)
    if args.help or args.hydra_help or args.info or args.cfg or args.shell_completion or args.experimental_rerun:
        return None  # Hydra answers these itself
    config_name = args.config_name or config_name
    first, bad = None, {}  # bad: message -> the jobs it holds for
    subdirs: dict[str, int] = {}  # a sweep's job directories (below its sweep directory) -> their first job
    try:
        jobs = job_overrides(args.overrides, args.multirun)
        varying = [i for i in range(len(jobs[0])) if any(job[i] != jobs[0][i] for job in jobs)]
        for num, overrides in checking(jobs, args.multirun, rank):  # says how far a long sweep got
            try:
                # a sweep's job numbers, as Hydra's basic sweeper gives them: its directory resolves
                cfg = compose(config_name, [*overrides, f"hydra.job.num={num}"] if args.multirun else overrides,
                              args.config_dir, args.config_path)
                if args.multirun and subdirs.setdefault(str(cfg.hydra.sweep.subdir), num) != num:
                    raise ConfigError(f"hydra.sweep.subdir={cfg.hydra.sweep.subdir} is the directory of job "
                                      f"{subdirs[str(cfg.hydra.sweep.subdir)]} and of job {num}: each job needs its "
                                      f"own (the default, ${{hydra.job.num}}, gives each its number)")
                check(without_hydra(cfg), cfg.hydra, args.multirun)
                if not args.multirun:
                    try:
                        writable_dir(Path(cfg.hydra.run.dir), _run_dir_name(cfg))
                    except PermissionError as exc:  # the system refuses the run directory: nothing has run
                        say(_os_error(exc), rank)
                        sys.exit(SYSTEM)
                    if rank == 0:  # before Hydra writes there (a sweep's jobs each take theirs as they start)
                        cfg = _hold_dated_dir(cfg, overrides, config_name, args) or cfg
                        hold_run_dir(Path(cfg.hydra.run.dir), _run_dir_name(cfg))
                first = first if first is not None else cfg.hydra
            except Exception as exc:  # composition and validation errors only: nothing has run
                bad.setdefault(_bad_input(exc, overrides), []).append(" ".join(overrides[i] for i in varying))
    except KeyboardInterrupt:
        say("interrupted (Ctrl-C)", rank)
        sys.exit(128 + signal.SIGINT)
    except Exception as exc:  # the command line itself does not parse
        say(_bad_input(exc, args.overrides), rank)
        sys.exit(BAD_INPUT)
    if bad:  # every bad job of a sweep at once, each message once
        for message, where in bad.items():
            say(message if not args.multirun else
                 f"{message} (in {len(where)} of {len(jobs)} jobs, e.g. {where[0] or 'every job'})", rank)
        sys.exit(BAD_INPUT)
    return first


def _hold_dated_dir(cfg, overrides: list[str], config_name: str, args):
    """Where the run directory is the command's dated default (no hydra.run.dir given): the first of it,
    <it>_2, <it>_3, ... that is empty and not in use, held, and named on the command line so that Hydra
    writes there (its own clock may have moved on): two commands started in one second each get one.
    The config with that directory, or None where the user named the directory."""
    from omegaconf import OmegaConf

    dated = "${now:" in str(OmegaConf.to_container(cfg.hydra.run, resolve=False).get("dir", ""))
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
    return compose(config_name, [*overrides, f"hydra.run.dir={chosen}"], args.config_dir, args.config_path)


def _run_dir_name(cfg) -> str:
    """How a command's run directory is named to its user: hydra.run.dir, or where a command on a run
    (nma.evaluate, nma.export: run=<dir>) writes inside it."""
    run, where = cfg.get("run"), Path(cfg.hydra.run.dir)
    if isinstance(run, str) and where.parent == Path(run):
        return f"run={run}: its {where.name}/ directory"
    return "hydra.run.dir"


def _bad_input(exc: Exception, overrides: list[str] = ()) -> str:
    """The one line of a composition or validation error; anything else is not bad input: re-raised."""
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
                return (f"the command-line override {o!r} does not parse: a list is [a, b], a string with "
                        f"spaces or commas is quoted ('a b'), a sweep is a,b under --multirun")
    if isinstance(exc, (HydraException, OmegaConfBaseException)):
        return _one_line(exc)
    if isinstance(exc, AssertionError) and "NoneType" in str(exc):  # omegaconf: a field of a group left at null
        for o in overrides:
            key = o.lstrip("+").split("=")[0]
            group = key.split(".")[0]
            if "." in key and not any(x.lstrip("+").startswith(group + "=") for x in overrides):
                from .config import options

                choices = options(group)
                return (f"{key} needs {group}= chosen first ({group}={choices[0]} {key}=...; one of {choices}): "
                        f"left unchosen, the command picks it (nma.evaluate: the run's own)")
    raise exc


def writable_dir(path: Path, what: str) -> None:
    """`path` is, or can be made, a directory this process writes (checked before Hydra creates it):
    ConfigError where the path is wrong (a file on the way), PermissionError (exit 3) where the system
    refuses.  Where the path does not exist yet, a directory is made and removed again where it would
    begin: permission bits alone do not answer for root, a read-only mount or /proc."""
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{what}={path} is an existing file, not a directory")
    chain = [path, *path.absolute().parents]
    existing = next(p for p in chain if p.exists())
    if not existing.is_dir():
        raise ConfigError(f"{what}={path} lies below {existing}, which is a file, not a directory")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise PermissionError(f"{what}={path} cannot be written: {existing} is not writable by this user")
    if existing != path:
        try:  # a directory of a unique name where the run's would begin (MPI ranks check at once), removed again
            os.rmdir(tempfile.mkdtemp(prefix=".nma-check-", dir=existing))
        except OSError as err:
            raise PermissionError(f"{what}={path} cannot be created: {err.strerror or err}") from None


def _remove_if_empty(run_dir: Path | None) -> None:
    """A run directory holding only what Hydra wrote on start (.hydra/, the job's log) and its lock goes
    again."""
    if run_dir is None or not run_dir.is_dir():
        return
    if (run_dir / RUN_LOCK).exists() and run_dir.resolve() not in _held:  # another process's directory
        return
    if all(p.name in (".hydra", RUN_LOCK) or p.suffix == ".log" for p in run_dir.iterdir()):
        shutil.rmtree(run_dir, ignore_errors=True)


RUN_LOCK = ".lock"  # in a run directory: held by the process that writes there
_held: dict[Path, object] = {}  # the run directories this process holds, their lock files open until it ends


def hold_run_dir(run_dir: Path, what: str = "hydra.run.dir") -> None:
    """One process writes a run directory: an exclusive lock on its RUN_LOCK file, held until this
    process ends (an operating-system lock: a killed run leaves none behind).  A directory another
    process holds is refused, naming that process."""
    import fcntl

    run_dir = Path(run_dir).resolve()
    if run_dir in _held:
        return
    run_dir.mkdir(parents=True, exist_ok=True)
    lock = open(run_dir / RUN_LOCK, "a+")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.seek(0)
        holder = lock.read().strip() or "another process"
        lock.close()
        raise ConfigError(f"{what}={run_dir} is in use by {holder}: two runs writing one directory would mix "
                          f"their checkpoints, metrics and logs; wait for it to end, or give this run another "
                          f"directory") from None
    lock.seek(0)
    lock.truncate()
    lock.write(f"process {os.getpid()} on {socket.gethostname()} (since {time.strftime('%Y-%m-%d %H:%M:%S')})\n")
    lock.flush()
    _held[run_dir] = lock


def holder_of(run_dir: Path) -> str | None:
    """Which other process holds `run_dir` (hold_run_dir) now, or None."""
    import fcntl

    path = Path(run_dir).resolve() / RUN_LOCK
    if path.parent in _held or not path.is_file():
        return None
    with open(path) as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return lock.read().strip() or "another process"
    return None


def _os_error(err: OSError) -> str:
    where = f": {err.filename}" if err.filename else ""
    return f"{err.strerror or err}{where}" if err.strerror else str(err)


@contextmanager
def exit_codes(rank: int = 0, run_dir: Path | None = None):
    """Inside a command's task function: each outcome a user can act on as one line and its exit code
    (the module's table); on bad input, `run_dir` is removed if the command left nothing in it.  The
    SystemExit carries the line too (`.message`), for a sweep that records its failed jobs."""
    try:
        yield
    except ConfigError as err:
        if rank == 0:
            _remove_if_empty(run_dir)
        _exit(str(err), BAD_INPUT, rank)
    except (SolverError, TrainingError) as err:
        _exit(str(err), FAILED, rank)
    except Stopped as err:
        _exit(str(err), 128 + err.signum, rank)
    except KeyboardInterrupt:
        _exit("interrupted (Ctrl-C)", 128 + signal.SIGINT, rank)
    except OSError as err:
        _exit(_os_error(err), SYSTEM, rank)
    except MemoryError:  # an operating-system limit the memory estimate did not foresee
        _exit("out of memory: ask for a coarser fidelity (fidelity.ctrl_per_patch, fidelity.quad_points), a "
              "smaller batch, or a machine with more memory", SYSTEM, rank)
    except Exception as err:  # Ctrl-C inside a host callback reaches here wrapped in JAX's runtime error
        if "KeyboardInterrupt" not in str(err):
            raise
        _exit("interrupted (Ctrl-C)", 128 + signal.SIGINT, rank)


def _exit(message: str, code: int, rank: int):
    say(message, rank)
    if code > 128 and threading.current_thread() is threading.main_thread():
        # stopped: another Ctrl-C while the interpreter shuts down ends it at once, without atexit's traceback
        signal.signal(signal.SIGINT, lambda *_: os._exit(code))
    stop = SystemExit(code)
    stop.message = message
    raise stop from None


def unused_path(path: Path) -> Path:
    """`path`, or where a file of that name exists already, the first free `<stem>_<n><suffix>` beside
    it: a command's result never replaces an earlier one."""
    base = candidate = Path(path)
    n = 1
    while candidate.exists():
        n += 1
        candidate = base.with_name(f"{base.stem}_{n}{base.suffix}")
    return candidate


def json_safe(value):
    """Non-finite floats as null (JSON has no NaN or Infinity)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value
