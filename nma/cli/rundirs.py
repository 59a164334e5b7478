"""Run directories: one process writes each (a lock it holds until it ends), checked writable
before Hydra creates them, and removed again where a command left nothing in them."""

from __future__ import annotations

import os
import shutil
import socket
import tempfile
import time
from pathlib import Path

from ..errors import ConfigError

RUN_LOCK = ".lock"  # in a run directory: held by the process that writes there
_held: dict[Path, object] = {}  # the run directories this process holds, their lock files open


def job_dir(hydra_cfg, multirun: bool) -> Path:
    """The directory a job writes: a sweep's job its subdirectory of the sweep directory, else
    hydra.run.dir."""
    if multirun:
        return Path(hydra_cfg.sweep.dir) / str(hydra_cfg.sweep.subdir)
    return Path(hydra_cfg.run.dir)


def writable_dir(path: Path, what: str) -> None:
    """`path` is, or can be made, a directory this process writes (checked before Hydra creates
    it): ConfigError where the path is wrong (a file on the way), PermissionError (exit 3) where
    the system refuses.  Where the path does not exist yet, a directory is made and removed again
    where it would begin: permission bits alone do not answer for root, a read-only mount or
    /proc."""
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{what}={path} is an existing file, not a directory")
    chain = [path, *path.absolute().parents]
    existing = next(p for p in chain if p.exists())
    if not existing.is_dir():
        raise ConfigError(f"{what}={path} lies below {existing}, which is a file, not a directory")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise PermissionError(
            f"{what}={path} cannot be written: {existing} is not writable by this user"
        )
    if existing != path:
        try:  # a directory of a unique name where the run's would begin (MPI ranks check at once)
            os.rmdir(tempfile.mkdtemp(prefix=".nma-check-", dir=existing))
        except OSError as err:
            raise PermissionError(
                f"{what}={path} cannot be created: {err.strerror or err}"
            ) from None


def remove_if_empty(run_dir: Path | None) -> None:
    """A run directory holding only what Hydra wrote on start (.hydra/, the job's log) and its
    lock goes again."""
    if run_dir is None or not run_dir.is_dir():
        return
    if (run_dir / RUN_LOCK).exists() and run_dir.resolve() not in _held:  # another process's
        return
    if all(p.name in (".hydra", RUN_LOCK) or p.suffix == ".log" for p in run_dir.iterdir()):
        shutil.rmtree(run_dir, ignore_errors=True)


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
        raise ConfigError(
            f"{what}={run_dir} is in use by {holder}: two runs writing one directory "
            f"would mix their checkpoints, metrics and logs; wait for it to end, or "
            f"give this run another directory"
        ) from None
    lock.seek(0)
    lock.truncate()
    since = time.strftime("%Y-%m-%d %H:%M:%S")
    lock.write(f"process {os.getpid()} on {socket.gethostname()} (since {since})\n")
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
