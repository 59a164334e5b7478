"""A command's outcome as one line and an exit code a script can rely on (the table in nma.cli)."""

from __future__ import annotations

import os
import signal
import sys
import threading
from contextlib import contextmanager
from pathlib import Path

from ..errors import ConfigError, SolverError, Stopped, TrainingError
from .rundirs import remove_if_empty

BAD_INPUT, FAILED, SYSTEM = 2, 1, 3


def say(message: str, rank: int = 0) -> None:
    if rank == 0:
        print(f"error: {message}", file=sys.stderr, flush=True)


def os_error(err: OSError) -> str:
    """What the operating system refused, in a line, naming the file where it says which."""
    where = f": {err.filename}" if err.filename else ""
    return f"{err.strerror or err}{where}" if err.strerror else str(err)


@contextmanager
def exit_codes(rank: int = 0, run_dir: Path | None = None):
    """Inside a command's task function: each outcome a user can act on as one line and its exit
    code (nma.cli's table); on bad input, `run_dir` is removed if the command left nothing in it.
    The SystemExit carries the line too (`.message`), for a sweep that records its failed jobs."""
    try:
        yield
    except ConfigError as err:
        if rank == 0:
            remove_if_empty(run_dir)
        _exit(str(err), BAD_INPUT, rank)
    except (SolverError, TrainingError) as err:
        _exit(str(err), FAILED, rank)
    except Stopped as err:
        _exit(str(err), 128 + err.signum, rank)
    except KeyboardInterrupt:
        _exit("interrupted (Ctrl-C)", 128 + signal.SIGINT, rank)
    except OSError as err:
        _exit(os_error(err), SYSTEM, rank)
    except MemoryError:  # an operating-system limit the memory estimate did not foresee
        _exit(
            "out of memory: ask for a coarser fidelity (fidelity.ctrl_per_patch, "
            "fidelity.quad_points), a smaller batch, or a machine with more memory",
            SYSTEM,
            rank,
        )
    except Exception as err:  # Ctrl-C inside a host callback reaches here wrapped in JAX's error
        if "KeyboardInterrupt" not in str(err):
            raise
        _exit("interrupted (Ctrl-C)", 128 + signal.SIGINT, rank)


def _exit(message: str, code: int, rank: int):
    say(message, rank)
    if code > 128 and threading.current_thread() is threading.main_thread():
        # stopped: another Ctrl-C while the interpreter shuts down ends it at once, without
        # atexit's traceback
        signal.signal(signal.SIGINT, lambda *_: os._exit(code))
    stop = SystemExit(code)
    stop.message = message
    raise stop from None
