"""Checkpoints written atomically: a crash at any moment leaves the last complete one loadable."""
from __future__ import annotations

import os
import re
from pathlib import Path

from flax import serialization

_NAME = re.compile(r"step_(\d+)\.msgpack$")
KEEP = 2


def save(directory: Path, step: int, state) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    final = directory / f"step_{step:07d}.msgpack"
    tmp = directory / f".step_{step:07d}.msgpack.tmp"
    with open(tmp, "wb") as f:
        f.write(serialization.to_bytes(state))
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, final)  # atomic on POSIX: readers see the old set or the new file, never half of it
    for old in sorted(_complete(directory))[:-KEEP]:
        old[1].unlink(missing_ok=True)
    return final


def _complete(directory: Path):
    return [(int(m.group(1)), p) for p in directory.glob("step_*.msgpack") if (m := _NAME.search(p.name))]


def latest(directory: Path):
    found = sorted(_complete(directory)) if directory.exists() else []
    return found[-1] if found else None


def restore(path: Path, template):
    return serialization.from_bytes(template, Path(path).read_bytes())
