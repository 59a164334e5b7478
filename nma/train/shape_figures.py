"""The figures of the tasks that show shapes and colours: pore shapes against their targets (shape
matching), the digits displayed by the colour field and the field itself (digital MNIST)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .evaluation import Evaluation  # noqa: E402


def draw_target(ax, task, out, t):
    if (
        task.shown_target(out, t) is None
        or np.asarray(out).size % 2
        or np.asarray(task.shown_target(out, t)).size % 2
    ):
        # not points in the plane (a task from outside may observe anything): nothing to draw
        return
    tgt = np.asarray(task.shown_target(out, t)).reshape(-1, 2)
    obs = np.asarray(out).reshape(-1, 2)
    if task.outline:
        close = lambda a: np.concatenate([a, a[:1]])
        ax.plot(*close(tgt).T, "--", color="#1f3fbf", lw=1.2, label="target")
        ax.plot(*close(obs).T, "-", color="#2ca02c", lw=1.2, label="reached")
    else:
        ax.plot(tgt[:, 0], tgt[:, 1], "x", color="#1f3fbf", ms=7, mew=2, label="target")
        ax.plot(obs[:, 0], obs[:, 1], "o", color="#2ca02c", ms=4, label="reached")


def figure_shapes(path: Path, task, evaluation: Evaluation, n: int = 16):
    """Held-out targets (dashed, fitted onto the pore by scale, rotation and re-indexing) and the
    pore the material reached for each, with its error."""
    out, ts, ok = evaluation.out, evaluation.ts, evaluation.ok
    k = min(n, len(ts))
    cols = int(np.ceil(np.sqrt(k)))
    rows = int(np.ceil(k / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(2.2 * cols, 2.2 * rows + 0.4), squeeze=False)
    for i, ax in enumerate(axes.ravel()):
        ax.axis("off")
        if i >= k:
            continue
        draw_target(ax, task, out[i], ts[i])
        ax.set_aspect("equal")
        err = evaluation.record["per_sample"][i]
        ax.set_title(f"error {err:.3f}" if ok[i] else "solve failed", fontsize=8)
    axes[0, 0].legend(loc="lower left", fontsize=6)
    fig.suptitle(
        f"{task.name}: held-out targets and reached pores\n"
        f"(mean {task.metric_label} = {evaluation.record[task.metric_name]:.3f} "
        f"{task.metric_unit})",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def colour_panel(ax, task, points, geom, title):
    pos = np.asarray(task.display.positions(points))
    col = np.asarray(task.display.colours(geom["colours"]))
    ax.scatter(
        pos[:, 0],
        pos[:, 1],
        c=col,
        cmap="Greys",
        vmin=0.0,
        vmax=1.0,
        s=0.6,
        marker="s",
        linewidths=0,
        rasterized=True,
    )
    for x0, x1, y0, y1 in np.asarray(task.display_windows):
        ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="#d62728", lw=0.6))
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=8, y=1.0)  # a fixed place, as draw_shape's
    ax.axis("off")


def figure_display(path: Path, task, evaluation: Evaluation, geom, n: int = 10):
    """What the material shows: the colour field (black = 1) on the deformed material, the seven
    display windows (red), for the first n evaluation samples, and their input images."""
    X, u, out, ts = evaluation.X, evaluation.u, evaluation.out, evaluation.ts
    pick = task.one_of_each_digit(ts, n)
    k = len(pick)
    images = not task.lookup
    cols = (k + 1) // 2
    rows = 2 * (1 + images)
    fig, axes = plt.subplots(
        rows,
        cols,
        figsize=(2.0 * cols, 2.9 * rows - 1.3 * images * 2),
        gridspec_kw={"height_ratios": ([1, 2.2] if images else [1]) * 2},
        squeeze=False,
    )
    for a in axes.ravel():
        a.axis("off")
    validity = evaluation.validity
    for j, i in enumerate(pick):
        row, col = divmod(j, cols)
        label = int(ts[i][0])
        shown = task.decode(np.asarray(out[i]))
        verdict = "right" if shown == label else f"shows {shown if shown is not None else '?'}"
        if validity[i] is not None and not validity[i].valid:
            verdict += ", NOT PHYSICAL"
        colour_panel(
            axes[row * (1 + images) + images, col],
            task,
            np.asarray(X + u[i]),
            geom,
            f"digit {label}: {verdict}",
        )
        if images:
            axes[row * 2, col].imshow(np.asarray(ts[i][1:]).reshape(28, 28), cmap="Greys")
    n_invalid = evaluation.record["invalid_states"]
    fig.suptitle(
        f"{task.name} ({'lookup table' if task.lookup else 'held-out images'}): "
        f"{task.metric_label} = {evaluation.record[task.metric_name]:.3g} {task.metric_unit}"
        + (
            f"; {n_invalid} of {evaluation.record['checked_states']} states not physical"
            if n_invalid
            else ""
        ),
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def figure_colour_map(path: Path, sim, task, geom):
    fig, ax = plt.subplots(figsize=(3.2, 4.4))
    X = np.asarray(sim.reference_points(geom))
    colour_panel(ax, task, X, geom, "learned colour field, undeformed (black = 1)")
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)
