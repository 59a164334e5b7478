"""Training from the command line: the run directory and its artefacts, every task, failures that
stop a run."""

import json
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest

from conftest import FAST, assert_same_params, copy_run, final_params, nma_run, train_in_process
from nma import config


def test_run_directory_holds_every_artefact(translation_run):
    d = translation_run
    assert (d / ".hydra" / "config.yaml").exists() and (d / "run.log").exists()
    # JAX's backend probe is not news
    assert "Unable to initialize backend" not in (d / "run.log").read_text()
    assert list((d / "checkpoints").glob("step_0000002.msgpack"))
    metrics = json.loads((d / "metrics.json").read_text())
    assert metrics["metric"] == "mean_pointer_error" and np.isfinite(metrics["value"])
    # the model auto chose for the paper's compressible material: the displacement model, Newton's
    # defaults
    assert metrics["model"] == {
        "nearly_incompressible": False,
        "formulation": "displacement",
        "corrector": "line_search",
        "max_iters": 200,
        "max_step_iters": 100,
        "inversion_barrier": 0.0,
        "contact": False,
    }
    assert [h["step"] for h in metrics["history"]] == [1, 2]
    # its units stated (part.scale 2 mm, 10 mm thick, MPa): lengths in mm, forces in N = MPa x mm x
    # mm
    assert metrics["units"] == {
        "length": "mm",
        "mm_per_unit": 2.0,
        "force": "N",
        "newton_per_force_unit": 20.0,
        "thickness_mm": 10.0,
        "stress": "MPa",
    }
    assert metrics["mean_pointer_error_mm"] == pytest.approx(2.0 * metrics["value"], rel=1e-12)
    assert np.allclose(
        metrics["max_actuation_force_N"],
        20.0 * np.asarray(metrics["max_actuation_force"]),
        rtol=1e-12,
    )
    assert len(metrics["max_actuation_force"]) == 2 and min(metrics["max_actuation_force"]) > 0
    # the strains the law is asked
    assert 0 < metrics["stretch_range"][0] < 1 < metrics["stretch_range"][1]
    # evaluations before the last on trainer.eval_subset samples, the last (the run's metric) on all
    assert [h["eval_samples"] for h in metrics["history"]] == [2, 4] and len(
        metrics["per_sample"]
    ) == 4
    assert (
        len(list((d / "fields").glob("eval_*.h5")))
        == 4
        == len(list((d / "fields").glob("eval_*.xdmf")))
    )
    for png in ("design.png", "deformed.png", "curves.png", "errors.png"):
        assert (d / "figures" / png).stat().st_size > 5_000
    from PIL import Image

    # the material along the task's sweep, frame by frame
    with Image.open(d / "figures" / "sweep.gif") as gif:
        assert gif.n_frames == 3
    assert list((d / "wandb").glob("offline-run-*"))  # wandb logs offline by default


