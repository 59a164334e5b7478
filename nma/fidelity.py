"""fidelity=auto: the cheapest measured discretisation whose gradients are accurate enough.

experiments/fidelity_study.py measures, for each scene, every setting's forward + gradient time and
its gradient error against a converged reference (the worst relative norm error over the learned
geometry groups and the actuations, over random draws), and ships the results as
nma/data/fidelity/<scene>.json. A run with `fidelity.tolerance` set takes, from its scene's file,
the fastest setting whose gradient error is at most the tolerance; nothing is calibrated at run
time.  A front's errors are of the body held as it was measured, so each front records its scene's
pinned points, supports and actuated segments, and auto reads only a front of the scene held as the
run holds it: the paper's scenes ship two, as the paper holds them (<scene>.json) and their
well-posed variants without pins (<scene>_unpinned.json, `scene.pinned=[]`).  Each command resolves
its settings once, where it checks them (nma.resolve, which calls `resolve` here), and hands the
concrete setting down: below the commands no module knows of fidelity=auto.
"""

from __future__ import annotations

import dataclasses
import glob
import json
import logging
import os
from functools import lru_cache
from pathlib import Path

from .errors import ConfigError
from .geometry.options import Resolution
from .geometry.scene import SceneSpec
from .schema import Fidelity, SceneConfig

DATA = Path(__file__).resolve().parent / "data" / "fidelity"


@dataclasses.dataclass(frozen=True)
class Choice:
    fidelity: Fidelity
    tolerance: float
    measured: dict  # the chosen setting's row of the study: time, errors, dofs
    reason: str

    def record(self) -> dict:
        """What metrics.json keeps of the choice."""
        return {
            "ctrl_per_patch": self.fidelity.ctrl_per_patch,
            "quad_points": self.fidelity.quad_points,
            "tolerance": self.tolerance,
            "measured": dict(self.measured),
            "reason": self.reason,
        }


def _front(path: Path) -> dict:
    """A front as read (read again where the file changed since)."""
    st = path.stat()
    return _read(path, st.st_mtime_ns, st.st_size)


@lru_cache(maxsize=None)
def _read(path: Path, mtime_ns: int, size: int) -> dict:
    return json.loads(path.read_text())


HOLDS = {
    "pinned": "scene.pinned",
    "supports": "scene.supports",
    "groups": "scene.groups (the actuated segments)",
    "round_pore_corners": "scene.round_pore_corners",
}
# what a front that does not record a field was measured with
UNRECORDED = {"round_pore_corners": False}


def holds(spec: SceneSpec) -> dict:
    """How a scene is held, as its front records it (JSON's lists and floats, each list sorted, so
    that the same body listed in another order is held the same): its pinned points, supports
    (segment, fixed components) and actuated segments (actuation, segment, direction); and where its
    pores' corners are round (they converge faster, so the errors differ), that too."""
    pt = lambda p: [float(p[0]), float(p[1])]
    return {
        "pinned": sorted(pt(p) for p in spec.pinned),
        "supports": sorted(
            [pt(t.segment[0]), pt(t.segment[1]), sorted(int(c) for c in t.components)]
            for t in spec.supports
        ),
        "groups": sorted(
            [int(g.actuation), pt(g.segment[0]), pt(g.segment[1]), pt(g.direction)]
            for g in spec.groups
        ),
        **({"round_pore_corners": True} if spec.round_pore_corners else {}),
    }


def _field(held: dict, key: str):
    return held.get(key, UNRECORDED.get(key))


