"""What a finished run leaves in its directory: metrics, fields of the evaluation samples,
figures."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import FuncFormatter  # noqa: E402
from matplotlib.transforms import Bbox  # noqa: E402

from ..io.fields import sampler, write_fields, write_trajectory  # noqa: E402
from .trainer import Evaluation  # noqa: E402
from .shape_figures import (  # noqa: E402
    colour_panel,
    draw_target,
    figure_colour_map,
    figure_display,
    figure_shapes,
)
from ..viz.plot import ACTUATED, MATERIAL, TRACKED, draw_actuated, draw_shape  # noqa: E402


def write_metrics(run_dir: Path, task, evaluation: Evaluation, history: list, extra: dict) -> Path:
    path = run_dir / "metrics.json"
    body = {
        "task": task.name,
        "metric": task.metric_name,
        "unit": task.metric_unit,
        "value": evaluation.record[task.metric_name],
        "step": evaluation.record["step"],
        "failed_solves": evaluation.record["failed_solves"],
        "per_sample": evaluation.record["per_sample"],
        "history": history,
        **extra,
        **evaluation.record,
    }
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(body, indent=1))
    tmp.replace(path)
    return path


def write_eval_fields(
    directory: Path, sim, evaluation: Evaluation, samples: int, task=None
) -> list[Path]:
    """One HDF5 (+ XDMF) file per converged evaluation sample, eval_<i>.h5, into `directory` (a task
    in time: its last state; and trajectories.h5, every state of every sample)."""
    X, d, u, out, ts, ok = (
        evaluation.X,
        evaluation.d,
        evaluation.u,
        evaluation.out,
        evaluation.ts,
        evaluation.ok,
    )
    paths, sample = [], sampler(sim.disc, X, samples)
    for i in range(len(ts)):
        if not ok[i]:
            continue
        h5, _ = write_fields(
            directory / f"eval_{i:03d}.h5",
            sim.disc,
            X,
            u[i],
            samples,
            attrs={
                "descriptor": np.asarray(ts[i]),
                "actuation": np.asarray(d[i]),
                "observed": np.asarray(out[i]),
            },
            sample=sample,
        )
        paths.append(h5)
    if evaluation.motion is not None:  # a task in time: every state of every sample
        motion = evaluation.motion
        paths.append(
            write_trajectory(
                directory / "trajectories.h5",
                task.times,
                motion.u,
                motion.v,
                {"descriptors": ts, "converged": ok},
            )
        )
    return paths


def figure_designs(path: Path, sim, X_before, X_after, mm_per_unit: float | None = None):
    """The design before and after training, on one scale: in mm where the run states its part's
    scale, else in the scene's length units."""
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.9), sharex=True, sharey=True)
    unit = "length units" if mm_per_unit is None else "mm"
    for ax, X, which in ((axes[0], X_before, "initial"), (axes[1], X_after, "learned")):
        X = np.asarray(X)
        draw_shape(
            ax,
            sim.disc,
            X,
            f"{which} design",
            colour=MATERIAL[which],
            tracked=sim.disc.tracked_points(X),
            frame=True,
        )
        draw_actuated(ax, sim.disc, X)
        ax.set_xlabel(f"x [{unit}]")
        if mm_per_unit is not None:  # the drawing stays in scene units; its ticks say millimetres
            for axis in (ax.xaxis, ax.yaxis):
                axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v * mm_per_unit:g}"))
    axes[0].set_ylabel(f"y [{unit}]")
    handles = [
        Patch(fc=MATERIAL["initial"], ec="#2b3a55", label="material, initial design"),
        Patch(fc=MATERIAL["learned"], ec="#2b3a55", label="material, learned design"),
        Line2D([], [], color=ACTUATED, lw=2, label="actuated boundary"),
    ]
    if sim.disc.tracked:
        handles.append(Line2D([], [], color=TRACKED, marker="o", ls="", label="tracked point"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path, dpi=130)
    plt.close(fig)


def _grid(xy: np.ndarray):
    """(xs, ys, column, row) when the points (n, 2) fill a grid of at least 2 x 2 exactly, else
    None."""
    xy = np.round(xy, 9)
    xs, ys = np.unique(xy[:, 0]), np.unique(xy[:, 1])
    if len(xs) * len(ys) != len(xy) or min(len(xs), len(ys)) < 2:
        return None
    return xs, ys, np.searchsorted(xs, xy[:, 0]), np.searchsorted(ys, xy[:, 1])


def _layout(task, ts, limit: int):
    """Which samples to draw (at most `limit`) and where: (indices, rows, cols, (row, col) per
    index). Samples on a 2D grid of descriptors keep their places (largest y on top)."""
    n = len(ts)
    pick = np.arange(n) if n <= limit else np.linspace(0, n - 1, limit).round().astype(int)
    coords = task.coordinates(np.asarray(ts)[pick])
    grid = _grid(coords[0]) if coords is not None and coords[0].shape[1] == 2 else None
    if grid is not None:
        xs, ys, col, row = grid
        return pick, len(ys), len(xs), list(zip(len(ys) - 1 - row, col))
    cols = int(np.ceil(np.sqrt(len(pick))))
    rows = int(np.ceil(len(pick) / cols))
    return pick, rows, cols, [divmod(j, cols) for j in range(len(pick))]


def figure_deformed(path: Path, sim, task, evaluation: Evaluation, limit: int = 36):
    """Every evaluation sample (at most `limit`, evenly chosen) deformed, all on one scale, with its
    target, what it reached and its error."""
    X, u, out, ts, ok = evaluation.X, evaluation.u, evaluation.out, evaluation.ts, evaluation.ok
    pick, rows, cols, place = _layout(task, ts, limit)
    # one scale set once below, not sharex/sharey: shared axes rescale every sibling at each drawing
    fig, axes = plt.subplots(rows, cols, figsize=(2.1 * cols, 2.2 * rows + 0.9), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    per = evaluation.record["per_sample"]
    validity = evaluation.validity
    for i, (r, c) in zip(pick, place):
        ax = axes[r, c]
        status = f"error {per[i]:.3g}" if ok[i] else f"solve failed, scored {per[i]:.3g}"
        invalid = validity[i] is not None and not validity[i].valid
        draw_shape(
            ax,
            sim.disc,
            np.asarray(X + u[i]),
            f"{task.describe(ts[i])}\n{status}" + (", NOT PHYSICAL" if invalid else ""),
            colour=MATERIAL["invalid" if invalid else "deformed"],
        )
        ax.title.set_fontsize(7)
        if invalid:
            ax.title.set_color(ACTUATED)
        draw_target(ax, task, out[i], ts[i])
    drawn = [axes[r, c] for r, c in place]
    box = Bbox.union([ax.dataLim for ax in drawn])
    pad = 0.05 * max(box.width, box.height)
    for ax in drawn:
        ax.set_xlim(box.x0 - pad, box.x1 + pad)
        ax.set_ylim(box.y0 - pad, box.y1 + pad)
    handles, labels = axes[place[0]].get_legend_handles_labels()
    shown = (
        "every evaluation sample"
        if len(pick) == len(ts)
        else f"{len(pick)} of the {len(ts)} evaluation samples"
    )
    n_invalid = evaluation.record["invalid_states"]
    fig.suptitle(
        f"{task.name}: {shown}, deformed, on one scale\nmean {task.metric_label} = "
        f"{evaluation.record[task.metric_name]:.3g} {task.metric_unit}"
        + (
            f"; {n_invalid} of {evaluation.record['checked_states']} states not physical (red: "
            f"material inverted or a wall through a wall)"
            if n_invalid
            else ""
        ),
        fontsize=9,
    )
    if labels:
        fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure_errors(path: Path, task, evaluation: Evaluation):
    """The metric of every evaluation sample over the task's descriptor (a map over a 2D target box,
    a curve over an angle range) or, where descriptors have no axes, its distribution."""
    ts, ok = evaluation.ts, evaluation.ok
    per, ok = np.asarray(evaluation.record["per_sample"], float), np.asarray(ok)
    label = f"{task.metric_label} [{task.metric_unit}]"
    coords = task.coordinates(np.asarray(ts))
    fig, ax = plt.subplots(figsize=(5.6, 4.4))
    if coords is None:
        ax.hist(
            per[ok], bins=min(20, max(5, ok.sum() // 3)), color=MATERIAL["initial"], ec="#2b3a55"
        )
        ax.set(xlabel=label, ylabel="evaluation samples")
    elif coords[0].shape[1] == 1:
        x = coords[0][:, 0]
        ax.plot(x[ok], per[ok], "o-", ms=4, color="#1f3fbf", label="converged")
        ax.set(xlabel=coords[1][0], ylabel=label, ylim=(0, None))
    else:
        x, y = coords[0].T
        grid = _grid(coords[0])
        if grid is not None:  # a map of cells
            xs, ys, col, row = grid
            values = np.full((len(ys), len(xs)), np.nan)
            values[row[ok], col[ok]] = per[ok]
            edges = lambda v: np.concatenate(
                [
                    [1.5 * v[0] - 0.5 * v[1]],
                    0.5 * (v[1:] + v[:-1]),
                    [1.5 * v[-1] - 0.5 * v[-2]],
                ]
            )
            shown = ax.pcolormesh(edges(xs), edges(ys), values, cmap="viridis", vmin=0.0)
        else:
            shown = ax.scatter(x[ok], y[ok], c=per[ok], s=40, cmap="viridis", vmin=0.0)
        fig.colorbar(shown, ax=ax, label=f"error [{task.metric_unit}]")
        # equal axes where the points span both (points on one line would make a degenerate box)
        span = np.ptp(coords[0], axis=0)
        ax.set(
            xlabel=coords[1][0],
            ylabel=coords[1][1],
            aspect="equal" if span.min() > 1e-6 * span.max() else "auto",
        )
    if (~ok).any() and coords is not None:
        xy = coords[0][~ok]
        ax.plot(
            xy[:, 0],
            xy[:, 1] if xy.shape[1] > 1 else np.zeros(len(xy)),
            "x",
            color=ACTUATED,
            ms=8,
            mew=2,
            label="solve failed",
        )
        ax.legend(fontsize=8)
    failed = evaluation.record["failed_solves"]
    ax.set_title(
        f"{task.name}: {task.metric_label} per evaluation sample\n"
        f"(mean over all {len(per)}: {evaluation.record[task.metric_name]:.3g} {task.metric_unit}"
        + (f"; {failed} solves failed" if failed else "")
        + ")",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def animation_sweep(path: Path, sim, task, sweep: Evaluation, geom, fps: float) -> Path | None:
    """figures/sweep.gif: the material as the descriptor runs along task.sweep, on one fixed scale,
    each frame titled with its descriptor and error (samples whose solve failed are left out)."""
    from matplotlib.animation import PillowWriter

    X, u, out, ts, ok = sweep.X, sweep.u, sweep.out, sweep.ts, sweep.ok
    frames = [i for i in range(len(ts)) if ok[i]]
    if not frames:
        return None
    deformed = np.asarray(X)[None] + np.asarray(u)[frames]
    lo, hi = deformed.reshape(-1, 2).min(axis=0), deformed.reshape(-1, 2).max(axis=0)
    pad = 0.04 * (hi - lo).max()
    fig, ax = plt.subplots(figsize=(4.4, 4.4 * (hi - lo)[1] / (hi - lo)[0] + 0.6))

    def draw(i):
        for artist in [*ax.collections, *ax.lines, *ax.patches]:
            # the last frame's drawing; ax.clear() would rebuild the axes (most of a frame's time)
            artist.remove()
        title = f"{task.describe(ts[i])}: error {sweep.record['per_sample'][i]:.3g}"
        if getattr(task, "display", None) is not None:
            colour_panel(ax, task, np.asarray(X + u[i]), geom, title)
        else:
            draw_shape(ax, sim.disc, np.asarray(X + u[i]), title, colour=MATERIAL["deformed"])
            draw_target(ax, task, out[i], ts[i])
            ax.legend(loc="lower left", fontsize=7)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        fig.suptitle(f"{task.name}, learned design; error in {task.metric_unit}", fontsize=8)

    # the writer's own loop: FuncAnimation would draw each frame twice (on screen, then into the
    # file)
    writer = PillowWriter(fps=fps)
    with writer.saving(fig, path, dpi=100):
        for i in frames:
            draw(i)
            writer.grab_frame()
    plt.close(fig)
    return path


def figure_curves(path: Path, task, history: list):
    steps = [h["step"] for h in history]
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
    losses = [np.nan if h["loss"] is None else h["loss"] for h in history]  # a gap: a skipped step
    ax[0].plot(steps, losses, lw=1)
    # a loss to maximise a share is negative
    positive = all(not np.isfinite(v) or v > 0 for v in losses)
    ax[0].set(
        xlabel="training step",
        ylabel="training loss (batch)",
        yscale="log" if positive else "linear",
        title="loss of each step",
    )
    ev = [(h["step"], h[task.metric_name]) for h in history if task.metric_name in h]
    if ev:
        ax[1].plot(*zip(*ev), "o-", ms=3)
    ax[1].set(
        xlabel="training step",
        ylabel=f"{task.metric_label}\n[{task.metric_unit}]",
        title="on the evaluation set",
    )
    for a in ax:
        a.title.set_fontsize(9)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def write_figures(
    figures: Path,
    trainer,
    evaluation,
    X_before,
    animation_frames: int,
    mm_per_unit: float | None = None,
) -> Path:
    """The figures of a finished run into `figures/`: the design before and after, the evaluation
    deformed (or, for a colour display, what it shows), the learning curves, the error map where the
    task has one, the sweep animation, the pore shapes.  `mm_per_unit`: the design's axes in mm
    (part.scale)."""
    sim, task = trainer.sim, trainer.task
    geom = trainer.state["params"]["geom"]
    figures.mkdir(exist_ok=True)
    figure_designs(figures / "design.png", sim, X_before, sim.reference_points(geom), mm_per_unit)
    if getattr(task, "display", None) is not None:  # a colour display: draw what it shows
        figure_display(figures / "deformed.png", task, evaluation, geom)
        figure_colour_map(figures / "colours.png", sim, task, geom)
    else:
        figure_deformed(figures / "deformed.png", sim, task, evaluation)
    figure_curves(figures / "curves.png", task, trainer.history)
    if task.coordinates(task.eval_set()) is not None or task.outline:
        figure_errors(figures / "errors.png", task, evaluation)
    if task.in_time:  # the trajectory against its target, the energies, one sample moving
        task.figures(figures, sim, evaluation)
    elif animation_frames:
        sweep = trainer.evaluate(task.sweep(animation_frames))
        animation_sweep(figures / "sweep.gif", sim, task, sweep, geom, task.sweep_fps)
    if task.outline:
        figure_shapes(figures / "shapes.png", task, evaluation)
    return figures