def test_every_evaluated_state_is_checked_and_the_export_says_so(translation_run, tmp_path):
    """metrics.json counts the states that are not physical objects; the fabrication report takes
    them from the run's final evaluation, and solving that evaluation again gives the same
    counts."""
    from nma.export import ExportConfig, export

    metrics = json.loads((translation_run / "metrics.json").read_text())
    assert metrics["checked_states"] == 4 and 0 <= metrics["invalid_states"] <= 4
    assert metrics["invalid_states"] == len(metrics["invalid_samples"])
    assert 0 < metrics["min_J"] <= 1.5 and 0 < metrics["min_gap"] < 2.5
    report = export(ExportConfig(run=str(translation_run), output=str(tmp_path / "a.svg")))
    states = report["evaluation_states"]
    assert (
        states["source"].startswith("the run's final evaluation")
        and states["step"] == metrics["step"]
    )
    assert states["valid"] == (metrics["invalid_states"] == 0)
    run = copy_run(translation_run, tmp_path / "run")
    (run / "metrics.json").unlink()
    again = export(ExportConfig(run=str(run), output=str(tmp_path / "b.svg"), load_cases=True))
    # the paper's Fig. 5 in simulation: tension and compression move the pointer in opposite
    # directions
    cases = again["load_cases"]["cases"]
    assert list(cases) == ["tension", "compression", "one-sided compression"] and all(
        c["converged"] for c in cases.values()
    )
    assert (
        np.dot(
            cases["tension"]["pointer_displacement_mm"],
            cases["compression"]["pointer_displacement_mm"],
        )
        < 0
    )
    # the actuators' forces in N (the run's units): tension pulls where compression pushes
    assert again["load_cases"]["units"]["force"] == "N"
    assert np.allclose(
        cases["tension"]["actuation_forces_N"],
        20.0 * np.asarray(cases["tension"]["actuation_forces"]),
    )
    assert np.all(
        np.sign(cases["tension"]["actuation_forces"])
        == -np.sign(cases["compression"]["actuation_forces"])
    )
    assert (tmp_path / "load_cases.png").stat().st_size > 20_000
    # the part as made in another material (Mooney-Rivlin, in kPa): its own forces, in N, the run
    # untouched
    from nma.schema import MaterialConfig

    made = MaterialConfig(
        name="a rubber",
        law="mooney_rivlin",
        E=None,
        parameters={"C10": 40.0, "C01": 10.0},
        unit="kPa",
    )
    rubber = export(
        ExportConfig(
            run=str(run),
            output=str(tmp_path / "c.svg"),
            load_cases=True,
            states=False,
            material=made,
        )
    )["load_cases"]
    assert rubber["material"]["law"] == "mooney_rivlin" and rubber["units"][
        "newton_per_force_unit"
    ] == pytest.approx(0.02)
    assert all(c["converged"] for c in rubber["cases"].values())
    tension = rubber["cases"]["tension"]
    assert np.allclose(
        tension["actuation_forces_N"], 0.02 * np.asarray(tension["actuation_forces"])
    )
    assert not np.allclose(tension["actuation_forces"], cases["tension"]["actuation_forces"])
    again = again["evaluation_states"]
    assert again["source"].startswith("solved again")
    assert again["invalid_states"] == metrics["invalid_states"] and again["checked_states"] == 4
    assert again["min_J"] == pytest.approx(metrics["min_J"], rel=1e-8)


def test_hdf5_fields_match_the_solution(translation_run):
    import h5py

    from nma.mechanics.material import material
    from nma.simulator import Simulator

    sim = Simulator.from_config(
        config.load("scene", "translation"), config.load("fidelity", "fast")
    )
    geom = {k: jnp.asarray(v) for k, v in final_params(translation_run)["geom"].items()}
    with h5py.File(translation_run / "fields" / "eval_001.h5") as f:
        d, u_file, X_file = (
            f.attrs["actuation"],
            f["control/displacement"][()],
            f["control/reference"][()],
        )
    sol = sim.solve(geom, jnp.asarray(d), material(0.07, 0.3))
    np.testing.assert_allclose(X_file, sim.reference_points(geom), atol=1e-12)
    np.testing.assert_allclose(u_file, sol.u, atol=1e-9)
    # the run writes its fields through one compiled sampler; the mesh and det F are those of the
    # eager path (nma.simulate's, one state)
    from nma.geometry.sampling import sample_jacobian, sample_positions

    with h5py.File(translation_run / "fields" / "eval_001.h5") as f:
        ref, cur, J, s = (
            f["mesh/reference"][()],
            f["mesh/deformed"][()],
            f["fields/J"][()],
            f.attrs["samples_per_side"],
        )
    np.testing.assert_allclose(
        ref, np.asarray(sample_positions(sim.disc.mesh, X_file, s)).reshape(-1, 2), atol=1e-12
    )
    np.testing.assert_allclose(
        cur,
        np.asarray(sample_positions(sim.disc.mesh, X_file + u_file, s)).reshape(-1, 2),
        atol=1e-12,
    )
    np.testing.assert_allclose(
        J, np.asarray(sample_jacobian(sim.disc.mesh, X_file, u_file, s)).reshape(-1), atol=1e-12
    )


# slow: the fast suite trains translation end to end (the translation_run fixture) and checks each
# other task's observations, loss and gradient on its own (test_tasks, test_shape_matching,
# test_digital_mnist)
@pytest.mark.slow
@pytest.mark.parametrize(
    "task, eval_size, metric",
    [
        ("rotation_single", ["task.eval_angles=3"], "mean_angle_error_deg"),
        ("rotation_double", ["task.eval_angles=3"], "mean_angle_error_deg"),
        ("shape_matching", ["task.eval_targets=3"], "shape_error"),
        (
            "digital_mnist",
            ["task.phase=finetune", "optim.lr=2e-4", "task.eval_digits=3"],
            "digit_exact_match",
        ),
    ],
)
def test_every_task_trains_and_writes_its_artefacts(tmp_path, task, eval_size, metric):
    train_in_process(
        tmp_path, f"task={task}", "logger=none", *eval_size, *FAST[:-2], "fidelity=fast"
    )
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["metric"] == metric and len(metrics["per_sample"]) == 3
    assert np.all(np.isfinite(metrics["per_sample"]))
    assert len(list((tmp_path / "fields").glob("eval_*.h5"))) == 3
    extra = {"shape_matching": ["shapes.png", "errors.png"], "digital_mnist": ["colours.png"]}.get(
        task, ["errors.png"]
    )
    for png in ["design.png", "deformed.png", "curves.png", "sweep.gif"] + extra:
        assert (tmp_path / "figures" / png).stat().st_size > 5_000


