"""The checks of a deformed state (nma/geometry/validity.py) on states built to be invalid in one
way.

Each state is a smooth map phi applied to the control points (u = phi(X) - X) of the translation
scene, so what is wrong with it is known by construction."""

import numpy as np
import pytest

from nma import config
from nma.discretise import discretise
from nma.schema import scene_from_config
from nma.geometry.validity import StateChecker, summarise
from nma.schema import Fidelity
from nma.mechanics.energy import deformation_gradient, quadrature
from nma.mechanics.material import det2

CELL = 5.0


@pytest.fixture(scope="module")
def scene():
    """The translation scene at 11 control points per patch: fine enough that the smooth maps below
    are represented with det F > 0 wherever the map itself has it."""
    disc = discretise(scene_from_config(config.load("scene", "translation")), Fidelity(11, 2))
    X = np.asarray(disc.reference_points(disc.init_params()))
    return disc, X, StateChecker(disc.mesh, X)


def smoothstep(s):
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10 - 15 * s + 6 * s * s)


def gauss_point_J(disc, X, u):
    return np.asarray(det2(deformation_gradient(disc.mesh, quadrature(disc.solid, X), u)))


def test_the_rest_state_is_valid(scene):
    disc, X, checker = scene
    rest = checker.check(np.zeros_like(X))
    assert rest.valid and rest.min_J == pytest.approx(1.0) and not rest.problems()
    # at rest the narrowest wall is between the outer boundary and a pore: half a cell less a pore's
    # half-width, 2.5 - 0.5 * 2.5 (radii 0.5)
    assert (
        rest.min_gap == pytest.approx(1.25, rel=1e-3) and "outer boundary" in rest.min_gap_between
    )


def test_the_boundary_stretch_is_measured_and_is_not_a_check(scene):
    """The boundary's smallest stretch along itself: 1 at rest; under u = (a - 1) x in x alone a
    chord at angle t to the x axis stretches by sqrt(a^2 cos^2 t + sin^2 t), smallest (a) where the
    boundary runs along x, e.g. the outer boundary's bottom edge.  Compressed to half its length the
    material is still an object: the state stays valid."""
    disc, X, checker = scene
    assert checker.check(np.zeros_like(X)).min_boundary_stretch == pytest.approx(1.0)
    a = 0.5
    u = np.stack([(a - 1.0) * X[:, 0], np.zeros(len(X))], axis=1)
    v = checker.check(u)
    assert v.valid and v.min_boundary_stretch == pytest.approx(a, abs=1e-12)
    assert v.min_boundary_stretch_at[1] == pytest.approx(0.0) or v.min_boundary_stretch_at[
        1
    ] == pytest.approx(25.0)
    # metrics.json carries the smallest over the states checked (None: a failed solve)
    assert summarise([checker.check(np.zeros_like(X)), v, None])[
        "min_boundary_stretch"
    ] == pytest.approx(a)


def test_a_wall_slid_through_its_pore_is_invalid_though_det_f_is_positive(scene):
    """The column above the pore of cell (2, 1) slides down by more than the pore's height: the
    material is sheared (J > 0 everywhere), but the pore's top wall passes through its bottom wall.
    det F cannot see it; the pore's boundary crossing itself does."""
    disc, X, checker = scene
    cx, cy = 12.5, 7.5
    x, y = X[:, 0], X[:, 1]
    column = 1.0 - smoothstep(np.abs(x - cx) / 1.8)  # 0 beyond |x - cx| = 1.8
    # within the pore's height (its half-width: 1.25)
    above = smoothstep((y - cy + 1.2) / 2.4)
    u = np.stack([np.zeros_like(x), -4.0 * column * above], axis=1)
    v = checker.check(u)
    assert gauss_point_J(disc, X, u).min() > 0 and v.min_J > 0 and v.inverted_elements == 0
    assert not v.valid and v.self_crossing == ["pore at (12.5, 7.5)"] and not v.crossing, (
        v.problems()
    )


