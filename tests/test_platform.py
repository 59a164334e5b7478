"""The experiment platform: configs, the training command, its run directory, MPI and resume."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from flax import serialization
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from nma import config
from nma.schema import register
from nma.train.runs import validate
from nma.errors import ConfigError

FAST = ["trainer.steps=2", "trainer.batch_size=2", "trainer.eval_every=2", "trainer.progress=false",
        "trainer.animation_frames=3", "task.eval_grid=2", "fidelity=fast"]


def compose_cfg(*overrides):
    register()  # the schemas in Hydra's ConfigStore, as every command does on import
    with initialize_config_dir(config_dir=str(config.CONF_DIR), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def nma_run(run_dir, *overrides, mpi=0, timeout=600):
    cmd = [sys.executable, "-m", "nma.run", f"hydra.run.dir={run_dir}", *overrides]
    if mpi:
        cmd = ["mpiexec", "-n", str(mpi), *cmd]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def final_params(run_dir):
    ckpts = sorted((Path(run_dir) / "checkpoints").glob("step_*.msgpack"))
    return serialization.msgpack_restore(ckpts[-1].read_bytes())["params"]


def assert_same_params(a, b, rtol):
    flat_a, flat_b = (dict(_flatten(x)) for x in (a, b))
    assert flat_a.keys() == flat_b.keys()
    for k in flat_a:
        np.testing.assert_allclose(flat_a[k], flat_b[k], rtol=rtol, atol=1e-12, err_msg=k)


def _flatten(tree, prefix=""):
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _flatten(v, f"{prefix}/{k}")
    else:
        yield prefix, np.asarray(tree)


@pytest.mark.parametrize("group", ["task", "solver", "fidelity", "model", "optim", "trainer", "logger", "experiment",
                                   "debug"])
def test_every_config_option_composes_and_validates(group):
    needs = {"repro_mnist_fit": ["task.lookup_run=outputs/repro/digital_mnist/lookup"]}  # a phase's input
    for option in config.options(group):
        cfg = compose_cfg(f"{group}={option}", *needs.get(option, []))
        validate(cfg)
    with pytest.raises(ConfigError, match="task.lookup_run must name the lookup phase's run directory"):
        validate(compose_cfg("experiment=repro_mnist_fit"))


@pytest.mark.parametrize("name", ["rotation_single", "rotation_double"])
def test_refinement_stage_changes_only_fidelity_and_schedule(name):
    """repro_<name>_refine continues the joint run of repro_<name> (experiments/repro.py): the same task,
    scene, material, model and design box, only a finer discretisation and a short, slower schedule."""
    base = OmegaConf.to_container(compose_cfg(f"experiment=repro_{name}"))
    refine = OmegaConf.to_container(compose_cfg(f"experiment=repro_{name}_refine"))
    assert (refine["fidelity"]["ctrl_per_patch"], refine["fidelity"]["quad_points"]) == (8, 2)
    assert (base["fidelity"]["ctrl_per_patch"], base["fidelity"]["quad_points"]) == (5, 2)
    assert refine["trainer"]["steps"] < base["trainer"]["steps"] and refine["optim"]["lr"] < base["optim"]["lr"]
    for cfg in (base, refine):
        cfg.pop("fidelity"), cfg["optim"].pop("lr")
        for key in ("steps", "eval_every", "checkpoint_every"):
            cfg["trainer"].pop(key)
    assert refine == base


@pytest.mark.parametrize("override, message", [
    ("material.nu=0.5", "material.nu must be a finite number in (-1, 0.5), got 0.5"),
    ("scene.radii_bounds=[0.1,1.5]", "scene.radii_bounds must be a list of numbers, each in (0, 1)"),
    ("optim.lr=-0.1", "optim.lr must be a finite number in (0, inf), got -0.1"),
    ("trainer.steps=0", "trainer.steps must be an integer in [1, 10000000], got 0"),
    ("solver.linear=cholesky", "solver.linear must be one of ['auto', 'dense', 'pardiso', 'superlu']"),
    ("optim.lr_scale.radii=-1", "optim.lr_scale.radii must be a finite number in [0, inf)"),
])
def test_bad_config_names_field_and_range(override, message):
    with pytest.raises(ConfigError) as err:
        validate(compose_cfg(override))
    assert message in str(err.value)


@pytest.fixture(scope="module")
def translation_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("translation")
    nma_run(run_dir, "task=translation", "logger=wandb", *FAST)
    return run_dir


def test_run_directory_holds_every_artefact(translation_run):
    d = translation_run
    assert (d / ".hydra" / "config.yaml").exists() and (d / "run.log").exists()
    assert list((d / "checkpoints").glob("step_0000002.msgpack"))
    metrics = json.loads((d / "metrics.json").read_text())
    assert metrics["metric"] == "mean_pointer_error" and np.isfinite(metrics["value"])
    assert [h["step"] for h in metrics["history"]] == [1, 2]
    assert len(list((d / "fields").glob("eval_*.h5"))) == 4 == len(list((d / "fields").glob("eval_*.xdmf")))
    for png in ("design.png", "deformed.png", "curves.png", "errors.png"):
        assert (d / "figures" / png).stat().st_size > 5_000
    from PIL import Image

    with Image.open(d / "figures" / "sweep.gif") as gif:  # the material along the task's sweep, frame by frame
        assert gif.n_frames == 3
    assert list((d / "wandb").glob("offline-run-*"))  # wandb logs offline by default


def test_every_evaluated_state_is_checked_and_the_export_says_so(translation_run, tmp_path):
    """metrics.json counts the states that are not physical objects; the fabrication report takes them
    from the run's final evaluation, and solving that evaluation again gives the same counts."""
    from nma.export import ExportConfig, export

    metrics = json.loads((translation_run / "metrics.json").read_text())
    assert metrics["checked_states"] == 4 and 0 <= metrics["invalid_states"] <= 4
    assert metrics["invalid_states"] == len(metrics["invalid_samples"])
    assert 0 < metrics["min_J"] <= 1.5 and 0 < metrics["min_gap"] < 2.5
    report = export(ExportConfig(run=str(translation_run), output=str(tmp_path / "a.svg")))
    states = report["evaluation_states"]
    assert states["source"].startswith("the run's final evaluation") and states["step"] == metrics["step"]
    assert states["valid"] == (metrics["invalid_states"] == 0)
    run = copy_run(translation_run, tmp_path / "run")
    (run / "metrics.json").unlink()
    again = export(ExportConfig(run=str(run), output=str(tmp_path / "b.svg"), load_cases=True))
    # the paper's Fig. 5 in simulation: tension and compression move the pointer in opposite directions
    cases = again["load_cases"]["cases"]
    assert list(cases) == ["tension", "compression", "one-sided compression"] and all(c["converged"] for c in cases.values())
    assert np.dot(cases["tension"]["pointer_displacement_mm"], cases["compression"]["pointer_displacement_mm"]) < 0
    assert (tmp_path / "load_cases.png").stat().st_size > 20_000
    again = again["evaluation_states"]
    assert again["source"].startswith("solved again")
    assert again["invalid_states"] == metrics["invalid_states"] and again["checked_states"] == 4
    assert again["min_J"] == pytest.approx(metrics["min_J"], rel=1e-8)


