"""What a command writes as its result: a file that replaces none, and JSON that is always JSON."""

from __future__ import annotations

import math
from pathlib import Path


def unused_path(path: Path) -> Path:
    """`path`, or where a file of that name exists already, the first free `<stem>_<n><suffix>`
    beside it: a command's result never replaces an earlier one."""
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
