"""Tasks in time (nma.tasks.timed) through the whole run: the trajectories solved, every state
checked, the figures and the trajectories written."""

import json

import h5py
import numpy as np
import pytest
from omegaconf import OmegaConf

from conftest import compose_cfg, train_in_process

SHORT = [
    "scene=translation",
    "debug=default",
    "dynamics.steps=8",
    "task.period_steps=20",
    "task.ramp_steps=2",
    "task.d_max=1",
    "trainer.fields=final",
]


def test_follow_path_runs_and_checks_every_state(tmp_path):
    """Two training steps of the pointer following circles (8 time steps, the window the last 5,
    actuations up to 1), two evaluation samples: every one of their 2 x 9 states checked, the
    figures in time drawn."""
    overrides = (
        "task=follow_path",
        *SHORT,
        "task.window=[4,8]",
        "task.eval_radii=1",
        "task.eval_phases=2",
    )
    record = train_in_process(tmp_path, *overrides)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert (
        metrics["metric"] == "mean_path_error"
        and np.isfinite(metrics["value"])
        and metrics["failed_solves"] == 0
    )
    assert record["checked_states"] == 2 * 9 and record["invalid_states"] == 0
    for name in ("trajectory.png", "energy.png", "motion.gif", "deformed.png"):
        assert (tmp_path / "figures" / name).stat().st_size > 5_000, name
    with h5py.File(tmp_path / "fields" / "trajectories.h5") as f:
        assert (
            f["u"].shape[:2] == (2, 9) and f["times"].shape == (9,) and np.all(f["converged"][()])
        )
        assert np.abs(f["u"][()][:, -1]).max() > 0  # the waveforms moved the part
    # two actuators' Fourier coefficients
    assert np.asarray(metrics["eval_actuations"]).shape == (2, 2 * (2 * 2 + 1))
    # experiments/repro.py's figure of the paths, from the run's saved fields and config: its errors
    from experiments.repro import follow_paths

    (tmp_path / ".hydra").mkdir()
    OmegaConf.save(compose_cfg(*overrides), tmp_path / ".hydra" / "config.yaml")
    paths = follow_paths(tmp_path)
    assert [p["sample"] for p in paths] == [0, 1]
    assert paths[0]["reached"].shape == paths[0]["target"].shape == (5, 2)
    assert [p["error"] for p in paths] == pytest.approx(metrics["per_sample"], rel=1e-9)


@pytest.mark.slow
def test_energy_focus_share_is_a_fraction(tmp_path):
    """The impulse moves the part; the region's share of the kinetic energy is a percentage, near
    the region's share of the material for the initial design (a quarter of the area at most)."""
    train_in_process(
        tmp_path, "task=energy_focus", *SHORT, "task.window=[6,8]", "task.pulse_steps=4"
    )
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["metric"] == "region_energy_share" and 0.0 < metrics["value"] < 100.0
    assert metrics["invalid_states"] == 0 and metrics["checked_states"] == 9


def test_an_energy_region_that_holds_no_element_is_refused(simulator):
    """A region off the part: its share is 0 whatever the design, so the task is refused by name."""
    from nma.errors import ConfigError
    from nma.tasks.schemas import EnergyFocusTask
    from nma.tasks.timed import energy_focus

    sim = simulator("translation", quad_points=3)
    with pytest.raises(
        ConfigError,
        match=r"task.region=\[100.0, 100.0, 110.0, 110.0\] holds no "
        r"element of scene translation .*centres span x",
    ):
        energy_focus(EnergyFocusTask(region=[100.0, 100.0, 110.0, 110.0]), sim)
    assert energy_focus(EnergyFocusTask(), sim).elements.sum() > 0  # the default region holds some


def test_a_task_in_time_posed_in_yaml_loads_and_steps(monkeypatch):
    """conf/task/strip_follow.yaml poses follow_path on the strip scene in YAML alone: it loads as
    the follow_path schema, composes into a run with its scheme, and its task, built by the
    registry and given its time stepping by the simulator (Simulator.dynamics, one modal solve),
    solves a trajectory of 3 steps with a finite loss and gradient."""
    import jax
    import jax.numpy as jnp

    from nma import config
    from nma.dynamics import modes
    from nma.registry import TASKS
    from nma.simulator import Simulator
    from nma.tasks.timed import Motion
    from nma.train.runs import validate

    assert config.load("task", "strip_follow")["kind"] == "follow_path"
    s = validate(
        compose_cfg(
            "task=strip_follow",
            "scene=strip",
            "fidelity=fast",
            "solver=superlu",
            "dynamics.steps=3",
            "task.window=[2,3]",
            "dynamics.damping_ratio=0.1",
        )
    )
    assert s.dynamics.scheme == "generalised_alpha" and s.task.factory == "follow_path"
    sim = Simulator.from_settings(s, 1)
    task = TASKS.get(s.task.factory)(s.task, sim)
    solves = []
    monkeypatch.setattr(
        modes,
        "natural_frequencies",
        lambda *a, f=modes.natural_frequencies, **k: solves.append(1) or f(*a, **k),
    )
    task.attach(sim, s.dynamics, s.material.density)
    assert len(solves) == 1 and task.dynamics.steps == 3 and task.dynamics.options.beta > 0
    X, mat = sim.reference_points(sim.init_params()), jnp.asarray(sim.material_params)
    t = task.sample(jax.random.PRNGKey(0), 1)
    coeffs = jnp.full((1, task.n_outputs(sim)), 0.3)

    def loss(coeffs):
        motion, info = task.solve(sim, X, coeffs, mat)
        out = jax.vmap(lambda u, v: task.observe(sim, None, X, Motion(u, v), mat))(*motion)
        return jnp.mean(jax.vmap(task.loss)(out, t)), info

    (value, info), grad = jax.value_and_grad(loss, has_aux=True)(coeffs)
    assert np.all(np.asarray(info.status) == 1) and np.isfinite(value)
    assert np.all(np.isfinite(grad)) and np.abs(grad).max() > 0
