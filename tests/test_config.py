"""One schema, one-line errors and exit codes: every bad input a user reported, from the command line.

Each case runs the command's real entry point in-process (argv patched): it must exit 2 before any
work, with one line naming the field, no traceback, and no run directory left behind."""
import math
import sys

import pytest

from nma import cli, run, simulate
from nma.errors import ConfigError
from nma.schema import Fidelity, MaterialConfig, SceneConfig, TrainerConfig, build

BAD_RUN = [
    ("trainer.batch_size=abc", "trainer.batch_size must be an integer, got 'abc'"),
    ("trainer.steps=1.5", "trainer.steps must be an integer, got '1.5'"),
    ("fidelity.ctrl_per_patch=five", "fidelity.ctrl_per_patch must be an integer, got 'five'"),
    ("material.E=abc", "material.E must be a finite number, got 'abc'"),
    ("+solver.foo=1", "solver.foo is not a known setting"),
    ("trainer.stepz=3", "trainer.stepz is not a known setting"),
    ("solver=foo", "solver=foo is unknown; choose one of ['auto', 'dense', 'pardiso', 'superlu']"),
    ("scene=translaton", "scene=translaton is unknown; choose one of"),
    ("task=juggling", "task=juggling is unknown; choose one of ['digital_mnist', 'rotation_double', 'rotation_single', 'shape_matching', 'translation']"),
    ("optim.lr=inf", "optim.lr must be a finite number in (0, inf), got inf"),
    ("optim.lr=nan", "optim.lr must be a finite number in (0, inf), got nan"),
    ("optim.lr_scale.corners=inf", "optim.lr_scale.corners must be a finite number in [0, inf)"),
    ("scene.radii_bounds=[0,1]", "scene.radii_bounds must be a list of numbers, each in (0, 1)"),
    ("scene.radii_init=0", "scene.radii_init must be a finite number in (0, 1), got 0.0"),
    ("scene.radii_init=1", "scene.radii_init must be a finite number in (0, 1), got 1.0"),
    ("fidelity.quad_points=1", "fidelity.quad_points must be an integer in [2, 10], got 1"),
    ("fidelity.ctrl_per_patch=6", "fidelity.ctrl_per_patch must be 3k + 2"),
    ("scene=rotation_double", "scene=rotation_double does not fit task=translation"),
    ("trainer.resume=maybe", "trainer.resume must be one of ['false', 'true', 'force'], got 'maybe'"),
    ("model.hidden=[30,0]", "model.hidden must be a list of numbers, each in [1, 100000]"),
    ("logger.mode=loud", "logger.mode must be one of ['offline', 'online', 'disabled'], got 'loud'"),
]
BAD_SIMULATE = [
    ("actuation=1.0", "actuation must be a list such as [1.0, 2.0], got a single float"),
    ("actuation=[1.0]", "actuation must have 2 entries for scene translation, got 1: [1.0]"),
    ("actuation=[1.0,nan]", "actuation must be finite numbers"),
    ("material.nu=0.5", "material.nu must be a finite number in (-1, 0.5), got 0.5"),
    ("solver.linear=cholesky", "solver.linear must be one of ['auto', 'dense', 'pardiso', 'superlu'], got 'cholesky'"),
    ("scene.corner_box=2.5", "scene.corner_box must be < half the smallest cell (2.5), got 2.5"),
]


def call(main, argv, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["nma", *argv])
    with pytest.raises(SystemExit) as exit_:
        main()
    return exit_.value.code, capsys.readouterr().err


@pytest.mark.parametrize("override, message", BAD_RUN)
def test_training_bad_input_exits_2_with_one_line(tmp_path, monkeypatch, capsys, override, message):
    code, err = call(run.main, [override, f"hydra.run.dir={tmp_path / 'run'}"], monkeypatch, capsys)
    assert code == 2
    assert err.strip().splitlines() == [f"error: {err.strip()[7:]}"] and message in err, err
    assert "Traceback" not in err and not (tmp_path / "run").exists()


@pytest.mark.parametrize("override, message", BAD_SIMULATE)
def test_simulate_bad_input_exits_2_with_one_line(tmp_path, monkeypatch, capsys, override, message):
    code, err = call(simulate.main, [override, f"hydra.run.dir={tmp_path / 'run'}"], monkeypatch, capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and message in err, err
    assert not (tmp_path / "run").exists()


def test_every_job_of_a_sweep_is_checked_first(tmp_path, monkeypatch, capsys):
    argv = ["--multirun", "trainer.seed=0,1", "trainer.batch_size=2,abc", f"hydra.sweep.dir={tmp_path / 'sweep'}"]
    code, err = call(run.main, argv, monkeypatch, capsys)
    assert code == 2 and "trainer.batch_size must be an integer, got 'abc'" in err
    assert not (tmp_path / "sweep").exists()
    assert cli.job_overrides(["a=1,2", "b=x", "c=3,4"], True) == [
        ["a=1", "b=x", "c=3"], ["a=1", "b=x", "c=4"], ["a=2", "b=x", "c=3"], ["a=2", "b=x", "c=4"]]


def test_internal_errors_are_not_dressed_as_bad_input():
    """Only ConfigError means bad input; any other error keeps its type (and Hydra its traceback)."""
    with pytest.raises(KeyError):
        with cli.exit_codes():
            raise KeyError("an internal bug")
    with pytest.raises(ValueError):
        with cli.exit_codes():
            raise ValueError("msgpack: unpack failed")
    with pytest.raises(SystemExit) as exit_:
        with cli.exit_codes():
            raise ConfigError("trainer.steps must be ...")
    assert exit_.value.code == 2


def test_schema_checks_python_construction_too():
    """The dataclasses are the one source of defaults and ranges, however a config is made."""
    assert Fidelity() == Fidelity(5, 5) and MaterialConfig().E == 0.07
    with pytest.raises(ConfigError, match=r"fidelity.quad_points must be an integer in \[2, 10\], got 1"):
        Fidelity(5, 1)
    with pytest.raises(ConfigError, match="fidelity.ctrl_per_patch must be an integer, got 5.0"):
        Fidelity(5.0, 3)
    with pytest.raises(ConfigError, match="material.E must be a finite number in"):
        MaterialConfig(E=math.inf)
    assert TrainerConfig(resume=True).resume == "true"  # Hydra parses `trainer.resume=true` as a bool
    with pytest.raises(ConfigError, match="scene.pinned\\[0\\] must be a pair"):
        build(SceneConfig, {"name": "x", "cells": "PP", "pinned": [[0, 0, 0]]})
    with pytest.raises(ConfigError, match="scene.groups actuation indices must be 0..1 without gaps"):
        build(SceneConfig, {"name": "x", "cells": "PP", "groups": [
            {"name": "a", "segment": [[0, 1], [0, 4]], "actuation": 1, "direction": [1, 0]}]})
