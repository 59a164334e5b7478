"""Canaries: short runs whose numbers are pinned, so that a change that moves a reproduction is seen
without rerunning it (slow: make test-all).

- each reproduction's first stage for a few steps from its fixed seed: the loss of every step and
  the evaluation after them, pinned in tests/canaries.json;
- each task's short run at its own defaults (`python -m nma.run task=<task> trainer.steps=20`, four
  steps in time): it beats the design it starts from (the frozen design's floor where the task has
  one, the rest state otherwise; digital MNIST: digits shown), and its metric is pinned too;
- the README's first run and its 20-step double rotation end where the README says.

Tolerances: the pins were made on one machine; another CPU rounds differently, which moves a
loss after a few steps by about 1e-9 and a 20-step metric by well under a percent (LOSS_RTOL,
METRIC_RTOL). A deliberate change of a pinned number: `python tests/test_canaries.py --pin [name
...]` rewrites tests/canaries.json, and the commit that carries it says why the numbers moved.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PINS = Path(__file__).with_name("canaries.json")
LOSS_RTOL, METRIC_RTOL = 1e-6, 1e-2
FAST_EVAL = ["logger=none", "trainer.progress=false", "trainer.animation_frames=0"]

# name: the overrides of `python -m nma.run`
REPRODUCTIONS = {
    name: [f"experiment=repro_{name}", "trainer.steps=3", "trainer.eval_every=3"]
    for name in (
        "translation",
        "rotation_single",
        "rotation_double",
        "shape_matching",
        "mnist_lookup",
        "dynamic_follow",
        "dynamic_energy",
        "periodic_poisson",
        "periodic_poisson_amortised",
    )
}
TASKS = {
    task: [f"task={task}", "trainer.steps=20"]
    for task in (
        "translation",
        "rotation_single",
        "rotation_double",
        "shape_matching",
        "digital_mnist",
    )
}
# tasks in time name their scene; a training step solves a whole trajectory, so they take fewer
TASKS.update(
    {
        task: [f"task={task}", "scene=translation", "trainer.steps=4"]
        for task in ("follow_path", "energy_focus")
    }
)
TIMED = ("task_follow_path", "task_energy_focus")  # four steps beat rest, not yet the frozen floor
CASES = {
    **{f"repro_{k}": v for k, v in REPRODUCTIONS.items()},
    **{f"task_{k}": v for k, v in TASKS.items()},
}


def run(name: str, run_dir: Path) -> dict:
    """The case's run in this process (the checked config of the command line) -> its numbers."""
    from conftest import train_in_process

    train_in_process(run_dir, *CASES[name], *FAST_EVAL)
    metrics = json.loads((Path(run_dir) / "metrics.json").read_text())
    return {
        "losses": [h["loss"] for h in metrics["history"]],
        "metric": metrics["value"],
        "frozen_floor": metrics.get("frozen_floor"),
        "no_actuation": metrics["no_actuation"],
        "failed": metrics["failed_solves"],
        "invalid_states": metrics.get("invalid_states", 0),
    }


def pins() -> dict:
    return json.loads(PINS.read_text())


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(CASES))
def test_canary(name, tmp_path):
    pinned = pins()[name]
    got = run(name, tmp_path)
    assert got["failed"] == 0 and got["invalid_states"] == 0
    assert got["losses"] == pytest.approx(pinned["losses"], rel=LOSS_RTOL), name
    assert got["metric"] == pytest.approx(pinned["metric"], rel=METRIC_RTOL), name
    if name.startswith("task_"):  # a short run at the task's defaults shows its design at work
        if name == "task_digital_mnist":
            assert got["metric"] > got["no_actuation"]  # digits of the ten shown right
        else:
            start = (
                got["no_actuation"]
                if name in TIMED or got["frozen_floor"] is None
                else got["frozen_floor"]
            )
            better = got["metric"] > start if name == "task_energy_focus" else got["metric"] < start
            assert better, (got["metric"], start)


def readme_quote(pattern: str) -> float:
    match = re.search(pattern, (ROOT / "README.md").read_text())
    assert match, f"README.md no longer quotes {pattern!r}"
    return float(match.group(1))


@pytest.mark.slow
def test_readme_first_run_ends_where_it_says(tmp_path):
    """`make run` (python -m nma.run, every default): the README quotes its final error."""
    from conftest import nma_run

    quoted = readme_quote(r"final mean_pointer_error = ([0-9.]+) length units")
    nma_run(tmp_path, "logger=none", "trainer.progress=false")
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["value"] == pytest.approx(quoted, abs=5e-4)
    assert metrics["failed_solves"] == 0 and metrics["invalid_states"] == 0


@pytest.mark.slow
def test_readme_rotation_double_beats_the_frozen_design(tmp_path):
    """The README's second command: 20 steps of the double rotation at its own settings, against the
    frozen design's floor that the README quotes beside it."""
    from conftest import nma_run

    quoted = readme_quote(r"about ([0-9.]+) deg after 20 steps")
    floor = readme_quote(r"([0-9.]+) for the frozen design")
    nma_run(
        tmp_path,
        "task=rotation_double",
        "trainer.steps=20",
        "logger=none",
        "trainer.progress=false",
    )
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["frozen_floor"] == pytest.approx(floor, abs=0.05)
    assert metrics["value"] == pytest.approx(quoted, abs=0.1) and metrics["value"] < floor / 2


if __name__ == "__main__":  # python tests/test_canaries.py --pin [name ...]
    import tempfile

    sys.path.insert(0, str(Path(__file__).parent))
    import conftest  # noqa: F401  (float64 and the compilation cache, as in the tests)

    if sys.argv[1:2] != ["--pin"]:
        sys.exit(__doc__)
    chosen = sys.argv[2:] or sorted(CASES)
    pinned = pins() if PINS.is_file() else {}
    for name in chosen:
        with tempfile.TemporaryDirectory() as tmp:
            pinned[name] = {
                k: v for k, v in run(name, Path(tmp)).items() if k in ("losses", "metric")
            }
        print(name, pinned[name]["metric"], flush=True)
        PINS.write_text(json.dumps(pinned, indent=1, sort_keys=True) + "\n")
