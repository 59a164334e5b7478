"""One schema, one-line errors and exit codes: every bad input a user reported, from the command
line.

Each case runs the command's real entry point in-process (argv patched): it must exit 2 before any
work, with one line naming the field, no traceback, and no run directory left behind."""

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from conftest import compose_cfg
from nma import cli, config, export, run, simulate
from nma.errors import ConfigError, Stopped
from nma.schema import (
    ContactConfig,
    ExportConfig,
    Fidelity,
    MaterialConfig,
    SceneConfig,
    TrainerConfig,
    build,
)
from nma.train.runs import validate

BAD_RUN = [
    ("trainer.batch_size=abc", "trainer.batch_size must be an integer, got 'abc'"),
    ("trainer.steps=1.5", "trainer.steps must be an integer, got '1.5'"),
    ("fidelity.ctrl_per_patch=five", "fidelity.ctrl_per_patch must be an integer, got 'five'"),
    ("material.E=abc", "material.E must be a finite number, got 'abc'"),
    (
        "material.formulation=fbar",
        "material.formulation must be one of ['auto', 'displacement', 'mixed'], got 'fbar'",
    ),
    ("+solver.foo=1", "solver.foo is not a known setting"),
    ("trainer.stepz=3", "trainer.stepz is not a known setting"),
    ("solver=foo", "solver=foo is unknown; choose one of ['auto', 'dense', 'pardiso', 'superlu']"),
    ("scene=translaton", "scene=translaton is unknown; choose one of"),
    (
        "task=juggling",
        "task=juggling is unknown; choose one of ['digital_mnist', 'energy_focus', 'follow_path', "
        "'periodic_poisson', 'periodic_poisson_amortised', 'rotation_double',",
    ),
    (
        "solver=dense solver.warm_start=true",
        "solver.warm_start needs a host linear solver (pardiso, superlu)",
    ),
    (
        "task=follow_path scene=translation dynamics=off",
        "task follow_path moves in time: choose dynamics=newmark",
    ),
    ("task=translation dynamics=newmark", "dynamics.scheme=newmark: task translation is static"),
    (
        "task=follow_path scene=translation task.window=[20,500]",
        "task.window [20, 500] ends after the run's last time step",
    ),
    (
        "task=energy_focus scene=translation task.region=[25,0,0,25]",
        "task.region must be [x0, y0, x1, y1] with x0 < x1",
    ),
    (
        "dynamics.damping_ratio=0.1 dynamics.alpha=0.01",
        "dynamics.damping_ratio replaces alpha and beta",
    ),
    ("optim.lr=inf", "optim.lr must be a finite number in (0, inf), got inf"),
    ("optim.lr=nan", "optim.lr must be a finite number in (0, inf), got nan"),
    ("optim.lr_scale.corners=inf", "optim.lr_scale.corners must be a finite number in [0, inf)"),
    ("scene.radii_bounds=[0,1]", "scene.radii_bounds must be a list of numbers, each in (0, 1)"),
    ("scene.radii_init=0", "scene.radii_init must be a finite number in (0, 1), got 0.0"),
    ("scene.radii_init=1", "scene.radii_init must be a finite number in (0, 1), got 1.0"),
    ("fidelity.quad_points=1", "fidelity.quad_points must be an integer in [2, 10], got 1"),
    ("fidelity.grading=0.5", "fidelity.grading must be a finite number in [1, 4], got 0.5"),
    (
        "fidelity=auto fidelity.ctrl_per_patch=8 fidelity.grading=2",
        "fidelity.grading=2 with fidelity=auto",
    ),
    ("fidelity.grading=2", "fidelity.grading=2 changes nothing at 5 control points per patch"),
    ("fidelity.ctrl_per_patch=6", "fidelity.ctrl_per_patch must be 3k + 2"),
    ("scene=rotation_double", "scene=rotation_double does not fit task=translation"),
    (
        "trainer.resume=maybe",
        "trainer.resume must be one of ['false', 'true', 'force'], got 'maybe'",
    ),
    ("model.hidden=[30,0]", "model.hidden must be a list of numbers, each in [1, 100000]"),
    (
        "logger.mode=loud",
        "logger.mode must be one of ['offline', 'online', 'disabled'], got 'loud'",
    ),
    ("scene.pinned=[1,2", "the command-line override 'scene.pinned=[1,2' does not parse"),
    # a discretisation far beyond any machine's memory (the element tangents alone: ~700 GiB)
    (
        "fidelity.ctrl_per_patch=998 fidelity.quad_points=5",
        "fidelity.ctrl_per_patch=998 with 5 Gauss points needs at least",
    ),
    ("trainer.init_from=/nonexistent/run", "trainer.init_from=/nonexistent/run is not a directory"),
    # a task posed in YAML (nma.tasks.spec): every mistake names the field
    (
        "task=translation_spec scene=translation task.goal=spin",
        "task.goal must be one of ['move', 'rotate', 'distance', 'pore_area', 'force']",
    ),
    (
        "task=translation_spec scene=translation task.points=[nowhere]",
        "task.points names ['nowhere'], which scene translation does not track; its tracked "
        "points are ['pointer']",
    ),
    (
        "task=translation_spec scene=translation task.goal=rotate",
        "task.points must name 2 tracked points for goal rotate",
    ),
    (
        "task=translation_spec scene=translation task.low=[0]",
        "task.low must have 2 values for goal move",
    ),
    (
        "task=translation_spec scene=translation task.high=[-2,2]",
        "task.high must exceed task.low [-1.5, -1.5]",
    ),
    (
        "task=rotation_single_spec scene=rotation_single task.high=[4]",
        "task.high holds angles in radians, within [-pi, pi]",
    ),
    (
        "task=strip_pore scene=strip task.low=[0] task.high=[1]",
        "task.low and task.high (a box), task.cases or task.dataset: give exactly one of them, "
        "got ['low', 'cases', 'high']",
    ),
    (
        "task=strip_pore scene=strip task.pore=[0,9]",
        "task.pore [0, 9] is not a porous cell of scene strip (a grid of 4 columns and 6 rows",
    ),
    (
        "task=strip_pore scene=strip task.pore=null",
        "task.pore must name a porous cell [column, row] for goal pore_area",
    ),
    (
        "task=strip_pore scene=strip task.points=[top_left]",
        "task.points must be empty for goal pore_area",
    ),
    (
        "task=strip_pore scene=strip task.cases.open=[-1.5]",
        "task.cases.open holds relative changes of the pore's area, each above -1",
    ),
    (
        "task=strip_pore scene=strip task.cases.open=[0.1,0.2]",
        "task.cases.open must have 1 value for goal pore_area",
    ),
    (
        "task=strip_spread scene=strip task.goal=force task.points=[]",
        "task.group must name an actuated group of the scene for goal force",
    ),
    (
        "task=strip_spread scene=strip task.goal=force task.points=[] task.group=middle",
        "task.group 'middle' is not an actuated group of scene strip; its groups are ['left', "
        "'right']",
    ),
    (
        "task=translation_spec scene=translation task.loss=l3",
        "task.loss must be one of ['l1', 'l2']",
    ),
    (
        "task=translation_spec scene=translation task.low=[-1.5,nan]",
        "task.low must hold finite numbers only",
    ),
    (
        "task=strip_pore scene=strip task.cases={open:[0.2],shut:[inf]}",
        "task.cases must hold finite numbers only",
    ),
    (
        "scene.groups.0.direction=[1,nan]",
        "scene.groups.direction must hold finite numbers only, got [1.0, nan]",
    ),
    ("scene.x_breaks=[0,5,nan,15,20,25]", "scene.x_breaks must hold finite numbers only"),
    (
        "task=translation_spec scene=translation +scene.tracked.twin=[12.5,12.5] "
        "task.points=[pointer,twin] "
        "task.goal=distance task.low=[-1] task.high=[1]",
        "task.points ['pointer', 'twin'] are one place in scene translation ([12.5, 12.5]): goal "
        "distance needs two",
    ),
    (
        "task=strip_spread scene=strip task.low=[-25]",
        "task.low asks for a distance change of -25, but top_left, "
        "top_right are 20 apart at rest: each change must be above -20",
    ),
    (
        "hydra.searchpath=[file:///nonexistent/conf]",
        "hydra.searchpath names /nonexistent/conf, which is not a directory",
    ),
    (
        "task=digital_mnist task.phase=finetune",
        "optim.lr must be in (0, 0.01] for task.phase=finetune, which trains "
        "a network, got 0.3 (task=digital_mnist's rate is the lookup table's)",
    ),
    (
        "task=translation_spec",
        "task=translation_spec names no scene of its own name (scene=translation_spec is "
        "unknown): give its scene, scene=translation",
    ),
    (
        "task=energy_focus",
        "task=energy_focus names no scene of its own name (scene=energy_focus is "
        "unknown): give its scene, scene=translation",
    ),
]
BAD_SIMULATE = [
    ("actuation=1.0", "actuation must be a list such as [1.0, 2.0], got a single float"),
    ("actuation=[1.0]", "actuation must have 2 entries for scene translation, got 1: [1.0]"),
    ("actuation=[1.0,nan]", "actuation must be finite numbers"),
    ("material.nu=0.5", "material.nu must be a finite number in (-1, 0.5), got 0.5"),
    ("material.E=1e300", "material.E must be a finite number in [1e-30, 1e30], got 1e+300"),
    ("scene.groups.0.direction=[0,0]", "scene.groups.direction of group left must not be [0, 0]"),
    ("scene.pinned=[[0,0]] scene.groups=[]", "nothing stops it rotating about (0, 0)"),
    (
        "solver.linear=cholesky",
        "solver.linear must be one of ['auto', 'dense', 'pardiso', 'superlu'], got 'cholesky'",
    ),
    (
        "solver.corrector=dogleg",
        "solver.corrector must be one of ['auto', 'line_search', 'trust_region'], got 'dogleg'",
    ),
    ("scene.corner_box=2.5", "scene.corner_box must be < half the smallest cell (2.5), got 2.5"),
]


