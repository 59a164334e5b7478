"""The errors a command turns into an exit status (nma.cli.exit_codes): one line each, no traceback.

    ConfigError    bad input (config or data), found before any work where possible: exit 2
    SolverError    Newton could not reach full load; the message says how far it got: exit 1
    TrainingError  training cannot go on for a stated reason (not a solver failure): exit 1
    Stopped        a run stopped on a signal after checkpointing: exit 128 + the signal

This module imports nothing, so every layer can raise these without importing another's machinery.
"""

from __future__ import annotations


class ConfigError(ValueError):
    """Bad input (config or data): the message names the field, the value and what is allowed."""


class SolverError(RuntimeError):
    """Newton could not reach full load: the message says how far it got and why; `info` holds the
    solver's statistics of the failed solve (a NewtonInfo of one sample) where there is one."""

    def __init__(self, message: str, info=None):
        super().__init__(message)
        self.info = info


class TrainingError(RuntimeError):
    """Training cannot go on for a stated reason (not a solver failure)."""


class Stopped(RuntimeError):
    """A run stopped on a signal (SIGTERM before a scheduler's time limit, Ctrl-C) after
    checkpointing: exit status 128 + the signal's number."""

    def __init__(self, message: str, signum: int):
        super().__init__(message)
        self.signum = signum