# test_nonfinite_loss_skips_updates_then_stops covers the non-finite path in process
@pytest.mark.slow
def test_diverging_learning_rate_stops_with_its_cause(tmp_path):
    """A finite but absurd learning rate: the network's actuations turn non-finite at step 2; the
    run stops at once with exit 1, naming the diverged group and the learning rate, not the
    solver."""
    cmd = [
        sys.executable,
        "-m",
        "nma.run",
        f"hydra.run.dir={tmp_path}",
        "logger=none",
        *FAST,
        "trainer.steps=20",
        "optim.lr=1e200",
    ]
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
    trainer = Trainer(
        task,
        sim,
        mlp([4], sim.n_actuations, task.d_max),
        material(0.07, 0.3),
        TrainerConfig(steps=10, batch_size=1, max_nonfinite_steps=2, progress=False),
        OptimConfig(),
        tmp_path,
    )
    before = jax.tree_util.tree_map(np.asarray, trainer.state["params"])
    assert trainer.step()["skipped_update"] == 1
    with pytest.raises(
        TrainingError, match=r"step 2: the loss or gradient was not finite for 2 steps in a row"
    ):
        trainer.step()
    assert_same_params(trainer.state["params"], before, rtol=0)


def test_the_inversion_penalty_adds_its_weighted_term_to_each_converged_samples_loss(
    simulator, tmp_path
):
    """trainer.inversion_penalty w: each converged sample's loss is the task's plus w times
    nma.mechanics.energy.inversion_penalty of its state (margin 0.99, so that the term acts where a
    state is compressed anywhere); with w = 0 the loss is the task's alone."""
    import dataclasses

    import jax
    from nma.mechanics.energy import inversion_penalty
    from nma.mechanics.material import material
    from nma.models.mlp import mlp
    from nma.schema import OptimConfig, TrainerConfig, TranslationTask
    from nma.tasks.translation import translation
    from nma.train.trainer import Trainer

    sim = simulator("translation", quad_points=3)
    task = translation(TranslationTask(eval_grid=1), sim)
    cfg = TrainerConfig(
        steps=1, batch_size=3, progress=False, inversion_penalty=0.5, inversion_margin=0.99
    )
    trainer = Trainer(
        task,
        sim,
        mlp([4], sim.n_actuations, task.d_max),
        material(0.07, 0.3),
        cfg,
        OptimConfig(),
        tmp_path,
    )
    params, ts = trainer.state["params"], task.sample(jax.random.PRNGKey(5), 3)
    total, (ok, losses, _, _) = trainer._loss_sum(params, ts)
    X, _, u, out, _ = trainer._forward(params, ts)
    penalty = np.array([float(inversion_penalty(sim.disc.mesh, X, ui, 0.99)) for ui in u])
    task_losses = np.asarray(jax.vmap(task.loss)(out, ts))
    assert np.all(np.asarray(ok)) and np.any(penalty > 0)
    np.testing.assert_allclose(np.asarray(losses), task_losses + 0.5 * penalty, rtol=1e-12)
    np.testing.assert_allclose(float(total), np.sum(task_losses + 0.5 * penalty), rtol=1e-12)
    trainer.cfg = dataclasses.replace(cfg, inversion_penalty=0.0)
    np.testing.assert_allclose(
        np.asarray(trainer._loss_sum(params, ts)[1][1]), task_losses, rtol=1e-12
    )


