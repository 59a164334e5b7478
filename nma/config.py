"""Where the configs live, and plain (non-Hydra) loading of one config group option."""
from __future__ import annotations

from pathlib import Path

import yaml

CONF_DIR = Path(__file__).resolve().parent.parent / "conf"


def options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


def load(group: str, name: str) -> dict:
    path = CONF_DIR / group / f"{name}.yaml"
    if not path.exists():
        raise ValueError(f"{group}={name!r} is unknown; choose one of {options(group)}")
    return yaml.safe_load(path.read_text())
