"""Tasks posed in YAML (nma.tasks.spec): the paper's translation and both rotations as specs are the
hand-written tasks, to the last bit; a spec's goal sets what a figure shows."""

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import compose_cfg, train_in_process
from nma import tasks  # noqa: F401  (declares the tasks)
from nma.registry import TASKS
from nma.train.runs import validate

PAPER_AS_SPECS = ["translation", "rotation_single", "rotation_double"]
MAT = jnp.array([0.07, 0.3])  # the paper's material, [E, nu]


def both(name, *overrides):
    """The settings of task=<name> and of task=<name>_spec on the same scene."""
    cls = validate(compose_cfg(f"task={name}", "logger=none", *overrides))
    spec = validate(compose_cfg(f"task={name}_spec", f"scene={name}", "logger=none", *overrides))
    return cls, spec


@pytest.mark.parametrize("name", PAPER_AS_SPECS)
def test_paper_tasks_as_specs_are_the_classes(simulator, name):
    """Same evaluation set, same draws from the same key, same targets (bit for bit), and the same
    loss and metric on the same observations to round-off (the two are different expressions of
    one formula, which the compiler may round differently), so training takes the same steps."""
    cls, spec = both(name)
    sim = simulator(name, quad_points=2)
    a, b = (TASKS.get(s.task.factory)(s.task, sim) for s in (cls, spec))
    assert type(b).__name__ == "SpecTask" and (a.metric_name, a.d_max) == (b.metric_name, b.d_max)
    np.testing.assert_array_equal(a.eval_set(), b.eval_set())
    ts = a.sample(jax.random.PRNGKey(3), 16)
    np.testing.assert_array_equal(ts, b.sample(jax.random.PRNGKey(3), 16))
    X = sim.reference_points(sim.init_params())
    u = 0.3 * jax.random.normal(jax.random.PRNGKey(5), X.shape)
    out_a, out_b = a.observe(sim, {}, X, u, MAT), b.observe(sim, {}, X, u, MAT)
    np.testing.assert_array_equal(jnp.reshape(out_a, out_b.shape), out_b)
    np.testing.assert_array_equal(jnp.reshape(a.targets(ts), (16, *out_b.shape)), b.targets(ts))
    for f in ("loss", "metric"):
        np.testing.assert_allclose(
            jax.vmap(lambda t: getattr(a, f)(out_a, t))(ts),
            jax.vmap(lambda t: getattr(b, f)(out_b, t))(ts),
            rtol=1e-12,
            atol=0,
        )


# test_paper_tasks_as_specs_are_the_classes checks the specs' tasks against the classes fast
@pytest.mark.slow
def test_a_spec_trains_as_its_class(tmp_path):
    """Two training steps of task=translation and of task=translation_spec from the same seed: the
    same parameters and the same metric, to round-off."""
    from nma.train.runs import make_trainer

    fast = [
        "fidelity=fast",
        "trainer.steps=2",
        "trainer.batch_size=2",
        "trainer.progress=false",
        "trainer.animation_frames=0",
    ]
    cls, spec = both("translation", *fast)
    spec.task.eval_points, cls.task.eval_grid = 2, 2
    results = []
    for k, s in enumerate((cls, spec)):
        trainer = make_trainer(s, tmp_path / str(k))
        record = trainer.fit().record
        results.append(
            (record[trainer.task.metric_name], jax.tree_util.tree_leaves(trainer.state["params"]))
        )
    assert results[0][0] == pytest.approx(results[1][0], rel=1e-12)
    for p, q in zip(results[0][1], results[1][1]):
        np.testing.assert_allclose(p, q, rtol=1e-12, atol=1e-14)


def test_distance_goal_reads_and_shows_the_distance(simulator):
    """goal distance: the metric is the error of the two points' distance, and the target a figure
    draws lies on the line through the reached points at the target distance."""
    from nma.schema import SpecTask as SpecConfig
    from nma.tasks.spec import SpecTask

    sim = simulator("rotation_single", quad_points=2)
    cfg = SpecConfig(
        name="rotation_single", points=["left", "right"], goal="distance", low=[-1.0], high=[2.0]
    )
    rest = jnp.stack(
        [
            sim.disc.tracked_points(sim.reference_points(sim.init_params()))[p]
            for p in ("left", "right")
        ]
    )
    task = SpecTask(cfg, rest)
    out = rest + jnp.array([[-0.5, 0.0], [0.25, 0.0]])  # 0.75 further apart
    t = jnp.array([1.0])
    assert float(task.metric(out, t)) == pytest.approx(0.25)
    shown = np.asarray(task.shown_target(out, t))
    assert np.linalg.norm(shown[1] - shown[0]) == pytest.approx(
        float(jnp.linalg.norm(rest[1] - rest[0])) + 1.0
    )
    assert task.coordinates(task.eval_set())[1] == ["change of distance [length units]"]


