"""The verification report: each benchmark's section (its module's `section`), then the outcome."""

from __future__ import annotations

import importlib

from . import BENCHMARKS


def module(name: str):
    return importlib.import_module(f"{__package__}.{name}")


def report(r: dict) -> str:
    lines = [
        "# Verification",
        "",
        "nma against references from theory and the literature (`make verify`, "
        "experiments/verify.py, one module a benchmark in experiments/verification/). Each "
        "benchmark's tolerance is its test's, with the reasons given there.",
    ]
    for name in BENCHMARKS:
        if name in r:
            lines += ["", *module(name).section(r[name])]
    lines += ["", "## Outcome", ""]
    lines += (
        [f"- {f}" for f in r["failures"]]
        if r["failures"]
        else ["Every benchmark is within its tolerance."]
    )
    return "\n".join(lines) + "\n"