def test_an_evaluation_says_which_solves_failed_and_why(simulator, tmp_path):
    """Newton given 2 iterations leaves some solves of the evaluation unconverged: the record lists
    them, none stopped by the element bound, and each is scored at the worse of the state it reached
    and no actuation, so the metric over every sample is no better than the mean over the others
    would have been had the failures done nothing; the run's warning line says so.  The element
    bound's reason is worded from its count (tests/test_solver.py checks the status)."""
    import jax
    import jax.numpy as jnp
    from nma.mechanics.material import material
    from nma.models.mlp import mlp
    from nma.run import failed_solves
    from nma.schema import OptimConfig, TrainerConfig, TranslationTask
    from nma.tasks.translation import translation
    from nma.train.trainer import Trainer

    sim = simulator("translation", solver={"max_iters": 2}, quad_points=3)
    task = translation(TranslationTask(eval_grid=2), sim)
    mat = material(0.07, 0.3)
    trainer = Trainer(
        task,
        sim,
        mlp([4], sim.n_actuations, task.d_max),
        mat,
        TrainerConfig(steps=1, progress=False),
        OptimConfig(),
        tmp_path,
    )
    ev = trainer.evaluate()
    r = ev.record
    failed = r["failed_samples"]
    assert 0 < len(failed) == r["failed_solves"] < 4 and r["stopped_inverting"] == 0
    per = np.asarray(r["per_sample"])
    assert r[task.metric_name] == pytest.approx(np.mean(per), rel=1e-12)  # every sample counts
    assert r["over_converged"] == pytest.approx(np.mean(np.delete(per, failed)), rel=1e-12)
    X = sim.reference_points(sim.init_params())
    at_rest = task.observe(sim, sim.init_params(), X, jnp.zeros_like(X), mat)
    for i in failed:  # the worse of the state reached and no actuation
        reached = float(task.metric(ev.out[i], ev.ts[i]))
        rest = float(task.metric(at_rest, ev.ts[i]))
        assert per[i] == pytest.approx(max(reached, rest), rel=1e-12) and per[i] >= rest
    assert np.all(np.isfinite(per)) and jax.tree_util.tree_leaves(ev.out)
    assert failed_solves(r).startswith(
        f"{len(failed)} of the final evaluation's 4 solves failed ({len(failed)} did not "
        f"converge): the metric scores each at the worse of the state it reached and "
        f"no actuation; over the other {4 - len(failed)} alone it is "
    )
    line = failed_solves({**r, "failed_solves": 3, "stopped_inverting": 2, "over_converged": 0.5})
    assert (
        "(2 stopped at Newton's element bound (solver.element_bound), where the material would "
        "invert between "
        "Gauss points; 1 did not converge): the metric scores each"
        in line
        and "over the other 1 alone it is 0.5" in line
    )
    assert "; none converged." in failed_solves({**r, "failed_solves": 4, "stopped_inverting": 0})


def test_a_failed_solve_scores_at_the_worse_end_of_the_metric():
    """Task.failed_score takes the worse of the state reached and no actuation in the metric's own
    direction (an error's larger, a count of right answers' smaller), and no actuation where the
    state reached is not a number."""
    from nma.tasks.base import Task

    error, right = Task(), Task()
    right.higher_is_better = True
    np.testing.assert_array_equal(
        error.failed_score([0.2, 0.9, np.nan], [0.5, 0.5, 0.5]), [0.5, 0.9, 0.5]
    )
    np.testing.assert_array_equal(
        right.failed_score([1.0, 0.0, np.nan], [0.0, 1.0, 1.0]), [0.0, 0.0, 1.0]
    )


@pytest.mark.slow
def test_digital_mnist_phases_chain(tmp_path):
    """Lookup table -> network fitted to it (no simulation) -> end-to-end fine-tuning, each phase
    starting from the one before (trainer.init_from)."""
    small = ["trainer.progress=false", "task.eval_digits=2", "trainer.eval_every=100"]
    lookup, fit, tune = tmp_path / "lookup", tmp_path / "fit", tmp_path / "finetune"
    nma_run(
        lookup, "experiment=repro_mnist_lookup", "trainer.steps=2", "trainer.batch_size=2", *small
    )
    table = json.loads((lookup / "metrics.json").read_text())
    assert table["metric"] == "lookup_digits_correct" and 0 <= table["value"] <= 10
    assert np.asarray(table["eval_actuations"]).shape == (10, 6)
    nma_run(
        fit,
        "experiment=repro_mnist_fit",
        "trainer.steps=30",
        "trainer.batch_size=32",
        f"task.lookup_run={lookup}",
        f"trainer.init_from={lookup}",
        *small,
    )
    losses = [h["loss"] for h in json.loads((fit / "metrics.json").read_text())["history"]]
    assert losses[-1] < 0.5 * losses[0]  # the regression onto the table learns
    lookup_geom, fit_geom = final_params(lookup)["geom"], final_params(fit)["geom"]
    # taken over, not learned
    np.testing.assert_array_equal(fit_geom["colours"], lookup_geom["colours"])
    nma_run(
        tune,
        "experiment=repro_mnist_finetune",
        "trainer.steps=1",
        "trainer.batch_size=1",
        f"trainer.init_from={fit}",
        *small,
    )
    metrics = json.loads((tune / "metrics.json").read_text())
    assert {"digit_exact_match", "digit_segment_accuracy"} <= metrics.keys()
    # pores fixed
    np.testing.assert_array_equal(final_params(tune)["geom"]["radii"], lookup_geom["radii"])


