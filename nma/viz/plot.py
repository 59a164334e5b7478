"""Figures of reference and deformed shapes (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from ..discretise import Discretisation  # noqa: E402
from ..geometry.sampling import sample_positions  # noqa: E402


def patch_outlines(disc: Discretisation, points, samples: int = 9) -> list[np.ndarray]:
    """Boundary polygon of every patch, traced through its material sample points."""
    grid = np.asarray(sample_positions(disc.mesh, points, samples)).reshape(
        disc.mesh.n_patches, samples, samples, 2
    )
    return [np.concatenate([g[:, 0], g[-1, 1:], g[::-1, -1][1:], g[0, ::-1][1:]]) for g in grid]


MATERIAL = {
    "initial": "#8fa8c8",
    "learned": "#7fb58f",
    "deformed": "#d9a38f",  # face colours
    "invalid": "#e06666",
}  # a deformed state that is not a physical object
ACTUATED, TRACKED = "#c0392b", "#2ca02c"


def draw_shape(
    ax,
    disc: Discretisation,
    points,
    title: str = "",
    colour=MATERIAL["initial"],
    tracked=None,
    samples: int = 9,
    frame: bool = False,
):
    """The patches at control points `points`, filled; `frame` keeps the axes (length units)."""
    ax.add_collection(
        PolyCollection(
            patch_outlines(disc, points, samples),
            facecolors=colour,
            edgecolors="#2b3a55",
            linewidths=0.3,
        )
    )
    if tracked:
        xy = np.array([np.asarray(v) for v in tracked.values()])
        ax.plot(xy[:, 0], xy[:, 1], "o", color=TRACKED, ms=4, label="tracked point")
    ax.set_aspect("equal")
    ax.autoscale_view()
    # a fixed place: matplotlib's automatic one measures every tick at each draw
    ax.set_title(title, fontsize=9, y=1.0)
    if not frame:
        ax.axis("off")


def draw_actuated(ax, disc: Discretisation, points) -> None:
    """The actuated boundaries (the control points each actuation moves), in red."""
    points = np.asarray(points)
    for k, group in enumerate(disc.boundary.group_points.values()):
        ax.plot(
            *points[group].T,
            "-",
            color=ACTUATED,
            lw=2,
            label="actuated boundary" if k == 0 else None,
        )


def save_reference_and_deformed(path: Path, disc: Discretisation, X, u, title: str = "") -> Path:
    X, u = np.asarray(X), np.asarray(u)
    fig, axes = plt.subplots(1, 2, figsize=(8, 4), sharex=True, sharey=True)
    draw_shape(axes[0], disc, X, "reference", tracked=disc.tracked_points(X))
    draw_shape(
        axes[1],
        disc,
        X + u,
        "deformed",
        colour=MATERIAL["deformed"],
        tracked=disc.tracked_points(X + u),
    )
    draw_actuated(axes[1], disc, X + u)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)
    return Path(path)
