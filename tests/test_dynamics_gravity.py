"""Gravity in time (nma.dynamics.initial, dynamics.start): a static start stays at the static sag,
a start from rest under a suddenly applied weight oscillates about it (mean the static sag, peak
twice it, the first natural period), gradients through time against central differences for both
starts, and the refusals.  References are named where each is used."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma.dynamics.mass import kinetic_energy, mass_blocks
from nma.dynamics.modes import natural_modes
from nma.dynamics.trajectory import Dynamics
from nma.errors import ConfigError, SolverError
from nma.mechanics.energy import Tangents, quadrature, strain_energy
from nma.simulator import Simulator
from nma.solver.status import Status

# BEAM: a clamped strip of 20 solid cells of 5 x 5, L = 100, h = 5
from experiments.verification.cantilever import BEAM, H

G = 6e-9  # tests/test_body_forces.py's weight: the tip sags 0.44% of the span
STILL = lambda coeffs, t: jnp.zeros(0)  # noqa: E731  (no actuation)


@pytest.fixture(scope="module")
def beam():
    """The strip under its weight: the simulator, design, material, static sag and first mode."""
    sim = Simulator.from_config(
        {**BEAM, "gravity": [0.0, -G]}, solver="superlu", material={"density": 1.0}
    )
    X, mat = sim.reference_points(sim.init_params()), sim.material_params
    u_static = np.asarray(sim.solve(sim.init_params(), jnp.zeros(0), mat).u)
    omega, phi = natural_modes(sim, X, mat, 1.0, count=1)
    return sim, X, mat, u_static, float(omega[0]), np.asarray(phi[0])


def _tip(sim, X, u):
    return np.array([float(sim.tracked(X, jnp.asarray(ui))["tip"][1]) - H / 2 for ui in u])


@pytest.mark.parametrize("scheme", ["newmark", "generalised_alpha"])
def test_a_static_start_under_gravity_stays_at_the_static_sag(beam, scheme):
    """With no actuation, the static equilibrium under the weight is a solution of every step's
    equations (v = a = 0): 100 steps of a 20th of the first period keep it to round-off, in the
    displacement and in the total energy (strain energy less the weight's work, plus the kinetic).
    generalised_alpha weighs the net force at t_n by alpha_f: with the weight left out of that term
    the strip would move at the first step by alpha_f / (1 - alpha_f) of the weight's share."""
    sim, X, mat, u_static, omega, _ = beam
    dyn = sim.dynamics(
        {"scheme": scheme, "dt": 2 * np.pi / omega / 20, "steps": 100, "start": "static"},
        STILL,
        1.0,
    )
    u, v, info, _ = dyn.run(X, jnp.zeros(0), mat)
    assert int(info.intervals) == 100
    scale = np.max(np.abs(u_static))
    np.testing.assert_allclose(u[0], u_static, atol=1e-9 * scale)
    assert np.max(np.abs(u - u[0])) < 1e-10 * scale
    eqs = sim.equations
    quad = quadrature(eqs.solid, jnp.asarray(X))
    f = np.asarray(eqs.external_force(quad))
    total = [
        float(strain_energy(eqs.solid, quad, jnp.asarray(ui), mat))
        - f @ ui.reshape(-1)
        + float(kinetic_energy(eqs, X, vi, 1.0))
        for ui, vi in zip(u, v)
    ]
    assert total[0] < 0  # the sag lowers the potential
    # the strain energy's round-off: Gauss-point terms of order mu strain^2 cancel with the
    # weight's work to a total 1e-4 of either, so eps of them is ~1e-11 of it; 1e-9 bounds it
    assert np.max(np.abs(np.array(total) - total[0])) < 1e-9 * abs(total[0])


def test_a_start_from_rest_oscillates_about_the_static_sag(beam):
    """Gravity applied at once to the strip at rest: an undamped linear oscillator under a suddenly
    applied constant load moves as q_s (1 - cos omega t), about the static q_s with peak 2 q_s
    (the dynamic amplification factor 2 of a suddenly applied load: Clough and Penzien, Dynamics
    of Structures, the step load).  Newmark's average acceleration steps it exactly as
    q_s (1 - cos(Omega k)), Omega = 2 atan(omega dt / 2): its period lengthened to
    T x / atan(x), x = omega dt / 2 (0.8% at dt = T / 20; Hughes, The Finite Element Method, 9.3),
    its amplitude kept.  The first mode's coordinate q_1 = phi_1.M u (the mode at rest,
    nma.dynamics.modes) follows that to 1e-3 of q_s: the geometric nonlinearity is of order
    (sag / L)^2 ~ 2e-5, and nothing is damped.  The period from its crossings of q_s matches to
    5e-4 (their linear interpolation).  The tip itself carries the higher modes too (the second's
    share of its sag is about 1.5%, at its own period): its mean over two periods is the static
    sag to 1%, its peak twice it to 3%."""
    sim, X, mat, u_static, omega, phi = beam
    period = 2 * np.pi / omega
    dt, steps = period / 20, 50
    dyn = sim.dynamics({"dt": dt, "steps": steps, "start": "rest"}, STILL, 1.0)
    u, _, info, _ = dyn.run(X, jnp.zeros(0), mat)
    assert int(info.intervals) == steps
    assert np.max(np.abs(u[0])) == 0.0  # at rest
    eqs = sim.equations
    M = mass_blocks(eqs.solid, quadrature(eqs.solid, jnp.asarray(X)), 1.0)
    none = Tangents(M, jnp.zeros((0, 18, 18)), jnp.zeros(0, int), jnp.asarray(0))
    M_ff, free = sim.backend.pattern.matrix(none), np.asarray(eqs.free)
    q = np.array([phi @ (M_ff @ ui.reshape(-1)[free]) for ui in u])
    r = q / (phi @ (M_ff @ u_static.reshape(-1)[free]))
    x = omega * dt / 2
    linear = 1.0 - np.cos(2 * np.arctan(x) * np.arange(steps + 1))
    assert np.max(np.abs(r - linear)) < 1e-3
    assert abs(r.max() - 2.0) < 1e-3
    s = r - 1.0
    crossings = [k + s[k] / (s[k] - s[k + 1]) for k in range(steps) if s[k] * s[k + 1] < 0]
    assert len(crossings) >= 4
    measured = 2 * np.mean(np.diff(crossings)) * dt
    np.testing.assert_allclose(measured, period * x / np.arctan(x), rtol=5e-4)
    tip, sag = _tip(sim, X, u), _tip(sim, X, u_static[None])[0]
    two = 40  # two periods' samples
    assert abs(tip[:two].mean() / sag - linear[:two].mean()) < 0.01
    assert abs(linear[:two].mean() - 1.0) < 0.01  # over two periods, about the static sag
    assert abs(tip.min() / sag - 2.0) < 0.03


BLOCK = {
    "name": "block",
    "cell_size": 5.0,
    "cells": "PP\nPP",
    "groups": [
        {"name": "top", "segment": [[0, 10], [10, 10]], "actuation": 0, "direction": [0, -1]}
    ],
    "supports": [{"segment": [[0, 0], [10, 0]], "kind": "clamped"}],
    "tracked": {"wall": [2.5, 5]},
    # a weight whose sag (about 1% of the height) is of the order of the actuation's
    "gravity": [0.5e-4, -2e-4],
}


@pytest.fixture(scope="module")
def block():
    sim = Simulator.from_config(BLOCK, fidelity="fast", solver="superlu", material={"density": 1.0})
    return sim, sim.init_params(), jnp.asarray(sim.material_params)


@pytest.mark.parametrize("start, adjoint", [("rest", "store_all"), ("static", "checkpointed")])
def test_gradients_through_time_under_gravity_match_central_differences(block, start, adjoint):
    """d/d(pore radii, waveform, material) of a trajectory's tracked point and velocities, the
    actuation not 0 at t = 0 (so the start depends on it too): the adjoint through the steps and
    the start's implicit derivative (rest: its acceleration, M_ff a = f_ext - f(u); static: the
    equilibrium) against central differences (step 1e-5: truncation ~ 1e-10, round-off ~ the
    steps' Newton tolerance / 1e-5), to 1e-6.  generalised_alpha with damping: every term of a
    step's residual is in play."""
    sim, params, mat = block
    period = 200.0  # about the block's first natural period

    def waveform(c, t):
        return c[0:1] + c[1:2] * (t / period)

    settings = {"scheme": "generalised_alpha", "dt": period / 10, "steps": 4, "alpha": 1e-3}
    dyn = sim.dynamics({**settings, "start": start, "adjoint": adjoint}, waveform, 1.0)

    def J(radii, c, m):
        X = sim.reference_points({**params, "radii": radii})
        u, v, _ = dyn.function(X, c, m)
        wall = jax.vmap(lambda ui: sim.tracked(X, ui)["wall"])(u)
        return jnp.sum(wall[:, 1] ** 2) + jnp.sum(wall[:, 0]) + 1e3 * jnp.sum(v**2)

    radii, c = jnp.asarray(params["radii"]), jnp.array([0.05, 0.1])
    g_r, g_c, g_m = jax.grad(J, argnums=(0, 1, 2))(radii, c, mat)
    h, direction = 1e-5, jnp.asarray(np.random.default_rng(0).uniform(-1, 1, radii.shape))
    fd = (J(radii + h * direction, c, mat) - J(radii - h * direction, c, mat)) / (2 * h)
    np.testing.assert_allclose(float(jnp.vdot(g_r, direction)), float(fd), rtol=1e-6)
    dc = jnp.array([1.0, 0.0])  # the actuation at t = 0
    fd = (J(radii, c + h * dc, mat) - J(radii, c - h * dc, mat)) / (2 * h)
    np.testing.assert_allclose(float(g_c[0]), float(fd), rtol=1e-6)
    dm = jnp.zeros_like(mat).at[0].set(1e-4 * mat[0])
    fd = (J(radii, c, mat + dm) - J(radii, c, mat - dm)) / (2e-4 * mat[0])
    np.testing.assert_allclose(float(g_m[0]), float(fd), rtol=1e-6)
    assert abs(float(fd)) > 1.0


def test_a_start_that_cannot_work_is_refused_saying_why(block):
    sim, params, mat = block
    with pytest.raises(ConfigError, match=r"dynamics.start must be one of \['rest', 'static'\]"):
        sim.dynamics({"dt": 1.0, "steps": 2, "start": "sag"}, lambda c, t: c, 1.0)
    with pytest.raises(ConfigError, match=r"Dynamics: start must be one of \['rest', 'static'\]"):
        Dynamics(sim, dt=1.0, steps=2, waveform=lambda c, t: c, start="sag")
    # a weight the static solver cannot carry (the pores' walls would invert): no static start
    heavy = Simulator.from_config(
        {**BLOCK, "gravity": [0.3, -1.0]}, fidelity="fast", solver="superlu"
    )
    dyn = heavy.dynamics({"dt": 1.0, "steps": 2, "start": "static"}, lambda c, t: c, 1.0)
    X = heavy.reference_points(params)
    with pytest.raises(SolverError, match=r"dynamics.start=static: the static equilibrium at t"):
        dyn.run(X, jnp.zeros(1), mat)
    # a non-finite design: either start ends the trajectory at once, saying so (as without gravity)
    X = np.array(sim.reference_points(params))
    X[3, 0] = np.nan
    for start in ("rest", "static"):
        dyn = sim.dynamics({"dt": 20.0, "steps": 2, "start": start}, lambda c, t: c, 1.0)
        _, _, info, _ = dyn.run(X, jnp.zeros(1), mat)
        assert int(info.status) == Status.NONFINITE_INPUT and int(info.intervals) == 0


@pytest.mark.parametrize("start", ["rest", "static"])
def test_nma_simulate_steps_a_scene_under_gravity_from_either_start(tmp_path, start):
    """nma.simulate with dynamics on the tutorial's strip under gravity: the run completes, its
    JSON names the start, and its first state is the reference at rest (rest) or the static sag
    under the weight at actuation 0 (static, where the actuation's smootherstep starts), to the
    static solver's tolerance."""
    import h5py
    from hydra import compose, initialize_config_dir

    from nma import config
    from nma.resolve import resolve
    from nma.schema import SimulateConfig, build, register
    from nma.simulate import run

    overrides = [
        "scene=strip",
        "fidelity=fast",
        "scene.gravity=[0,-1e-4]",
        "actuation=[0.2,0.2]",
        "dynamics=newmark",
        f"dynamics.start={start}",
        "dynamics.steps=4",
        "output.figure=false",
    ]
    register()
    with initialize_config_dir(config_dir=str(config.CONF_DIR), version_base="1.3"):
        s = resolve(build(SimulateConfig, compose(config_name="simulate", overrides=overrides)))
    out = run(s, tmp_path)
    assert out["converged"] and out["valid"] and out["dynamics"]["completed"]
    assert out["dynamics"]["start"] == start
    with h5py.File(out["dynamics"]["trajectory"]) as f:
        u0 = np.asarray(f["u"][0])
        # the weight's potential -f . u beside the kinetic and strain energies: 0 at rest, and
        # falling as the strip sags
        potential = np.asarray(f["load_potential"][()])
    assert len(potential) == 5 and potential[-1] < 0
    if start == "rest":
        assert potential[0] == 0.0
        assert not np.any(u0)
        return
    sim = Simulator.from_settings(s)
    sag = np.asarray(sim.solve(sim.init_params(), jnp.zeros(2), sim.material_params).u)
    np.testing.assert_allclose(u0, sag, atol=1e-8 * np.max(np.abs(sag)))
    assert np.max(np.abs(sag)) > 0.1  # the weight sags the strip's top by about 0.17


def test_a_mass_of_another_density_than_the_weights_is_refused(beam):
    """The weight was made with material.density = 1: a run in time whose mass is of density 2
    would step two materials at once."""
    sim, X, mat, _, omega, _ = beam
    settings = {"scheme": "newmark", "dt": 2 * np.pi / omega / 20, "steps": 2}
    with pytest.raises(
        ConfigError, match=r"density must be the one the scene's weight .* = 1, got 2"
    ):
        sim.dynamics(settings, STILL, 2.0)
    assert sim.dynamics(settings, STILL, 1.0).n > 0
