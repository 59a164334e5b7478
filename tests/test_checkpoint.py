"""Checkpoints: a killed or signalled run resumes to the uninterrupted one; a changed config or a
corrupt checkpoint is refused or skipped, saying which."""

import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import (
    FAST,
    assert_same_params,
    copy_run,
    final_params,
    nma_run,
    train_in_process,
)
from nma.errors import ConfigError


@pytest.mark.slow  # the fast suite resumes after SIGTERM (below) and from damaged checkpoints
def test_kill_and_resume_matches_uninterrupted(tmp_path, translation_run):
    """SIGKILL after the first checkpoint, resume, and land on the uninterrupted run's
    parameters."""
    args = ["task=translation", "logger=none", "trainer.checkpoint_every=1", *FAST]
    killed = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-m", "nma.run", f"hydra.run.dir={killed}", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    deadline = time.time() + 300
    while not (killed / "checkpoints" / "step_0000001.msgpack").exists():
        assert time.time() < deadline and proc.poll() is None
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    nma_run(killed, *args, "trainer.resume=true")
    assert "resumed from" in (killed / "run.log").read_text()
    assert_same_params(final_params(killed), final_params(translation_run), rtol=1e-12)


def test_sigterm_checkpoints_says_so_and_resumes_to_the_uninterrupted_run(
    tmp_path, translation_run
):
    """SIGTERM (what SLURM sends before a time limit) during the first step: the run finishes that
    step, checkpoints it (checkpoint_every would not have), says so in one line, exits 143; resuming
    lands on the uninterrupted run's parameters."""
    args = ["task=translation", "logger=none", *FAST]
    stopped = tmp_path / "stopped"
    proc = subprocess.Popen(
        [sys.executable, "-m", "nma.run", f"hydra.run.dir={stopped}", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    deadline = time.time() + 300
    while not ((stopped / "run.log").exists() and "dofs" in (stopped / "run.log").read_text()):
        assert time.time() < deadline and proc.poll() is None
        time.sleep(0.02)
    # the trainer is built; its first step (compiling) takes seconds
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 143, err[-2000:]
    assert (
        "error: stopped by SIGTERM after step 1 of 2; checkpoint" in err
        and "trainer.resume=true" in err
    )
    assert [p.name for p in (stopped / "checkpoints").glob("step_*.msgpack")] == [
        "step_0000001.msgpack"
    ]
    train_in_process(stopped, *args, "trainer.resume=true")  # the resume itself, in this process
    assert_same_params(final_params(stopped), final_params(translation_run), rtol=1e-12)


@pytest.mark.parametrize(
    "change, named",
    [
        ("trainer.batch_size=4", "trainer.batch_size: 2 -> 4"),
        ("model.hidden=[8]", "model.hidden: None -> [8]"),
        ("task.box_half_width=1.0", "task.box_half_width: 1.5 -> 1.0"),
        ("trainer.inversion_penalty=0.2", "trainer.inversion_penalty: 0.1 -> 0.2"),
        ("trainer.inversion_penalty=0", "trainer.inversion_penalty: 0.1 -> 0.0"),
        # a run from before contact=auto, resumed where the scene now says on
        ("contact=on", "(it trained without contact: add contact=off)"),
    ],
)
def test_resume_with_another_config_stops_naming_the_fields(
    tmp_path, translation_run, monkeypatch, capsys, change, named
):
    from nma import run

    d = copy_run(translation_run, tmp_path / "run")
    recorded = (d / ".hydra" / "config.yaml").read_text()
    monkeypatch.setattr(
        sys,
        "argv",
        [
            "nma",
            f"hydra.run.dir={d}",
            "task=translation",
            "logger=wandb",
            *FAST,
            "trainer.resume=true",
            change,
        ],
    )
    with pytest.raises(SystemExit) as exit_:
        run.main()
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and named in err and "trainer.resume=force" in err, err
    assert (d / ".hydra" / "config.yaml").read_text() == recorded  # the run's record is untouched


def test_a_run_trained_at_the_papers_default_is_told_to_add_fidelity_paper():
    """A shape-matching run from before fidelity=scene trained at 5 x 5; resumed with today's
    default (the scene's 5 x 3 then) it stops naming the field and the override that resumes it."""
    import json

    from nma.train.checkpoint import check_fingerprint

    def fp(quad, **extra):
        return {
            "fidelity": {"ctrl_per_patch": 5, "quad_points": quad},
            "trainer": {"seed": 0},
            **extra,
        }

    with pytest.raises(
        ConfigError,
        match=r"fidelity.quad_points: 5 -> 3\) \(it trained at the paper's 5 x 5: add "
        r"fidelity=paper\)",
    ):
        check_fingerprint("c", {"config": json.dumps(fp(5))}, fp(3))
    with pytest.raises(ConfigError) as other:  # another change beside it: no hint
        check_fingerprint("c", {"config": json.dumps(fp(5))}, fp(3, trainer={"seed": 1}))
    assert "add fidelity=paper" not in str(other.value)


def test_a_run_trained_before_the_element_bound_is_told_to_add_it_off():
    """A checkpoint from before Newton's element bound was the default records no solver setting;
    resumed with today's default it stops naming the field and the override that resumes it as it
    trained."""
    import json

    from nma.train.checkpoint import check_fingerprint

    from nma.train.runs import ABSENT_MEANS

    before, today = (
        {"trainer": {"seed": 0}},
        {"trainer": {"seed": 0}, "solver": {"element_bound": True}},
    )
    with pytest.raises(
        ConfigError,
        match=r"solver.element_bound: False -> True\) \(it trained without "
        r"Newton's element bound: add solver.element_bound=false\)",
    ):
        check_fingerprint("c", {"config": json.dumps(before)}, today, ABSENT_MEANS)
    off = {"trainer": {"seed": 0}, "solver": {"element_bound": False}}
    # with it off: as it trained
    check_fingerprint("c", {"config": json.dumps(before)}, off, ABSENT_MEANS)


def test_a_run_trained_before_the_inversion_penalty_is_told_to_add_it_off():
    """A translation checkpoint from before the inversion penalty was a default and translation's
    scene stated 5 x 2 records no penalty and 5 x 5; resumed with today's defaults it stops naming
    both overrides that resume it as it trained.  A hint is given only where the hints explain every
    changed field."""
    import copy
    import json

    from conftest import compose_cfg
    from nma.train.checkpoint import check_fingerprint
    from nma.train.runs import absent_means, fingerprint, validate

    settings = validate(compose_cfg("task=translation", "logger=none"))
    today, absent = json.loads(json.dumps(fingerprint(settings))), absent_means(settings)
    assert today["trainer"]["inversion_penalty"] == 0.1 and today["fidelity"]["quad_points"] == 2
    before = copy.deepcopy(today)
    del before["trainer"]["inversion_penalty"]
    before["fidelity"]["quad_points"] = 5
    with pytest.raises(ConfigError) as both:
        check_fingerprint("c", {"config": json.dumps(before)}, today, absent)
    assert "trainer.inversion_penalty: 0.0 -> 0.1" in str(both.value)
    assert (
        "(it trained at the paper's 5 x 5: add fidelity=paper; it trained without the inversion "
        "penalty: add trainer.inversion_penalty=0)"
    ) in str(both.value)
    other_penalty = copy.deepcopy(before)
    other_penalty["trainer"].update(inversion_penalty=0.2, inversion_margin=0.2)
    for old, new in [
        (other_penalty, today),  # a penalty of its own: the 5 x 5 hint alone would not resume it
        # another change beside
        (before, {**today, "trainer": {**today["trainer"], "seed": 1}}),
    ]:
        with pytest.raises(ConfigError) as no_hint:
            check_fingerprint("c", {"config": json.dumps(old)}, new, absent)
        assert "add fidelity=paper" not in str(
            no_hint.value
        ) and "add trainer.inversion_penalty" not in str(no_hint.value)
    # before translation had an optimiser of its own
    generic = {**today, "optim": {**today["optim"], "lr": 1e-3}}
    with pytest.raises(
        ConfigError,
        match=r"optim.lr: 0.001 -> 0.01\) \(it trained with the generic optimiser: add "
        r"optim=adam\)",
    ):
        check_fingerprint(
            "c", {"config": json.dumps(generic)}, today, absent, {**today["optim"], "lr": 1e-3}
        )


def test_a_missing_setting_means_its_default_and_a_full_record_compares():
    """A checkpoint's record holds each setting where it differs from what its absence means (its
    default, or ABSENT_MEANS's value for the few whose default changed): a run recorded before a new
    setting existed resumes with no rule for it, and a record that spells out every value (as
    checkpoints did before records left defaults out) compares equal to today's."""
    import json

    from conftest import compose_cfg
    from nma.train.checkpoint import check_fingerprint, flatten
    from nma.train.runs import _shaping, absent_means, fingerprint, validate

    settings = validate(compose_cfg("task=rotation_double", "logger=none"))
    today, absent = fingerprint(settings), absent_means(settings)
    assert "max_failed_steps" not in json.dumps(today)  # not a setting that shapes the run
    full = dict(flatten(json.loads(json.dumps(_shaping(settings)))))
    assert set(dict(flatten(today))) < set(full)  # defaults left out
    check_fingerprint("c", {"config": json.dumps(full)}, today, absent)
    # from before the setting existed
    older = {k: v for k, v in full.items() if k != "optim.final_fraction"}
    check_fingerprint("c", {"config": json.dumps(older)}, today, absent)
    changed = validate(
        compose_cfg("task=rotation_double", "logger=none", "optim.final_fraction=0.2")
    )
    with pytest.raises(ConfigError, match=r"optim.final_fraction: 0.1 -> 0.2\)"):
        check_fingerprint("c", {"config": json.dumps(older)}, fingerprint(changed), absent)


@pytest.mark.parametrize("damage", [b"", b"garbage", "truncated"])
def test_corrupt_latest_checkpoint_falls_back_to_the_previous(
    tmp_path, translation_run, caplog, damage
):
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


@pytest.mark.slow  # resume is checked by the SIGTERM test, warm starts by test_solver
def test_a_run_with_warm_starts_resumes_to_the_uninterrupted_run(tmp_path):
    """Warm starts (solver.warm_start, every warm solve audited) keep equilibria between steps;
    every checkpoint drops them, so a run stopped at a checkpoint and resumed solves exactly as the
    one not stopped: the same parameters, bit for bit.  The audits' tallies, which decide whether
    warm starts stop, go into the checkpoint and come back on resume.  The final evaluation solves
    from rest."""
    import jax
    import numpy as np

    from conftest import compose_cfg
    from nma.train.runs import make_trainer, validate

    args = [
        "task=translation",
        "logger=none",
        "fidelity=fast",
        "trainer.batch_size=2",
        "trainer.progress=false",
        "trainer.animation_frames=0",
        "task.eval_grid=2",
        "trainer.eval_every=100",
        "trainer.checkpoint_every=2",
        "solver.warm_start=true",
        "solver.warm_audit=1",
    ]

    def trainer(run, steps, *more):
        return make_trainer(validate(compose_cfg(*args, f"trainer.steps={steps}", *more)), run)

    whole = trainer(tmp_path / "whole", 4)
    record = whole.fit().record
    stats = record["warm_starts"]
    assert stats["warm_solves"] >= 2 and stats["warm_converged"] == stats["warm_solves"]
    assert stats["audits"] == stats["warm_solves"]
    # the first step's two, every one after a checkpoint, the audits' and the final evaluation's 4
    assert stats["cold_solves"] >= 4 + stats["audits"] + 4
    trainer(tmp_path / "stopped", 2).fit()
    resumed = trainer(tmp_path / "stopped", 4, "trainer.resume=true")
    resumed.fit()
    leaves = lambda t: jax.tree_util.tree_leaves(t.state["params"])
    for a, b in zip(leaves(whole), leaves(resumed)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert resumed.sim.warm_starts.verdict == whole.sim.warm_starts.verdict == (stats["audits"], 0)


def under_stop_on_signals(grace: float, body: list[str]):
    """A Python process that runs `body` (lines) inside stop_on_signals(grace): (its result, its
    wall seconds)."""
    code = "\n".join(
        [
            "import os, signal, time",
            "from nma.signals import stop_on_signals",
            f"with stop_on_signals(grace={grace}):",
            *("    " + line for line in body),
        ]
    )
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    return proc, time.monotonic() - t0


def test_a_stop_signal_ends_a_step_that_never_finishes_within_its_grace():
    """SIGTERM asks a run to stop after its current step; a step that does not finish (here the main
    thread sleeps on, as a step stuck in compiled code would) is not waited for past the grace
    period: the process ends with 128 + SIGTERM and says why."""
    proc, seconds = under_stop_on_signals(
        1.0, ["os.kill(os.getpid(), signal.SIGTERM)", "time.sleep(60)"]
    )
    assert proc.returncode == 128 + signal.SIGTERM and seconds < 30, proc.stderr
    assert "SIGTERM: the current step did not finish within trainer.stop_grace = 1 s" in proc.stderr


def test_a_second_ctrl_c_ends_the_run_at_once_in_one_line():
    """A first Ctrl-C asks for a stop after the current step; a second ends the run at once (exit
    130), in a line and without a traceback, even while the step runs on (here: the main thread
    sleeps)."""
    proc, seconds = under_stop_on_signals(
        60.0,
        [
            "os.kill(os.getpid(), signal.SIGINT)",
            "time.sleep(0.5)",
            "os.kill(os.getpid(), signal.SIGINT)",
            "time.sleep(60)",
        ],
    )
    assert proc.returncode == 128 + signal.SIGINT and seconds < 30, proc.stderr
    assert proc.stderr.splitlines() == [
        "SIGINT: stopping after the current step, with a checkpoint (Ctrl-C again to interrupt at "
        "once)",
        "SIGINT: stopping now; the run resumes from its last checkpoint",
    ]