def test_a_pore_area_goal_is_exact_and_its_cases_or_dataset_are_the_evaluation_set(
    simulator, tmp_path
):
    """goal pore_area observes the wall of the pore of a cell: its area (each span the Bezier
    segment through the observed start, midpoint and end) equals the area inside the wall's spline
    by Gauss quadrature of Green's theorem (nma.geometry.outline.enclosed_area, exact for the cubic
    integrand), at rest and deformed; named cases, or the rows of a dataset file, are the evaluation
    set, and training draws each with equal chance; a file that does not fit is a ConfigError naming
    task.dataset."""
    from nma.errors import ConfigError
    from nma.geometry.outline import enclosed_area
    from nma.schema import SpecTask as SpecConfig
    from nma.tasks.spec import spec, wall_area

    sim = simulator("strip", quad_points=2)
    cfg = SpecConfig(
        name="strip", goal="pore_area", pore=[1, 3], cases={"shut": [-0.25], "open": [0.25]}
    )
    task = spec(cfg, sim)
    X = sim.reference_points(sim.init_params())
    u = sim.solve(sim.init_params(), jnp.array([2.0, 2.0]), MAT).u  # both sides pushed in
    for x in (X, X + u):
        exact = float(enclosed_area(np.asarray(x)[task.pore_loop]))
        assert float(wall_area(task.observe(sim, {}, X, x - X, MAT))) == pytest.approx(
            exact, rel=1e-12
        )
    # a pore of a 5 x 5 cell, clockwise
    assert float(task.rest_area) == pytest.approx(-6.25, rel=0.05)
    out = task.observe(sim, {}, X, u, MAT)
    ratio = float(wall_area(out) / task.rest_area)
    assert 0.5 < ratio < 0.95  # squeezed
    t = jnp.array([ratio - 1.0 + 0.1])
    assert float(task.metric(out, t)) == pytest.approx(10.0)  # 10% of the rest area short
    assert float(wall_area(task.shown_target(out, t)) / task.rest_area) == pytest.approx(
        ratio + 0.1
    )
    np.testing.assert_array_equal(task.eval_set(), [[-0.25], [0.25]])
    assert task.describe(task.eval_set()[1]) == "open: pore area x 1.25"
    drawn = np.asarray(task.sample(jax.random.PRNGKey(0), 400))[:, 0]
    assert set(drawn) == {-0.25, 0.25} and abs(np.mean(drawn == 0.25) - 0.5) < 0.1

    rows = tmp_path / "areas.csv"
    rows.write_text("# relative change of the pore's area\n-0.2\n0.0\n0.3\n")
    task = spec(SpecConfig(name="strip", goal="pore_area", pore=[1, 3], dataset=str(rows)), sim)
    np.testing.assert_array_equal(task.eval_set(), [[-0.2], [0.0], [0.3]])
    rows.write_text("0.1, 0.2\n")
    with pytest.raises(
        ConfigError, match=r"task.dataset .* must hold finite rows of 1 value for goal pore_area"
    ):
        spec(SpecConfig(name="strip", goal="pore_area", pore=[1, 3], dataset=str(rows)), sim)
    rows.write_text("-1.5\n")
    with pytest.raises(ConfigError, match=r"task.dataset \(row 1 of .*\) holds relative changes"):
        spec(SpecConfig(name="strip", goal="pore_area", pore=[1, 3], dataset=str(rows)), sim)
    rows.write_text("0.5\n1e308\n")  # finite, but no set-up reaches it (and a loss would overflow)
    with pytest.raises(
        ConfigError,
        match=r"task.dataset .* asks for 1e\+308: a descriptor's entries must be within",
    ):
        spec(SpecConfig(name="strip", goal="pore_area", pore=[1, 3], dataset=str(rows)), sim)
    with pytest.raises(ConfigError, match="task.dataset .*missing.csv cannot be read"):
        spec(
            SpecConfig(
                name="strip", goal="pore_area", pore=[1, 3], dataset=str(tmp_path / "missing.csv")
            ),
            sim,
        )


