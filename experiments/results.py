"""Results as generated artefacts: each reproduction writes results/<name>/ (report.md, result.json
and its figures), stamped with the commit, date, machine and command that produced it, and the
README's results table is generated from them.

    # rewrites README.md's results table from results/*/result.json
    python experiments/results.py
    python experiments/results.py --check    # exits 1 where README.md's table differs

tests/test_docs.py checks that the README's table is what this script writes from results/.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "results"
README = ROOT / "README.md"
BEGIN, END = (
    "<!-- results table: python experiments/results.py -->",
    "<!-- end of results table -->",
)
ROWS = [  # (results/<name>, the README's label)
    ("translation", "translation"),
    ("rotation_single", "rotation, single"),
    ("rotation_double", "rotation, double"),
    ("shape_matching", "pore shape matching"),
    ("digital_mnist", "digital MNIST"),
    ("dynamic_follow", "in time: a circle followed"),
    ("dynamic_energy", "in time: an impulse focused"),
    ("periodic_poisson", "periodic: Poisson's ratio -0.5"),
    ("periodic_poisson_amortised", "periodic: Poisson's ratio, held out"),
]


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def stamp(command: list[str], wall_seconds: float) -> dict:
    """Who made a result: the commit (with -dirty where the tree had changes), the date (UTC), the
    machine and the command, and how long it took."""

    def git(*args):
        return subprocess.run(
            ["git", *args], cwd=ROOT, capture_output=True, text=True
        ).stdout.strip()

    commit = git("rev-parse", "HEAD") or "unknown"
    if git("status", "--porcelain", "--untracked-files=no"):
        commit += "-dirty"
    return {
        "commit": commit,
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": {"cpu": cpu_model(), "cores": os.cpu_count(), "system": platform.platform()},
        "command": relative(" ".join(command)),
        "wall_seconds": round(wall_seconds, 1),
    }


def relative(value):
    """`value` (a string, or lists and mappings of them) with every path inside the repository
    written relative to it, also inside a command line: a result names its runs the same on every
    machine."""
    if isinstance(value, dict):
        return {k: relative(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [relative(v) for v in value]
    if isinstance(value, str):
        return "." if value == str(ROOT) else value.replace(f"{ROOT}/", "")
    return value


def write(name: str, summary: dict, report: str, figures: list[Path], stamped: dict) -> Path:
    """results/<name>/: result.json (the summary and its stamp), report.md (`report` and the stamp)
    and copies of `figures`; paths inside the repository relative to it."""
    summary, report, stamped = relative(summary), relative(report), relative(stamped)
    out = RESULTS / name
    out.mkdir(parents=True, exist_ok=True)
    (out / "result.json").write_text(json.dumps({**summary, "stamp": stamped}, indent=1) + "\n")
    machine = stamped["machine"]
    (out / "report.md").write_text(
        report.rstrip() + "\n\n"
        f"Made by `{stamped['command']}` at commit {stamped['commit']} on {stamped['date']}, "
        f"{machine['cpu']} ({machine['cores']} cores), in {stamped['wall_seconds'] / 60:.1f} min.\n"
    )
    for figure in figures:
        shutil.copyfile(figure, out / figure.name)
    return out


def _row(name: str, label: str) -> str:
    r = json.loads((RESULTS / name / "result.json").read_text())
    minutes = f"{r['stamp']['wall_seconds'] / 60:.1f} min"
    fine = r.get("reevaluated")
    if name == "digital_mnist":
        # nma.evaluate's, where run
        again = f" ({fine['value']:.3f} on {fine['samples']})" if fine else ""
        return (
            f"| {label} | held-out digits shown exactly | "
            f"{r['digit_exact_match']['finetune']:.3f}{again} | | {minutes} |"
        )
    again = ""
    if fine:  # the states a finer model finds not physical are said beside its value
        unphysical = (
            f"; {fine['invalid_states']} of {fine['samples']} not physical"
            if fine["invalid_states"]
            else ""
        )
        again = f" ({fine['value']:#.3g}{unphysical})"
    unit = "deg" if r["unit"].startswith("deg") else "%" if r["unit"].startswith("%") else ""
    value = lambda v: f"{v:#.3g}{' ' + unit if unit else ''}"
    metric = {
        "mean_pointer_error": "mean pointer error (cell = 5)",
        "mean_angle_error_deg": "mean angle error",
        "shape_error": "shape error (mean pore radii)",
        "mean_path_error": "mean path error (cell = 5)",
        "region_energy_share": "kinetic energy in the target region",
        "poisson_error": "abs(Poisson's ratio - target) at 10% compression",
    }.get(r["metric"], r["metric"])
    return (
        f"| {label} | {metric} | {value(r['joint'])}{again} | {value(r['baseline'])} | {minutes} |"
    )


def table() -> str:
    """The README's results table, from results/*/result.json."""
    rows = [_row(name, label) for name, label in ROWS if (RESULTS / name / "result.json").is_file()]
    return "\n".join(
        [
            "| experiment | metric | learned design | geometry frozen | wall time |",
            "|---|---|---|---|---|",
            *rows,
        ]
    )


def readme_with_table(text: str) -> str:
    head, _, rest = text.partition(BEGIN)
    _, _, tail = rest.partition(END)
    if not rest or END not in rest:
        raise SystemExit(f"README.md has no results table between {BEGIN!r} and {END!r}")
    return f"{head}{BEGIN}\n{table()}\n{END}{tail}"


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--check", action="store_true", help="exit 1 where README.md's table is not the results'"
    )
    args = ap.parse_args()
    text = README.read_text()
    new = readme_with_table(text)
    if args.check:
        sys.exit(
            0
            if new == text
            else "README.md's results table is stale: python experiments/results.py"
        )
    README.write_text(new)
    print(table())


if __name__ == "__main__":
    main()