def call(main, argv, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["nma", *argv])
    with pytest.raises(SystemExit) as exit_:
        main()
    return exit_.value.code, capsys.readouterr().err


def test_every_job_of_a_sweep_is_checked_and_each_has_its_own_directory(
    tmp_path, monkeypatch, capsys
):
    """However many jobs a sweep has, each is composed and checked before any runs
    (cli.job_overrides lists them all); two jobs that would write one directory are refused before
    either runs."""
    assert len(cli.job_overrides(["trainer.seed=range(0,300)", "trainer.steps=1,2"], True)) == 600
    code, err = call(
        run.main,
        [
            "--multirun",
            "trainer.seed=0,1",
            f"hydra.sweep.dir={tmp_path / 'sweep'}",
            "hydra.sweep.subdir=same",
            "logger=none",
        ],
        monkeypatch,
        capsys,
    )
    assert (
        code == 2
        and "hydra.sweep.subdir=same is the directory of job 0 and of job 1: each job needs" in err
    ), err
    assert not (tmp_path / "sweep").exists()


def test_a_config_of_ones_own_named_as_a_shipped_one_is_refused(tmp_path, monkeypatch, capsys):
    """A file in --config-dir named as one nma ships would be shadowed by the shipped one (Hydra
    reads conf/ first): refused before any work, naming it."""
    (tmp_path / "mine" / "task").mkdir(parents=True)
    (tmp_path / "mine" / "task" / "strip_spread.yaml").write_text(
        "defaults: [spec_schema, _self_]\nname: strip\n"
    )
    code, err = call(
        run.main,
        [
            "--config-dir",
            str(tmp_path / "mine"),
            "task=strip_spread",
            "scene=strip",
            f"hydra.run.dir={tmp_path / 'run'}",
        ],
        monkeypatch,
        capsys,
    )
    assert (
        code == 2 and "task/strip_spread.yaml has the name of a config nma ships (conf/)" in err
    ), err


