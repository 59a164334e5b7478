"""The front doors of the dynamics (nma.dynamics): Dynamics' settings, a trajectory's arrays, the
waveforms, the schemes and the natural frequencies refuse a bad argument before any work, in one
line that names it and its range (nma.checks, as Simulator.equilibrium's)."""

import re

import jax.numpy as jnp
import numpy as np
import pytest

from nma.dynamics.modes import dynamic_amplification, natural_frequencies, static_suffices
from nma.dynamics.schemes import Scheme
from nma.dynamics.trajectory import Dynamics
from nma.dynamics.waveform import Fourier, Pulse
from nma.errors import ConfigError
from nma.simulator import Simulator
from nma.solver.status import Status

L, H = 20.0, 5.0  # a clamped strip of 4 solid cells pulled down at its tip
TIP = {"name": "tip", "segment": [[L, 0], [L, H]], "actuation": 0, "direction": [0, -1]}
STRIP = {
    "name": "strip4",
    "cell_size": 5.0,
    "cells": "SSSS",
    "groups": [TIP],
    "supports": [{"segment": [[0, 0], [0, H]], "kind": "clamped"}],
    "tracked": {"tip": [L, H / 2]},
}
WAVE = Fourier(1, 1, 10.0, 2.0, 0.1)


@pytest.fixture(scope="module")
def strip():
    sim = Simulator.from_config(
        STRIP, fidelity={"quad_points": 2, "ctrl_per_patch": 5}, solver="superlu"
    )
    return sim, sim.reference_points(sim.init_params()), sim.material_params


@pytest.mark.parametrize(
    "kwargs, kind, says",
    [
        ({"dt": -0.5}, ConfigError, "Dynamics: dt must be a finite number in (0, inf), got -0.5"),
        ({"dt": 0.0}, ConfigError, "Dynamics: dt must be"),
        ({"dt": float("nan")}, ConfigError, "Dynamics: dt must be"),
        ({"dt": "0.1"}, TypeError, "Dynamics: dt must be a finite number"),
        ({"steps": 0}, ConfigError, "Dynamics: steps must be an integer in [1, 1000000], got 0"),
        ({"steps": 2.5}, ConfigError, "Dynamics: steps must be an integer"),
        ({"density": 0.0}, ConfigError, "Dynamics: density must be a finite number"),
        ({"density": float("nan")}, ConfigError, "Dynamics: density must be a finite number"),
        (
            {"scheme": "generalised_alpha", "rho_inf": 1.5},
            ConfigError,
            "Dynamics: rho_inf must be a finite number in [0, 1]",
        ),
        ({"rho_inf": -0.1}, ConfigError, "Dynamics: rho_inf must be"),
        ({"alpha": -1.0}, ConfigError, "Dynamics: alpha must be a finite number in [0, inf)"),
        ({"beta": float("inf")}, ConfigError, "Dynamics: beta must be"),
        ({"max_cuts": -1}, ConfigError, "Dynamics: max_cuts must be an integer in [0, 20]"),
        ({"workers": 0}, ConfigError, "Dynamics: workers must be an integer"),
        (
            {"scheme": "euler"},
            ConfigError,
            "Dynamics: scheme must be one of ['newmark', 'generalised_alpha']",
        ),
        ({"waveform": None}, TypeError, "Dynamics: waveform must be a function f(coeffs, t)"),
        (
            {"waveform": Fourier(2, 1, 10.0, 1.0, 1.0)},
            ConfigError,
            "Dynamics: waveform drives 2 actuators; scene strip4 has 1",
        ),
        ({"v0": np.zeros(5)}, ValueError, "Dynamics: v0 must have shape"),
        ({"v0": np.full((85, 2), np.nan)}, ValueError, "Dynamics: v0 must be finite"),
        (
            {"controller": "pid"},
            ConfigError,
            "Dynamics: controller must be one of ['cuts', 'fixed', 'adaptive'], got 'pid'",
        ),
        (
            {"adjoint": "backsolve"},
            ConfigError,
            "Dynamics: adjoint must be one of ['store_all', 'checkpointed'], got 'backsolve'",
        ),
        ({"rtol": 0.0}, ConfigError, "Dynamics: rtol must be a finite number in (0, 1], got 0.0"),
        ({"atol": -1e-6}, ConfigError, "Dynamics: atol must be a finite number in (0, inf)"),
        (
            {"checkpoints": 0},
            ConfigError,
            "Dynamics: checkpoints must be an integer in [1, 1000000]",
        ),
    ],
)
def test_dynamics_refuses_a_setting_out_of_range_naming_it(strip, kwargs, kind, says):
    """Before any work, in one line naming the argument and its range (the dynamics settings')."""
    with pytest.raises(kind) as err:
        Dynamics(strip[0], **{"dt": 0.1, "steps": 2, "waveform": WAVE, "workers": 1, **kwargs})
    assert says in str(err.value) and "\n" not in str(err.value)