def test_a_force_goal_reads_what_the_actuation_pushes_with(simulator):
    """goal force observes the force of the group's actuation: at an equilibrium, the derivative of
    the equilibrium's strain energy with respect to that actuation (the envelope theorem; central
    differences of two more solves), summed over every group the actuation drives (rotation_single's
    actuation pulls its left and right sides)."""
    from nma.schema import SpecTask as SpecConfig
    from nma.solver.options import NewtonOptions
    from nma.tasks.spec import spec

    scene, d = "rotation_single", [1.5]
    sim = simulator(scene, quad_points=2)
    tight = type(sim)(sim.disc, "superlu", NewtonOptions(rtol=1e-12))
    task = spec(SpecConfig(name=scene, goal="force", group="left", low=[0.0], high=[0.1]), tight)
    p = tight.init_params()
    X = tight.reference_points(p)
    d = jnp.asarray(d)
    h = jnp.zeros_like(d).at[0].set(1e-4)
    energy = lambda d: tight.energy(X, tight.solve(p, d, MAT).u, MAT)
    reaction = float(task.observe(tight, p, X, tight.solve(p, d, MAT).u, MAT)[0])
    # pytest.approx takes Python numbers
    central = float((energy(d + h) - energy(d - h)) / (2 * h[0]))
    assert reaction > 0 and reaction == pytest.approx(central, rel=1e-6)
    assert float(task.metric(jnp.array([reaction]), jnp.array([0.1]))) == pytest.approx(
        abs(reaction - 0.1)
    )


# test_a_force_goal_reads_what_the_actuation_pushes_with checks the force goal in the fast suite
@pytest.mark.slow
def test_a_force_goal_trains(tmp_path):
    """A run with goal force trains: the loss differentiates the energy's gradient through the
    adjoint."""
    from nma.train.runs import make_trainer

    s = validate(
        compose_cfg(
            "task=strip_spread",
            "scene=strip",
            "task.goal=force",
            "task.group=left",
            "task.points=[]",
            "task.low=[0.0]",
            "task.high=[0.1]",
            "task.eval_points=2",
            "logger=none",
            "fidelity=fast",
            "trainer.steps=2",
            "trainer.batch_size=2",
            "trainer.progress=false",
        )
    )
    trainer = make_trainer(s, tmp_path)
    before = jax.tree_util.tree_leaves(trainer.state["params"])
    record = trainer.fit().record
    assert trainer.task.metric_name == "mean_force_error" and np.isfinite(
        record["mean_force_error"]
    )
    moved = [
        not np.allclose(a, b)
        for a, b in zip(before, jax.tree_util.tree_leaves(trainer.state["params"]))
    ]
    assert all(moved)  # every parameter (network and radii) took a finite step


# three trainings; test_a_spec_trains_as_its_class and the force-goal tests cover YAML tasks fast
@pytest.mark.slow
def test_the_tutorials_commands_run(tmp_path):
    """docs/tutorials/own-scene-and-task.md's training commands, at debug size (two steps at the
    fast discretisation): the scene and the tasks it poses in YAML train, learned and frozen, a
    distance and a pore's area."""
    text = (
        Path(__file__).resolve().parent.parent / "docs" / "tutorials" / "own-scene-and-task.md"
    ).read_text()
    commands = re.findall(r"^python3 -m nma\.run .*$", text, re.M)
    assert len(commands) == 3
    for k, line in enumerate(commands):
        args = [a for a in shlex.split(line)[3:] if not a.startswith("hydra.run.dir=")]
        run_dir = tmp_path / str(k)
        train_in_process(run_dir, *args, "debug=default")
        metrics = json.loads((run_dir / "metrics.json").read_text())
        pore = "task=strip_pore" in line
        assert metrics["metric"] == ("mean_pore_area_error_pct" if pore else "mean_distance_error")
        # the cases; eval_points
        assert np.isfinite(metrics["value"]) and len(metrics["per_sample"]) == (3 if pore else 9)
        assert metrics["freeze_geometry"] == ("freeze_geometry=true" in line)


OUTSIDE_TASK = '''"""A task written outside nma: lift the strip's top corners' midpoint by t."""
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from nma.registry import TASKS
from nma.tasks.schemas import TaskConfig
from nma.tasks.base import Task


@dataclass
class LiftConfig(TaskConfig):
    name: str = "strip"
    d_max: float = 3.0


class Lift(Task):
    metric_name, metric_unit = "mean_lift_error", "length units"

    def __init__(self, cfg, rest):
        self.name, self.d_max, self.rest = cfg.name, cfg.d_max, rest

    def sample(self, key, n):
        return jax.random.uniform(key, (n, 1), minval=-0.5, maxval=0.5)

    def observe(self, sim, geom, X, u, mat):
        t = sim.tracked(X, u)
        return 0.5 * (t["top_left"][1:] + t["top_right"][1:])

    def targets(self, t):
        return self.rest + t

    def metric(self, out, t):
        return jnp.abs(out - self.targets(t))[0]

    def eval_set(self):
        return jnp.linspace(-0.5, 0.5, 3)[:, None]


@TASKS.register("strip", schema=LiftConfig)
def lift(cfg, sim):
    t = sim.disc.tracked_points(sim.reference_points(sim.init_params()))
    return Lift(cfg, 0.5 * (t["top_left"][1:] + t["top_right"][1:]))
'''


