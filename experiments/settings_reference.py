"""docs/reference/settings.md from the config schema: every setting of every config group, its
type, default, allowed values and meaning (the field's doc, or the comment beside it in the
schema's source), and every material law's parameters from the law's declaration
(nma/mechanics/laws/); and each law's material file, conf/material/<law>.yaml, its declared
defaults (what `material=<law>` picks).

    python experiments/settings_reference.py            # writes the page and the laws' files
    python experiments/settings_reference.py --check    # exits 1 where one of them differs

tests/test_docs.py checks that the page is what this script writes from today's schema, and
tests/test_law_modules.py that the laws' files are.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
import sys
import typing
from pathlib import Path

import yaml

from nma.schema import (
    ContactConfig,
    DynamicsConfig,
    EvaluateConfig,
    ExportConfig,
    Fidelity,
    LoggerConfig,
    MaterialConfig,
    PartConfig,
    ModelConfig,
    OptimConfig,
    SceneConfig,
    SolverConfig,
    TrainerConfig,
)
from nma.mechanics.laws import builtin, law_names, law_of
from nma.schema.commands import FitConfig, OutputConfig
from nma.schema.periodic import LoadConfig, PeriodicSceneConfig
from nma.settings import Schema
from nma.tasks.schemas import TASK_SCHEMAS

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "reference" / "settings.md"
MATERIALS = ROOT / "conf" / "material"
WRITTEN = "# Written by `make settings-reference` from the law's declaration: do not edit."
LAWS = """## Material laws