def test_hdf5_fields_match_the_solution(translation_run):
    import h5py

    from nma.mechanics.material import material
    from nma.simulator import Simulator

    sim = Simulator.from_config(config.load("scene", "translation"), config.load("fidelity", "fast"))
    geom = {k: jnp.asarray(v) for k, v in final_params(translation_run)["geom"].items()}
    with h5py.File(translation_run / "fields" / "eval_001.h5") as f:
        d, u_file, X_file = f.attrs["actuation"], f["control/displacement"][()], f["control/reference"][()]
    sol = sim.solve(geom, jnp.asarray(d), material(0.07, 0.3))
    np.testing.assert_allclose(X_file, sim.reference_points(geom), atol=1e-12)
    np.testing.assert_allclose(u_file, sol.u, atol=1e-9)


@pytest.mark.parametrize("task, eval_size, metric", [("rotation_single", "task.eval_angles=3", "mean_angle_error_deg"),
                                                      ("rotation_double", "task.eval_angles=3", "mean_angle_error_deg"),
                                                      ("shape_matching", "task.eval_targets=3", "shape_error"),
                                                      ("digital_mnist", "task.eval_digits=3", "digit_exact_match")])
def test_tasks_train_from_the_command_line(tmp_path, task, eval_size, metric):
    nma_run(tmp_path, f"task={task}", "logger=none", eval_size, *FAST[:-2], "fidelity=fast")
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["metric"] == metric and len(metrics["per_sample"]) == 3
    assert np.all(np.isfinite(metrics["per_sample"]))
    assert len(list((tmp_path / "fields").glob("eval_*.h5"))) == 3
    extra = {"shape_matching": ["shapes.png", "errors.png"], "digital_mnist": ["colours.png"]}.get(task, ["errors.png"])
    for png in ["design.png", "deformed.png", "curves.png", "sweep.gif"] + extra:
        assert (tmp_path / "figures" / png).stat().st_size > 5_000


