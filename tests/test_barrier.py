"""The inversion barrier (fidelity.inversion_barrier, nma/mechanics/energy.py): det F at 4 x 4 check
points of every element, a barrier below J_hat there, and Newton's step bound at those points."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma import config
from nma.discretise import discretise
from nma.schema import scene_from_config
from nma.geometry.validity import StateChecker
from nma.mechanics.energy import (
    deformation_gradient,
    energy_force_tangents,
    quadrature,
    step_bounds,
    strain_energy,
)
from nma.mechanics.material import det2, material
from nma.schema import Fidelity
from nma.solver.assembly import element_dofs
from conftest import barrier_case

J_HAT = 0.05


@pytest.fixture(scope="module")
def scene():
    spec = scene_from_config(config.load("scene", "translation"))
    on, off = (
        discretise(spec, Fidelity(5, 2, inversion_barrier=J_HAT)),
        discretise(spec, Fidelity(5, 2)),
    )
    X = on.reference_points(on.init_params())
    return on, off, X, quadrature(on.solid, X)


def pulled(disc, X, scale):
    """One interior control point of the first patch moved towards its neighbour by `scale` of the
    way: det F falls near it, first at the element corners (check points), then at the Gauss
    points."""
    patch = disc.mesh.patch_points[0].reshape(5, 5)
    k = patch[2, 2]
    u = jnp.zeros_like(X).at[k].set(scale * (X[patch[3, 2]] - X[k]))
    return u, k, patch


def check_J(disc, quad, u):
    return float(det2(deformation_gradient(disc.mesh, quad, u, at_checks=True)).min())


@pytest.mark.slow  # the barrier's force and tangent are checked against autodiff in the fast suite
def test_the_barrier_changes_nothing_while_det_f_stays_above_j_hat(scene):
    on, off, X, quad = scene
    u, *_ = pulled(on, X, 0.6)
    assert check_J(on, quad, u) > J_HAT
    mat = material(0.07, 0.3)
    for a, b in zip(
        *(
            jax.tree_util.tree_leaves(energy_force_tangents(d.solid, quad, u, mat))
            for d in (on, off)
        )
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_barrier_force_and_tangent_are_the_energy_derivatives(scene):
    """In the barrier's range (0 < J < J_hat at a check point, every Gauss point well above): the
    force is the gradient of the energy (autodiff) and the tangent the derivative of the force."""
    on, off, X, quad = scene
    u, *_ = pulled(on, X, 1.3)
    assert (
        0 < check_J(on, quad, u) < J_HAT
        and float(det2(deformation_gradient(on.mesh, quad, u)).min()) > 0.3
    )
    mat = material(0.07, 0.3)
    energy, force, kel = energy_force_tangents(on.solid, quad, u, mat)
    assert float(energy) > float(strain_energy(off.solid, quad, u, mat))  # the barrier acts
    np.testing.assert_allclose(
        force, jax.grad(lambda v: strain_energy(on.solid, quad, v, mat))(u), rtol=1e-10, atol=1e-14
    )
    v = jax.random.normal(jax.random.PRNGKey(2), X.shape)
    ed = element_dofs(on.solid)
    Kv = jnp.zeros(X.size).at[ed].add(jnp.einsum("eab,eb->ea", kel.elements, v.reshape(-1)[ed]))
    jvp = jax.jvp(lambda w: energy_force_tangents(on.solid, quad, w, mat)[1], (u,), (v,))[1]
    np.testing.assert_allclose(Kv, jvp.reshape(-1), rtol=1e-9, atol=1e-12)


def test_the_energy_is_infinite_and_the_step_bounded_where_a_check_point_inverts(scene):
    """A state inverted at an element's corner but at none of its Gauss points: infinite energy with
    the barrier, finite without; the step bound stops the move where the first check point reaches J
    = 0."""
    on, off, X, quad = scene
    u, k, patch = pulled(on, X, 1.6)
    assert check_J(on, quad, u) < 0 < float(det2(deformation_gradient(on.mesh, quad, u)).min())
    mat = material(0.07, 0.3)
    assert np.isinf(float(strain_energy(on.solid, quad, u, mat))) and np.isfinite(
        float(strain_energy(off.solid, quad, u, mat))
    )
    du = jnp.zeros_like(X).at[k].set(X[patch[3, 2]] - X[k])

    def max_step(disc, quad):  # the step bound Newton takes: the smallest of the three
        return float(min(step_bounds(disc.solid, quad, jnp.zeros_like(X), du)))

    # off: Gauss points only
    a_on, a_off = max_step(on, quad), max_step(off, quadrature(off.solid, X))
    # Newton's element bound, no barrier
    assert max_step(off, quadrature(off.solid, X, check_points=True)) == a_on
    assert a_on < 1.6 < a_off
    assert (
        check_J(on, quad, a_on * du) == pytest.approx(0.0, abs=1e-9)
        and check_J(on, quad, 0.99 * a_on * du) > 0
    )


def test_a_solve_with_the_barrier_is_a_physical_state(simulator, barrier_simulator):
    """conftest.barrier_case: without the barrier (and without Newton's element bound, which fails
    that solve: test_solver) its equilibrium is inverted between Gauss points; with it, det F > 0
    over the whole material, J_hat reached at the check points from above."""
    radii, d = barrier_case()
    results = {}
    plain = simulator(
        "translation", solver={"element_bound": False}, ctrl_per_patch=5, quad_points=2
    )
    for j_hat, sim in ((0.0, plain), (J_HAT, barrier_simulator)):
        params = {"radii": jnp.asarray(radii)}
        sol = sim.solve(params, jnp.asarray(d), material(0.07, 0.3))
        results[j_hat] = StateChecker(
            sim.disc.mesh, np.asarray(sim.reference_points(params))
        ).check(sol.u)
    assert results[0.0].inverted_elements > 0 and results[0.0].min_J < 0
    assert results[J_HAT].valid and 0.5 * J_HAT < results[J_HAT].min_J < 1.0