@pytest.mark.slow  # every training test writes the final fields; this checks the other two settings
def test_fields_are_written_as_asked(tmp_path):
    """trainer.fields: every evaluation into fields/step_<n>/, or none at all (default: the final
    one)."""
    train_in_process(
        tmp_path / "all", "logger=none", *FAST, "trainer.eval_every=1", "trainer.fields=all"
    )
    for step in (1, 2):
        assert len(list((tmp_path / "all" / "fields" / f"step_{step:07d}").glob("eval_*.h5"))) == 4
    assert not list((tmp_path / "all" / "fields").glob("eval_*.h5"))
    train_in_process(tmp_path / "none", "logger=none", *FAST, "trainer.fields=none")
    assert (tmp_path / "none" / "metrics.json").exists() and not (
        tmp_path / "none" / "fields"
    ).exists()


def test_a_wholly_failed_batch_is_skipped_counted_and_stops_the_run_only_in_a_row(
    simulator, tmp_path
):
    """A step in which no sample converged changes nothing and is recorded; the next step trains as
    usual; trainer.max_failed_steps such steps in a row stop the run, saying why and what to change.
    (The batch's failure is made by marking its solves unconverged: what the trainer does with a
    failed batch is the subject, not why a solve fails, which tests/test_solver.py covers.)"""
    import jax
    from nma.errors import SolverError
    from nma.mechanics.material import material
    from nma.models.mlp import mlp
    from nma.schema import OptimConfig, TrainerConfig, TranslationTask
    from nma.solver.status import Status
    from nma.tasks.translation import translation
    from nma.train.trainer import Trainer

    sim = simulator("translation", quad_points=3)
    task = translation(TranslationTask(eval_grid=1), sim)
    trainer = Trainer(
        task,
        sim,
        mlp([4], sim.n_actuations, task.d_max),
        material(0.07, 0.3),
        TrainerConfig(steps=10, batch_size=2, max_failed_steps=2, progress=False),
        OptimConfig(),
        tmp_path,
    )
    real, failing = trainer._grad, {1, 3, 4}  # the batches of steps 1, 3 and 4 fail entirely

    def grad(params, ts):
        (loss, (ok, losses, status, info)), g = real(params, ts)
        if trainer.state["step"] + 1 in failing:
            status = jnp.full_like(status, Status.ITERATION_LIMIT)
            ok, info = status == 1, info._replace(status=status)
        return (loss, (ok, losses, status, info)), g

    trainer._grad = grad
    before = jax.tree_util.tree_map(np.asarray, trainer.state["params"])
    rec = trainer.step()
    assert (
        rec["failed_step"] == 1
        and rec["loss"] is None
        and rec["failed_solves"] == 2
        and trainer.state["step"] == 1
    )
    assert_same_params(trainer.state["params"], before, rtol=0)
    rec = trainer.step()  # a batch that converges: an update
    assert "failed_step" not in rec and np.isfinite(rec["loss"]) and rec["failed_solves"] == 0
    moved = jax.tree_util.tree_map(
        lambda a, b: not np.array_equal(a, b), trainer.state["params"], before
    )
    assert any(jax.tree_util.tree_leaves(moved))
    assert trainer.step()["failed_step"] == 1  # one in a row: skipped
    with pytest.raises(
        SolverError,
        match=r"step 4: no sample of the batch converged in 2 steps in a row "
        r"\(trainer.max_failed_steps\).*the iteration limit.*Give Newton more room",
    ):
        trainer.step()


def test_a_run_whose_every_final_solve_fails_errs_after_writing_everything(tmp_path):
    """A run that trained nothing (every solve failed: a Newton of one iteration) writes its
    checkpoint and metrics.json, then ends in a TrainingError (exit 1) that says why: its metric is
    not a result."""
    from conftest import train_in_process
    from nma.errors import TrainingError

    with pytest.raises(
        TrainingError, match=r"25 of the final evaluation's 25 solves failed .*none converged"
    ):
        train_in_process(
            tmp_path, "task=translation", "debug=default", "solver.max_iters=1", "logger=none"
        )
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["failed_solves"] == 25 and metrics["failed_steps"] == 2