def test_a_misspelt_schema_in_a_config_file_is_named_with_the_schemas_there_are(
    tmp_path, monkeypatch, capsys
):
    (tmp_path / "mine" / "task").mkdir(parents=True)
    (tmp_path / "mine" / "task" / "mine.yaml").write_text(
        "defaults:\n  - translaton_schema\n  - _self_\n"
    )
    code, err = call(
        run.main,
        [
            "--config-dir",
            str(tmp_path / "mine"),
            "task=mine",
            "scene=translation",
            f"hydra.run.dir={tmp_path / 'run'}",
        ],
        monkeypatch,
        capsys,
    )
    assert (
        code == 2
        and (
            "the schema translaton_schema in a task file's defaults list is unknown; choose one of "
            "['digital_mnist_schema',"
        )
        in err
        and "'translation_schema'" in err
    ), err


def test_a_misspelt_schema_name_and_a_shadowing_search_path_are_refused(
    tmp_path, monkeypatch, capsys
):
    """A defaults entry that misspells a schema without its _schema ending (spec_shema) is named
    with the schemas there are; a hydra.searchpath directory holding a shipped config's name is
    refused as --config-dir's is (Hydra would read the shipped one)."""
    (tmp_path / "mine" / "task").mkdir(parents=True)
    (tmp_path / "mine" / "task" / "mine.yaml").write_text("defaults:\n  - spec_shema\n  - _self_\n")
    code, err = call(
        run.main,
        [
            "--config-dir",
            str(tmp_path / "mine"),
            "task=mine",
            "scene=strip",
            f"hydra.run.dir={tmp_path / 'run'}",
        ],
        monkeypatch,
        capsys,
    )
    assert (
        code == 2
        and "the schema spec_shema in a task file's defaults list is unknown; choose one of" in err
    ), err
    (tmp_path / "path" / "task").mkdir(parents=True)
    (tmp_path / "path" / "task" / "strip_spread.yaml").write_text(
        "defaults: [spec_schema, _self_]\nname: strip\n"
    )
    code, err = call(
        run.main,
        [
            f"hydra.searchpath=[file://{tmp_path / 'path'}]",
            "task=strip_spread",
            "scene=strip",
            f"hydra.run.dir={tmp_path / 'run2'}",
        ],
        monkeypatch,
        capsys,
    )
    assert (
        code == 2 and "task/strip_spread.yaml has the name of a config nma ships (conf/)" in err
    ), err


def test_a_run_never_takes_another_commands_directory(tmp_path):
    """nma.run pointed at nma.simulate's output would replace its record (.hydra/config.yaml):
    refused."""
    from nma.train.runs import check_run_dir

    (tmp_path / "sim" / ".hydra").mkdir(parents=True)
    (tmp_path / "sim" / ".hydra" / "config.yaml").write_text(
        "scene: {name: translation}\nactuation: [1.0, 0.0]\n"
    )
    with pytest.raises(ConfigError, match="holds another command's output"):
        check_run_dir(tmp_path / "sim", "false")


def test_two_commands_in_one_second_get_a_dated_directory_each(tmp_path, monkeypatch):
    """The dated default directory that holds files already (a command started in the same second)
    is not shared: the next free <dir>_2 is taken, and named on the command line so that Hydra
    writes there."""
    import argparse

    from nma.cli.preflight import hold_dated_dir

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("sys.argv", ["nma.simulate"])
    args = argparse.Namespace(config_dir=None, config_path=None)
    cfg = cli.compose("simulate", [])
    taken = Path(cfg.hydra.run.dir)
    taken.mkdir(parents=True)
    (taken / "result.json").write_text("{}")
    cfg = hold_dated_dir(cfg, [], "simulate", args)
    assert Path(cfg.hydra.run.dir) == taken.with_name(taken.name + "_2")
    assert sys.argv[-1] == f"hydra.run.dir={taken.with_name(taken.name + '_2')}"
    assert (
        hold_dated_dir(
            cli.compose("simulate", ["hydra.run.dir=mine"]),
            ["hydra.run.dir=mine"],
            "simulate",
            args,
        )
        is None
    )  # a directory the user named is theirs


def test_simulate_never_writes_into_a_directory_that_holds_files(tmp_path, monkeypatch, capsys):
    """nma.simulate pointed at a training run's directory (or an earlier solve's) would replace its
    .hydra/config.yaml and fields: refused before any work."""
    (tmp_path / "run" / ".hydra").mkdir(parents=True)
    (tmp_path / "run" / ".hydra" / "config.yaml").write_text("task: {name: translation}\n")
    code, err = call(simulate.main, [f"hydra.run.dir={tmp_path / 'run'}"], monkeypatch, capsys)
    assert code == 2 and "holds files already: nma.simulate writes a directory of its own" in err, (
        err
    )
    assert (
        tmp_path / "run" / ".hydra" / "config.yaml"
    ).read_text() == "task: {name: translation}\n"


def test_a_result_never_replaces_an_earlier_one(tmp_path):
    """cli.unused_path: the name asked for where it is free, else the first free <stem>_<n> beside
    it."""
    first = tmp_path / "5x5_contact.json"
    assert cli.unused_path(first) == first
    first.write_text("{}")
    assert cli.unused_path(first) == tmp_path / "5x5_contact_2.json"
    (tmp_path / "5x5_contact_2.json").write_text("{}")
    assert cli.unused_path(first) == tmp_path / "5x5_contact_3.json"


def test_a_config_path_of_ones_own_gets_the_checks_before_work(tmp_path, monkeypatch, capsys):
    """--config-path (a primary config directory in place of conf/) is composed and checked before
    any work, as the shipped one is; one that is not a directory is named."""
    import shutil

    shutil.copytree(config.CONF_DIR, tmp_path / "conf")
    code, err = call(
        run.main,
        [
            "--config-path",
            str(tmp_path / "conf"),
            "trainer.steps=1.5",
            f"hydra.run.dir={tmp_path / 'run'}",
        ],
        monkeypatch,
        capsys,
    )
    assert code == 2 and "trainer.steps must be an integer, got '1.5'" in err, err
    code, err = call(run.main, ["--config-path", str(tmp_path / "nowhere")], monkeypatch, capsys)
    assert code == 2 and f"--config-path {tmp_path / 'nowhere'} is not a directory" in err, err
    assert not (tmp_path / "run").exists()


