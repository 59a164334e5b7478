"""nma.evaluate: a trained run re-evaluated, at its own fidelity and another."""

import json
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from conftest import copy_run
from nma.errors import ConfigError


def test_evaluate_refuses_a_run_whose_files_changed_after_training(tmp_path, translation_run):
    """A run whose recorded config no longer says what its checkpoint trained (the network's widths,
    the task's box; a dataset edited after training changes the recorded sha256 the same way) is not
    evaluated: ConfigError naming each difference, before any work."""
    from nma.evaluate import evaluate
    from nma.schema import EvaluateConfig, Fidelity

    d = copy_run(translation_run, tmp_path / "run")
    recorded = d / ".hydra" / "config.yaml"
    cfg = OmegaConf.load(recorded)
    cfg.model.hidden, cfg.task.box_half_width = [8], 1.0
    OmegaConf.save(cfg, recorded)
    with pytest.raises(
        ConfigError,
        match=r"its files no longer say what checkpoint step_\d+.msgpack trained \("
        r"model.hidden: None -> \[8\]; task.box_half_width: 1.5 -> 1.0\)",
    ):
        evaluate(EvaluateConfig(run=str(d), fidelity=Fidelity(5, 3)))


def test_evaluate_reproduces_the_run_and_refines_it(translation_run):
    """nma.evaluate: the run's checkpoint at its own fidelity gives its metrics.json value back; at
    the paper fidelity (5 Gauss points instead of 3) the same design gives a nearby value, side by
    side."""
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
    written = Path(result["file"])  # evaluate/5x5.json, or 5x5_<n>.json beside an earlier one
    assert written.parent == translation_run / "evaluate" and written.name.startswith("5x5")
    assert json.loads(written.read_text())["change"] == result["change"]


def test_evaluate_on_a_subset_reads_the_same_samples_of_the_run(translation_run):
    """eval_subset=N evaluates N samples evenly spaced through the evaluation set (the trainer's
    eval_subset), at both fidelities: at the training fidelity their values are the run's own for
    those samples, and the file says how many.  Out of range: ConfigError naming the field."""
    import numpy as np

    from nma.evaluate import evaluate
    from nma.schema import EvaluateConfig, Fidelity

    logged = json.loads((translation_run / "metrics.json").read_text())
    result = evaluate(
        EvaluateConfig(run=str(translation_run), fidelity=Fidelity(5, 3), eval_subset=3)
    )
    idx = np.linspace(0, len(logged["per_sample"]) - 1, 3).round().astype(int)
    assert result["samples"] == 3 and len(idx) == 3
    np.testing.assert_allclose(
        result["training_fidelity"]["per_sample"], np.asarray(logged["per_sample"])[idx], rtol=1e-9
    )
    assert (
        Path(result["file"]).name.startswith("5x3_3_samples")
        and json.loads(Path(result["file"]).read_text())["samples"] == 3
    )
    with pytest.raises(ConfigError, match=r"eval_subset must be .* in \[1, 100000000\], got 0"):
        EvaluateConfig(run=str(translation_run), eval_subset=0)


# test_evaluate_reproduces_the_run_and_refines_it evaluates with the run's own settings
@pytest.mark.slow
def test_evaluate_solves_with_the_runs_own_solver_unless_told(tmp_path, translation_run):
    """Without solver=, a run is re-evaluated with the solver settings it trained with (so its
    metric is reproduced): a run whose Newton had 2 iterations fails its solves again; solver=
    chooses others."""
    import shutil

    from omegaconf import OmegaConf

    from nma.evaluate import evaluate
    from nma.schema import EvaluateConfig, Fidelity, SolverConfig

    run = tmp_path / "run"
    shutil.copytree(translation_run / ".hydra", run / ".hydra")
    shutil.copytree(translation_run / "checkpoints", run / "checkpoints")
    cfg = OmegaConf.load(run / ".hydra" / "config.yaml")
    cfg.solver.max_iters = 2
    OmegaConf.save(cfg, run / ".hydra" / "config.yaml")
    own = evaluate(EvaluateConfig(run=str(run), fidelity=Fidelity(5, 3), eval_subset=2))
    assert (
        own["training_fidelity"]["failed_solves"] == 2
        and own["evaluated_fidelity"]["failed_solves"] == 2
    )
    assert own["solver"]["from"] == "run" and own["solver"]["max_iters"] == 2
    assert own["training_fidelity"]["failed_samples"] == [0, 1]  # which ones, not only how many
    # and why: the iteration limit, not the element bound
    assert own["training_fidelity"]["stopped_inverting"] == 0
    told = evaluate(
        EvaluateConfig(run=str(run), fidelity=Fidelity(5, 3), eval_subset=2, solver=SolverConfig())
    )
    assert (
        told["training_fidelity"]["failed_solves"] == 0
        and told["training_fidelity"]["failed_samples"] == []
    )


@pytest.mark.parametrize(
    "field, said",
    [
        ("solver.rtol=1e-12", "solver.rtol needs solver= chosen first (solver=auto"),
        ("++solver.rtol=1e-12", "solver.rtol needs solver= chosen first (solver=auto"),
        ("contact.distance=0.01", "contact.distance needs contact= chosen first"),
    ],
)
def test_evaluate_asks_for_a_group_before_its_fields(monkeypatch, capsys, field, said):
    """solver and contact are the run's own unless chosen: a field of either alone is exit 2, one
    line."""
    from nma import evaluate

    monkeypatch.setattr("sys.argv", ["nma.evaluate", "run=/nonexistent", field])
    with pytest.raises(SystemExit) as exit_:
        evaluate.main()
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and said in err and "Traceback" not in err


