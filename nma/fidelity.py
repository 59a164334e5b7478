"""fidelity=auto: the cheapest measured discretisation whose gradients are accurate enough.

experiments/fidelity_study.py measures, for each scene, every setting's forward + gradient time and its
gradient error against a converged reference (the worst relative norm error over the learned geometry
groups and the actuations, over random draws), and ships the results as nma/data/fidelity/<scene>.json.
A run with `fidelity.tolerance` set takes, from its scene's file, the fastest setting whose gradient
error is at most the tolerance; nothing is calibrated at run time.  Each command resolves its settings
once, where it checks them (`resolve`), and hands the concrete setting down: below the commands no
module knows of fidelity=auto.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import os
from functools import lru_cache
from pathlib import Path

from .errors import ConfigError
from .schema import Fidelity, SceneConfig

DATA = Path(__file__).resolve().parent / "data" / "fidelity"


@dataclasses.dataclass(frozen=True)
class Choice:
    fidelity: Fidelity
    tolerance: float
    measured: dict      # the chosen setting's row of the study: time, errors, dofs
    reason: str

    def record(self) -> dict:
        """What metrics.json keeps of the choice."""
        return {"ctrl_per_patch": self.fidelity.ctrl_per_patch, "quad_points": self.fidelity.quad_points,
                "tolerance": self.tolerance, "measured": self.measured, "reason": self.reason}


@lru_cache(maxsize=None)
def _front(path: Path) -> dict:
    return json.loads(path.read_text())


def fastest_within(rows: list[dict], tolerance: float) -> dict | None:
    """The measured setting with the smallest forward + gradient time whose gradient error is within
    `tolerance`, or None."""
    ok = [r for r in rows if r.get("gradient_error", float("inf")) <= tolerance]
    return min(ok, key=lambda r: r["forward_grad_seconds"]["median"]) if ok else None


@lru_cache(maxsize=None)
def choose(scene: str, tolerance: float, data: Path = DATA) -> Choice:
    """The fastest measured setting of `scene` whose gradient error is at most `tolerance`."""
    path = data / f"{scene}.json"
    if not path.is_file():
        raise ConfigError(f"fidelity=auto has no measured front for scene {scene} ({path} is missing): measure it "
                          f"with `python experiments/fidelity_study.py --scenes {scene}` or choose a preset "
                          "(fidelity=paper, fast, fine)")
    front = _front(path)
    rows = front["settings"]
    pick = fastest_within(rows, tolerance)
    if pick is None:
        best = min(rows, key=lambda r: r["gradient_error"])
        raise ConfigError(f"fidelity.tolerance must be at least {best['gradient_error']:.3g} for scene {scene}, the "
                          f"smallest gradient error measured ({best['ctrl_per_patch']} control points, "
                          f"{best['quad_points']} Gauss points), got {tolerance}")
    ref = front["reference"]
    reason = (f"fidelity=auto chose {pick['ctrl_per_patch']} control points per patch, {pick['quad_points']} Gauss "
              f"points ({pick['dofs']} dofs) for scene {scene}: the fastest measured setting "
              f"({pick['forward_grad_seconds']['median']:.3g} s forward + gradient on {front['machine']['cpus']} "
              f"cores) whose gradient error {pick['gradient_error']:.3g} (cosine {pick['gradient_cosine']:.4f}) "
              f"is within fidelity.tolerance={tolerance:g}; errors against {ref['ctrl_per_patch']} x "
              f"{ref['quad_points']}, measured by experiments/fidelity_study.py")
    fidelity = Fidelity(pick["ctrl_per_patch"], pick["quad_points"], tolerance)
    return Choice(fidelity, tolerance, pick, reason)


def resolve(fidelity: Fidelity, scene: SceneConfig) -> Fidelity:
    """A concrete setting: `fidelity` itself, or with a tolerance set (fidelity=auto), the setting its
    scene's front picks, the tolerance kept as the record of what was asked (resolving it again picks
    the same).  ConfigError where the scene has no front, no setting meets the tolerance, or the
    setting's model would not fit in this machine's memory."""
    if fidelity.tolerance is not None:
        choice = choose(scene.name, fidelity.tolerance)
        logging.getLogger("nma.fidelity").info(choice.reason)
        pick = choice.fidelity
        # the front sets the discretisation; what it does not measure is the user's
        fidelity = dataclasses.replace(fidelity, ctrl_per_patch=pick.ctrl_per_patch, quad_points=pick.quad_points)
    need, have = memory_floor(fidelity, scene), physical_memory()
    if have and need > have:
        raise ConfigError(f"fidelity.ctrl_per_patch={fidelity.ctrl_per_patch} with {fidelity.quad_points} Gauss points "
                          f"needs at least {need / 2**30:.0f} GiB for scene {scene.name} (the element tangents and "
                          f"quadrature tables of one state), more than this machine's {have / 2**30:.0f} GiB")
    return fidelity


def memory_floor(fidelity: Fidelity, scene: SceneConfig) -> int:
    """Bytes a solve needs at least: per element its 18 x 18 tangent and, per Gauss point, the physical
    basis gradients (9 x 2) and the deformation gradient and its stress (2 x 2 each); a lower bound (the
    sparse factor and the batch come on top).  Patches: four per porous cell, one per solid cell, one
    per node of a central pore's ring."""
    cells = "".join(scene.rows())
    patches = 4 * cells.count("P") + cells.count("S") + len(scene.central_pore)
    elements = patches * (fidelity.ctrl_per_patch - 2) ** 2
    per_element = 8 * (18 * 18 + fidelity.quad_points ** 2 * (9 * 2 + 2 * 4))
    return elements * per_element


def physical_memory() -> int | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not POSIX: no up-front check
        return None


def choice_of(fidelity: Fidelity, scene: str) -> Choice | None:
    """For a setting fidelity=auto resolved: the measured row it came from and why (metrics.json, the log)."""
    return None if fidelity.tolerance is None else choose(scene, fidelity.tolerance)