def test_a_run_directory_another_process_writes_is_refused_and_kept(tmp_path, monkeypatch, capsys):
    """Two runs never write one directory: while another process holds its lock (as a run does from
    its checks to its end), a run there exits 2 naming that process, and leaves the directory as it
    was; once that process has ended, the directory can be held again."""
    from conftest import HeldElsewhere

    run_dir = tmp_path / "run"
    with HeldElsewhere(run_dir):
        code, err = call(
            run.main,
            ["task=translation", "logger=none", f"hydra.run.dir={run_dir}"],
            monkeypatch,
            capsys,
        )
        assert (
            code == 2
            and f"hydra.run.dir={run_dir} is in use by process 4242 on elsewhere: two runs" in err
        ), err
        # nothing written, nothing removed
        assert [p.name for p in run_dir.iterdir()] == [cli.RUN_LOCK]
    cli.hold_run_dir(run_dir)  # the lock went with its process
    assert f"process {os.getpid()} on " in (run_dir / cli.RUN_LOCK).read_text()


@pytest.mark.parametrize("override, message", BAD_RUN)
def test_training_bad_input_exits_2_with_one_line(tmp_path, monkeypatch, capsys, override, message):
    code, err = call(
        run.main, [*override.split(" "), f"hydra.run.dir={tmp_path / 'run'}"], monkeypatch, capsys
    )
    assert code == 2
    assert err.strip().splitlines() == [f"error: {err.strip()[7:]}"] and message in err, err
    assert "Traceback" not in err and not (tmp_path / "run").exists()


@pytest.mark.parametrize("override, message", BAD_SIMULATE)
def test_simulate_bad_input_exits_2_with_one_line(tmp_path, monkeypatch, capsys, override, message):
    code, err = call(
        simulate.main,
        [*override.split(" "), f"hydra.run.dir={tmp_path / 'run'}"],
        monkeypatch,
        capsys,
    )
    assert code == 2 and len(err.strip().splitlines()) == 1 and message in err, err
    assert not (tmp_path / "run").exists()


def test_every_job_of_a_sweep_is_checked_first(tmp_path, monkeypatch, capsys):
    """Every bad job of a sweep is reported at once (each message once, with a job it holds for),
    and none has run."""
    argv = [
        "--multirun",
        "trainer.seed=0,1",
        "trainer.batch_size=2,abc,xyz",
        f"hydra.sweep.dir={tmp_path / 'sweep'}",
    ]
    code, err = call(run.main, argv, monkeypatch, capsys)
    assert code == 2 and err.strip().splitlines() == [
        "error: trainer.batch_size must be an integer, got 'abc' (in 2 of 6 jobs, e.g. "
        "trainer.seed=0 "
        "trainer.batch_size=abc)",
        "error: trainer.batch_size must be an integer, got 'xyz' (in 2 of 6 jobs, e.g. "
        "trainer.seed=0 "
        "trainer.batch_size=xyz)",
    ], err
    assert not (tmp_path / "sweep").exists()
    # what only the discretisation finds (a tracked point in a pore) is found for every job up front
    # too
    argv = [
        "--multirun",
        "fidelity=fast",
        "scene.tracked.pointer=[12.5,12.5],[2.5,2.5],[7.5,7.5]",
        f"hydra.sweep.dir={tmp_path / 'sweep'}",
    ]
    code, err = call(run.main, argv, monkeypatch, capsys)
    assert code == 2 and err.strip().splitlines() == [
        f"error: scene translation: tracked point pointer at ({p}, {p}) lies in no patch (in 1 of "
        f"3 jobs, e.g. scene.tracked.pointer=[{p},{p}])"
        for p in ("2.5", "7.5")
    ], err
    assert not (tmp_path / "sweep").exists()
    assert cli.job_overrides(["a=1,2", "b=x", "c=3,4"], True) == [
        ["a=1", "b=x", "c=3"],
        ["a=1", "b=x", "c=4"],
        ["a=2", "b=x", "c=3"],
        ["a=2", "b=x", "c=4"],
    ]


def test_a_sweep_job_never_starts_over_another(tmp_path, monkeypatch, capsys):
    """A sweep's job directories (hydra.sweep.dir/<job number>) are checked like a single run's: a
    job whose directory holds a run is refused before Hydra records anything there, and nothing is
    touched."""
    sweep = tmp_path / "sweep"
    old = fake_run(sweep / "1")
    before = {p: p.read_bytes() for p in old.rglob("*") if p.is_file()}
    argv = ["--multirun", "trainer.seed=0,1", "trainer.steps=1", f"hydra.sweep.dir={sweep}"]
    code, err = call(run.main, argv, monkeypatch, capsys)
    assert code == 2 and f"a sweep job's directory={old} holds a run already" in err, err
    assert "(in 1 of 2 jobs, e.g. trainer.seed=1)" in err
    assert {p: p.read_bytes() for p in old.rglob("*") if p.is_file()} == before and not (
        sweep / "0"
    ).exists()


def test_config_dir_is_checked_up_front(tmp_path, monkeypatch, capsys):
    """--config-dir adds configs; they are composed and checked before any work like conf/'s own."""
    (tmp_path / "conf" / "trainer").mkdir(parents=True)
    (tmp_path / "conf" / "trainer" / "broken.yaml").write_text("steps: -3\n")
    argv = [
        "--config-dir",
        str(tmp_path / "conf"),
        "trainer=broken",
        f"hydra.run.dir={tmp_path / 'run'}",
    ]
    code, err = call(run.main, argv, monkeypatch, capsys)
    assert code == 2 and "trainer.steps must be an integer in [1, 10000000], got -3" in err, err
    assert not (tmp_path / "run").exists()
    code, err = call(
        run.main,
        ["--config-dir", str(tmp_path / "none"), f"hydra.run.dir={tmp_path / 'run'}"],
        monkeypatch,
        capsys,
    )
    assert code == 2 and f"--config-dir {tmp_path / 'none'} is not a directory" in err, err