def test_two_pores_pushed_into_each_other_are_reported(scene):
    """The right side of the bottom-left cell's pore (at x = 3.75) pushed 4 to the right, through
    the 2.5 wide wall and into the next cell's pore (whose left side, at 6.25, hardly moves)."""
    disc, X, checker = scene
    x, y = X[:, 0], X[:, 1]
    push = np.exp(-((x - 3.75) ** 2 + (y - 2.5) ** 2) / 0.8)
    u = np.stack([4.0 * push, np.zeros_like(x)], axis=1)
    v = checker.check(u)
    assert not v.valid
    assert ["pore at (2.5, 2.5)", "pore at (7.5, 2.5)"] in v.crossing, v.problems()
    assert v.min_gap == 0.0


def test_material_inverted_between_gauss_points_is_found(scene):
    """One interior control point pulled towards its neighbour: det F turns negative near it while
    every Gauss point (2 x 2 per element) stays positive; the Bernstein bound finds the inverted
    element."""
    disc, X, checker = scene
    patch = disc.mesh.patch_points[0].reshape(11, 11)
    k = patch[3, 3]
    direction = X[patch[4, 3]] - X[k]
    found = []
    for scale in np.linspace(0.5, 2.0, 7):
        u = np.zeros_like(X)
        u[k] = scale * direction
        v = checker.check(u)
        if gauss_point_J(disc, X, u).min() > 0 and v.inverted_elements:
            found.append((scale, v))
    assert found, "no pull inverts the material between Gauss points only"
    scale, v = found[0]
    assert v.min_J <= 0 and not v.valid and "material inverted" in v.problems()[0]


def test_the_bernstein_bound_agrees_with_a_dense_grid(scene):
    """Random smooth states: an element the bound calls positive is positive on a 12 x 12 grid, and
    one the grid finds inverted is counted inverted (nothing undecided)."""
    from nma.geometry.sampling import sample_jacobian

    disc, X, checker = scene
    rng = np.random.default_rng(3)
    for _ in range(6):
        k = rng.normal(size=(2, 2)) * 0.35
        x, y = X[:, 0] / 25, X[:, 1] / 25
        u = np.stack(
            [
                3 * np.sin(2 * np.pi * (k[0, 0] * x + k[0, 1] * y) * 4),
                3 * np.cos(2 * np.pi * (k[1, 0] * x + k[1, 1] * y) * 4),
            ],
            axis=1,
        ) * rng.uniform(0.2, 1.0)
        v = checker.check(u)
        # 12 points per element side
        dense = np.asarray(sample_jacobian(disc.mesh, X, u, 9 * 12 + 1)).min()
        assert v.undecided_elements == 0
        assert (v.inverted_elements > 0) == (dense <= 0) or (
            v.inverted_elements > 0 and dense > -1e-9
        )
        assert v.min_J >= dense - 1e-12


def test_the_inversion_penalty_sees_det_f_where_the_check_does(scene):
    """nma.mechanics.energy.check_point_dets (what trainer.inversion_penalty samples) gives det F at
    the same 4 x 4 points of every element as the check's first look (before any subdivision): their
    smallest values agree on a state inverted in one element; the penalty acts there and not at
    rest."""
    import jax.numpy as jnp
    from nma.mechanics.energy import check_point_dets, inversion_penalty

    disc, X, checker = scene
    patch = disc.mesh.patch_points[0].reshape(11, 11)
    k = patch[4, 4]
    u = np.zeros_like(X)
    u[k] = 1.6 * (X[patch[5, 4]] - X[k])  # past its neighbour: inverted near it
    J, defined = check_point_dets(disc.mesh, jnp.asarray(X), jnp.asarray(u))
    v = checker.check(u)
    assert v.inverted_elements > 0 and bool(jnp.all(defined))
    # the smallest is at a check point here
    assert float(jnp.min(J)) == pytest.approx(v.min_J, rel=1e-9)
    assert (
        float(inversion_penalty(disc.mesh, jnp.asarray(X), jnp.asarray(u), 0.2))
        >= (0.2 - v.min_J) ** 2
    )
    assert (
        float(inversion_penalty(disc.mesh, jnp.asarray(X), jnp.zeros_like(jnp.asarray(X)), 0.2))
        == 0.0
    )
