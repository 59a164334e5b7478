"""Adjoint gradients against central finite differences, for every parameter kind, at ordinary
points and at the extremes (radii 0.1 / 0.9, actuation +-d_max, nu = 0.49)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma import config
from nma.discretise import Resolution, discretise
from nma.geometry.sampling import sample_colours, sample_positions
from nma.schema import scene_from_config
from nma.mechanics.material import material
from nma.simulator import Simulator
from nma.solver.options import NewtonOptions

# FD of the solution needs it converged below the FD step's effect
TIGHT = NewtonOptions(rtol=1e-12)
_SIMS = {}


def tight_simulator(scene, formulation="displacement"):
    if (scene, formulation) not in _SIMS:
        disc = discretise(scene_from_config(config.load("scene", scene)), material=formulation)
        _SIMS[scene, formulation] = Simulator(disc, "pardiso", TIGHT)
    return _SIMS[scene, formulation]


def make_loss(sim, key):
    """A random smooth functional of every deformed control point (actuated ones included),
    of the tracked points, and for colour scenes of the colour-weighted material points."""
    w = jax.random.normal(key, (sim.disc.mesh.n_points, 2)) / np.sqrt(sim.disc.mesh.n_points)

    def loss(params, d, mat):
        X = sim.reference_points(params)
        u, _ = sim.equilibrium(X, d, mat)
        x = X + u
        out = jnp.sum(w * x) + 0.05 * jnp.sum(u**2) / sim.disc.mesh.n_points
        out += sum(jnp.sum(p**2) for p in sim.tracked(X, u).values()) * 1e-3
        if "colours" in params:
            c = sample_colours(params["colours"], 5)
            out += jnp.sum(c[..., None] * sample_positions(sim.disc.mesh, x, 5)) * 1e-3
        return out

    return jax.jit(loss), jax.jit(jax.grad(loss, argnums=(0, 1, 2)))


def check_directional(sim, params, d, mat, key, kinds, h=1e-5, rtol=1e-6):
    loss, grad = make_loss(sim, key)
    g_params, g_d, g_mat = grad(params, d, mat)
    keys = jax.random.split(jax.random.PRNGKey(7), 8)
    for n, kind in enumerate(kinds):
        if kind == "actuation":
            v = jax.random.normal(keys[n], d.shape)
            plus, minus, exact = (
                (params, d + h * v, mat),
                (params, d - h * v, mat),
                jnp.vdot(g_d, v),
            )
        elif kind == "material":
            v = jnp.array([0.07, 0.01]) * jax.random.normal(keys[n], (2,))
            plus, minus, exact = (
                (params, d, mat + h * v),
                (params, d, mat - h * v),
                jnp.vdot(g_mat, v),
            )
        else:
            v = jax.random.normal(keys[n], params[kind].shape)
            shifted = lambda s: {**params, kind: params[kind] + s * v}
            plus, minus, exact = (
                (shifted(h), d, mat),
                (shifted(-h), d, mat),
                jnp.vdot(g_params[kind], v),
            )
        fd = (loss(*plus) - loss(*minus)) / (2 * h)
        assert np.isfinite(float(exact))
        np.testing.assert_allclose(float(exact), float(fd), rtol=rtol, atol=1e-9, err_msg=kind)


# (radii, nu, actuation): ordinary, then the extremes of the task (d_max = 4)
TRANSLATION_POINTS = [
    (0.5, 0.3, [1.0, -0.5]),
    (0.1, 0.3, [4.0, -4.0]),
    (0.1, 0.3, [-4.0, 4.0]),
    (0.9, 0.3, [4.0, -4.0]),
    (0.5, 0.49, [4.0, -4.0]),
]


@pytest.mark.parametrize("radii, nu, d", TRANSLATION_POINTS)
def test_translation_gradients(radii, nu, d):
    sim = tight_simulator("translation")
    p = sim.init_params()
    params = {
        "radii": jnp.full_like(p["radii"], radii)
        + 0.02
        * jax.random.uniform(jax.random.PRNGKey(1), p["radii"].shape, minval=-1, maxval=1)
        * (0.1 < radii < 0.9)
    }
    check_directional(
        sim,
        params,
        jnp.array(d),
        material(0.07, nu),
        jax.random.PRNGKey(0),
        ["radii", "actuation", "material"],
    )


# the mixed model's solves (Cook's membrane, nu 0.499) are fast tests; its adjoint shares the
# displacement model's
@pytest.mark.slow
def test_translation_gradients_mixed_formulation():
    """material.formulation=mixed, nearly incompressible (nu = 0.499, where the displacement model
    locks): the adjoint differentiates the element mean dilatation too.  Step 1e-4: at nu = 0.499
    the solves at +-1e-5 differ by solver noise of ~1e-10 in the loss (measured: h = 1e-3 and 1e-4
    agree with the adjoint to 2e-9 and 7e-11 relative, 1e-5 to 2e-5)."""
    sim = tight_simulator("translation", "mixed")
    p = sim.init_params()
    params = {
        "radii": p["radii"]
        + 0.05 * jax.random.uniform(jax.random.PRNGKey(1), p["radii"].shape, minval=-1)
    }
    check_directional(
        sim,
        params,
        jnp.array([2.0, -1.0]),
        material(0.07, 0.499),
        jax.random.PRNGKey(0),
        ["radii", "actuation", "material"],
        h=1e-4,
    )


# graded knots are checked in test_bspline, the adjoint in test_translation_gradients
@pytest.mark.slow
def test_gradients_of_the_well_posed_translation_with_graded_knots():
    """The paper's translation scene without its pinned corners (its actuated segments hold it: the
    well-posed variant, docs/explanation/fidelity.md) at 8 x 3 with knots graded towards the patch
    corners."""
    spec = config.load("scene", "translation")
    disc = discretise(scene_from_config({**spec, "pinned": []}), Resolution(8, 3, grading=2.5))
    sim = Simulator(disc, "pardiso", TIGHT)
    p = sim.init_params()
    params = {
        "radii": p["radii"]
        + 0.05 * jax.random.uniform(jax.random.PRNGKey(1), p["radii"].shape, minval=-1)
    }
    check_directional(
        sim,
        params,
        jnp.array([2.0, -1.0]),
        material(0.07, 0.3),
        jax.random.PRNGKey(0),
        ["radii", "actuation", "material"],
    )


# test_round_pore_corners checks the derived radii; the adjoint is test_translation_gradients'
@pytest.mark.slow
def test_gradients_of_the_well_posed_shape_matching_with_round_pore_corners():
    """Shape matching held by its actuated segments alone, its pores' corners round
    (scene.round_pore_corners: each corner radius derived from its neighbours'), at 8 x 2 with
    graded knots: the derived corners differentiate with the rest (every cell's radii, the central
    pore's, the corner moves)."""
    spec = config.load("scene", "shape_matching")
    disc = discretise(
        scene_from_config({**spec, "pinned": [], "round_pore_corners": True}),
        Resolution(8, 2, grading=3.0),
    )
    sim = Simulator(disc, "pardiso", TIGHT)
    p = sim.init_params()
    params = {
        **p,
        "radii": p["radii"]
        + 0.05 * jax.random.uniform(jax.random.PRNGKey(1), p["radii"].shape, minval=-1),
        "corners": 0.5 * jax.random.uniform(jax.random.PRNGKey(2), p["corners"].shape, minval=-1),
    }
    d = 1.5 * jax.random.uniform(jax.random.PRNGKey(4), (12,), minval=-1)
    check_directional(
        sim,
        params,
        d,
        material(0.07, 0.3),
        jax.random.PRNGKey(5),
        ["radii", "pore_radii", "corners", "actuation"],
    )


@pytest.mark.slow  # corner moves share the adjoint path of test_translation_gradients
def test_corner_gradients_rotation_double():
    sim = tight_simulator("rotation_double")
    p = sim.init_params()
    params = {
        **p,
        "corners": 0.5 * jax.random.uniform(jax.random.PRNGKey(2), p["corners"].shape, minval=-1),
    }
    check_directional(
        sim,
        params,
        jnp.array([3.0, -1.5]),
        material(0.07, 0.3),
        jax.random.PRNGKey(3),
        ["corners", "radii", "actuation"],
    )


@pytest.mark.slow  # shape matching's loss gradient is checked in test_shape_matching
def test_central_pore_gradients_shape_matching():
    sim = tight_simulator("shape_matching")
    d = 1.5 * jax.random.uniform(jax.random.PRNGKey(4), (12,), minval=-1)
    check_directional(
        sim,
        sim.init_params(),
        d,
        material(0.07, 0.3),
        jax.random.PRNGKey(5),
        ["pore_radii", "corners", "actuation"],
    )


# test_window_score_reads_the_colour_under_it checks the display's colours fast; the adjoint is
# test_translation_gradients'
@pytest.mark.slow
def test_colour_gradients_digital_mnist():
    sim = tight_simulator("digital_mnist")
    p = sim.init_params()
    params = {**p, "colours": jax.random.normal(jax.random.PRNGKey(6), p["colours"].shape)}
    check_directional(
        sim,
        params,
        jnp.array([3.0, -3.0, 2.0, 1.0, -1.0, 3.0]),
        material(0.07, 0.3),
        jax.random.PRNGKey(8),
        ["colours", "actuation"],
    )


# the barrier's force and tangent, and the penalty's gradient through the equilibrium, are fast
# tests
@pytest.mark.slow
def test_gradients_with_the_inversion_barrier_acting(barrier_simulator):
    """conftest.barrier_case, whose equilibrium leans on the barrier (det F at check points near
    J_hat): the adjoint carries the barrier's force and tangent."""
    from conftest import barrier_case
    from nma.geometry.validity import StateChecker

    radii, d = barrier_case()
    sim, params, mat = barrier_simulator, {"radii": jnp.asarray(radii)}, material(0.07, 0.3)
    sol = sim.solve(params, jnp.asarray(d), mat)
    # the barrier is in its range here
    assert (
        StateChecker(sim.disc.mesh, np.asarray(sim.reference_points(params))).check(sol.u).min_J
        < 0.05
    )
    check_directional(
        sim, params, jnp.asarray(d), mat, jax.random.PRNGKey(0), ["radii", "actuation", "material"]
    )


def test_the_inversion_penalty_is_differentiable_through_the_equilibrium():
    """trainer.inversion_penalty's term (nma.mechanics.energy.inversion_penalty) on
    conftest.barrier_case, whose equilibrium at 5 x 2 without the barrier is inverted between Gauss
    points: the penalty acts, and its gradient with respect to the radii and the actuation, carried
    by the adjoint through u and directly through X, matches central differences.  Solved without
    the element bound, which would stop Newton before that inverted state (the model the penalty was
    measured on, docs/explanation/physical-states.md)."""
    from conftest import barrier_case
    from nma.mechanics.energy import inversion_penalty

    radii, d = barrier_case()
    disc = discretise(scene_from_config(config.load("scene", "translation")), Resolution(5, 2))
    sim, mat = (
        Simulator(disc, "pardiso", NewtonOptions(rtol=1e-12, element_bound=False)),
        material(0.07, 0.3),
    )

    @jax.jit
    def penalty(radii, d):
        X = sim.reference_points({"radii": radii})
        return inversion_penalty(sim.disc.mesh, X, sim.equilibrium(X, d, mat)[0], 0.2)

    radii, d = jnp.asarray(radii), jnp.asarray(d)
    assert float(penalty(radii, d)) > 0.04  # a check point inverted: (0.2 - det F)^2 > 0.04 there
    g_radii, g_d = jax.grad(penalty, argnums=(0, 1))(radii, d)
    h, keys = 1e-5, jax.random.split(jax.random.PRNGKey(3))
    v, w = jax.random.normal(keys[0], radii.shape), jax.random.normal(keys[1], d.shape)
    for exact, plus, minus in (
        (jnp.vdot(g_radii, v), (radii + h * v, d), (radii - h * v, d)),
        (jnp.vdot(g_d, w), (radii, d + h * w), (radii, d - h * w)),
    ):
        fd = (penalty(*plus) - penalty(*minus)) / (2 * h)
        np.testing.assert_allclose(float(exact), float(fd), rtol=1e-6)
