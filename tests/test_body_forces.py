"""Gravity as a body force (scene.gravity): the dead load material.density x gravity per unit
reference area, its consistent nodal forces, a cantilever's sag under its own weight against beam
theory, its derivative in the design, and the settings' checks.  References are named where each
is used."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma.dynamics.trajectory import Dynamics
from nma.errors import ConfigError
from nma.mechanics.energy import quadrature
from nma.simulator import Simulator

# BEAM: a clamped strip of 20 solid cells of 5 x 5, L = 100, h = 5 (slenderness 20)
from experiments.verification.cantilever import BEAM, H, L

# a small self-weight: the tip sags about 0.5% of the span, so the geometric nonlinearity, of
# relative order (w / L)^2, is below 1e-4
G = 6e-9
DENSITY = 1.0


def _sim(scene, fidelity=None, density=DENSITY):
    return Simulator.from_config(
        scene, fidelity=fidelity, solver="superlu", material={"density": density}
    )


def test_nodal_gravity_loads_sum_to_the_weight():
    """Partition of unity: the consistent nodal forces sum to rho g A, A the body's area by the same
    quadrature (exact for the strip, whose map is affine: A = L h), to round-off; on a porous scene
    A is the integral of dA the energy uses, and the load follows the design."""
    sim = _sim({**BEAM, "gravity": [0.25 * G, -G]})
    X = sim.reference_points(sim.init_params())
    f = np.asarray(sim.equations.external_force(quadrature(sim.equations.solid, X))).reshape(-1, 2)
    np.testing.assert_allclose(f.sum(0), DENSITY * L * H * np.array([0.25 * G, -G]), rtol=1e-13)

    porous = _sim({**BEAM, "cells": "PPS", "gravity": [0.0, -1.0], "tracked": {}}, density=2.0)
    for radius in (0.3, 0.6):
        params = {**porous.init_params()}
        params["radii"] = jnp.full_like(params["radii"], radius)
        quad = quadrature(porous.equations.solid, porous.reference_points(params))
        f = np.asarray(porous.equations.external_force(quad)).reshape(-1, 2)
        np.testing.assert_allclose(f.sum(0), [0.0, -2.0 * float(quad.weights.sum())], rtol=1e-13)
    assert float(quad.weights.sum()) < 3 * 25.0


def test_cantilever_sag_under_self_weight_against_beam_theory():
    """Tip deflection of the clamped strip under its weight q = rho g h per unit length against
    Euler-Bernoulli's q L^4 / (8 E' I), I = h^3 / 12, plus Timoshenko's shear deflection
    q L^2 / (2 k G A), k = 5/6, A = h (Timoshenko and Gere, Mechanics of Materials, the uniformly
    loaded cantilever).  E' is the plane modulus of the model's small-strain tangent: with the
    Neo-Hookean volume term kappa/2 (log J)^2, E' = 4 mu (kappa + mu) / (kappa + 2 mu), 6.4% above
    E / (1 - nu^2) at nu = 0.3.  The shear term, 0.30% of the total at slenderness 20, is
    included.  Tolerance 0.6%: the model's clamp holds the whole end section (no warping, no
    Poisson contraction), which a beam's clamp does not: a Saint-Venant end effect that stiffens the
    strip by a relative amount of the shear term's order, (h / L)^2 E' / G (nma gives 0.36% below
    Euler-Bernoulli plus shear, 0.06% below Euler-Bernoulli alone, at 11 control points a patch;
    0.44% below at the 8 of fidelity=fine used here).  The paper's 5 x 5 patches are 0.9% stiffer
    still: the clamp's corners, where the stress is singular, need the finer mesh."""
    sim = _sim({**BEAM, "gravity": [0.0, -G]}, fidelity="fine")
    X = sim.reference_points(sim.init_params())
    mat = sim.material_params
    eq = sim.solve(sim.init_params(), jnp.zeros(0), mat)
    tip = float(sim.tracked(X, eq.u)["tip"][1]) - H / 2

    mu, kappa = (float(m) for m in sim.disc.solid.material.moduli(jnp.asarray(mat)))
    E_plane = 4 * mu * (kappa + mu) / (kappa + 2 * mu)
    q, inertia = DENSITY * G * H, H**3 / 12
    bending = q * L**4 / (8 * E_plane * inertia)
    shear = q * L**2 / (2 * 5 / 6 * mu * H)
    reference = -(bending + shear)
    print(f"tip {tip:.6e}  EB {-bending:.6e}  EB+shear {reference:.6e}")
    print(f"relative error {(tip - reference) / reference:.3e}")
    np.testing.assert_allclose(tip, reference, rtol=6e-3)
    assert 5e-3 * L > abs(tip) > 1e-3 * L  # small, but not lost in the solver's tolerance


