import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma.discretise import Resolution, discretise
from nma.geometry.scene import Group, PatchSceneSpec, bilinear_net
from nma.mechanics.energy import force_and_tangents, quadrature, strain_energy
from nma.mechanics.material import material, neo_hookean, piola, tangent
from nma.simulator import Simulator


@pytest.fixture(scope="module")
def translation(simulator):
    sim = simulator("translation")
    p = sim.init_params()
    radii = jax.random.uniform(jax.random.PRNGKey(0), p["radii"].shape, minval=0.2, maxval=0.8)
    X = sim.reference_points({"radii": radii})
    return sim, X


@pytest.mark.parametrize("motion", ["translation", "rotation"])
def test_rigid_motion_has_zero_energy_and_force(translation, motion):
    sim, X = translation
    if motion == "translation":
        u = jnp.broadcast_to(jnp.array([1.7, -0.4]), X.shape)
    else:
        c, s = np.cos(0.6), np.sin(0.6)
        u = X @ jnp.array([[c, s], [-s, c]]) - X
    mat = material(0.07, 0.3)
    quad = quadrature(sim.disc.solid, X)
    assert abs(float(strain_energy(sim.disc.solid, quad, u, mat))) < 1e-12
    force, _ = force_and_tangents(sim.disc.solid, quad, u, mat)
    assert float(jnp.max(jnp.abs(force))) < 1e-12


def test_tangent_is_the_derivative_of_the_force(translation):
    """Element tangents contracted with a direction equal the directional derivative of the
    force."""
    sim, X = translation
    mat = material(0.07, 0.4)
    quad = quadrature(sim.disc.solid, X)
    key1, key2 = jax.random.split(jax.random.PRNGKey(1))
    u = 0.05 * jax.random.normal(key1, X.shape)
    v = jax.random.normal(key2, X.shape)
    _, kel = force_and_tangents(sim.disc.solid, quad, u, mat)
    from nma.solver.assembly import element_dofs

    ed = element_dofs(sim.disc.solid)
    Kv = jnp.zeros(X.size).at[ed].add(jnp.einsum("eab,eb->ea", kel.elements, v.reshape(-1)[ed]))
    jvp = jax.jvp(lambda u: force_and_tangents(sim.disc.solid, quad, u, mat)[0], (u,), (v,))[1]
    np.testing.assert_allclose(Kv, jvp.reshape(-1), rtol=1e-10, atol=1e-12)


def test_elements_in_chunks_give_the_terms_of_all_at_once(translation, monkeypatch):
    """The cache-sized chunks (padded to whole ones) change only the order of the arithmetic."""
    from nma.mechanics import energy

    sim, X = translation
    quad = quadrature(sim.disc.solid, X)
    u = 0.01 * jax.random.normal(jax.random.PRNGKey(2), X.shape)
    mat = material(0.07, 0.4)
    n = np.prod(sim.disc.mesh.elem_points.shape[:2])
    monkeypatch.setattr(energy, "ELEMENT_CHUNK", 100)
    assert n % 100, "the last chunk should be padded"
    results = []
    for above in (0, np.inf):  # every scene in chunks; none
        monkeypatch.setattr(energy, "CHUNK_ABOVE", above)
        results.append(
            jax.jit(lambda u: energy.energy_force_tangents(sim.disc.solid, quad, u, mat))(u)
        )
    for chunked, whole in zip(*map(jax.tree_util.tree_leaves, results)):
        if not np.size(whole):  # the contact blocks of a scene without contact
            continue
        assert np.all(np.isfinite(whole))
        np.testing.assert_allclose(
            chunked, whole, rtol=1e-13, atol=1e-15 * float(jnp.max(jnp.abs(whole)))
        )


def test_material_derivatives_match_finite_differences():
    rng = np.random.default_rng(3)
    F = np.eye(2) + 0.2 * rng.normal(size=(2, 2))
    mu, kappa = 0.3, 2.0
    h = 1e-6
    fd = np.zeros((2, 2))
    for i in range(2):
        for j in range(2):
            E = np.zeros((2, 2))
            E[i, j] = h
            fd[i, j] = (neo_hookean(F + E, mu, kappa) - neo_hookean(F - E, mu, kappa)) / (2 * h)
    np.testing.assert_allclose(piola(jnp.asarray(F), mu, kappa), fd, rtol=1e-8)
    # the closed-form stress and tangent equal autodiff of the energy
    np.testing.assert_allclose(
        piola(jnp.asarray(F), mu, kappa),
        jax.grad(neo_hookean)(jnp.asarray(F), mu, kappa),
        rtol=1e-13,
    )
    C = np.asarray(tangent(jnp.asarray(F), mu, kappa))
    np.testing.assert_allclose(
        C, jax.hessian(neo_hookean)(jnp.asarray(F), mu, kappa), rtol=1e-12, atol=1e-14
    )
    # major symmetry (hyperelastic)
    np.testing.assert_allclose(C, C.transpose(2, 3, 0, 1), atol=1e-12)


def test_zero_actuation_gives_zero_displacement(translation):
    sim, _ = translation
    mat = material(0.07, 0.3)
    sol = sim.solve(sim.init_params(), jnp.zeros(2), mat)
    assert (
        np.abs(sol.u).max() == 0.0
        and sim.energy(sim.reference_points(sim.init_params()), sol.u, mat) == 0.0
    )


def _patch_test_scene(F0, grading=1.0):
    """One distorted patch whose every boundary control point is a point actuator moved by (F0 - I)
    X."""
    net = bilinear_net([(0, 0), (4, 0), (4, 3), (0, 3)])
    # interior distortion: the map is curved, the exact solution stays affine
    net[2, 2] += (0.4, -0.3)
    net[1, 3] += (-0.2, 0.25)
    probe = discretise(PatchSceneSpec("probe", net[None]), Resolution(8, 3, grading=grading))
    X = np.asarray(probe.reference_points({}))
    on_edge = (
        np.isclose(X[:, 0], 0)
        | np.isclose(X[:, 0], 4)
        | np.isclose(X[:, 1], 0)
        | np.isclose(X[:, 1], 3)
    )
    groups = []
    for k, x in enumerate(X[on_edge]):
        groups.append(Group(f"p{k}", (tuple(x), tuple(x)), k, tuple((F0 - np.eye(2)) @ x)))
    return PatchSceneSpec("patch_test", net[None], groups=tuple(groups)), len(groups)


@pytest.mark.parametrize("nu, grading", [(0.3, 1.0), (0.49, 1.0), (0.3, 2.5)])
def test_patch_test_reproduces_homogeneous_stretch(nu, grading):
    """Also with knots graded towards the corners (fidelity.grading): non-uniform spans pass it
    too."""
    F0 = np.array([[1.25, 0.1], [-0.05, 0.85]])
    spec, n = _patch_test_scene(F0, grading)
    sim = Simulator(discretise(spec, Resolution(8, 3, grading=grading)), "pardiso")
    sol = sim.solve({}, jnp.ones(n), material(1.0, nu))
    exact = np.asarray(sim.reference_points({})) @ (F0 - np.eye(2)).T
    np.testing.assert_allclose(sol.u, exact, atol=1e-10)
