"""Clusters: MPI data parallelism matches one process; --multirun sweeps through submitit; the SLURM
preset; the whole paper in lanes side by side (experiments/repro_all.py)."""

import json
import subprocess
import sys

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from conftest import FAST, MPIEXEC, _flatten, assert_same_params, final_params, nma_run
from nma import config


def test_mpi_two_ranks_match_single_process(tmp_path, translation_run):
    """Two ranks, each bound to a core of its own (as a cluster binds them), train what one process
    does."""
    nma_run(tmp_path, "task=translation", "logger=none", *FAST, mpi=2)
    assert not list(tmp_path.parent.glob(f"{tmp_path.name}_*"))  # one run directory
    assert (tmp_path / "metrics.json").exists()
    assert_same_params(final_params(tmp_path), final_params(translation_run), rtol=1e-9)


# an end-to-end MPI run; test_mpi_two_ranks_match_single_process covers MPI in the fast suite
@pytest.mark.slow
def test_mpi_rotation_experiment_lands_in_its_task_directory(tmp_path):
    cmd = [
        MPIEXEC,
        "-n",
        "2",
        sys.executable,
        "-m",
        "nma.run",
        "experiment=repro_rotation_double",
        "trainer.steps=1",
        "trainer.batch_size=2",
        "trainer.eval_every=1",
        "task.eval_angles=2",
        "trainer.progress=false",
        "trainer.animation_frames=0",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = list((tmp_path / "outputs" / "runs").glob("*/*"))
    assert [r.parent.name for r in runs] == ["rotation_double"] and (
        runs[0] / "metrics.json"
    ).exists()


@pytest.mark.slow  # the SLURM preset's composition and the sweep checks are fast tests
def test_multirun_sweeps_seeds_through_submitit_and_summarises(tmp_path):
    """A 2-job sweep through hydra-submitit-launcher's local executor (the SLURM launcher's twin:
    each job a separate process), then the sweep summary of every job's overrides and final
    metric."""
    cmd = [
        sys.executable,
        "-m",
        "nma.run",
        "--multirun",
        "hydra/launcher=submitit_local",
        "trainer.seed=0,1",
        f"hydra.sweep.dir={tmp_path}",
        "task=translation",
        "logger=none",
        "trainer.steps=1",
        "trainer.batch_size=1",
        "trainer.eval_every=1",
        "trainer.progress=false",
        "trainer.animation_frames=0",
        "task.eval_grid=1",
        "fidelity=fast",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = sorted(tmp_path.glob("*/metrics.json"))
    assert len(runs) == 2 and list((tmp_path / ".submitit").iterdir())
    a, b = (final_params(r.parent)["net"] for r in runs)
    assert not np.allclose(
        dict(_flatten(a))["/params/Dense_0/kernel"], dict(_flatten(b))["/params/Dense_0/kernel"]
    )
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [j["job"] for j in summary["jobs"]] == ["0", "1"]
    for job, run in zip(summary["jobs"], runs):
        assert f"trainer.seed={job['job']}" in job["overrides"]
        assert (
            job["value"] == json.loads(run.read_text())["value"]
            and job["metric"] == "mean_pointer_error"
        )
    assert "trainer.seed=1" in (tmp_path / "summary.md").read_text()


def test_slurm_launcher_preset_composes():
    from nma.schema import register

    # the schemas in Hydra's ConfigStore, as every command does on import (not only other tests)
    register()
    with initialize_config_dir(config_dir=str(config.CONF_DIR), version_base="1.3"):
        cfg = compose(
            config_name="config",
            overrides=["hydra/launcher=slurm", "hydra.launcher.partition=cpu"],
            return_hydra_config=True,
        )
    assert cfg.hydra.launcher._target_.endswith("SlurmLauncher")
    assert cfg.hydra.launcher.cpus_per_task == 2 and cfg.hydra.launcher.partition == "cpu"


def test_the_whole_paper_runs_every_reproduction_once_in_lanes():
    """experiments/repro_all.py (make repro-all): every Makefile repro-* target exactly once in each
    lane layout, each passing the lane's overrides on (REPRO_ARGS) to experiments/repro.py (the
    periodic ones to experiments/periodic_repro.py)."""
    import re
    from pathlib import Path

    from experiments import repro_all

    makefile = (Path(__file__).resolve().parent.parent / "Makefile").read_text()
    targets = dict(re.findall(r"^repro-([a-z-]+):.*\n\t(.*)", makefile, re.M))
    assert targets.pop("all") == "$(PYTHON) experiments/repro_all.py"
    assert targets.pop("check") == "$(PYTHON) experiments/guard.py"  # not a reproduction
    assert all(
        recipe.startswith(
            ("$(PYTHON) experiments/repro.py ", "$(PYTHON) experiments/periodic_repro")
        )
        and recipe.endswith(" $(REPRO_ARGS)")
        for recipe in targets.values()
    )
    for lanes in repro_all.LANES.values():
        assert sorted(name.replace("_", "-") for lane in lanes for name in lane) == sorted(targets)


def test_a_reduced_record_keeps_its_names_and_shapes():
    """World.allreduce_record: one Allreduce of a named record; each field comes back by name, in
    its shape (the MPI sum itself: test_mpi_two_ranks_match_single_process)."""
    from nma.train.mpi import World

    record = {"grads": np.arange(6.0).reshape(2, 3), "loss": 1.5, "converged": np.int64(3)}
    total = World().allreduce_record(record)
    assert list(total) == ["grads", "loss", "converged"]
    np.testing.assert_array_equal(total["grads"], record["grads"])
    assert (
        total["loss"].shape == ()
        and float(total["loss"]) == 1.5
        and float(total["converged"]) == 3.0
    )


def test_a_failed_sweep_job_is_recorded_and_the_sweep_goes_on(tmp_path):
    """Each job of a 2-job sweep fails (another process writes its directory): each failure is
    recorded in the job's failed.json and the summary, the second job still runs after the first
    failed, and the command exits 1 saying which jobs failed."""
    from conftest import HeldElsewhere

    sweep = tmp_path / "sweep"
    with HeldElsewhere(sweep / "0", sweep / "1"):
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "nma.run",
                "--multirun",
                "trainer.seed=0,1",
                f"hydra.sweep.dir={sweep}",
                "task=translation",
                "logger=none",
            ],
            capture_output=True,
            text=True,
            timeout=300,
        )
    assert (
        proc.returncode == 1
        and "2 of the sweep's 2 jobs failed (job 0, 1): each job's failed.json" in proc.stderr
    ), proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    for job in ("0", "1"):
        failed = json.loads((sweep / job / "failed.json").read_text())
        assert (
            failed["exit_code"] == 2 and "is in use by process 4242 on elsewhere" in failed["error"]
        )
    summary = (sweep / "summary.md").read_text()
    assert (
        summary.count("failed (exit 2): this job's directory=") == 2
        and "| failed solves |" in summary
    )