def front_path(scene: str | SceneSpec, data: Path = DATA) -> Path:
    """The front fidelity=auto reads for a scene: by name, the front of the scene as shipped
    (<name>.json); for a SceneSpec, the front measured with the scene held as it is (<name>.json or
    one of <name>_*.json: the well-posed variant's <name>_unpinned.json).  ConfigError where the
    scene has no front, or none of its fronts was measured so held."""
    name = scene if isinstance(scene, str) else scene.name
    shipped = data / f"{name}.json"
    if not shipped.is_file():
        raise ConfigError(
            f"fidelity=auto has no measured front for scene {name} ({shipped} is missing): "
            f"measure it with `python experiments/fidelity_study.py --scenes {name}` or choose a "
            "preset (fidelity=paper, fast, fine)"
        )
    if isinstance(scene, str):
        return shipped
    variants = sorted(Path(p) for p in glob.glob(str(data / f"{glob.escape(name)}_*.json")))
    paths = [shipped] + [p for p in variants if _front(p).get("scene") == name]
    held = holds(scene)
    match = [p for p in paths if _front(p).get("holds") == held]
    if match:
        return match[0]

    def differs(p: Path) -> str:
        other = _front(p).get("holds")
        if other is None:
            return (
                f"{p.name} records no holds (the scene's pins, supports and actuated "
                "segments): measure it again"
            )
        return (
            p.name
            + ": "
            + ", ".join(
                f"{HOLDS[k]}={json.dumps(_field(other, k))}"
                for k in HOLDS
                if _field(other, k) != _field(held, k)
            )
        )

    raise ConfigError(
        f"fidelity=auto has no front for scene {name} held as this run holds it: a front's errors "
        "are of the body held as it was measured, and each front measured for it differs ("
        + "; ".join(differs(p) for p in paths)
        + "; this run: "
        + ", ".join(
            f"{HOLDS[k]}={json.dumps(_field(held, k))}"
            for k in HOLDS
            if any(_field(_front(p).get("holds", {}), k) != _field(held, k) for p in paths)
        )
        + ").  Measure its front with experiments/fidelity_study.py, or choose a preset "
        "(fidelity=paper, fast, fine)"
    )


def fastest_within(rows: list[dict], tolerance: float) -> dict | None:
    """The measured setting with the smallest forward + gradient time whose gradient error is within
    `tolerance`, or None."""
    ok = [r for r in rows if r.get("gradient_error", float("inf")) <= tolerance]
    return min(ok, key=lambda r: r["forward_grad_seconds"]["median"]) if ok else None


def choose(scene: str | SceneSpec, tolerance: float, data: Path = DATA) -> Choice:
    """The fastest measured setting of `scene` whose gradient error is at most `tolerance`, from the
    front `front_path` finds."""
    path = front_path(scene, data)
    front = _front(path)
    scene = front["scene"]
    rows = front["settings"]
    pick = fastest_within(rows, tolerance)
    if pick is None:
        best = min(rows, key=lambda r: r["gradient_error"])
        raise ConfigError(
            f"fidelity.tolerance must be at least {best['gradient_error']:.3g} for scene {scene}, "
            f"the smallest gradient error measured ({best['ctrl_per_patch']} control points, "
            f"{best['quad_points']} Gauss points), got {tolerance}"
        )
    ref = front["reference"]
    reason = (
        f"fidelity=auto chose {pick['ctrl_per_patch']} control points per patch, "
        f"{pick['quad_points']} Gauss "
        f"points ({pick['dofs']} dofs) for scene {scene} ({path.name}): the fastest measured "
        f"setting ({pick['forward_grad_seconds']['median']:.3g} s forward + gradient on "
        f"{front['machine']['cpus']} "
        f"cores) whose gradient error {pick['gradient_error']:.3g} (cosine "
        f"{pick['gradient_cosine']:.4f}) "
        f"is within fidelity.tolerance={tolerance:g}; errors against {ref['ctrl_per_patch']} x "
        f"{ref['quad_points']}, measured by experiments/fidelity_study.py"
    )
    fidelity = Fidelity(pick["ctrl_per_patch"], pick["quad_points"], tolerance)
    return Choice(fidelity, tolerance, pick, reason)