def test_a_run_from_before_the_element_bound_is_read_without_it(tmp_path, translation_run):
    """A run directory whose saved config has no solver.element_bound trained before the bound was
    Newton's default: load_run (nma.evaluate, nma.export) reads it with the bound off, as it
    trained; a run that records the setting keeps it."""
    import shutil

    from nma.train.runs import load_run

    run = tmp_path / "run"
    shutil.copytree(translation_run / ".hydra", run / ".hydra")
    shutil.copytree(translation_run / "checkpoints", run / "checkpoints")
    assert load_run(run)[0].solver.element_bound is True  # this run recorded the default
    cfg = OmegaConf.load(run / ".hydra" / "config.yaml")
    del cfg.solver["element_bound"]
    OmegaConf.save(cfg, run / ".hydra" / "config.yaml")
    assert load_run(run)[0].solver.element_bound is False


def test_a_directory_that_is_no_training_run_is_named_as_such(tmp_path):
    """load_run (nma.evaluate's and nma.export's): another command's directory, or a damaged config,
    is a ConfigError naming the directory, not a traceback."""
    from nma.train.runs import load_run

    (tmp_path / "simulated" / ".hydra").mkdir(parents=True)
    (tmp_path / "simulated" / ".hydra" / "config.yaml").write_text(
        "scene: {name: translation}\nactuation: null\n"
    )
    with pytest.raises(
        ConfigError,
        match=r"run=.*simulated is not a training run directory \(its .hydra/config.yaml "
        r"holds no task and trainer: another command's\)",
    ):
        load_run(tmp_path / "simulated")
    (tmp_path / "damaged" / ".hydra").mkdir(parents=True)
    (tmp_path / "damaged" / ".hydra" / "config.yaml").write_text("task: [unclosed\n")
    with pytest.raises(ConfigError, match=r"run=.*damaged: .*config.yaml does not read \(\w+"):
        load_run(tmp_path / "damaged")


def test_a_run_with_no_readable_checkpoint_is_named_as_the_run(tmp_path, translation_run):
    """load_run (nma.evaluate's and nma.export's): when every checkpoint is damaged, the error names
    the run given (run=...), not a setting of training the user never gave."""
    from nma.train.runs import load_run

    d = copy_run(translation_run, tmp_path / "run")
    for path in (d / "checkpoints").glob("step_*.msgpack"):
        path.write_bytes(b"garbage")
    with pytest.raises(ConfigError, match=rf"^run={d}: no readable checkpoint in "):
        load_run(d)


@pytest.mark.parametrize(
    "command, taken, refused",
    [
        ("evaluate", ["fidelity", "contact", "solver"], ["task", "optim", "experiment"]),
        ("simulate", ["scene", "fidelity", "contact", "solver"], ["task", "optim", "trainer"]),
        ("run", ["task", "scene", "optim", "experiment"], ["task: digital_mnist_schema"]),
    ],
)
def test_help_lists_the_groups_a_command_takes(command, taken, refused):
    """Each command's --help lists the config groups it takes, each with the options in conf/, and
    no other (nma.evaluate takes no task: the run's own).  A subprocess: the command line is what is
    checked."""
    import subprocess
    import sys

    from nma.config import options

    done = subprocess.run(
        [sys.executable, "-m", f"nma.{command}", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    out = done.stdout
    assert done.returncode == 0 and out.startswith(f"python -m nma.{command} "), done.stderr[-2000:]
    for group in taken:
        assert f"\n{group}: {', '.join(options(group))}\n" in out
    for line in refused:
        assert f"\n{line}" not in out


def test_a_run_still_training_is_not_evaluated_or_exported(tmp_path, translation_run):
    """While another process holds a run's directory (it is training: its newest checkpoint
    changes), load_run (nma.evaluate's and nma.export's) refuses it, naming the process, rather than
    read a checkpoint that the next one replaces."""
    import subprocess
    import sys

    from nma.train.runs import load_run

    d = copy_run(translation_run, tmp_path / "run")
    hold = (
        "import fcntl, sys, time; f = open(sys.argv[1], 'a+'); fcntl.flock(f, fcntl.LOCK_EX); "
        "f.write('process 4242 on somewhere'); f.flush(); print('held', flush=True); time.sleep(60)"
    )
    holder = subprocess.Popen(
        [sys.executable, "-c", hold, str(d / ".lock")], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(
            ConfigError, match=r"is still training \((.|\n)*process 4242 on somewhere"
        ):
            load_run(d)
    finally:
        holder.kill()
        holder.wait()
    load_run(d)  # the lock goes with its process


def test_an_evaluation_whose_every_solve_fails_exits_1_with_valid_json(tmp_path, translation_run):
    """Every solve failed (a Newton given one iteration): the JSON is written and valid, and the
    exit status says the evaluation says nothing (1), naming the file."""
    import subprocess
    import sys

    d = copy_run(translation_run, tmp_path / "run")
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "nma.evaluate",
            f"run={d}",
            "fidelity=fast",
            "solver=auto",
            "solver.max_iters=1",
            "eval_subset=2",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert (
        done.returncode == 1
        and "every solve failed at the training fidelity (2 of 2;" in done.stderr
    ), done.stderr
    assert (
        json.loads(done.stdout)["evaluated_failed_solves"] == 2 and "Traceback" not in done.stderr
    )
