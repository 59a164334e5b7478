"""A load path's figure: the periodic cell tiled and deformed at a few strains, and its effective
response (nominal stress and Poisson's ratio against the axial strain, the bifurcation marked)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .cell import PeriodicCell
from .solve import PathResult


def tiled(cell: PeriodicCell, points: np.ndarray, F: np.ndarray, tiles=(2, 2)) -> list:
    """The patches' outlines of `tiles` periodic images of the cell at control points `points`,
    each image shifted by F_bar times a whole number of periods."""
    from ..viz.plot import patch_outlines

    outlines = patch_outlines(cell.disc, points)
    A = np.asarray(F, float).reshape(2, 2) @ np.diag(cell.period)
    return [o + A @ [i, j] for i in range(tiles[0]) for j in range(tiles[1]) for o in outlines]


def save_path_figure(
    file: Path, cell: PeriodicCell, X, path: PathResult, shown: int = 3, tiles=(2, 2)
) -> Path:
    """The figure of a load path: `shown` states (rest, then equally spaced up to the last) of
    the cell tiled `tiles` times, and the curves.  Returns the file."""
    from matplotlib.collections import PolyCollection

    from ..viz.plot import MATERIAL, plt

    X = np.asarray(X)
    picks = np.unique(np.linspace(-1, len(path.t) - 1, shown).round().astype(int))
    fig, axes = plt.subplots(1, len(picks) + 2, figsize=(3.2 * (len(picks) + 2), 3.4))
    for ax, k in zip(axes, picks):
        u = np.zeros_like(X) if k < 0 else path.u[k]
        F = np.eye(2).ravel() if k < 0 else path.F[k]
        colour = MATERIAL["invalid"] if k >= 0 and not path.valid[k] else MATERIAL["deformed"]
        polys = tiled(cell, X + u, F, tiles)
        ax.add_collection(PolyCollection(polys, facecolors=colour, edgecolors="#2b3a55", lw=0.2))
        ax.set_aspect("equal")
        ax.autoscale_view()
        ax.axis("off")
        strain = 0.0 if k < 0 else path.strain_axial[k]
        ax.set_title(f"axial strain {strain:+.3f}", fontsize=9)
    crit = path.critical["strain"] if path.critical else None
    rest = lambda a: np.concatenate([[0.0], a])  # the stress-strain curve starts at rest
    stress, poisson = axes[-2], axes[-1]
    stress.plot(rest(path.strain_axial), rest(path.P[:, path.axial]), ".-")
    stress.set_title("average nominal stress", fontsize=9)
    poisson.plot(path.strain_axial, path.poisson, ".-", label="secant")
    poisson.plot(path.strain_axial, path.poisson_incremental, ":", label="incremental")
    poisson.axhline(0.0, color="grey", lw=0.5)
    poisson.legend(fontsize=7)
    poisson.set_title("Poisson's ratio", fontsize=9)
    for ax in (stress, poisson):
        if crit is not None:
            ax.axvline(crit, color="#c0392b", lw=0.8, ls="--")
        ax.set_xlabel("axial nominal strain", fontsize=8)
        ax.tick_params(labelsize=7)
    title = f"bifurcation at strain {crit:.4f}" if crit is not None else "no bifurcation"
    fig.suptitle(f"{cell.disc.spec.name}: {title}", fontsize=10)
    fig.tight_layout()
    fig.savefig(file, dpi=150)
    plt.close(fig)
    return Path(file)