def test_internal_errors_are_not_dressed_as_bad_input():
    """Only ConfigError means bad input; any other error keeps its type (and Hydra its
    traceback)."""
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
    with pytest.raises(
        ConfigError, match=r"fidelity.quad_points must be an integer in \[2, 10\], got 1"
    ):
        Fidelity(5, 1)
    with pytest.raises(ConfigError, match="fidelity.ctrl_per_patch must be an integer, got 5.0"):
        Fidelity(5.0, 3)
    with pytest.raises(ConfigError, match="material.E must be a finite number in"):
        MaterialConfig(E=math.inf)
    # Hydra parses `trainer.resume=true` as a bool
    assert TrainerConfig(resume=True).resume == "true"
    with pytest.raises(ConfigError, match="scene.pinned\\[0\\] must be a pair"):
        build(SceneConfig, {"name": "x", "cells": "PP", "pinned": [[0, 0, 0]]})
    with pytest.raises(
        ConfigError, match="scene.groups actuation indices must be 0..1 without gaps"
    ):
        build(
            SceneConfig,
            {
                "name": "x",
                "cells": "PP",
                "groups": [
                    {"name": "a", "segment": [[0, 1], [0, 4]], "actuation": 1, "direction": [1, 0]}
                ],
            },
        )


def fake_run(directory, scene="translation"):
    """A run directory as nma.run leaves it, as far as the up-front checks read it."""
    (directory / ".hydra").mkdir(parents=True)
    (directory / ".hydra" / "config.yaml").write_text(
        f"task:\n  name: {scene}\nscene:\n  name: {scene}\n"
    )
    (directory / "checkpoints").mkdir()
    (directory / "checkpoints" / "step_0000002.msgpack").write_bytes(b"")
    (directory / "metrics.json").write_text("{}")
    return directory


def test_a_new_run_never_starts_over_another(tmp_path, monkeypatch, capsys):
    """One run per directory: a new run in a directory holding one is refused and the old run is
    left as it was; a file where the run directory belongs is refused too."""
    old = fake_run(tmp_path / "old")
    before = {p: p.read_bytes() for p in old.rglob("*") if p.is_file()}
    code, err = call(run.main, ["trainer.steps=1", f"hydra.run.dir={old}"], monkeypatch, capsys)
    assert (
        code == 2 and f"hydra.run.dir={old} holds a run already (checkpoints, metrics.json)" in err
    ), err
    assert (
        "trainer.resume=true" in err
        and {p: p.read_bytes() for p in old.rglob("*") if p.is_file()} == before
    )
    (tmp_path / "file").write_text("x")
    code, err = call(run.main, [f"hydra.run.dir={tmp_path / 'file'}"], monkeypatch, capsys)
    assert code == 2 and "is an existing file, not a directory" in err


@pytest.mark.skipif(
    os.geteuid() == 0, reason="root writes anywhere: no read-only directory to test with"
)
def test_a_run_directory_that_cannot_be_written_is_refused_up_front(tmp_path, monkeypatch, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        code, err = call(simulate.main, [f"hydra.run.dir={locked / 'run'}"], monkeypatch, capsys)
    finally:
        locked.chmod(0o700)
    assert code == 3 and "cannot be written" in err and not (locked / "run").exists()


@pytest.mark.skipif(
    not os.path.isdir("/proc/self"), reason="needs Linux's /proc, where no one creates a directory"
)
def test_a_run_directory_the_system_refuses_is_exit_3_and_one_line(tmp_path, monkeypatch, capsys):
    """Permission bits do not answer for root or special file systems: the directory is made (and
    removed) up front.  A path below a file is the user's mistake: exit 2."""
    code, err = call(run.main, ["hydra.run.dir=/proc/nma-run"], monkeypatch, capsys)
    assert code == 3 and err.strip().splitlines() == [
        "error: hydra.run.dir=/proc/nma-run cannot be created: No such file or directory"
    ], err
    (tmp_path / "file").write_text("x")
    code, err = call(run.main, [f"hydra.run.dir={tmp_path / 'file' / 'run'}"], monkeypatch, capsys)
    assert (
        code == 2 and f"lies below {tmp_path / 'file'}, which is a file, not a directory" in err
    ), err
    code, err = call(
        run.main,
        [f"hydra.run.dir={tmp_path / 'new' / 'run'}", "trainer.steps=abc"],
        monkeypatch,
        capsys,
    )
    assert code == 2 and not (tmp_path / "new").exists()  # the check's directories are gone again


def test_a_finished_run_without_checkpoints_is_not_started_again(tmp_path, monkeypatch, capsys):
    old = fake_run(tmp_path / "old")
    for p in (old / "checkpoints").iterdir():
        p.unlink()
    code, err = call(run.main, ["trainer.resume=true", f"hydra.run.dir={old}"], monkeypatch, capsys)
    assert code == 2 and "holds a run's metrics.json but no checkpoint to continue from" in err, err
    code, err = call(run.main, [f"hydra.run.dir={old}"], monkeypatch, capsys)
    assert code == 2 and "(metrics.json)" in err and "trainer.resume=true" not in err, err


def test_an_unknown_key_in_a_config_dir_file_is_named(tmp_path, monkeypatch, capsys):
    (tmp_path / "trainer").mkdir()
    (tmp_path / "trainer" / "bad.yaml").write_text("defaults:\n  - default\nstepz: 3\n")
    code, err = call(
        run.main,
        ["--config-dir", str(tmp_path), "trainer=bad", f"hydra.run.dir={tmp_path / 'run'}"],
        monkeypatch,
        capsys,
    )
    assert code == 2 and err.strip() == (
        "error: trainer.stepz is not a known setting (Key 'stepz' not in "
        "'TrainerConfig') (in the config file trainer/bad.yaml)"
    ), err


def test_init_from_a_run_of_another_scene_is_refused(tmp_path, monkeypatch, capsys):
    other = fake_run(tmp_path / "other", scene="rotation_double")
    code, err = call(
        run.main,
        [f"trainer.init_from={other}", f"hydra.run.dir={tmp_path / 'run'}"],
        monkeypatch,
        capsys,
    )
    assert (
        code == 2 and "is a run on scene rotation_double; this run's scene is translation" in err
    ), err
    assert not (tmp_path / "run").exists()


def test_bad_input_found_after_start_up_leaves_no_run_directory(tmp_path):
    """A scene error only the discretisation finds (a tracked point in no patch) is still exit 2
    with one line, and the run directory Hydra created for it goes again.  (A subprocess: inside the
    task function Hydra sets up logging on the test's captured stderr.)"""
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "nma.simulate",
            "scene.tracked.pointer=[2.5,2.5]",  # a pore's centre
            f"hydra.run.dir={tmp_path / 'run'}",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    assert proc.returncode == 2 and lines == [
        "error: scene translation: tracked point pointer at (2.5, 2.5) lies in no patch"
    ], proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "run").exists()


