import json
import re
import subprocess
import sys

import h5py
import numpy as np
import pytest


def simulate(tmp_path, *overrides):
    cmd = [sys.executable, "-m", "nma.simulate", f"hydra.run.dir={tmp_path}", *overrides]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300)


def test_simulate_writes_fields_figure_and_json(tmp_path):
    proc = simulate(tmp_path, "scene=translation", "actuation=[1.0,-0.5]", "fidelity=fast")
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 1, proc.stdout  # stdout is the result only; logs go to stderr
    assert "libtpu" not in proc.stderr  # JAX's TPU probe is not news on a CPU
    result = json.loads(lines[0])
    for key in (
        "scene",
        "dofs",
        "tracked",
        "energy",
        "load_steps",
        "newton_iterations",
        "converged",
        "seconds",
    ):
        assert key in result
    assert result["scene"] == "translation" and result["dofs"] == 3462 and result["converged"]
    # a mild actuation of the initial design: a physical state, its walls 1.25 wide at rest barely
    # thinner
    assert result["valid"] is True and result["validity"]["problems"] == []
    assert 0.5 < result["validity"]["min_J"] < 1.0 and 1.0 < result["validity"]["min_gap"] < 1.25
    # d0 = 1 moves the left side by (-1, 0) and d1 = -0.5 the right by (+0.5, 0): the pointer goes
    # left
    assert result["tracked"]["pointer"][0] < 12.5
    # the paper's scene solves with the paper's volume term and says what its nu gives in the plane:
    # kappa / (kappa + 2 mu) = 0.52 and 1.064 E / (1 - nu^2) at nu = 0.3 (tests/test_volumetric.py)
    plane = result["plane_strain"]
    assert result["material"]["volumetric"] == plane["volumetric"] == "bulk"
    assert plane["poisson"] == pytest.approx(0.52, rel=1e-12)
    assert plane["modulus"] / plane["modulus_3d_consistent"] == pytest.approx(1.064, rel=1e-12)
    assert "material.volumetric=bulk" in proc.stderr
    with h5py.File(tmp_path / "fields.h5") as f:
        u = f["control/displacement"][()]
        assert np.all(np.isfinite(u)) and np.abs(u).max() > 0.5
        assert f["mesh/cells"].shape[1] == 4 and np.all(f["fields/J"][()] > 0)
        np.testing.assert_allclose(
            f["mesh/deformed"][()] - f["mesh/reference"][()], f["fields/displacement"][()][:, :2]
        )
    assert "fields.h5:/mesh/cells" in (tmp_path / "fields.xdmf").read_text()
    assert (tmp_path / "deformation.png").stat().st_size > 10_000
    # small vibrations about the equilibrium (nma.dynamics.modes)
    omega = np.asarray(result["natural_frequencies"])
    assert len(omega) == 3 and np.all(omega > 0) and np.all(np.diff(omega) >= 0)
    np.testing.assert_allclose(result["natural_periods"], 2 * np.pi / omega)


@pytest.mark.slow
def test_simulate_in_time_says_when_the_static_model_suffices(tmp_path):
    """The strip's actuation raised over 10000 time units, ~25 of its lowest natural periods (~400):
    the run says the static model suffices, and its last state (generalised-alpha, the high
    frequencies damped) is the static equilibrium to within 1% of the motion."""
    proc = simulate(
        tmp_path,
        "scene=strip",
        "actuation=[1.0,1.0]",
        "fidelity=fast",
        "dynamics=generalised_alpha",
        "dynamics.rho_inf=0.5",
        "dynamics.ramp=10000",
        "dynamics.dt=2000",
        "dynamics.steps=10",
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    dyn = json.loads(proc.stdout.strip().splitlines()[-1])["dynamics"]
    assert dyn["completed"] and dyn["every_state_physical"] and dyn["time_steps"] == 10
    assert "the static model gives the same answer" in dyn["static_suffices"]
    assert "static model gives the same answer" in proc.stderr
    assert dyn["final_vs_static"] < 0.01
    with h5py.File(tmp_path / "trajectory.h5") as f:
        assert (
            f["times"].shape == (11,)
            and f["u"].shape[:1] == (11,)
            and f["tracked/top_left"].shape == (11, 2)
        )


def test_failed_solve_exits_1_with_a_json_line(tmp_path):
    proc = simulate(
        tmp_path, "scene=translation", "actuation=[4.0,-4.0]", "fidelity=fast", "solver.max_iters=2"
    )
    assert proc.returncode == 1, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])  # valid JSON: NaN would not parse
    assert result["converged"] is False and 0.0 <= result["load_reached"] < 1.0
    assert "iteration limit" in result["error"] and proc.stderr.strip().splitlines()[-1].startswith(
        "error: "
    )


