"""What every command shares: config checks before any work, and exit codes a script can rely on.

    0  success
    2  bad input (config or data), reported before any work where it can be, as one line naming
       the field; a run directory the command created for nothing is removed again
    1  a solve or a training step that failed for a stated reason
    3  the operating system refused (a directory that cannot be written, a disk that is full, ...)
    130, 143  stopped by Ctrl-C or SIGTERM (128 + the signal): training saves a checkpoint first
    anything unexpected keeps its traceback (Hydra prints it) and is never reported as bad input

`preflight` composes the command line's config exactly as Hydra will (every job of a --multirun
sweep, saying how far it got where that takes a while), checks it against the schema, and exits 2
on the first error, before Hydra creates a run directory.  Under MPI every rank checks and exits,
and rank 0 alone prints.

By job: exits.py (the exit codes and the one line each outcome is said in), compose.py (a job's
config composed as Hydra composes it; a composition error in a line), preflight.py (every job
checked before any work), rundirs.py (one process per run directory; a directory checked
writable), output.py (a result's file and its JSON).
"""

from __future__ import annotations

from ..sweep import job_overrides  # the jobs a sweep launches
from .compose import compose, without_hydra
from .exits import BAD_INPUT, FAILED, SYSTEM, exit_codes, say
from .output import json_safe, unused_path
from .preflight import preflight
from .rundirs import RUN_LOCK, hold_run_dir, holder_of, job_dir, writable_dir

__all__ = [
    "BAD_INPUT",
    "FAILED",
    "SYSTEM",
    "RUN_LOCK",
    "compose",
    "exit_codes",
    "hold_run_dir",
    "holder_of",
    "job_dir",
    "job_overrides",
    "json_safe",
    "preflight",
    "say",
    "unused_path",
    "without_hydra",
    "writable_dir",
]