def test_export_follows_the_output_extension_and_refuses_a_contradiction(
    tmp_path, monkeypatch, capsys
):
    assert build(ExportConfig, {"run": "r", "output": "part.dxf"}).format == "dxf"
    assert build(ExportConfig, {"run": "r", "output": "part.STL"}).format == "stl"
    assert build(ExportConfig, {"run": "r"}).format == "svg"
    with pytest.raises(ConfigError, match="format is svg but output=part.dxf names a .dxf file"):
        build(ExportConfig, {"run": "r", "output": "part.dxf", "format": "svg"})
    with pytest.raises(ConfigError, match="output needs format="):
        build(ExportConfig, {"run": "r", "output": "part.txt"})
    code, err = call(
        export.main, [f"run={tmp_path}", f"output={tmp_path}", "format=svg"], monkeypatch, capsys
    )
    assert (
        code == 2
        and "output is a directory; name the file to write" in err
        and str(tmp_path) in err
    )
    # below a micron the geometry libraries round the part away
    for field in ("scale", "thickness"):
        with pytest.raises(ConfigError, match=f"{field} must be a finite number in \\[0.001, "):
            build(ExportConfig, {"run": "r", field: 1e-12})


@pytest.mark.parametrize(
    "raised, code, line",
    [
        (
            PermissionError(13, "Permission denied", "/runs/x/metrics.json"),
            3,
            "error: Permission denied: /runs/x/metrics.json",
        ),
        (KeyboardInterrupt(), 130, "error: interrupted (Ctrl-C)"),
        (
            RuntimeError("INTERNAL: CpuCallback error: KeyboardInterrupt"),
            130,
            "error: interrupted (Ctrl-C)",
        ),
        (
            MemoryError(),
            3,
            "error: out of memory: ask for a coarser fidelity (fidelity.ctrl_per_patch, "
            "fidelity.quad_points), a smaller batch, or a machine with more memory",
        ),
        (
            Stopped("stopped by SIGTERM after step 3 of 10; checkpoint c saved", 15),
            143,
            "error: stopped by SIGTERM after step 3 of 10; checkpoint c saved",
        ),
    ],
)
def test_the_users_situation_is_one_line_and_a_documented_exit_code(capsys, raised, code, line):
    with pytest.raises(SystemExit) as exit_:
        with cli.exit_codes():
            raise raised
    assert exit_.value.code == code and capsys.readouterr().err.strip().splitlines() == [line]


def test_a_solve_that_took_no_step_says_so_instead_of_a_zero_residual():
    import numpy as np

    from nma.solver.status import NewtonInfo, Status, failure

    info = NewtonInfo(
        *(np.asarray(v) for v in (Status.INCREMENT_TOO_SMALL, 12, 0, 14, 0.0, 0.0, 1e-12, [0.0]))
    )
    message = str(failure(info))
    assert (
        "last residual" not in message and "no load increment beyond it could be taken" in message
    )


def test_commands_are_console_scripts():
    """The commands are installed as console scripts beside `python -m nma.<command>`."""
    from importlib.metadata import entry_points

    scripts = {
        e.name: e.value for e in entry_points(group="console_scripts") if e.name.startswith("nma-")
    }
    assert scripts == {
        "nma-run": "nma.run:main",
        "nma-simulate": "nma.simulate:main",
        "nma-fit": "nma.fit:main",
        "nma-evaluate": "nma.evaluate:main",
        "nma-export": "nma.export:main",
    }
    assert all(
        callable(e.load()) for e in entry_points(group="console_scripts") if e.name in scripts
    )


def test_checkpoints_of_the_default_formulation_keep_their_fingerprint():
    """Runs from before material.formulation existed resume: a record without it means displacement
    (ABSENT_MEANS); the formulation is always recorded, so a mixed run's checkpoints are never mixed
    up."""
    import json

    from nma.train.checkpoint import check_fingerprint
    from nma.train.runs import absent_means, fingerprint

    settings = validate(compose_cfg("task=translation", "logger=none"))
    default = fingerprint(settings)
    mixed = fingerprint(
        validate(compose_cfg("task=translation", "logger=none", "material.formulation=mixed"))
    )
    assert (
        default["material"] == {"formulation": "displacement", "volumetric": "bulk"}
        and mixed["material"]["formulation"] == "mixed"
    )
    # a record from before the setting existed
    before = {**default, "material": {"E": 0.07, "nu": 0.3}}
    check_fingerprint("c", {"config": json.dumps(before)}, default, absent_means(settings))
    with pytest.raises(ConfigError, match="material.formulation: 'displacement' -> 'mixed'"):
        check_fingerprint("c", {"config": json.dumps(before)}, mixed, absent_means(settings))


def test_checkpoints_with_uniform_knots_keep_their_fingerprint():
    """Runs from before fidelity.grading existed resume (uniform knots, the default, are left out of
    the fingerprint); graded knots are in it, so a graded run never continues a uniform one's
    checkpoint."""
    from nma.train.runs import fingerprint

    default = fingerprint(validate(compose_cfg("task=translation", "logger=none")))
    graded = fingerprint(
        validate(
            compose_cfg(
                "task=translation", "logger=none", "fidelity.ctrl_per_patch=8", "fidelity.grading=2"
            )
        )
    )
    assert "grading" not in default["fidelity"] and graded["fidelity"]["grading"] == 2.0