def of_scene(fidelity: Fidelity, scene: SceneConfig) -> Fidelity:
    """`fidelity` with what fidelity=scene leaves open (None) taken from the scene's own `fidelity`
    (the discretisation its reproduction trains at), else the paper's 5 x 5."""
    if fidelity.concrete:
        return fidelity
    paper = Resolution()
    own = {
        "ctrl_per_patch": paper.ctrl_per_patch,
        "quad_points": paper.quad_points,
        **scene.fidelity,
    }
    return dataclasses.replace(
        fidelity, **{k: v for k, v in own.items() if getattr(fidelity, k) is None}
    )


def resolve(
    fidelity: Fidelity, scene: SceneConfig, chosen: tuple[int, int] | None = None
) -> Fidelity:
    """A concrete setting: `fidelity` itself (with fidelity=scene, what it leaves open from the
    scene's own setting, of_scene), or with a tolerance set (fidelity=auto), the setting its
    scene's front picks, the tolerance kept as the record of what was asked (resolving it again
    picks the same), or where `chosen` (control points, Gauss points) is given, that one: the
    setting a trained run's checkpoint records auto chose for it, which fronts measured since must
    not change. ConfigError where the scene has no front, no setting meets the tolerance, or the
    setting's model would not fit in this machine's memory."""
    fidelity = of_scene(fidelity, scene)
    if fidelity.tolerance is not None and chosen is not None:
        fidelity = dataclasses.replace(
            fidelity, ctrl_per_patch=int(chosen[0]), quad_points=int(chosen[1])
        )
    elif fidelity.tolerance is not None:
        choice = choose(scene.spec(), fidelity.tolerance)
        logging.getLogger("nma.fidelity").info(choice.reason)
        pick = choice.fidelity
        # the front sets the discretisation; what it does not measure is the user's
        fidelity = dataclasses.replace(
            fidelity, ctrl_per_patch=pick.ctrl_per_patch, quad_points=pick.quad_points
        )
    need, have = memory_floor(fidelity, scene), physical_memory()
    if have and need > have:
        raise ConfigError(
            f"fidelity.ctrl_per_patch={fidelity.ctrl_per_patch} with {fidelity.quad_points} Gauss "
            "points "
            f"needs at least {need / 2**30:.0f} GiB for scene {scene.name} (the element tangents "
            f"and quadrature tables of one state), more than this machine's {have / 2**30:.0f} GiB"
        )
    return fidelity


def memory_floor(fidelity: Fidelity, scene: SceneConfig) -> int:
    """Bytes a solve needs at least: per element its 18 x 18 tangent and, per Gauss point, the
    physical basis gradients (9 x 2) and the deformation gradient and its stress (2 x 2 each); a
    lower bound (the sparse factor and the batch come on top).  Patches: four per porous cell, one
    per solid cell, one per node of a central pore's ring."""
    cells = "".join(scene.rows())
    patches = 4 * cells.count("P") + cells.count("S") + len(scene.central_pore)
    elements = patches * (fidelity.ctrl_per_patch - 2) ** 2
    per_element = 8 * (18 * 18 + fidelity.quad_points**2 * (9 * 2 + 2 * 4))
    return elements * per_element


def physical_memory() -> int | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not POSIX: no up-front check
        return None


def choice_of(fidelity: Fidelity, scene: str | SceneSpec) -> Choice | None:
    """For a setting fidelity=auto resolved: the measured row it came from and why (metrics.json,
    the log); for one a trained run's checkpoint fixed (resolve's `chosen`) that today's fronts
    would not pick, or have no front for, a Choice that says so and has no measured row."""
    if fidelity.tolerance is None:
        return None
    try:
        choice = choose(scene, fidelity.tolerance)
    except ConfigError as exc:
        choice, why = None, str(exc)
    else:
        why = choice.reason
    if choice is not None and (choice.fidelity.ctrl_per_patch, choice.fidelity.quad_points) == (
        fidelity.ctrl_per_patch,
        fidelity.quad_points,
    ):
        return choice
    return Choice(
        fidelity,
        fidelity.tolerance,
        {},
        f"fidelity=auto chose {fidelity.ctrl_per_patch} control points per patch, "
        f"{fidelity.quad_points} "
        f"Gauss points when the run was trained (its checkpoint records it); today: {why}",
    )