def test_a_task_from_outside_registers_and_trains(tmp_path):
    """A package that is not nma declares an `nma.tasks` entry point: its module registers a task
    and its schema, a task file in the user's --config-dir selects it, and it trains from the
    command line."""
    (tmp_path / "outside_task.py").write_text(OUTSIDE_TASK)
    dist = tmp_path / "outside_task-0.1.dist-info"  # what pip install leaves: found on sys.path
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: outside-task\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[nma.tasks]\nlift = outside_task\n")
    (tmp_path / "conf" / "task").mkdir(parents=True)
    (tmp_path / "conf" / "task" / "lift.yaml").write_text(
        "defaults:\n  - strip_schema\n  - _self_\n"
    )
    run_dir = tmp_path / "run"
    env = {**__import__("os").environ, "PYTHONPATH": str(tmp_path)}
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "nma.run",
            "--config-dir",
            str(tmp_path / "conf"),
            "task=lift",
            "scene=strip",
            "debug=default",
            f"hydra.run.dir={run_dir}",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["metric"] == "mean_lift_error" and np.isfinite(metrics["value"])


def test_a_broken_plugin_is_named_and_the_commands_go_on(tmp_path):
    """Installed `nma.tasks` entry points whose modules raise, or call sys.exit, do not take the
    commands down: each is named in one warning, --help works, and asking for a task one of them
    would bring says that the task is unknown and which plugins did not import (exit 2, no
    traceback)."""
    (tmp_path / "raises.py").write_text("raise RuntimeError('missing dependency foo')\n")
    (tmp_path / "exits.py").write_text("import sys\nsys.exit(3)\n")
    dist = tmp_path / "broken_tasks-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-tasks\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[nma.tasks]\nraises = raises\nexits = exits\n")
    env = {**__import__("os").environ, "PYTHONPATH": str(tmp_path)}
    help_ = subprocess.run(
        [sys.executable, "-m", "nma.run", "--help"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert help_.returncode == 0 and "Traceback" not in help_.stderr, help_.stderr[-2000:]
    proc = subprocess.run(
        [sys.executable, "-m", "nma.run", "task=lift", f"hydra.run.dir={tmp_path / 'run'}"],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert (
        "warning: the nma.tasks entry point raises = raises does not import (RuntimeError: "
        "missing dependency "
        "foo); its tasks are unavailable" in proc.stderr
    )
    assert "entry point exits = exits does not import (SystemExit: 3)" in proc.stderr
    assert "error: task=lift is unknown; choose one of" in proc.stderr
    assert (
        "(the nma.tasks entry points that did not import: raises = raises: RuntimeError"
        in proc.stderr
    )


def test_a_spec_fingerprint_holds_its_datasets_contents_and_no_unset_new_fields(tmp_path):
    """A checkpoint's fingerprint (what a resume compares) holds a dataset's contents, so that a
    changed file is not continued silently, and leaves out the spec fields a task does not set, so
    that runs written before they existed resume."""
    from nma.train.runs import fingerprint

    plain = fingerprint(validate(compose_cfg("task=strip_spread", "scene=strip", "logger=none")))[
        "task"
    ]
    assert not {"pore", "group", "cases", "dataset", "dataset_sha256"} & set(plain)
    rows = tmp_path / "areas.csv"
    prints = []
    for text in ("-0.2\n0.2\n", "-0.2\n0.3\n"):
        rows.write_text(text)
        s = validate(
            compose_cfg(
                "task=strip_spread",
                "scene=strip",
                "logger=none",
                "task.goal=pore_area",
                "task.points=[]",
                "task.pore=[1,3]",
                "task.low=null",
                "task.high=null",
                f"task.dataset={rows}",
            )
        )
        prints.append(fingerprint(s)["task"])
    assert (
        prints[0]["dataset"] == str(rows)
        and prints[0]["dataset_sha256"] != prints[1]["dataset_sha256"]
    )