@pytest.mark.parametrize(
    "overrides, contact",
    [
        (["task=translation"], False),
        (["task=digital_mnist"], False),  # their states are physical without it
        (["task=rotation_single"], True),
        (["task=rotation_double"], True),
        (["task=shape_matching"], True),
        (["task=shape_matching", "contact=off"], False),
        (["task=translation", "contact=on"], True),
        (
            ["experiment=repro_rotation_double"],
            False,
        ),  # the reproductions' joint stage, as measured
        (["experiment=repro_rotation_double_refine"], True),
    ],
)
def test_contact_auto_follows_the_scene_and_a_stated_choice_wins(overrides, contact):
    """contact=auto (the default) is resolved once, by the scene's `contact` field, before any work;
    the resolved choice is what a checkpoint's fingerprint records."""
    from nma.train.runs import fingerprint

    settings = validate(compose_cfg(*overrides, "logger=none"))
    assert settings.contact.enabled is contact
    assert (
        fingerprint(settings)["contact"]["enabled"] is contact
        and "contact" not in fingerprint(settings)["scene"]
    )


def test_a_run_from_before_contact_auto_resolves_as_it_trained(tmp_path):
    """A run's saved config holds what it trained with: one from before contact=auto (contact off
    explicitly, its scene without a `contact` field) loads with contact off; a new run's (contact
    auto, the scene's field saved with it) loads as the scene said."""
    from nma.resolve import contact_options
    from nma.train import checkpoint
    from nma.train.runs import load_run

    def saved(run, cfg):
        (run / ".hydra").mkdir(parents=True)
        OmegaConf.save(cfg, run / ".hydra" / "config.yaml")
        checkpoint.save(run / "checkpoints", 1, {"params": {"net": {}, "geom": {}}, "step": 1})
        return load_run(run)[0]

    from nma.train.runs import fingerprint

    before = OmegaConf.to_container(
        compose_cfg("task=rotation_double", "contact=off", "logger=none")
    )
    del before["scene"]["contact"]
    assert saved(tmp_path / "before", before).contact.enabled is False
    del before["contact"]  # and from before contact existed at all
    older = saved(tmp_path / "older", before)
    assert older.contact.enabled is False and fingerprint(older)["contact"] == {"enabled": False}
    assert "contact" not in fingerprint(older)["scene"]
    now = compose_cfg("task=rotation_double", "logger=none")
    assert now.contact.enabled is None and saved(tmp_path / "now", now).contact.enabled is True
    with pytest.raises(ValueError, match="contact=auto is decided by the material and the scene"):
        contact_options(build(ContactConfig, {"enabled": None}))


def test_a_task_brings_its_optimiser_and_a_reproduction_keeps_its_own():
    """task=<t> selects conf/optim/<t>.yaml, and its YAML spec the same one; optim=adam is the
    generic optimiser; an experiment states its own over the generic one, whatever the task's is."""
    from nma.schema import OptimConfig

    def optim(*overrides):
        return OmegaConf.to_container(compose_cfg(*overrides, "logger=none").optim)

    generic = OmegaConf.to_container(OmegaConf.structured(OptimConfig))
    single = optim("task=rotation_single")
    assert (single["lr"], single["lr_scale"]["radii"]) == (3e-3, 10.0) and single["name"] == "adam"
    assert optim("task=rotation_single_spec", "scene=rotation_single") == single
    assert optim("task=rotation_single", "optim=adam") == generic
    # a field over the task's
    assert optim("task=rotation_single", "optim.lr=1e-4")["lr_scale"]["radii"] == 10.0
    assert optim("task=strip_pore", "scene=strip") == generic  # a task without a file of its own
    repro = optim("experiment=repro_rotation_single")
    assert repro == {
        **generic,
        "lr": 2e-3,
        "schedule": "cosine",
        "lr_scale": {**generic["lr_scale"], "radii": 10.0},
    }


@pytest.mark.parametrize(
    "group",
    [
        "task",
        "solver",
        "fidelity",
        "contact",
        "model",
        "optim",
        "trainer",
        "logger",
        "experiment",
        "debug",
    ],
)
def test_every_config_option_composes_and_validates(group):
    # a phase's input
    needs = {"repro_mnist_fit": ["task.lookup_run=outputs/repro/digital_mnist/lookup"]}
    for option in config.options(group):
        # a task named otherwise names its scene
        if group == "task" and option not in config.options("scene"):
            needs[option] = [f"scene={config.load('task', option)['name']}"]
        cfg = compose_cfg(f"{group}={option}", *needs.get(option, []))
        validate(cfg)
    with pytest.raises(
        ConfigError, match="task.lookup_run must name the lookup phase's run directory"
    ):
        validate(compose_cfg("experiment=repro_mnist_fit"))


@pytest.mark.parametrize("name", ["rotation_single", "rotation_double"])
def test_refinement_stage_changes_only_fidelity_schedule_and_contact(name):
    """repro_<name>_refine continues the joint run of repro_<name> (experiments/repro.py): the same
    task, scene, material, model and design box, only a finer discretisation, a short, slower
    schedule and the pores' contact (their walls touch under the largest angles)."""
    base = OmegaConf.to_container(compose_cfg(f"experiment=repro_{name}"))
    refine = OmegaConf.to_container(compose_cfg(f"experiment=repro_{name}_refine"))
    assert (refine["fidelity"]["ctrl_per_patch"], refine["fidelity"]["quad_points"]) == (8, 2)
    assert refine["contact"]["enabled"] and not base["contact"]["enabled"]
    refine["contact"]["enabled"] = False
    assert (base["fidelity"]["ctrl_per_patch"], base["fidelity"]["quad_points"]) == (5, 2)
    assert (
        refine["trainer"]["steps"] < base["trainer"]["steps"]
        and refine["optim"]["lr"] < base["optim"]["lr"]
    )
    for cfg in (base, refine):
        cfg.pop("fidelity"), cfg["optim"].pop("lr")
        for key in ("steps", "eval_every", "checkpoint_every"):
            cfg["trainer"].pop(key)
    assert refine == base