def test_gravity_ramps_with_the_load_steps_to_a_large_sag():
    """A weight 100 times the benchmark's (the tip sags about 40% of the span): reached in eight
    load steps of an eighth (the predictor's right-hand side carries each step's share of the
    weight) and in whatever steps Newton chooses, the same equilibrium (a dead load is conservative:
    the path does not matter), one of the full load: the residual of the potential (strain energy
    less the weight's work) vanishes there."""
    scene = {**BEAM, "gravity": [0.0, -100 * G]}
    sim = _sim(scene)
    params, mat = sim.init_params(), sim.material_params
    eq = sim.solve(params, jnp.zeros(0), mat)
    stepped = Simulator.from_config(
        scene, solver={"linear": "superlu", "initial_increment": 0.125, "grow": 1.0}
    ).solve(params, jnp.zeros(0), mat)
    assert int(stepped.info.load_steps) == 8
    np.testing.assert_allclose(stepped.u, eq.u, atol=1e-6 * L)
    X = sim.reference_points(params)
    eqs = sim.equations
    u = jnp.asarray(eq.u).reshape(-1)[eqs.free]
    g = eqs.residual(quadrature(eqs.solid, X), u, eqs.A @ jnp.zeros(0), 1.0, mat)
    assert float(jnp.linalg.norm(g)) < 1e-6 * 100 * G * DENSITY * L * H
    assert -float(sim.tracked(X, eq.u)["tip"][1] - H / 2) > 0.3 * L


def test_sag_gradient_in_the_design_matches_central_differences():
    """d(tip sag)/d(pore radii) and /d(material) of a porous cantilever under its weight, through
    the implicit adjoint (the weight's nodal forces depend on the design through the reference
    areas), against central differences (step 1e-5: truncation ~ 1e-10, round-off ~ 1e-10 / 1e-5
    of the solve's tolerance).  material.density is a setting, not an entry of the parameter
    array, so the derivative is in the design and the material's parameters only."""
    scene = {**BEAM, "cells": "PPPP", "tracked": {"tip": [20.0, 2.5]}, "gravity": [0.0, -1e-4]}
    sim = _sim(scene)
    mat = jnp.asarray(sim.material_params)
    params0 = sim.init_params()

    def sag(radii, mat):
        X = sim.reference_points({**params0, "radii": radii})
        u, info = sim.equilibrium(X, jnp.zeros(0), mat)
        return sim.tracked(X, u)["tip"][1]

    radii = jnp.asarray(params0["radii"])
    g_radii, g_mat = jax.grad(sag, argnums=(0, 1))(radii, mat)
    direction = jnp.asarray(np.random.default_rng(0).uniform(-1, 1, radii.shape))
    h = 1e-5
    fd = (sag(radii + h * direction, mat) - sag(radii - h * direction, mat)) / (2 * h)
    np.testing.assert_allclose(float(jnp.vdot(g_radii, direction)), float(fd), rtol=1e-5)
    dm = jnp.zeros_like(mat).at[0].set(1e-3 * mat[0])
    fd_E = (sag(radii, mat + dm) - sag(radii, mat - dm)) / (2e-3 * mat[0])
    np.testing.assert_allclose(float(g_mat[0]), float(fd_E), rtol=1e-5)
    assert abs(float(fd)) > 1e-6


@pytest.mark.parametrize(
    "gravity, says",
    [
        ([0.0, float("nan")], "scene.gravity must be a list of numbers, each in"),
        ([0.0, float("inf")], "scene.gravity must be a list of numbers, each in"),
        ([1.0], "scene.gravity must be [gx, gy]"),
        ([0.0, -1.0, 0.0], "scene.gravity must be [gx, gy]"),
        ([0.0, -1e31], "scene.gravity must be a list of numbers, each in [-1e30, 1e30]"),
    ],
)
def test_a_bad_gravity_is_refused_naming_the_field(gravity, says):
    with pytest.raises(ConfigError) as err:
        _sim({**BEAM, "gravity": gravity})
    assert says in str(err.value)


def test_no_gravity_leaves_no_body_force():
    """null and [0, 0] both mean no gravity: no body force enters the equations."""
    for gravity in (None, [0.0, 0.0]):
        assert _sim({**BEAM, "gravity": gravity}).equations.body is None


def test_dynamics_from_rest_under_gravity_starts_falling_at_g():
    """Time stepping from rest (dynamics.start=rest) applies the weight at once: the state at t = 0
    is at rest, out of balance, with the acceleration M_ff a = f_ext (nma.dynamics.initial).  A
    uniform body force rho g is what the consistent mass gives a rigid acceleration g (the basis'
    partition of unity), so a = g wherever the clamp (a = 0) is not felt: beyond half the span, to
    round-off (the consistent mass's inverse decays geometrically away from the clamp: 5e-4 of g
    a tenth of the span from it, 1e-8 at a quarter)."""
    sim = _sim({**BEAM, "gravity": [0.25 * G, -G]})
    X = np.asarray(sim.reference_points(sim.init_params()))
    dyn = Dynamics(sim, dt=1000.0, steps=1, waveform=lambda c, t: jnp.zeros(0))
    u, v, _, trace = dyn.run(X, jnp.zeros(0), sim.material_params)
    assert not np.any(u[0]) and not np.any(v[0])
    far = X[:, 0] > L / 2
    np.testing.assert_allclose(
        trace.a[0][far], np.broadcast_to([0.25 * G, -G], (far.sum(), 2)), rtol=1e-12
    )
    assert not np.any(trace.a[0][X[:, 0] == 0.0])  # the clamped end
