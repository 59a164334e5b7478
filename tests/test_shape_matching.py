"""Pore shape matching (paper Sec. 4.2): the target generator, the loss, its gradient."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma.mechanics.material import material
from nma.schema import ShapeMatchingTask
from nma.tasks.shape_matching import resample, shape_distance, shape_matching, signed_area


@pytest.fixture(scope="module")
def setup(simulator):
    sim = simulator("shape_matching", quad_points=3)
    task = shape_matching(ShapeMatchingTask(eval_targets=16), sim)
    X = sim.reference_points(sim.init_params())
    return (
        sim,
        task,
        task.observe(sim, sim.init_params(), X, jnp.zeros_like(X), material(0.07, 0.3)),
    )


def test_targets_are_deterministic_and_fresh_per_key(setup):
    sim, task, _ = setup
    again = shape_matching(ShapeMatchingTask(eval_targets=16), sim)
    key = jax.random.PRNGKey(3)
    np.testing.assert_array_equal(task.sample(key, 4), again.sample(key, 4))
    np.testing.assert_array_equal(task.eval_set(), again.eval_set())
    assert not np.allclose(task.sample(key, 4), task.sample(jax.random.PRNGKey(4), 4))
    # other frequencies
    other = shape_matching(ShapeMatchingTask(dataset_seed=1, eval_targets=16), sim)
    assert not np.allclose(task.sample(key, 4), other.sample(key, 4))


def test_targets_run_like_the_pore_and_are_spaced_by_arc_length(setup):
    _, task, pore = setup
    assert pore.shape == (48, 2) and float(signed_area(pore)) > 0  # counter-clockwise
    targets = task.targets(task.sample(jax.random.PRNGKey(0), 32))
    assert np.all(np.asarray(signed_area(targets)) > 0)  # the same orientation as the pore
    # normalised: centred, unit mean radius; starts at the lowest x + y
    np.testing.assert_allclose(targets.mean(axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(targets, axis=-1).mean(axis=1), 1.0, rtol=1e-12)
    assert np.all(np.argmin(targets[..., 0] + targets[..., 1], axis=1) == 0)
    # equal arc length between neighbours: exact along a unit square's outline (perimeter 4, so
    # 48 points lie 1/12 apart along its edges)
    edge = np.linspace(0.0, 1.0, 101)[:-1]
    square = np.concatenate(
        [
            np.stack(p, -1)
            for p in (
                (edge, 0 * edge),
                (1 + 0 * edge, edge),
                (1 - edge, 1 + 0 * edge),
                (0 * edge, 1 - edge),
            )
        ]
    )
    square = np.concatenate([square, square[:1]])
    s = np.arange(48) / 12.0
    side, f = np.floor(s).astype(int), s - np.floor(s)
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]], float)
    expected = corners[side] + f[:, None] * (corners[side + 1] - corners[side])
    np.testing.assert_allclose(resample(jnp.asarray(square), 48), expected, atol=1e-12)


def test_loss_is_zero_for_a_similar_copy_and_positive_otherwise(setup):
    _, task, pore = setup
    target = task.targets(task.eval_set()[0])
    th = 0.7
    R = jnp.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    # scaled, rotated, re-indexed
    copy = 3.0 * jnp.roll(target, 11, axis=0) @ R.T + jnp.array([5.0, -2.0])
    assert float(shape_distance(copy, target)) < 1e-12
    assert float(shape_distance(pore, target)) > 0.05
    mirrored = copy * jnp.array([1.0, -1.0])  # a reflection is not a rotation
    assert float(shape_distance(mirrored, target)) > 1e-3


def test_loss_gradient_matches_central_differences(setup):
    _, task, pore = setup
    target = task.targets(task.eval_set()[1])
    x = pore + 0.3 * jax.random.normal(jax.random.PRNGKey(2), pore.shape)
    g = jax.grad(shape_distance)(x, target)
    h = 1e-6
    for i, j in [(0, 0), (5, 1), (17, 0), (47, 1)]:
        e = jnp.zeros_like(x).at[i, j].set(h)
        fd = (shape_distance(x + e, target) - shape_distance(x - e, target)) / (2 * h)
        np.testing.assert_allclose(g[i, j], fd, rtol=1e-5, atol=1e-9)


def test_no_actuation_reference(setup):
    """The undeformed pore against held-out targets: about 0.37 mean radii in the authors' code."""
    _, task, pore = setup
    value = float(np.mean([task.metric(pore, t) for t in task.eval_set()]))
    assert 0.3 < value < 0.45
