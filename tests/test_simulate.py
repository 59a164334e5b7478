import json
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
    for key in ("scene", "dofs", "tracked", "energy", "load_steps", "newton_iterations", "converged", "seconds"):
        assert key in result
    assert result["scene"] == "translation" and result["dofs"] == 3462 and result["converged"]
    # a mild actuation of the initial design: a physical state, its walls 1.25 wide at rest barely thinner
    assert result["valid"] is True and result["validity"]["problems"] == []
    assert 0.5 < result["validity"]["min_J"] < 1.0 and 1.0 < result["validity"]["min_gap"] < 1.25
    # d0 = 1 moves the left side by (-1, 0) and d1 = -0.5 the right by (+0.5, 0): the pointer goes left
    assert result["tracked"]["pointer"][0] < 12.5
    with h5py.File(tmp_path / "fields.h5") as f:
        u = f["control/displacement"][()]
        assert np.all(np.isfinite(u)) and np.abs(u).max() > 0.5
        assert f["mesh/cells"].shape[1] == 4 and np.all(f["fields/J"][()] > 0)
        np.testing.assert_allclose(f["mesh/deformed"][()] - f["mesh/reference"][()],
                                   f["fields/displacement"][()][:, :2])
    assert "fields.h5:/mesh/cells" in (tmp_path / "fields.xdmf").read_text()
    assert (tmp_path / "deformation.png").stat().st_size > 10_000
    omega = np.asarray(result["natural_frequencies"])  # small vibrations about the equilibrium (nma.dynamics.modes)
    assert len(omega) == 3 and np.all(omega > 0) and np.all(np.diff(omega) >= 0)
    np.testing.assert_allclose(result["natural_periods"], 2 * np.pi / omega)


@pytest.mark.slow
def test_simulate_in_time_says_when_the_static_model_suffices(tmp_path):
    """The strip's actuation raised over 10000 time units, ~25 of its lowest natural periods (~400): the
    run says the static model suffices, and its last state (generalised-alpha, the high frequencies
    damped) is the static equilibrium to within 1% of the motion."""
    proc = simulate(tmp_path, "scene=strip", "actuation=[1.0,1.0]", "fidelity=fast", "dynamics=generalised_alpha",
                    "dynamics.rho_inf=0.5", "dynamics.ramp=10000", "dynamics.dt=2000", "dynamics.steps=10")
    assert proc.returncode == 0, proc.stderr[-2000:]
    dyn = json.loads(proc.stdout.strip().splitlines()[-1])["dynamics"]
    assert dyn["completed"] and dyn["every_state_physical"] and dyn["time_steps"] == 10
    assert "the static model gives the same answer" in dyn["static_suffices"]
    assert "static model gives the same answer" in proc.stderr
    assert dyn["final_vs_static"] < 0.01
    with h5py.File(tmp_path / "trajectory.h5") as f:
        assert f["times"].shape == (11,) and f["u"].shape[:1] == (11,) and f["tracked/top_left"].shape == (11, 2)


def test_failed_solve_exits_1_with_a_json_line(tmp_path):
    proc = simulate(tmp_path, "scene=translation", "actuation=[4.0,-4.0]", "fidelity=fast", "solver.max_iters=2")
    assert proc.returncode == 1, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])  # valid JSON: NaN would not parse
    assert result["converged"] is False and 0.0 <= result["load_reached"] < 1.0
    assert "iteration limit" in result["error"] and proc.stderr.strip().splitlines()[-1].startswith("error: ")


def test_json_line_has_null_for_non_finite_values():
    from nma.simulate import json_safe
    line = json.dumps(json_safe({"residual": float("nan"), "x": [1.0, float("inf")], "n": 3}), allow_nan=False)
    assert json.loads(line) == {"residual": None, "x": [1.0, None], "n": 3}
