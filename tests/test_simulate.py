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
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    for key in ("scene", "dofs", "tracked", "energy", "load_steps", "newton_iterations", "converged", "seconds"):
        assert key in result
    assert result["scene"] == "translation" and result["dofs"] == 3462 and result["converged"]
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


@pytest.mark.parametrize("override, message", [
    ("material.nu=0.5", "material.nu"),
    ("actuation=[1.0]", "actuation must have 2 entries"),
    ("fidelity.ctrl_per_patch=6", "fidelity.ctrl_per_patch"),
    ("solver.linear=cholesky", "solver.linear"),
])
def test_simulate_rejects_bad_input(tmp_path, override, message):
    proc = simulate(tmp_path, "scene=translation", override)
    assert proc.returncode == 2 and message in proc.stderr