def test_mpi_two_ranks_match_single_process(tmp_path, translation_run):
    nma_run(tmp_path, "task=translation", "logger=none", *FAST, mpi=2)
    assert not list(tmp_path.parent.glob(f"{tmp_path.name}_*"))  # one run directory
    assert (tmp_path / "metrics.json").exists()
    assert_same_params(final_params(tmp_path), final_params(translation_run), rtol=1e-9)


def test_kill_and_resume_matches_uninterrupted(tmp_path, translation_run):
    """SIGKILL after the first checkpoint, resume, and land on the uninterrupted run's parameters."""
    args = ["task=translation", "logger=none", "trainer.checkpoint_every=1", *FAST]
    killed = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "nma.run", f"hydra.run.dir={killed}", *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 300
    while not (killed / "checkpoints" / "step_0000001.msgpack").exists():
        assert time.time() < deadline and proc.poll() is None
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    nma_run(killed, *args, "trainer.resume=true")
    assert "resumed from" in (killed / "run.log").read_text()
    assert_same_params(final_params(killed), final_params(translation_run), rtol=1e-12)


def test_sigterm_checkpoints_says_so_and_resumes_to_the_uninterrupted_run(tmp_path, translation_run):
    """SIGTERM (what SLURM sends before a time limit) during the first step: the run finishes that step,
    checkpoints it (checkpoint_every would not have), says so in one line, exits 143; resuming lands on
    the uninterrupted run's parameters."""
    args = ["task=translation", "logger=none", *FAST]
    stopped = tmp_path / "stopped"
    proc = subprocess.Popen([sys.executable, "-m", "nma.run", f"hydra.run.dir={stopped}", *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.time() + 300
    while not ((stopped / "run.log").exists() and "dofs" in (stopped / "run.log").read_text()):
        assert time.time() < deadline and proc.poll() is None
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)  # the trainer is built; its first step (compiling) takes seconds
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 143, err[-2000:]
    assert "error: stopped by SIGTERM after step 1 of 2; checkpoint" in err and "trainer.resume=true" in err
    assert [p.name for p in (stopped / "checkpoints").glob("step_*.msgpack")] == ["step_0000001.msgpack"]
    nma_run(stopped, *args, "trainer.resume=true")
    assert_same_params(final_params(stopped), final_params(translation_run), rtol=1e-12)


def test_evaluate_refuses_a_checkpoint_its_config_does_not_fit(tmp_path, translation_run):
    """A run whose recorded config no longer fits its checkpoint (here the network's widths) is not
    evaluated with a freshly initialised network: ConfigError naming what does not fit."""
    from nma.evaluate import evaluate
    from nma.schema import EvaluateConfig, Fidelity

    d = copy_run(translation_run, tmp_path / "run")
    recorded = d / ".hydra" / "config.yaml"
    cfg = OmegaConf.load(recorded)
    cfg.model.hidden = [8]
    OmegaConf.save(cfg, recorded)
    with pytest.raises(ConfigError, match=r"does not fit this run's config: the network"):
        evaluate(EvaluateConfig(run=str(d), fidelity=Fidelity(5, 3)))


def copy_run(src, dst):
    import shutil
    shutil.copytree(src, dst)
    return dst


@pytest.mark.parametrize("change, named", [("trainer.batch_size=4", "trainer.batch_size: 2 -> 4"),
                                           ("model.hidden=[8]", "model.hidden: None -> [8]"),
                                           ("task.box_half_width=1.0", "task.box_half_width: 1.5 -> 1.0")])
def test_resume_with_another_config_stops_naming_the_fields(tmp_path, translation_run, monkeypatch, capsys,
                                                             change, named):
    from nma import run
    d = copy_run(translation_run, tmp_path / "run")
    recorded = (d / ".hydra" / "config.yaml").read_text()
    monkeypatch.setattr(sys, "argv", ["nma", f"hydra.run.dir={d}", "task=translation", "logger=wandb", *FAST,
                                      "trainer.resume=true", change])
    with pytest.raises(SystemExit) as exit_:
        run.main()
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and named in err and "trainer.resume=force" in err, err
    assert (d / ".hydra" / "config.yaml").read_text() == recorded  # the run's record is untouched


@pytest.mark.parametrize("damage", [b"", b"garbage", "truncated"])
def test_corrupt_latest_checkpoint_falls_back_to_the_previous(tmp_path, translation_run, caplog, damage):
    from nma.train import checkpoint
    good = final_params(translation_run)
    d = tmp_path / "checkpoints"
    d.mkdir()
    latest = sorted((translation_run / "checkpoints").glob("step_*.msgpack"))[-1]
    (d / "step_0000002.msgpack").write_bytes(latest.read_bytes())
    blob = latest.read_bytes()[: len(latest.read_bytes()) // 2] if damage == "truncated" else damage
    (d / "step_0000003.msgpack").write_bytes(blob)
    path, raw = checkpoint.load_latest(d)
    assert path.name == "step_0000002.msgpack"
    assert "step_0000003.msgpack is unreadable" in caplog.text
    assert_same_params(raw["params"], good, rtol=0)
    (d / "step_0000002.msgpack").write_bytes(b"")
    with pytest.raises(ConfigError, match="no readable checkpoint in .*step_0000003.*step_0000002"):
        checkpoint.load_latest(d)


def test_diverging_learning_rate_stops_with_its_cause(tmp_path):
    """A finite but absurd learning rate: the network's actuations turn non-finite at step 2; the run
    stops at once with exit 1, naming the diverged group and the learning rate, not the solver."""
    cmd = [sys.executable, "-m", "nma.run", f"hydra.run.dir={tmp_path}", "logger=none", *FAST,
           "trainer.steps=20", "optim.lr=1e200"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 1, proc.stderr[-2000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("error: step 1:") and "network (max |value| 1e+200)" in last
    assert "optim.lr = 1e+200" in last and "Traceback" not in proc.stderr


def test_nonfinite_loss_skips_updates_then_stops(simulator, tmp_path):
    """optax.apply_if_finite skips an update whose gradient is not finite; after
    trainer.max_nonfinite_steps in a row the run stops with the cause."""
    import jax
    from nma.mechanics.material import material
    from nma.models.mlp import mlp
    from nma.schema import OptimConfig, TrainerConfig, TranslationTask
    from nma.tasks.translation import translation
    from nma.errors import TrainingError
    from nma.train.trainer import Trainer

    sim = simulator("translation", quad_points=3)
    task = translation(TranslationTask(eval_grid=1), sim)
    task.loss = lambda out, t: jnp.sum(out) * jnp.nan
    trainer = Trainer(task, sim, mlp([4], sim.n_actuations, task.d_max), material(0.07, 0.3),
                      TrainerConfig(steps=10, batch_size=1, max_nonfinite_steps=2, progress=False),
                      OptimConfig(), tmp_path)
    before = jax.tree_util.tree_map(np.asarray, trainer.state["params"])
    assert trainer.step()["skipped_update"] == 1
    with pytest.raises(TrainingError, match=r"step 2: the loss or gradient was not finite for 2 steps in a row"):
        trainer.step()
    assert_same_params(trainer.state["params"], before, rtol=0)


@pytest.mark.slow
def test_digital_mnist_phases_chain(tmp_path):
    """Lookup table -> network fitted to it (no simulation) -> end-to-end fine-tuning, each phase
    starting from the one before (trainer.init_from)."""
    small = ["trainer.progress=false", "task.eval_digits=2", "trainer.eval_every=100"]
    lookup, fit, tune = tmp_path / "lookup", tmp_path / "fit", tmp_path / "finetune"
    nma_run(lookup, "experiment=repro_mnist_lookup", "trainer.steps=2", "trainer.batch_size=2", *small)
    table = json.loads((lookup / "metrics.json").read_text())
    assert table["metric"] == "lookup_digits_correct" and 0 <= table["value"] <= 10
    assert np.asarray(table["eval_actuations"]).shape == (10, 6)
    nma_run(fit, "experiment=repro_mnist_fit", "trainer.steps=30", "trainer.batch_size=32",
            f"task.lookup_run={lookup}", f"trainer.init_from={lookup}", *small)
    losses = [h["loss"] for h in json.loads((fit / "metrics.json").read_text())["history"]]
    assert losses[-1] < 0.5 * losses[0]  # the regression onto the table learns
    lookup_geom, fit_geom = final_params(lookup)["geom"], final_params(fit)["geom"]
    np.testing.assert_array_equal(fit_geom["colours"], lookup_geom["colours"])  # taken over, not learned
    nma_run(tune, "experiment=repro_mnist_finetune", "trainer.steps=1", "trainer.batch_size=1",
            f"trainer.init_from={fit}", *small)
    metrics = json.loads((tune / "metrics.json").read_text())
    assert {"digit_exact_match", "digit_segment_accuracy"} <= metrics.keys()
    np.testing.assert_array_equal(final_params(tune)["geom"]["radii"], lookup_geom["radii"])  # pores fixed


def test_mpi_rotation_experiment_lands_in_its_task_directory(tmp_path):
    cmd = ["mpiexec", "-n", "2", sys.executable, "-m", "nma.run", "experiment=repro_rotation_double",
           "trainer.steps=1", "trainer.batch_size=2", "trainer.eval_every=1", "task.eval_angles=2",
           "trainer.progress=false"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = list((tmp_path / "outputs" / "runs").glob("*/*"))
    assert [r.parent.name for r in runs] == ["rotation_double"] and (runs[0] / "metrics.json").exists()


def test_multirun_sweeps_seeds_through_submitit_and_summarises(tmp_path):
    """A 2-job sweep through hydra-submitit-launcher's local executor (the SLURM launcher's twin: each
    job a separate process), then the sweep summary of every job's overrides and final metric."""
    cmd = [sys.executable, "-m", "nma.run", "--multirun", "hydra/launcher=submitit_local", "trainer.seed=0,1",
           f"hydra.sweep.dir={tmp_path}", "task=translation", "logger=none", "trainer.steps=1",
           "trainer.batch_size=1", "trainer.eval_every=1", "trainer.progress=false", "trainer.animation_frames=0",
           "task.eval_grid=1", "fidelity=fast"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = sorted(tmp_path.glob("*/metrics.json"))
    assert len(runs) == 2 and list((tmp_path / ".submitit").iterdir())
    a, b = (final_params(r.parent)["net"] for r in runs)
    assert not np.allclose(dict(_flatten(a))["/params/Dense_0/kernel"], dict(_flatten(b))["/params/Dense_0/kernel"])
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [j["job"] for j in summary["jobs"]] == ["0", "1"]
    for job, run in zip(summary["jobs"], runs):
        assert f"trainer.seed={job['job']}" in job["overrides"]
        assert job["value"] == json.loads(run.read_text())["value"] and job["metric"] == "mean_pointer_error"
    assert "trainer.seed=1" in (tmp_path / "summary.md").read_text()


def test_slurm_launcher_preset_composes():
    with initialize_config_dir(config_dir=str(config.CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=["hydra/launcher=slurm", "hydra.launcher.partition=cpu"],
                      return_hydra_config=True)
    assert cfg.hydra.launcher._target_.endswith("SlurmLauncher")
    assert cfg.hydra.launcher.cpus_per_task == 2 and cfg.hydra.launcher.partition == "cpu"


def test_fields_are_written_as_asked(tmp_path):
    """trainer.fields: every evaluation into fields/step_<n>/, or none at all (default: the final one)."""
    nma_run(tmp_path / "all", "logger=none", *FAST, "trainer.eval_every=1", "trainer.fields=all")
    for step in (1, 2):
        assert len(list((tmp_path / "all" / "fields" / f"step_{step:07d}").glob("eval_*.h5"))) == 4
    assert not list((tmp_path / "all" / "fields").glob("eval_*.h5"))
    nma_run(tmp_path / "none", "logger=none", *FAST, "trainer.fields=none")
    assert (tmp_path / "none" / "metrics.json").exists() and not (tmp_path / "none" / "fields").exists()


def test_evaluate_reproduces_the_run_and_refines_it(translation_run):
    """nma.evaluate: the run's checkpoint at its own fidelity gives its metrics.json value back; at the
    paper fidelity (5 Gauss points instead of 3) the same design gives a nearby value, side by side."""
    from nma.evaluate import evaluate
    from nma.schema import EvaluateConfig, Fidelity

    result = evaluate(EvaluateConfig(run=str(translation_run), fidelity=Fidelity(5, 5)))
    logged = json.loads((translation_run / "metrics.json").read_text())
    assert result["training_fidelity"]["metric"] == pytest.approx(logged["value"], rel=1e-9)
    assert result["training_fidelity"]["fidelity"] == logged["fidelity"]
    assert logged["fidelity"]["ctrl_per_patch"] == 5 and logged["fidelity"]["quad_points"] == 3
    assert logged["fidelity"]["auto"] is None
    refined = result["evaluated_fidelity"]
    assert refined["fidelity"]["quad_points"] == 5 and refined["failed_solves"] == 0
    assert result["change"] == pytest.approx(refined["metric"] - logged["value"], rel=1e-9)
    assert 0 < abs(result["change"]) < 0.1 * logged["value"]
    assert json.loads((translation_run / "evaluate" / "5x5.json").read_text())["change"] == result["change"]