def test_the_single_rotations_last_stage_changes_only_its_discretisation_and_steps():
    """repro_rotation_single_finish fine-tunes the design of repro_rotation_single_refine
    (experiments/repro.py runs it into outputs/repro/rotation_single/finished): the same settings
    but for a finer mesh at the same two Gauss points, and fewer steps."""
    from experiments.repro import stages

    assert stages("rotation_single") == [("refine", "refined"), ("finish", "finished")]
    assert stages("rotation_double") == [("refine", "refined")] and stages("translation") == []
    refine = OmegaConf.to_container(compose_cfg("experiment=repro_rotation_single_refine"))
    finish = OmegaConf.to_container(compose_cfg("experiment=repro_rotation_single_finish"))
    assert (finish["fidelity"]["ctrl_per_patch"], finish["fidelity"]["quad_points"]) == (11, 2)
    assert finish["trainer"]["steps"] < refine["trainer"]["steps"]
    for cfg in (refine, finish):
        cfg["fidelity"].pop("ctrl_per_patch")
        for key in ("steps", "eval_every", "checkpoint_every"):
            cfg["trainer"].pop(key)
    assert finish == refine


@pytest.mark.parametrize(
    "override, message",
    [
        ("material.nu=0.5", "material.nu must be a finite number in (-1, 0.5), got 0.5"),
        (
            "scene.radii_bounds=[0.1,1.5]",
            "scene.radii_bounds must be a list of numbers, each in (0, 1)",
        ),
        ("optim.lr=-0.1", "optim.lr must be a finite number in (0, inf), got -0.1"),
        ("trainer.steps=0", "trainer.steps must be an integer in [1, 10000000], got 0"),
        (
            "solver.linear=cholesky",
            "solver.linear must be one of ['auto', 'dense', 'pardiso', 'superlu']",
        ),
        ("optim.lr_scale.radii=-1", "optim.lr_scale.radii must be a finite number in [0, inf)"),
    ],
)
def test_bad_config_names_field_and_range(override, message):
    with pytest.raises(ConfigError) as err:
        validate(compose_cfg(override))
    assert message in str(err.value)


def test_auto_models_nearly_incompressible_locking_free_and_compressible_as_before():
    """material.formulation=auto, solver.corrector=auto and the limits and barrier left unset (the
    defaults): at nu 0.3 they resolve to exactly the settings stated before auto existed (equal
    settings: the same discretisation and Newton options, so the same answers bit for bit); from nu
    0.495 on, to the locking-free model with the settings under which every cell of the stability
    map at nu 0.499 converges (docs/how-to/nearly-incompressible.md); a stated choice wins."""
    from nma.resolve import model_record
    from nma.train.runs import validate

    stated = validate(
        compose_cfg(
            "material.formulation=displacement",
            "solver.corrector=line_search",
            "solver.max_iters=200",
            "solver.max_step_iters=100",
            "fidelity.inversion_barrier=0",
            "contact=auto",
        )
    )
    assert validate(compose_cfg()) == stated
    for nu, nearly in ((0.49, False), (0.495, True), (0.499, True)):
        record = model_record(validate(compose_cfg(f"material.nu={nu}")))
        model = (
            {
                "formulation": "mixed",
                "corrector": "trust_region",
                "max_iters": 1000,
                "max_step_iters": 300,
                "inversion_barrier": 0.5,
                "contact": True,
            }
            if nearly
            else {
                "formulation": "displacement",
                "corrector": "line_search",
                "max_iters": 200,
                "max_step_iters": 100,
                "inversion_barrier": 0.0,
                "contact": False,
            }
        )
        assert record == {"nearly_incompressible": nearly, **model}, nu
    own = validate(
        compose_cfg(
            "material.nu=0.499",
            "material.formulation=displacement",
            "solver.max_iters=50",
            "contact=off",
        )
    )
    assert (own.material.formulation, own.solver.max_iters, own.contact.enabled) == (
        "displacement",
        50,
        False,
    )
    assert (own.solver.corrector, own.solver.max_step_iters, own.fidelity.inversion_barrier) == (
        "trust_region",
        300,
        0.5,
    )


def test_a_long_sweeps_checks_say_what_they_check_and_how_far_they_got():
    """nma.sweep.checking: silent where the checks end within 2 s, else a first line saying what
    is checked, one every 10 s with the jobs done, and the time they took; nothing from a single
    run or from the ranks after the first."""
    import io

    from nma.sweep import checking

    def lines(multirun=True, rank=0, step=0.5, jobs=60):
        ticks, out = iter(step * k for k in range(10 * jobs)), io.StringIO()
        done = checking([["j"]] * jobs, multirun, rank, clock=lambda: next(ticks), out=out)
        assert [n for n, _ in done] == list(range(jobs))
        return out.getvalue().splitlines()

    said = lines()
    assert said[0] == (
        "checking the sweep's jobs before any starts, each config composed and "
        "checked as it will run: 3 of 60 done, 2 s"
    )  # job k: at 0.5 (k + 1) s
    assert said[1:-1] == [
        "checking the sweep's jobs: 23 of 60 done, 12 s",
        "checking the sweep's jobs: 43 of 60 done, 22 s",
    ]
    assert said[-1] == "checked the sweep's 60 jobs in 30 s"
    assert lines(step=0.01) == [] and lines(multirun=False) == [] and lines(rank=1) == []


def test_a_relative_dataset_not_found_is_said_so_not_called_a_changed_config(tmp_path, monkeypatch):
    """A dataset named relative to the directory a run started in, resumed from another: its file
    is not found there, which the check says (naming the directory it looked in) before it compares
    the checkpoint's record of the dataset's contents."""
    (tmp_path / "rows.csv").write_text("0.1,0.2\n-0.1,0.0\n")
    overrides = (
        "task=translation_spec",
        "scene=translation",
        "task.low=null",
        "task.high=null",
        "task.dataset=rows.csv",
        "trainer.resume=true",
    )
    monkeypatch.chdir(tmp_path)
    run.validate_in(compose_cfg(*overrides), tmp_path / "run")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    with pytest.raises(
        ConfigError,
        match=r"^task\.dataset rows\.csv cannot be read: it is not a "
        f"file, read from the current directory {elsewhere}$",
    ):
        run.validate_in(compose_cfg(*overrides), tmp_path / "run")