`material.law` picks one; its parameters are `material.parameters.<name>` (Neo-Hookean's E:
`material.E`), and where none is given, its defaults, which `material=<law>`
(conf/material/<law>.yaml) holds too.  Each law is one module of nma/mechanics/laws/, which declares
these.  psi is its strain energy of the 3D deformation, which the model takes in plane strain, and
mu0 its initial shear modulus (the compressible form:
[The model](../explanation/model.md#material-hyperelastic-laws-in-plane-strain)).
"""
INTRO = """# Settings

Every setting of every config group: its type, default, allowed values and meaning.  Give any of
them on the command line as `group.setting=value` (`trainer.steps=20`, `material.nu=0.45`); a value
outside its range is refused before any work, naming the setting.  So is a setting given where the
rest of the config leaves it unused (a `contact` setting with contact off, a `dynamics` one with
dynamics off, `part.thickness` without `part.scale`), naming what would make it matter
(nma/schema/effect.py).  Generated from the schema (nma/schema/, nma/tasks/schemas.py) by
`python experiments/settings_reference.py`; do not edit by hand.
"""
GROUPS = [  # (heading, prefix, schema): the training run's groups, then the other commands' own
    ("Material", "material", MaterialConfig),
    ("Part", "part", PartConfig),
    ("Fidelity", "fidelity", Fidelity),
    ("Contact", "contact", ContactConfig),
    ("Solver", "solver", SolverConfig),
    ("Dynamics", "dynamics", DynamicsConfig),
    ("Model", "model", ModelConfig),
    ("Optimiser", "optim", OptimConfig),
    ("Trainer", "trainer", TrainerConfig),
    ("Logger", "logger", LoggerConfig),
    ("Scene", "scene", SceneConfig),
    *[(f"Task {name}", "task", schema) for name, schema in sorted(TASK_SCHEMAS.items())],
    ("Periodic scene: its own settings besides the scene's", "scene", PeriodicSceneConfig),
    ("nma.simulate: output", "output", OutputConfig),
    ("nma.simulate: load, of a periodic scene", "load", LoadConfig),
    ("nma.export", "", ExportConfig),
    ("nma.evaluate", "", EvaluateConfig),
    ("nma.fit", "", FitConfig),
]


def comments(cls) -> dict[str, str]:
    """The comment beside each field in the source of `cls` and its bases (a field without a
    doc)."""
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
    """A row per field of `schema`; a subclass of another listed schema, its own fields only."""
    hints, notes, out, nested = typing.get_type_hints(schema), comments(schema), [], []
    listed = {g[2] for g in GROUPS if g[2] is not schema}
    base = next((b for b in schema.__mro__[1:] if b in listed), None)
    known = {f.name for f in dataclasses.fields(base)} if base else set()
    for f in (f for f in dataclasses.fields(schema) if f.name not in known):
        key = f"{prefix}.{f.name}" if prefix else f.name
        tp = hints.get(f.name)
        if isinstance(tp, type) and issubclass(tp, Schema):
            nested.append((key, tp))
            continue
        allowed = (
            f"[{', '.join('null' if c is None else c for c in f.metadata['choices'])}]"
            if "choices" in f.metadata
            else f.metadata.get("range", "")
        )
        meaning = f.metadata.get("doc") or notes.get(f.name, "") or inherited(schema, f.name)
        cells = [
            f"`{key}`",
            type_name(tp),
            f"`{default_of(f)!r}`".replace("|", "\\|"),
            allowed.replace("|", "\\|"),
            meaning.replace("|", "\\|"),
        ]
        out.append("| " + " | ".join(cells) + " |")
    for key, tp in nested:
        out.extend(rows(key, tp))
    return out


def key(name: str) -> str:
    """The setting a law's parameter is given as: a field of the material's schema (E), else
    material.parameters.<name>."""
    own = {f.name for f in dataclasses.fields(MaterialConfig)}
    return f"material.{name}" if name in own else f"material.parameters.{name}"


def laws() -> str:
    """The Material laws section: each law's psi and its parameters, from its declaration."""
    parts = [LAWS]
    for name in filter(builtin, law_names()):
        law = law_of(name)
        table = ["| setting | default | allowed | unit | meaning |", "|---|---|---|---|---|"]
        for p in type(law).parameters:
            default = "(optional)" if p.default is None else f"`{p.default!r}`"
            table.append(
                f"| `{key(p.name)}` | {default} | {p.range} | "
                f"{'stress' if p.stress else 'none'} | {p.doc} |"
            )
        about = " ".join(type(law).__doc__.split())
        parts.append(f"### {name}\n\n{about}\n\n" + "\n".join(table) + "\n")
    return "\n".join(parts)


def page() -> str:
    parts = [INTRO]
    for heading, prefix, schema in GROUPS:
        parts.append(
            f"## {heading}\n\n| setting | type | default | allowed | meaning |\n"
            "|---|---|---|---|---|\n" + "\n".join(rows(prefix, schema)) + "\n"
        )
        if schema is MaterialConfig:
            parts.append(laws())
    return "\n".join(parts)


def material_file(name: str) -> str:
    """conf/material/<name>.yaml: law `name` with its declared defaults and the default nu."""
    law, cfg, paper = law_of(name), MaterialConfig.of_law(name), MaterialConfig()
    mu0, paper_mu0 = (
        float(law_of(c.law).shear_modulus({**c.values, "nu": c.nu})) for c in (cfg, paper)
    )
    head = [
        f"Law {name} ({type(law).__module__.replace('.', '/')}.py), its declared defaults:",
        *(line.strip() for line in type(law).__doc__.splitlines()),
        f"Initial shear modulus {mu0:.4g} in the scene's units (the paper's material: "
        f"{paper_mu0:.4g}).",
        "Its settings, to set yours: docs/reference/settings.md (Material laws).",
    ]
    body = {"law": name, "E": cfg.E, "nu": cfg.nu, "parameters": cfg.parameters}
    if cfg.stretches != paper.stretches:  # a law not stable over the default range
        body["stretches"] = cfg.stretches
    return (
        "\n".join([*(f"# {line}" for line in head), WRITTEN])
        + "\n"
        + yaml.safe_dump(body, sort_keys=False, default_flow_style=None)
    )


def material_files() -> dict[Path, str]:
    """Each law's material file, and None for a file written here before whose law is gone."""
    files = {
        MATERIALS / f"{name}.yaml": material_file(name) for name in law_names() if builtin(name)
    }
    stale = {
        p: None for p in MATERIALS.glob("*.yaml") if p not in files and WRITTEN in p.read_text()
    }
    return {**files, **stale}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--check",
        action="store_true",
        help="exit 1 where docs/reference/settings.md or a law's file is not what it would write",
    )
    written = {PAGE: page(), **material_files()}
    if ap.parse_args().check:
        fresh = all(path.exists() and path.read_text() == text for path, text in written.items())
        sys.exit(0 if fresh else 1)
    for path, text in written.items():
        if text is None:
            path.unlink()
        else:
            path.write_text(text)
        print(path)


if __name__ == "__main__":
    main()