def test_a_trajectorys_arrays_are_checked_naming_them(strip):
    """dyn.run and dyn.function check the reference points, coefficients and material as
    sim.equilibrium does (shape, dtype, the waveform's count, the law's ranges); another real
    precision is taken as float64 and gives the same trajectory."""
    sim, X, mat = strip
    c = jnp.array([0.5, 0.0, 0.0])
    dyn = Dynamics(sim, dt=0.5, steps=1, waveform=WAVE, workers=1)
    cases = [
        ((X[:-1], c, mat), ValueError, f"X must have shape ({X.shape[0]}, 2), got"),
        ((X, c[:2], mat), ValueError, "coeffs must have shape (3,), got (2,)"),
        ((X, c.astype(complex), mat), TypeError, "coeffs must hold real numbers"),
        ((X, "rubber", mat), TypeError, "coeffs must be an array"),
        ((X, c, mat[:1]), ValueError, "mat must have shape (2,), got (1,)"),
        ((X, c, jnp.array([1.0, 0.6])), ValueError, "mat = [E, nu] must have nu in (-1, 0.5)"),
    ]
    for args, kind, says in cases:
        with pytest.raises(kind, match=re.escape(f"Dynamics.run: {says}")):
            dyn.run(*args)
    with pytest.raises(ValueError, match=re.escape("Dynamics.function: X must have shape")):
        dyn.function(X[:-1], c, mat)
    with pytest.raises(ValueError, match=re.escape("Dynamics.function: X must be finite")):
        dyn.function(X.at[0, 0].set(jnp.nan), c, mat)
    wrong = Dynamics(sim, dt=0.5, steps=1, waveform=lambda cc, t: jnp.zeros(2) * cc[0], workers=1)
    says = "the waveform must give the scene's 1 actuations, got shape (2,)"
    with pytest.raises(ValueError, match=re.escape(says)):
        wrong.run(X, c, mat)
    x32 = X.astype(jnp.float32)
    u32, _, info, _ = dyn.run(x32, c, mat)
    assert int(info.status) == Status.CONVERGED
    np.testing.assert_array_equal(u32, dyn.run(jnp.asarray(x32, jnp.float64), c, mat)[0])
    assert int(dyn.function(x32, c.astype(jnp.float32), mat)[2].status) == Status.CONVERGED


def test_waveforms_and_schemes_refuse_bad_parameters_naming_them():
    cases = [
        (lambda: Fourier(1, 1, 0.0, 1.0, 1.0), "Fourier: period must be a finite number in"),
        (lambda: Fourier(1, -1, 1.0, 1.0, 1.0), "Fourier: harmonics must be an integer"),
        (lambda: Fourier(1, 1, 1.0, -1.0, 1.0), "Fourier: ramp must be a finite number in"),
        (lambda: Fourier(1, 1, 1.0, 1.0, float("nan")), "Fourier: d_max must be a finite"),
        (
            lambda: Fourier(1, 2, 1.0, 1.0, 1.0)(jnp.zeros(3), 0.5),
            "Fourier: coeffs must have shape (5,)",
        ),
        (lambda: Pulse(1.0, 0.0), "Pulse: duration must be a finite number in (0, inf)"),
        (
            lambda: Scheme.of("generalised_alpha", 2.0),
            "Scheme.of: rho_inf must be a finite number in [0, 1]",
        ),
    ]
    for make, says in cases:
        with pytest.raises(ValueError, match=re.escape(says)):
            make()


