"""How every nma command sets JAX up: float64, and a persistent compilation cache.

The simulator's kernels (linearisation, step, adjoint pullback) compile once per scene, fidelity and
Newton options, and JAX's persistent cache keeps them across processes: a second run, or each job of a
`--multirun` sweep, loads them instead of compiling.  The cache lives in $NMA_CACHE_DIR (default
~/.cache/nma/jax); NMA_CACHE_DIR=off disables it.  Programs that hold host callbacks (the training
step's thin outer program) are compiled per process; JAX does not cache those.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

MIN_COMPILE_SECONDS = 0.0  # even the ~100 small programs of setting up a scene (20 ms each) load faster


def cache_dir() -> Path | None:
    value = os.environ.get("NMA_CACHE_DIR", str(Path.home() / ".cache" / "nma" / "jax"))
    return None if value.lower() in ("", "off", "none", "0") else Path(value)


def configure_jax() -> None:
    import jax

    # JAX probes for a TPU and logs its absence at INFO on every start: not news on a CPU or GPU
    logging.getLogger("jax._src.xla_bridge").setLevel(logging.WARNING)
    jax.config.update("jax_enable_x64", True)
    path = cache_dir()
    if path is not None:
        jax.config.update("jax_compilation_cache_dir", str(path))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
