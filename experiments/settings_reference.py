"""docs/reference/settings.md from the config schema: every setting of every config group, its type, default,
allowed values and meaning (the field's doc, or the comment beside it in the schema's source).

    python experiments/settings_reference.py            # writes docs/reference/settings.md
    python experiments/settings_reference.py --check    # exits 1 where docs/reference/settings.md differs

tests/test_docs.py checks that the page is what this script writes from today's schema.
"""
from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
import sys
import typing
from pathlib import Path

from nma.schema import (ContactConfig, DynamicsConfig, EvaluateConfig, ExportConfig, Fidelity, LoggerConfig, MaterialConfig, PartConfig,
                        ModelConfig, OptimConfig, SceneConfig, SolverConfig, TrainerConfig)
from nma.schema.commands import FitConfig, OutputConfig
from nma.settings import Schema
from nma.tasks.schemas import TASK_SCHEMAS

PAGE = Path(__file__).resolve().parent.parent / "docs" / "reference" / "settings.md"
INTRO = """# Settings

Every setting of every config group: its type, default, allowed values and meaning.  Give any of them on
the command line as `group.setting=value` (`trainer.steps=20`, `material.nu=0.45`); a value outside its
range is refused before any work, naming the setting.  So is a setting given where the rest of the
config leaves it unused (a `contact` setting with contact off, a `dynamics` one with dynamics off,
`part.thickness` without `part.scale`), naming what would make it matter (nma/schema/effect.py).
Generated from the schema (nma/schema/, nma/tasks/schemas.py) by
`python experiments/settings_reference.py`; do not edit by hand.
"""
GROUPS = [  # (heading, prefix, schema): the training run's groups, then the other commands' own
    ("Material", "material", MaterialConfig), ("Part", "part", PartConfig), ("Fidelity", "fidelity", Fidelity),
    ("Contact", "contact", ContactConfig), ("Solver", "solver", SolverConfig),
    ("Dynamics", "dynamics", DynamicsConfig), ("Model", "model", ModelConfig),
    ("Optimiser", "optim", OptimConfig), ("Trainer", "trainer", TrainerConfig), ("Logger", "logger", LoggerConfig),
    ("Scene", "scene", SceneConfig),
    *[(f"Task {name}", "task", schema) for name, schema in sorted(TASK_SCHEMAS.items())],
    ("nma.simulate: output", "output", OutputConfig), ("nma.export", "", ExportConfig),
    ("nma.evaluate", "", EvaluateConfig), ("nma.fit", "", FitConfig),
]


def comments(cls) -> dict[str, str]:
    """The comment beside each field in the source of `cls` and its bases (a field without a doc)."""
    found: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        try:
            source = inspect.getsource(klass)
        except (OSError, TypeError):
            continue
        for name, comment in re.findall(r"^\s{4}(\w+):[^\n#]*#\s*(.+)$", source, flags=re.M):
            found[name] = comment.strip()
    return found


def inherited(cls, name: str) -> str:
    """The doc a base class gives the field `name`, where a subclass redeclares it without one."""
    for base in cls.__mro__[1:]:
        if dataclasses.is_dataclass(base):
            for f in dataclasses.fields(base):
                if f.name == name and f.metadata.get("doc"):
                    return f.metadata["doc"]
    return ""


def type_name(tp) -> str:
    text = str(tp).replace("typing.", "")
    return re.sub(r"<class '(\w+)'>", r"\1", text)


def default_of(f: dataclasses.Field):
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
        return "(see below)" if isinstance(value, Schema) else value
    return "(required)"


def rows(prefix: str, schema: type) -> list[str]:
    hints, notes, out, nested = typing.get_type_hints(schema), comments(schema), [], []
    for f in dataclasses.fields(schema):
        key = f"{prefix}.{f.name}" if prefix else f.name
        tp = hints.get(f.name)
        if isinstance(tp, type) and issubclass(tp, Schema):
            nested.append((key, tp))
            continue
        allowed = (f"[{', '.join('null' if c is None else c for c in f.metadata['choices'])}]" if "choices" in f.metadata
                   else f.metadata.get("range", ""))
        meaning = f.metadata.get("doc") or notes.get(f.name, "") or inherited(schema, f.name)
        cells = [f"`{key}`", type_name(tp), f"`{default_of(f)!r}`".replace("|", "\\|"), allowed.replace("|", "\\|"),
                 meaning.replace("|", "\\|")]
        out.append("| " + " | ".join(cells) + " |")
    for key, tp in nested:
        out.extend(rows(key, tp))
    return out


def page() -> str:
    parts = [INTRO]
    for heading, prefix, schema in GROUPS:
        parts.append(f"## {heading}\n\n| setting | type | default | allowed | meaning |\n|---|---|---|---|---|\n"
                     + "\n".join(rows(prefix, schema)) + "\n")
    return "\n".join(parts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 where docs/reference/settings.md is not what it would write")
    if ap.parse_args().check:
        sys.exit(0 if PAGE.read_text() == page() else 1)
    PAGE.write_text(page())
    print(PAGE)


if __name__ == "__main__":
    main()
