"""How every nma command sets JAX up: float64, a persistent compilation cache, and what XLA needs to
know before it starts (before_jax_starts).

The simulator's kernels (linearisation, step, adjoint pullback) compile once per scene, fidelity and
Newton options, and JAX's persistent cache keeps them across processes: a second run, or each job of
a `--multirun` sweep, loads them instead of compiling.  The cache lives in $NMA_CACHE_DIR (default
~/.cache/nma/jax); NMA_CACHE_DIR=off disables it.  Programs that hold host callbacks (the training
step's thin outer program) are compiled per process; JAX does not cache those.
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

# even the many small programs of setting up a scene load faster than they compile
MIN_COMPILE_SECONDS = 0.0


def cache_dir() -> Path | None:
    value = os.environ.get("NMA_CACHE_DIR", str(Path.home() / ".cache" / "nma" / "jax"))
    return None if value.lower() in ("", "off", "none", "0") else Path(value)


def available_cores() -> int:
    """The cores this process may run on (its affinity: taskset, a SLURM allocation, an MPI
    binding)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


# XLA's CPU client runs programs on a thread pool as large as the cores this process may use.  On
# one core that is one thread, which a training step's program holds while it calls back into the
# host Newton, whose own compiled kernels then wait for a thread forever.  A client with two CPU
# devices keeps a thread for them; every array stays on the first device.
MIN_CPU_DEVICES = 2


def before_jax_starts() -> None:
    """What must be set before JAX starts its backend (the commands call it first thing): room for
    the host Newton's kernels on one core (MIN_CPU_DEVICES), and no INFO line about the TPU that JAX
    probes for and does not find (not news on a CPU or GPU)."""
    logging.getLogger("jax._src.xla_bridge").setLevel(logging.WARNING)
    if available_cores() < MIN_CPU_DEVICES and "JAX_NUM_CPU_DEVICES" not in os.environ:
        os.environ["JAX_NUM_CPU_DEVICES"] = str(MIN_CPU_DEVICES)  # read when jax is imported
        if "jax" in sys.modules:  # imported already: its config takes it until the backend starts
            try:
                sys.modules["jax"].config.update("jax_num_cpu_devices", MIN_CPU_DEVICES)
            except RuntimeError:
                logging.getLogger("nma").warning(
                    "this process may use one core, and JAX started before nma could keep XLA a "
                    "thread for the "
                    "host Newton: a training step may hang.  Call nma.runtime.configure_jax() "
                    "before any JAX "
                    "operation, or set JAX_NUM_CPU_DEVICES=%d",
                    MIN_CPU_DEVICES,
                )


def configure_jax() -> None:
    """What every command sets before any JAX operation (the backend reads some of it once, when
    it starts): float64, the persistent cache, programs run on their caller's thread."""
    import jax

    before_jax_starts()
    jax.config.update("jax_enable_x64", True)
    # Each program runs on the thread that calls it.  With the CPU client's async dispatch, a
    # program whose inputs are still being computed runs later on one of XLA's threads, and its
    # host callback (the host Newton, a periodic response) calls compiled kernels there while
    # the caller goes on with its own: the two can wait on each other for ever.
    jax.config.update("jax_cpu_enable_async_dispatch", False)
    path = cache_dir()
    if path is not None:
        jax.config.update("jax_compilation_cache_dir", str(path))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
