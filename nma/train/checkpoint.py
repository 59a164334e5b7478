"""Checkpoints written atomically: a crash at any moment leaves the last complete one loadable.

Each checkpoint holds the training state and a fingerprint of the config fields that shape the
parameters and the data (task, scene, model, fidelity, material, optimiser, batch size, seed, ...).
Resuming compares fingerprints, so a run is never continued under a different config by accident.
The two newest checkpoints are kept: a corrupt newest one is reported and the previous one used.
"""

from __future__ import annotations

import json
import logging
import os
import re
from pathlib import Path

from flax import serialization

from ..errors import ConfigError

log = logging.getLogger(__name__)
_NAME = re.compile(r"step_(\d+)\.msgpack$")
KEEP = 2


def path_of(directory: Path, step: int) -> Path:
    return directory / f"step_{step:07d}.msgpack"


def save(directory: Path, step: int, state) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    final = path_of(directory, step)
    tmp = directory / f".step_{step:07d}.msgpack.tmp"
    with open(tmp, "wb") as f:
        f.write(serialization.to_bytes(state))
        f.flush()
        os.fsync(f.fileno())
    # atomic on POSIX: readers see the old set or the new file, never half of it
    os.replace(tmp, final)
    for old in sorted(_complete(directory))[:-KEEP]:
        old[1].unlink(missing_ok=True)
    return final


def _complete(directory: Path):
    return [
        (int(m.group(1)), p)
        for p in directory.glob("step_*.msgpack")
        if (m := _NAME.search(p.name))
    ]


def latest(directory: Path):
    found = sorted(_complete(directory)) if directory.exists() else []
    return found[-1] if found else None


def load_latest(directory: Path, warn: bool = True, what: str = "trainer.resume"):
    """(path, raw state dict) of the newest checkpoint that reads back, or None if there is none.
    Unreadable ones (truncated, empty, not msgpack) are reported by path and passed over; if every
    checkpoint is unreadable that is bad data: ConfigError naming them, and `what` asked for
    them."""
    found = sorted(_complete(directory), reverse=True) if directory.exists() else []
    bad = []
    for _, path in found:
        try:
            raw = serialization.msgpack_restore(path.read_bytes())
            if not isinstance(raw, dict) or "step" not in raw:
                raise ValueError("not a training state")
        except Exception as exc:  # msgpack raises several types for bad bytes
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            bad.append(f"{path} ({reason})")
            if warn:
                log.warning(
                    "checkpoint %s is unreadable (%s); trying the previous one", path, reason
                )
            continue
        return path, raw
    if bad:
        raise ConfigError(f"{what}: no readable checkpoint in {directory}: {'; '.join(bad)}")
    return None


def flatten(tree, prefix=""):
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from flatten(v, f"{prefix}.{k}" if prefix else str(k))
    else:
        yield prefix, tree


# a setting missing from a fingerprint, where nothing says what its absence means
ABSENT = "(unset)"


def differences(old: dict, new: dict, absent: dict | None = None) -> tuple[set[str], list[str]]:
    """The flat keys whose values differ between two flattened fingerprints, a key missing from one
    meaning `absent`'s value for it, and each difference as 'key: old -> new'."""
    absent = absent or {}
    value = lambda d, k: d[k] if k in d else absent.get(k, ABSENT)
    changed = {k for k in old.keys() | new.keys() if value(old, k) != value(new, k)}
    return changed, [f"{k}: {value(old, k)!r} -> {value(new, k)!r}" for k in sorted(changed)]


def recorded(raw: dict, groups) -> dict | None:
    """The flattened fingerprint a checkpoint recorded, of the given groups (None where it records
    none)."""
    if "config" not in raw:
        return None
    return {k: v for k, v in flatten(json.loads(raw["config"])) if k.split(".")[0] in groups}


def check_fingerprint(
    path: Path,
    raw: dict,
    fingerprint: dict,
    absent: dict | None = None,
    generic_optim: dict | None = None,
) -> None:
    """Stop with the differing fields named if the checkpoint was written under another config, a
    setting missing from either fingerprint meaning `absent`'s value for it
    (nma.train.runs.absent_means); `generic_optim`: the generic optimiser's settings, optim=adam,
    named where the run trained with it."""
    if "config" not in raw:
        log.warning("checkpoint %s records no config; resuming without checking it", path)
        return
    old = dict(flatten(json.loads(raw["config"])))
    new = dict(flatten(json.loads(json.dumps(fingerprint))))
    changed, diff = differences(old, new, absent)
    if changed:
        # what the checkpoint trained with
        was = lambda k: old.get(k, (absent or {}).get(k))
        # defaults that changed since runs trained: contact=auto turned contact on for a scene whose
        # runs trained without it, fidelity=scene a discretisation for one whose runs trained at the
        # paper's 5 x 5, Newton's element bound on, the inversion penalty a term of every loss, and
        # each task an optimiser of its own.  Each hint maps to the fields it explains; they are
        # given only where together they explain every change.
        hints = {}
        contact = {k for k in changed if k.startswith("contact.")}
        if contact and not was("contact.enabled"):
            hints["it trained without contact: add contact=off"] = contact
        resolution = changed & {"fidelity.ctrl_per_patch", "fidelity.quad_points"}
        if resolution and all(
            was(k) == 5 for k in ("fidelity.ctrl_per_patch", "fidelity.quad_points")
        ):
            hints["it trained at the paper's 5 x 5: add fidelity=paper"] = resolution
        bound = "solver.element_bound"
        if bound in changed and not was(bound):
            hints["it trained without Newton's element bound: add solver.element_bound=false"] = {
                bound
            }
        penalty = {"trainer.inversion_penalty", "trainer.inversion_margin"}
        if changed & penalty and not was("trainer.inversion_penalty"):
            hints["it trained without the inversion penalty: add trainer.inversion_penalty=0"] = (
                changed & penalty
            )
        optim = {k for k in changed if k.startswith("optim.")}
        if (
            optim
            and generic_optim
            and all(was(k) == v for k, v in flatten({"optim": generic_optim}))
        ):
            hints["it trained with the generic optimiser: add optim=adam"] = optim
        hint = f" ({'; '.join(hints)})" if hints and changed <= set().union(*hints.values()) else ""
        raise ConfigError(
            f"trainer.resume: checkpoint {path} was written with another config ("
            + "; ".join(diff)
            + f"){hint}. Resume with the same settings, start a new run directory, "
            "or set trainer.resume=force to continue anyway"
        )


def restore(raw: dict, template):
    """The raw state dict put into the structure of `template`; shapes must match."""
    import jax
    import numpy as np

    out = serialization.from_state_dict(template, raw)
    for (path, a), b in zip(
        jax.tree_util.tree_flatten_with_path(template)[0], jax.tree_util.tree_leaves(out)
    ):
        if np.shape(a) != np.shape(b):
            raise ValueError(
                f"{jax.tree_util.keystr(path)} has shape {np.shape(b)}, this run needs "
                f"{np.shape(a)}"
            )
    return out