def test_json_line_has_null_for_non_finite_values():
    from nma.simulate import json_safe

    line = json.dumps(
        json_safe({"residual": float("nan"), "x": [1.0, float("inf")], "n": 3}), allow_nan=False
    )
    assert json.loads(line) == {"residual": None, "x": [1.0, None], "n": 3}


def _settings(*overrides):
    """nma.simulate's checked settings, as the command builds them from its command line."""
    from hydra import compose, initialize_config_dir

    from nma import config
    from nma.schema import register
    from nma.simulate import validate

    register()
    with initialize_config_dir(config_dir=str(config.CONF_DIR), version_base="1.3"):
        return validate(compose(config_name="simulate", overrides=list(overrides)))


def test_a_completed_run_in_time_reports_and_checks_every_state(tmp_path, monkeypatch):
    """Six steps of 1.1 (six sums of 1.1 fall short of 1.1 x 6, by which a state found by its time
    would be lost): all seven states are in trajectory.h5, checked, and in the peak kinetic
    energy.  One modal solve in all, at rest (where the run starts), whose lowest frequency also
    sets the damping."""
    from nma.dynamics import modes
    from nma.simulate import run

    solves = []
    monkeypatch.setattr(
        modes,
        "natural_frequencies",
        lambda *a, f=modes.natural_frequencies, **k: solves.append(1) or f(*a, **k),
    )
    result = run(
        _settings(
            "scene=strip",
            "actuation=[0.01,0.01]",
            "fidelity=fast",
            "dynamics=newmark",
            "dynamics.dt=1.1",
            "dynamics.steps=6",
            "dynamics.ramp=6",
            "dynamics.damping_ratio=0.01",
            "output.figure=false",
        ),
        tmp_path,
    )
    assert len(solves) == 1 and result["natural_frequencies_about"] == "rest"
    dyn = result["dynamics"]
    assert result["converged"] and result["valid"] and dyn["completed"]
    assert dyn["every_state_physical"] and dyn["final_vs_static"] is not None
    assert dyn["states_reached"] == 7 and dyn["valid_states"]["checked_states"] == 7
    assert dyn["time_reached"] == 1.1 * 6 > sum([1.1] * 6)
    with h5py.File(tmp_path / "trajectory.h5") as f:
        assert f["u"].shape[0] == 7 and f["times"][-1] == 1.1 * 6
        kinetic = f["kinetic_energy"][()]
        assert len(kinetic) == 7 and dyn["kinetic_energy_max"] == kinetic.max() > 0


def test_a_run_in_time_whose_step_fails_exits_1_and_says_when(tmp_path):
    """The actuation applied at once (ramp 0), no cuts: a time step fails.  One line on stderr says
    which step, from and to which time, and why; the JSON's top level says not converged and not
    valid, its dynamics the states reached, each checked, and no final state to compare with the
    static one."""
    proc = simulate(
        tmp_path,
        "scene=strip",
        "fidelity=fast",
        "actuation=[2.0,2.0]",
        "dynamics=newmark",
        "dynamics.steps=4",
        "dynamics.ramp=0",
        "dynamics.max_cuts=0",
        "output.figure=false",
    )
    assert proc.returncode == 1, proc.stderr[-2000:]
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith("error: scene strip") and "time stepping failed: time step" in line
    assert " of 4, from t = " in line and "did not converge (dynamics.max_cuts=0: not cut)" in line
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    dyn = result["dynamics"]
    assert result["converged"] is False and result["valid"] is False and result["error"] in line
    assert not dyn["completed"] and not dyn["every_state_physical"]
    assert dyn["final_vs_static"] is None
    failed_step = int(re.search(r"time step (\d+) of 4", line).group(1))
    assert dyn["states_reached"] == failed_step  # step k (from 1) fails: states 0 .. k - 1 solved
    assert dyn["valid_states"]["checked_states"] == dyn["states_reached"]
    with h5py.File(tmp_path / "trajectory.h5") as f:
        assert f["u"].shape[0] == dyn["states_reached"]