def test_natural_frequencies_check_their_arguments_naming_them(strip):
    """A negative density, a count Lanczos cannot give, arrays of the wrong shape: refused, not
    answered."""
    sim, X, mat = strip
    free = sim.disc.boundary.n_dofs
    cases = [
        ({"density": -1.0}, "density must be a finite number"),
        ({"density": 0.0}, "density must be"),
        ({"count": 0}, f"count must be an integer in [1, {free - 2}], got 0"),
        ({"count": free}, "count must be an integer"),
        ({"X": X[:-1]}, "X must have shape"),
        ({"mat": mat[:1]}, "mat must have shape (2,), got (1,)"),
        ({"mat": jnp.array([-1.0, 0.3])}, "mat = [E, nu] must have E in"),
        ({"d": jnp.zeros(3)}, "d must have shape (1,), got (3,)"),
        ({"u_free": jnp.zeros(3)}, f"u_free must have shape ({free},), got (3,)"),
    ]
    for change, says in cases:
        with pytest.raises(ValueError, match=re.escape(f"natural_frequencies: {says}")):
            natural_frequencies(sim, **{"X": X, "mat": mat, "count": 1, **change})
    for call, says in (
        (lambda: dynamic_amplification(0.0, 1.0), "dynamic_amplification: omega_1 must be"),
        (lambda: static_suffices(1.0, -2.0), "static_suffices: period must be"),
    ):
        with pytest.raises(ValueError, match=re.escape(says)):
            call()


def test_library_defaults_are_the_configs(strip):
    """Dynamics' defaults are the `dynamics` settings' (DynamicsOptions, declared once), dt null
    included: a 20th of the lowest natural period at rest; config.load("dynamics", "newmark") is
    what Simulator.dynamics takes, and builds the same time stepping as the defaults."""
    import inspect

    from nma import config
    from nma.dynamics.modes import natural_frequencies
    from nma.schema import DynamicsConfig

    sim, X, mat = strip
    schema = DynamicsConfig()
    signature = inspect.signature(Dynamics).parameters
    shared = [name for name in signature if hasattr(schema, name) and name != "scheme"]
    assert len(shared) == 12
    for name in shared:
        assert signature[name].default == getattr(schema, name), name
    loaded = config.load("dynamics", "newmark")
    assert loaded["scheme"] == "newmark" and loaded["controller"] == "cuts"
    period = 2 * np.pi / natural_frequencies(sim, X, mat, count=1)[0]
    built, default = sim.dynamics(loaded, WAVE), Dynamics(sim, waveform=WAVE)
    assert built.dt == default.dt == period / 20  # the modal solve repeats itself to the bit
    assert (built.steps, built.scheme, built.options) == (
        100,
        Scheme.of("newmark"),
        default.options,
    )
    with pytest.raises(ConfigError, match="dynamics.scheme is off"):
        sim.dynamics(config.load("dynamics", "off"), WAVE)


@pytest.mark.parametrize(
    "settings, says",
    [
        (
            {"controller": "cuts", "rtol": 1e-4},
            "dynamics.rtol=0.0001 has no effect: only the controller adaptive takes it, and "
            "dynamics.controller is cuts",
        ),
        ({"controller": "fixed", "max_cuts": 2}, "dynamics.max_cuts=2 has no effect"),
        ({"checkpoints": 4}, "dynamics.checkpoints=4 has no effect: only the adjoint checkpointed"),
        (
            {"controller": "euler"},
            "dynamics.controller must be one of ['cuts', 'fixed', 'adaptive']",
        ),
        (
            {"adjoint": "checkpointed", "checkpoints": 0},
            "dynamics.checkpoints must be an integer in [1, 1000000], got 0",
        ),
        (
            {"controller": "adaptive", "rtol": 2.0},
            "dynamics.rtol must be a finite number in (0, 1]",
        ),
    ],
)
def test_dynamics_settings_refuse_a_part_they_do_not_take(settings, says):
    """Before any work, naming the setting: a name no registry holds, a value out of range, and a
    setting of a part that is not chosen."""
    from nma.schema import DynamicsConfig

    with pytest.raises(ConfigError) as err:
        DynamicsConfig(scheme="newmark", **settings)
    assert says in str(err.value) and "\n" not in str(err.value)
