"""Results a reader can move and read (experiments/results.py, experiments/repro.py):
repository-relative paths in results/, and the figure of the path a follow_path design traces
against its target."""

import json
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "experiments"))
import results  # noqa: E402

from experiments.verification import BENCHMARKS  # noqa: E402


def test_paths_inside_the_repository_are_written_relative_to_it():
    summary = {
        "runs": {"joint": str(ROOT / "outputs" / "repro" / "x" / "joint")},
        "n": 3,
        "files": [str(ROOT / "a.png"), "/elsewhere/b.png"],
        "command": f"python experiments/repro.py x --out {ROOT / 'outputs' / 'v'} s=2",
    }
    assert results.relative(summary) == {
        "runs": {"joint": "outputs/repro/x/joint"},
        "n": 3,
        "files": ["a.png", "/elsewhere/b.png"],
        "command": "python experiments/repro.py x --out outputs/v s=2",
    }
    assert results.relative(str(ROOT)) == "."


def strings(value):
    if isinstance(value, dict):
        for v in value.values():
            yield from strings(v)
    elif isinstance(value, list):
        for v in value:
            yield from strings(v)
    elif isinstance(value, str):
        yield value


@pytest.mark.parametrize(
    "result", sorted((ROOT / "results").glob("*/result.json")), ids=lambda p: p.parent.name
)
def test_no_result_names_a_path_of_the_machine_that_made_it(result):
    """results/*/: the runs, files and commands named relative to the repository, never absolute."""
    body = json.loads(result.read_text())
    absolute = [s for s in strings(body) if s.startswith("/") or " /" in s]
    assert absolute == [], absolute
    report = (result.parent / "report.md").read_text()
    assert str(ROOT) not in report and "/work/" not in report and "/home/" not in report


def fake_follow_run(run: Path, reached_offset: float) -> np.ndarray:
    """A follow_path run's saved config and fields, as nma.run writes them (nma.train.artefacts):
    two evaluation samples, the point over a window of 3 of 5 time steps 0.5 apart, a period of 4
    steps."""
    (run / ".hydra").mkdir(parents=True)
    (run / "fields").mkdir()
    OmegaConf.save(
        {
            "task": {"window": [2, 4], "period_steps": 4, "point": "pointer"},
            "scene": {"tracked": {"pointer": [10.0, 5.0]}},
        },
        run / ".hydra" / "config.yaml",
    )
    with h5py.File(run / "fields" / "trajectories.h5", "w") as f:
        f["times"] = 0.5 * np.arange(5)
    # a quarter turn a step: at the window's steps 2, 3, 4 the angle is phi + pi, + 3 pi / 2, + 2 pi
    r, phi = 1.0, 0.0
    target = np.array([[10.0 - 2.0, 5.0], [10.0 - 1.0, 5.0 - 1.0], [10.0, 5.0]])
    for i in range(2):
        with h5py.File(run / "fields" / f"eval_{i:03d}.h5", "w") as f:
            f.attrs["descriptor"] = np.array([r, phi])
            f.attrs["observed"] = target + [reached_offset, 0.0]
    return target


def test_a_follow_path_result_shows_each_traced_path_against_its_target(tmp_path):
    from experiments.repro import figure_paths_side_by_side, follow_paths

    target = fake_follow_run(tmp_path / "joint", 0.0)
    fake_follow_run(tmp_path / "baseline", 0.25)
    joint, frozen = follow_paths(tmp_path / "joint"), follow_paths(tmp_path / "baseline")
    np.testing.assert_allclose(joint[0]["target"], target, atol=1e-12)
    assert [p["error"] for p in joint] == pytest.approx([0.0, 0.0], abs=1e-12)
    assert [p["error"] for p in frozen] == pytest.approx([0.25, 0.25])
    figure = figure_paths_side_by_side(tmp_path)
    assert figure == tmp_path / "paths.png" and figure.stat().st_size > 10_000


def test_the_verification_report_records_every_benchmark_within_tolerance():
    """results/verification/ (make verify, experiments/verify.py): every benchmark passed."""
    body = json.loads((ROOT / "results" / "verification" / "result.json").read_text())
    assert body["passed"] and body["failures"] == [], body["failures"]
    assert set(BENCHMARKS) <= set(body)
    assert (ROOT / "results" / "verification" / "report.md").is_file()