# the dense backend's static solve and its time steps are checked at the library level in the fast
# suite: test_solver.py's test_backends_agree, test_dynamics.py's
# test_the_dense_backend_steps_through_time_as_the_host_ones
@pytest.mark.slow
def test_simulate_serves_the_dense_backend_static_and_in_time(tmp_path):
    """solver=dense: the static solve with its natural frequencies (from the scene's sparse
    pattern), and the run in time (its steps' Newton driven from the host with dense LU factors), as
    SuperLU's."""
    from nma.simulate import run

    common = (
        "scene=strip",
        "actuation=[1.0,1.0]",
        "fidelity=fast",
        "dynamics=newmark",
        "dynamics.dt=50",
        "dynamics.steps=2",
        "output.figure=false",
    )
    dense, host = (
        run(_settings(*common, f"solver={name}"), tmp_path / name) for name in ("dense", "superlu")
    )
    assert dense["converged"] and dense["dynamics"]["completed"]
    assert dense["dynamics"]["states_reached"] == 3
    np.testing.assert_allclose(dense["natural_frequencies"], host["natural_frequencies"], rtol=1e-8)
    for k, p in host["tracked"].items():
        np.testing.assert_allclose(dense["tracked"][k], p, atol=1e-10)
    with h5py.File(tmp_path / "dense" / "trajectory.h5") as a:
        with h5py.File(tmp_path / "superlu" / "trajectory.h5") as b:
            np.testing.assert_allclose(a["u"][()], b["u"][()], atol=1e-10)


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["material.E=1e-300"], "material.E must be a finite number in [1e-30, 1e30], got 1e-300"),
        (["material.E=1e31"], "material.E must be a finite number in [1e-30, 1e30]"),
        (
            ["material.density=1e-300"],
            "material.density must be a finite number in [1e-30, 1e30], got 1e-300",
        ),
        (
            ["material.E=1e30", "material.density=1e-30"],
            "material.density must be in [3.85e-11, 1e+30] for this material: its shear modulus "
            "3.85e+29 over the density",
        ),
        (
            [
                "material=yeoh",
                "material.parameters={C10: 1e-20, C20: 0, C30: 0}",
                "material.density=1e25",
            ],
            "material.density must be in [1e-30, 2e+20] for this material: its shear modulus 2e-20",
        ),
    ],
)
def test_a_material_no_float64_solve_can_honour_is_refused_before_work(overrides, message):
    from nma.errors import ConfigError

    with pytest.raises(ConfigError, match=re.escape(message)):
        _settings("scene=translation", *overrides)


def test_natural_frequencies_that_cannot_be_computed_are_null_with_the_reason(
    simulator, monkeypatch, caplog, tmp_path
):
    """A modal solve that fails (ARPACK; a singular tangent) leaves the static result standing: the
    frequencies null and why, said on the log, not a traceback.  A run in time, which needs the
    lowest one for its time step, fails with the reason (the JSON line then says so)."""
    from scipy.sparse.linalg import ArpackError

    from nma.dynamics import modes, report
    from nma.dynamics.settings import lowest_frequency
    from nma.errors import SolverError

    def fails(*args, **kwargs):
        raise ArpackError(-9)

    monkeypatch.setattr(modes, "natural_frequencies", fails)
    sim = simulator("translation", "superlu", ctrl_per_patch=5, quad_points=2)
    X = sim.reference_points(sim.init_params())
    out = report.frequencies(sim, X, sim.material_params, 1.0, np.zeros(2), np.zeros(X.shape))
    assert out["natural_frequencies"] is None and out["natural_periods"] is None
    assert "ArpackError" in out["natural_frequencies_error"]
    assert "could not be computed" in caplog.text
    with pytest.raises(SolverError, match="lowest natural frequency at rest could not be computed"):
        lowest_frequency(sim, X, sim.material_params, 1.0)
    from nma.simulate import run

    result = run(
        _settings(
            "scene=strip",
            "actuation=[0.1,0.1]",
            "fidelity=fast",
            "dynamics=newmark",
            "dynamics.steps=2",
            "output.figure=false",
        ),
        tmp_path,
    )
    assert result["natural_frequencies"] is None and "energy" in result
    assert result["converged"] is False and result["valid"] is False
    assert "lowest natural frequency at rest could not be computed" in result["error"]
