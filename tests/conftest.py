import os

os.environ.setdefault("WANDB_MODE", "disabled")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import pytest  # noqa: E402

from nma import config  # noqa: E402
from nma.simulator import Simulator  # noqa: E402

_SIMS = {}


@pytest.fixture(scope="session")
def simulator():
    """Simulators shared across tests (building and compiling once per scene and backend)."""

    def get(scene: str, linear: str = "pardiso", **fidelity) -> Simulator:
        key = (scene, linear, tuple(sorted(fidelity.items())))
        if key not in _SIMS:
            _SIMS[key] = Simulator.from_config(config.load("scene", scene), fidelity, {"linear": linear})
        return _SIMS[key]

    return get
