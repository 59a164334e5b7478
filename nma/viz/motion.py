"""Figures of a task in time (nma.tasks.timed): the tracked point's path against its target, the
kinetic energy over time, and an animation of one evaluation sample moving."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .plot import MATERIAL, draw_actuated, draw_shape  # noqa: E402

FRAMES = 60  # an animation's frames at most (states evenly chosen)


def figure_paths(path: Path, task, evaluation, limit: int = 8) -> Path:
    """Each evaluation sample's tracked point over the goal's window against its moving target."""
    n = min(limit, len(evaluation.ts))
    cols = min(4, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(2.6 * cols, 2.6 * rows + 0.6), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for i in range(n):
        ax = axes.ravel()[i]
        ax.axis("on")
        target, reached = np.asarray(task.targets(evaluation.ts[i])), np.asarray(evaluation.out[i])
        ax.plot(*target.T, "--", color="#1f3fbf", lw=1.2, label="target")
        ax.plot(*reached.T, "-", color="#2ca02c", lw=1.2, label="reached")
        ax.plot(*reached[0], "o", color="#2ca02c", ms=3)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
        status = (
            f"error {evaluation.record['per_sample'][i]:.3g}"
            if evaluation.ok[i]
            else "solve failed"
        )
        ax.set_title(f"{task.describe(evaluation.ts[i])}\n{status}", fontsize=7)
    axes.ravel()[0].legend(fontsize=6, loc="best")
    fig.suptitle(
        f"{task.name}: the point over the window against its target; mean {task.metric_label} = "
        f"{evaluation.record[task.metric_name]:.3g} {task.metric_unit}",
        fontsize=8,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def figure_energy(path: Path, task, times, kinetic, region=None, window=None) -> Path:
    """The kinetic energy over time of each evaluation sample (and of the task's region, where it
    has one), the goal's window shaded."""
    fig, ax = plt.subplots(figsize=(6.4, 3.4))
    for i, k in enumerate(kinetic):
        ax.plot(
            times,
            k,
            "-",
            color="#2b3a55",
            lw=1.0,
            alpha=0.8,
            label="whole part" if i == 0 else None,
        )
        if region is not None:
            ax.plot(
                times, region[i], "-", color="#d62728", lw=1.2, label="region" if i == 0 else None
            )
    if window is not None:
        ax.axvspan(
            times[window[0]], times[window[1]], color="#f2c14e", alpha=0.3, label="goal's window"
        )
    ax.set_xlabel("time [scene units]")
    ax.set_ylabel("kinetic energy")
    ax.legend(fontsize=7)
    ax.set_title(f"{task.name}: kinetic energy over time", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def animation_motion(
    path: Path, sim, task, X, u, times, title: str, points=None, targets=None, fps: float = 12.0
):
    """One trajectory as an animation on one fixed scale (at most FRAMES states), with the tracked
    point's trail and its target where given (points, targets: (steps + 1, 2), NaN where there is
    none)."""
    from matplotlib.animation import PillowWriter

    X, u = np.asarray(X), np.asarray(u)
    frames = np.unique(np.linspace(0, len(u) - 1, min(FRAMES, len(u))).round().astype(int))
    deformed = X[None] + u[frames]
    lo, hi = deformed.reshape(-1, 2).min(axis=0), deformed.reshape(-1, 2).max(axis=0)
    pad = 0.04 * (hi - lo).max()
    fig, ax = plt.subplots(figsize=(4.4, 4.4 * (hi - lo)[1] / (hi - lo)[0] + 0.6))
    writer = PillowWriter(fps=fps)
    with writer.saving(fig, path, dpi=90):
        for k in frames:
            for artist in [*ax.collections, *ax.lines, *ax.patches]:
                artist.remove()
            draw_shape(ax, sim.disc, X + u[k], f"t = {times[k]:.4g}", colour=MATERIAL["deformed"])
            draw_actuated(ax, sim.disc, X + u[k])
            if points is not None:
                ax.plot(*points[: k + 1].T, "-", color="#2ca02c", lw=1.0)
            if targets is not None and np.all(np.isfinite(targets[k])):
                ax.plot(*targets[k], "x", color="#1f3fbf", ms=7, mew=2)
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
            fig.suptitle(title, fontsize=8)
            writer.grab_frame()
    plt.close(fig)
    return path
