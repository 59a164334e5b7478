"""What a finished run leaves in its directory: metrics, fields of the evaluation samples, figures."""
from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..io.fields import write_fields  # noqa: E402
from ..viz.plot import draw_shape  # noqa: E402


def write_metrics(run_dir: Path, task, evaluation: dict, history: list, extra: dict) -> Path:
    path = run_dir / "metrics.json"
    body = {"task": task.name, "metric": task.metric_name, "unit": task.metric_unit,
            "value": evaluation[task.metric_name], "step": evaluation["step"],
            "failed_solves": evaluation["failed_solves"], "per_sample": evaluation["per_sample"],
            "history": history, **extra,
            **{k: v for k, v in evaluation.items() if not k.startswith("_")}}
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(body, indent=1))
    tmp.replace(path)
    return path


def write_eval_fields(directory: Path, sim, evaluation: dict, samples: int) -> list[Path]:
    """One HDF5 (+ XDMF) file per converged evaluation sample, eval_<i>.h5, into `directory`."""
    X, d, u, out, ts, ok = evaluation["_solution"]
    paths = []
    for i in range(len(ts)):
        if not ok[i]:
            continue
        h5, _ = write_fields(directory / f"eval_{i:03d}.h5", sim.disc, X, u[i], samples,
                             attrs={"descriptor": np.asarray(ts[i]), "actuation": np.asarray(d[i]),
                                    "observed": np.asarray(out[i])})
        paths.append(h5)
    return paths


def figure_designs(path: Path, sim, X_before, X_after):
    fig, axes = plt.subplots(1, 2, figsize=(8, 4))
    draw_shape(axes[0], sim.disc, np.asarray(X_before), "design before")
    draw_shape(axes[1], sim.disc, np.asarray(X_after), "design after", colour="#7fb58f")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def figure_deformed(path: Path, sim, task, evaluation: dict, n: int = 4):
    X, d, u, out, ts, ok = evaluation["_solution"]
    pick = np.linspace(0, len(ts) - 1, min(n, len(ts))).astype(int)
    fig, axes = plt.subplots(1, len(pick), figsize=(3.2 * len(pick), 3.4))
    for ax, i in zip(np.atleast_1d(axes), pick):
        draw_shape(ax, sim.disc, np.asarray(X + u[i]), f"t = {np.round(np.asarray(ts[i]), 2).tolist()}",
                   colour="#d9a38f")
        _draw_target(ax, task, out[i], ts[i])
    np.atleast_1d(axes)[0].legend(loc="lower left", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def _draw_target(ax, task, out, t):
    tgt = np.asarray(task.shown_target(out, t)).reshape(-1, 2)
    obs = np.asarray(out).reshape(-1, 2)
    if task.outline:
        close = lambda a: np.concatenate([a, a[:1]])
        ax.plot(*close(tgt).T, "--", color="#1f3fbf", lw=1.2, label="target")
        ax.plot(*close(obs).T, "-", color="#2ca02c", lw=1.2, label="reached")
    else:
        ax.plot(tgt[:, 0], tgt[:, 1], "x", color="#1f3fbf", ms=7, mew=2, label="target")
        ax.plot(obs[:, 0], obs[:, 1], "o", color="#2ca02c", ms=4, label="reached")


def figure_shapes(path: Path, task, evaluation: dict, n: int = 16):
    """Held-out targets (dashed, fitted onto the pore by scale, rotation and re-indexing) and the pore
    the material reached for each, with its error."""
    X, d, u, out, ts, ok = evaluation["_solution"]
    k = min(n, len(ts))
    cols = int(np.ceil(np.sqrt(k)))
    rows = int(np.ceil(k / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(2.2 * cols, 2.2 * rows + 0.4), squeeze=False)
    for i, ax in enumerate(axes.ravel()):
        ax.axis("off")
        if i >= k:
            continue
        _draw_target(ax, task, out[i], ts[i])
        ax.set_aspect("equal")
        err = evaluation["per_sample"][i]
        ax.set_title(f"error {err:.3f}" if ok[i] else "solve failed", fontsize=8)
    axes[0, 0].legend(loc="lower left", fontsize=6)
    fig.suptitle(f"{task.name}: held-out targets and reached pores "
                 f"(mean {task.metric_name} = {evaluation[task.metric_name]:.3f} {task.metric_unit})", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def _colour_panel(ax, task, points, geom, title):
    pos = np.asarray(task.display.positions(points))
    col = np.asarray(task.display.colours(geom["colours"]))
    ax.scatter(pos[:, 0], pos[:, 1], c=col, cmap="Greys", vmin=0.0, vmax=1.0, s=0.6, marker="s",
               linewidths=0, rasterized=True)
    for (x0, x1, y0, y1) in np.asarray(task.display_windows):
        ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="#d62728", lw=0.6))
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=8)
    ax.axis("off")


def figure_display(path: Path, task, evaluation: dict, geom, n: int = 10):
    """What the material shows: the colour field (black = 1) on the deformed material, the seven
    display windows (red), for the first n evaluation samples, and their input images."""
    X, d, u, out, ts, ok = evaluation["_solution"]
    labels = np.asarray(ts)[:, 0].astype(int)
    pick = [int(np.flatnonzero(labels == c)[0]) for c in np.unique(labels)][:n]  # one sample of each digit
    k = len(pick)
    images = not task.lookup
    cols = (k + 1) // 2
    rows = 2 * (1 + images)
    fig, axes = plt.subplots(rows, cols, figsize=(2.0 * cols, 2.9 * rows - 1.3 * images * 2),
                             gridspec_kw={"height_ratios": ([1, 2.2] if images else [1]) * 2}, squeeze=False)
    for a in axes.ravel():
        a.axis("off")
    for j, i in enumerate(pick):
        row, col = divmod(j, cols)
        label = int(ts[i][0])
        shown = task.decode(np.asarray(out[i]))
        verdict = "right" if shown == label else f"shows {shown if shown is not None else '?'}"
        _colour_panel(axes[row * (1 + images) + images, col], task, np.asarray(X + u[i]), geom,
                      f"digit {label}: {verdict}")
        if images:
            axes[row * 2, col].imshow(np.asarray(ts[i][1:]).reshape(28, 28), cmap="Greys")
    name = task.metric_name.replace("_", " ")
    fig.suptitle(f"{task.name} ({'lookup table' if task.lookup else 'held-out images'}): "
                 f"{name} = {evaluation[task.metric_name]:.3g} {task.metric_unit}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def figure_colour_map(path: Path, sim, task, geom):
    fig, ax = plt.subplots(figsize=(3.2, 4.4))
    X = np.asarray(sim.reference_points(geom))
    _colour_panel(ax, task, X, geom, "learned colour field, undeformed (black = 1)")
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def figure_curves(path: Path, task, history: list):
    steps = [h["step"] for h in history]
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
    ax[0].plot(steps, [h["loss"] for h in history], lw=1)
    ax[0].set(xlabel="step", ylabel="training loss", yscale="log")
    ev = [(h["step"], h[task.metric_name]) for h in history if task.metric_name in h]
    if ev:
        ax[1].plot(*zip(*ev), "o-", ms=3)
    ax[1].set(xlabel="step", ylabel=f"{task.metric_name} [{task.metric_unit}]")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
