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


@pytest.fixture(scope="session")
def barrier_simulator():
    """The translation scene at 5 x 2 with the inversion barrier (J_hat 0.05), Newton converged to 1e-12
    (tight enough for central differences of its solution); shared by the barrier and gradient tests."""
    from nma.geometry.discretise import Fidelity, discretise
    from nma.geometry.scene import scene_from_config
    from nma.solver.options import NewtonOptions

    disc = discretise(scene_from_config(config.load("scene", "translation")), Fidelity(5, 2, inversion_barrier=0.05))
    return Simulator(disc, "pardiso", NewtonOptions(rtol=1e-12))


def barrier_case():
    """A random design of the translation scene (radii uniform in [0.1, 0.9]) and a mild actuation whose
    equilibrium at 5 x 2 is inverted between Gauss points near the pinned corner (25, 0) without the
    barrier: the eighth draw of this sequence, found by a search over random designs."""
    import numpy as np

    rng = np.random.default_rng(0)
    for _ in range(8):
        radii, d = rng.uniform(0.1, 0.9, (24, 16)), rng.uniform(-4.0, 4.0, 2)
    return radii, d
