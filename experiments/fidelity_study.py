"""Fidelity study: what each discretisation setting costs and how wrong it is, for every scene.

    # every scene (about an hour on 2 cores)
    python experiments/fidelity_study.py
    # a smoke run: outputs/studies/fidelity_quick
    python experiments/fidelity_study.py --scenes translation --quick
    # tables and figures from the JSON only
    python experiments/fidelity_study.py --replot
    python experiments/fidelity_study.py --unpinned             # the well-posed variants' fronts

Settings: control points per patch (5, 8, 11) x Gauss points per span (2..5) at the solver's default
Newton tolerance, and looser tolerances (1e-8, 1e-6) at the paper's (5 x 5) and the fast (5 x 3)
setting. Per setting: DOFs; forward and forward + gradient wall time (min and median over the draws,
after one compiling call, all settings of a scene in one process); the peak resident memory while it
ran; and, against a reference discretisation,
  - the error of what the task reads off the equilibrium (tracked points, the pore's boundary
    points, the segment scores), max over the draws, in the task's units,
  - the gradient of the task's loss with respect to each learned group (radii, corners, central
    radii, colours: whichever the scene has) and the actuations: relative norm error and cosine
    similarity, worst over the draws.  `gradient_error` is the worst relative error over the groups.
Draws (fixed per scene): one random non-uniform design inside the design box (random colours for the
display), and per draw actuations uniform in [-d_max/2, d_max/2] with a task descriptor.

The reference is 14 control points per patch, 5 Gauss points, tolerance 1e-12.  It is checked by
successive refinement: the differences 8 -> 11 -> 14 (5 Gauss points) give an observed order of
convergence p and a Richardson estimate of the reference's own error, |q11 - q14| / ((h11/h14)^p -
1). `--convergence` checks that estimate with one more refinement (8 -> 11 -> 14 -> 17 at 5 Gauss
points, tolerance 1e-12): the order from each three successive levels (the same p twice says the
ladder is in the asymptotic range, where Richardson's estimate holds), the Richardson limit q* = q17
+ (q17 - q14) / ((h14/h17)^p - 1) per draw and component, and the error of the settings runs train
at (5 x 2: the reproductions, 8 x 2: fidelity=auto's usual pick, 5 x 5: the paper's) against the
14 x 5 reference and against q*: outputs/studies/fidelity/<scene>.convergence.{json,md}.  Every
state is checked (nma.geometry.validity): a converged state that cannot exist (material inverted
between Gauss points, walls through each other) is named, and the orders are taken again over the
draws physical at every level.  The radii gradient's convergence is also split by where each radius
acts: the corner radii by the pore's angle at their corner (the sharper, the more singular the
stress there), the side radii next to a corner and mid-side.

Writes outputs/studies/fidelity/<scene>.{json,md,png} (the png: time against error, log-log, the
Pareto front marked) and the measured front that `fidelity=auto` reads,
nma/data/fidelity/<scene>.json, which records how the scene was held (its pinned points, supports
and actuated segments: auto reads a front only for a scene held the same way).  `--unpinned`
measures each scene's well-posed variant (scene.pinned=[]): <scene>_unpinned.{json,md,png} and the
front nma/data/fidelity/<scene>_unpinned.json.  `--round-corners` measures the scene with its pores'
walls meeting tangent at their corners (scene.round_pore_corners):
<scene>[_unpinned]_round*.{json,md,png}, its front, or with --convergence its reference check.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCENES = ["translation", "rotation_single", "rotation_double", "shape_matching", "digital_mnist"]
DEFAULT_RTOL = 1e-10
GRID = [(c, q, DEFAULT_RTOL) for c in (5, 8, 11) for q in (2, 3, 4, 5)] + [
    (5, q, rtol) for q in (3, 5) for rtol in (1e-8, 1e-6)
]
REFERENCE = (14, 5, 1e-12)
QUICK_GRID = [(5, 3, DEFAULT_RTOL), (5, 5, DEFAULT_RTOL), (8, 5, DEFAULT_RTOL), (5, 5, 1e-6)]
QUICK_REFERENCE = (11, 5, 1e-12)
PAPER, FAST = (5, 5), (5, 3)
# --convergence: control points per patch of the refinements (5 Gauss points)
LADDER = (8, 11, 14, 17)
# --convergence: the reproductions', fidelity=auto's usual, the paper's
CHECKED = ((5, 2), (8, 2), PAPER)


class PeakMemory:
    """The largest resident set size of this process while the block ran, sampled every 5 ms (the
    process-wide maximum of getrusage cannot be reset between settings)."""

    def __enter__(self):
        self.page = os.sysconf("SC_PAGE_SIZE")
        self.before = self.peak = self.rss()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def rss(self) -> int:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * self.page

    def _sample(self):
        while not self._stop.wait(0.005):
            self.peak = max(self.peak, self.rss())

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self.rss())


def scene_config(scene: str, unpinned: bool = False, round_corners: bool = False) -> dict:
    """The scene's config as the study measures it: as shipped, or its well-posed variant (its
    pinned points removed; the actuated segments hold it), with `round_corners` its pores' walls
    meeting tangent at the pore corners (scene.round_pore_corners)."""
    from nma import config

    spec = config.load("scene", scene)
    if unpinned:
        spec["pinned"] = []
    if round_corners:
        spec["round_pore_corners"] = True
    return spec


def stats(xs) -> dict:
    return {"min": float(np.min(xs)), "median": float(np.median(xs)), "n": len(xs)}


# the random design's radii and corner moves: uniform over this central part of their ranges
SPREAD = 0.6
ACTUATION = 0.5  # the actuations: uniform in [-ACTUATION d_max, ACTUATION d_max]


def study_design(design, seed: int = 0, spread: float = SPREAD):
    """The study's random design inside the design box (GridDesign.random_params with `spread`), and
    the generator that drew it, to draw the actuations from next."""
    rng = np.random.default_rng(seed)
    return design.random_params(rng, spread), rng


def study_draws(
    sim,
    d_max: float,
    draws: int,
    seed: int = 0,
    spread: float = SPREAD,
    actuation: float = ACTUATION,
):
    """The study's draws, the same for every setting of a scene: one random design (study_design),
    and `draws` actuation vectors uniform in [-actuation d_max, actuation d_max] (a smaller
    `actuation` gives the same directions, shorter)."""
    geom, rng = study_design(sim.disc.design, seed, spread)
    return geom, rng.uniform(-actuation, actuation, (draws, sim.n_actuations)) * d_max


def measure(
    scene: str,
    setting,
    draws: int,
    seed: int = 0,
    grading: float = 1.0,
    unpinned: bool = False,
    spread: float = SPREAD,
    actuation: float = ACTUATION,
    round_corners: bool = False,
) -> dict:
    """Times, memory, observed outputs and loss gradients of one setting on the scene's fixed draws,
    with knots graded by `grading` (fidelity.grading), the scene's pinned points removed where
    `unpinned` (its well-posed variant: the actuated segments hold it), round pore corners where
    `round_corners`, the random design drawn with `spread`, the actuations with `actuation`
    (study_draws)."""
    import jax

    from nma import config, tasks  # noqa: F401  (declares the tasks)
    from nma.discretise import discretise
    from nma.geometry.validity import StateChecker
    from nma.schema import scene_from_config
    from nma.mechanics.material import material
    from nma.registry import TASKS
    from nma.schema import TASK_SCHEMAS, Fidelity, build
    from nma.simulator import Simulator
    from nma.solver.status import Status
    from nma.solver.options import NewtonOptions

    ctrl, quad, rtol = setting
    with PeakMemory() as memory:
        spec = scene_config(scene, unpinned, round_corners)
        # at 5 control points every side has one span per design span: nothing to grade
        # without Newton's element bound, as the shipped fronts were measured (fidelity=auto reads
        # them)
        sim = Simulator(
            discretise(
                scene_from_config(spec), Fidelity(ctrl, quad, grading=grading if ctrl > 5 else 1.0)
            ),
            "auto",
            NewtonOptions(rtol=rtol, element_bound=False),
        )
        task = TASKS.get(scene)(build(TASK_SCHEMAS[scene], config.load("task", scene)), sim)
        geom, ds = study_draws(sim, task.d_max, draws, seed, spread, actuation)
        learned = [k for k in geom if k not in task.frozen_geometry]
        ts = task.sample(jax.random.PRNGKey(seed), draws)
        mat = material(0.07, 0.3)

        def loss(geom, d, t):
            X = sim.reference_points(geom)
            u, info = sim.equilibrium(X, d, mat)
            out = task.observe(sim, geom, X, u, mat)
            return task.loss(out, t), (out, info, u)

        forward = jax.jit(loss)
        forward_grad = jax.jit(jax.value_and_grad(loss, argnums=(0, 1), has_aux=True))
        jax.block_until_ready(forward(geom, ds[0], ts[0]))  # compile both before timing
        jax.block_until_ready(forward_grad(geom, ds[0], ts[0]))
        t_fwd, t_grad, outs, grads, iters, failed, nonphysical = [], [], [], [], [], [], []
        checker = StateChecker(sim.disc.mesh, sim.reference_points(geom))
        for i in range(draws):
            t0 = time.perf_counter()
            jax.block_until_ready(forward(geom, ds[i], ts[i]))
            t_fwd.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            (_, (out, info, u)), (g_geom, g_d) = jax.block_until_ready(
                forward_grad(geom, ds[i], ts[i])
            )
            t_grad.append(time.perf_counter() - t0)
            if int(info.status) != Status.CONVERGED:
                failed.append(
                    {"draw": i, "load_reached": float(info.load), "residual": float(info.residual)}
                )
            # a converged state that cannot exist (material inverted, walls through each other)
            else:
                state = checker.check(u)
                if not state.valid:
                    nonphysical.append(
                        {"draw": i, "min_J": state.min_J, "problems": state.problems()}
                    )
            iters.append(int(info.iterations))
            outs.append(np.asarray(out).ravel())
            grads.append(
                {
                    **{k: np.asarray(g_geom[k]).ravel() for k in learned},
                    "actuations": np.asarray(g_d),
                }
            )
    return {
        "ctrl_per_patch": ctrl,
        "quad_points": quad,
        "rtol": rtol,
        "dofs": sim.disc.boundary.n_dofs,
        "forward_seconds": stats(t_fwd),
        "forward_grad_seconds": stats(t_grad),
        "newton_iterations": stats(iters),
        "peak_memory_mb": memory.peak / 2**20,
        "added_memory_mb": (memory.peak - memory.before) / 2**20,
        "failed_draws": failed,
        "nonphysical_draws": nonphysical,
        "_outputs": np.array(outs),
        "_grads": grads,
    }


def quantities(row: dict) -> dict:
    """What the study compares between settings, per draw: the task's outputs and each gradient
    group."""
    return {
        "observable": row["_outputs"],
        **{f"gradient {k}": np.array([d[k] for d in row["_grads"]]) for k in row["_grads"][0]},
    }


def distance(
    name: str, a: np.ndarray, b: np.ndarray, scale: np.ndarray | None = None
) -> np.ndarray:
    """Per draw: outputs in the task's units (max abs); gradients relative to the norm of `scale`
    (default b)."""
    if name == "observable":
        return np.abs(a - b).max(axis=1)
    return np.linalg.norm(a - b, axis=1) / np.linalg.norm(b if scale is None else scale, axis=1)


def cosine(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per draw, the cosine of the angle between two gradients (rows)."""
    return np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))


def compare(row: dict, ref: dict) -> dict:
    """Errors of one setting's outputs and gradients against the reference's, worst over the
    draws."""
    mine, theirs = quantities(row), quantities(ref)
    groups = {
        name.removeprefix("gradient "): {
            "relative_error": float(np.max(distance(name, mine[name], theirs[name]))),
            "cosine": float(np.min(cosine(mine[name], theirs[name]))),
        }
        for name in theirs
        if name != "observable"
    }
    return {
        "observable_error": float(
            np.max(distance("observable", mine["observable"], theirs["observable"]))
        ),
        "gradient": groups,
        "gradient_error": max(v["relative_error"] for v in groups.values()),
        "gradient_cosine": min(v["cosine"] for v in groups.values()),
    }


def observed_order(diffs: list[float], spans: list[int]) -> dict:
    """Order p with e(h) = C h^p from the differences of three successive refinements (h = 1/spans),
    and the Richardson estimate of the finest one's own error."""
    from scipy.optimize import brentq

    h = 1.0 / np.asarray(spans, dtype=float)
    d1, d2 = diffs
    if not (d1 > 0 and d2 > 0 and d1 > d2):
        return {"differences": diffs, "order": None, "reference_error": None}
    f = lambda p: (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p) - d1 / d2
    try:
        p = brentq(f, 0.05, 12.0)
    except ValueError:
        return {"differences": diffs, "order": None, "reference_error": None}
    return {
        "differences": diffs,
        "order": float(p),
        "reference_error": float(d2 / ((h[1] / h[2]) ** p - 1)),
    }


def draws_of(row: dict, keep: list[int]) -> dict:
    """A measured setting restricted to the draws `keep`."""
    return {**row, "_outputs": row["_outputs"][keep], "_grads": [row["_grads"][i] for i in keep]}


def refinement(levels: list[dict]) -> tuple[dict, dict]:
    """Successive refinement at fixed Gauss points, coarse to fine.  Per quantity: the differences
    of consecutive levels (worst over the draws), the observed order from each three successive
    levels (the same order twice: the asymptotic range, where Richardson holds), the Richardson
    estimate of the finest level's own error with the last order; and, apart (arrays, per draw), the
    Richardson limit."""
    spans = [r["ctrl_per_patch"] - 2 for r in levels]  # knot spans per patch side, h = 1 / spans
    summary, limits = {"spans": spans, "quantities": {}}, {}
    per_level = [quantities(r) for r in levels]
    for name in per_level[-1]:
        q = [level[name] for level in per_level]
        # one scale for every difference (the finest level), so that a power law stays one
        diffs = [float(np.max(distance(name, a, b, q[-1]))) for a, b in zip(q[:-1], q[1:])]
        triples = [
            observed_order(diffs[j : j + 2], spans[j : j + 3]) for j in range(len(diffs) - 1)
        ]
        p = triples[-1]["order"]
        limits[name] = q[-1] + (q[-1] - q[-2]) / ((spans[-1] / spans[-2]) ** p - 1) if p else None
        summary["quantities"][name] = {
            "differences": diffs,
            "orders": [t["order"] for t in triples],
            "finest_error": triples[-1]["reference_error"],
        }
    return summary, limits


def richardson(
    scene: str,
    draws: int,
    ladder=LADDER,
    checked=CHECKED,
    grading: float = 1.0,
    unpinned: bool = False,
    spread: float = SPREAD,
    actuation: float = ACTUATION,
    round_corners: bool = False,
) -> dict:
    """The reference check: refinement one level past the reference, the Richardson limit, and the
    error of the settings runs train at against the reference and against that limit (worst over the
    draws); every level with `grading`, `unpinned`, `spread`, `actuation` and `round_corners` (see
    measure)."""
    model = {
        "grading": grading,
        "unpinned": unpinned,
        "spread": spread,
        "actuation": actuation,
        "round_corners": round_corners,
    }
    levels = [measure(scene, (c, REFERENCE[1], REFERENCE[2]), draws, **model) for c in ladder]
    for r in levels:
        print(
            f"{scene}: {r['ctrl_per_patch']}x{r['quad_points']}: {r['dofs']} dofs, "
            "forward+gradient "
            f"{r['forward_grad_seconds']['median']:.2f} s",
            flush=True,
        )
    rows = {(r["ctrl_per_patch"], r["quad_points"]): r for r in levels}
    rows.update({s: measure(scene, (*s, DEFAULT_RTOL), draws, **model) for s in checked})
    # a solve that stopped short has no answer to compare: its draw is left out of every level
    # (hours of the other draws' solves are kept), and only where no draw solves everywhere is there
    # no check
    failed = {f"{c}x{q}": r["failed_draws"] for (c, q), r in rows.items() if r["failed_draws"]}
    unsolved = {d["draw"] for found in failed.values() for d in found}
    solved = [i for i in range(draws) if i not in unsolved]
    if not solved:
        raise RuntimeError(f"{scene}: no draw solves at every level, no reference check: {failed}")
    if unsolved:
        rows = {k: draws_of(r, solved) for k, r in rows.items()}
        levels = [rows[(c, REFERENCE[1])] for c in ladder]
    result, limits = refinement(levels)
    # states the solver converged to that cannot exist: their gradients have no continuum limit to
    # converge to, so the orders are taken again over the draws physical at every level of the
    # ladder
    nonphysical = {
        f"{c}x{q}": r["nonphysical_draws"] for (c, q), r in rows.items() if r["nonphysical_draws"]
    }
    bad = {d["draw"] for r in levels for d in r["nonphysical_draws"]}
    physical = [i for i in solved if i not in bad]
    if bad - unsolved:
        result["physical"] = {
            "draws": physical,
            **(
                refinement([draws_of(r, [solved.index(i) for i in physical]) for r in levels])[0]
                if physical
                else {}
            ),
        }
    per_row = {setting: quantities(r) for setting, r in rows.items()}
    reference = per_row[REFERENCE[:2]]
    for name, v in result["quantities"].items():
        against = {"reference": reference[name], "limit": limits[name]}
        v["error"] = {}
        for (c, qp), mine in per_row.items():
            e = {
                f"vs_{k}": None if b is None else float(np.max(distance(name, mine[name], b)))
                for k, b in against.items()
            }
            if name != "observable":  # a right direction matters more to Adam than a right length
                e.update(
                    {
                        f"cosine_vs_{k}": None
                        if b is None
                        else float(np.min(cosine(mine[name], b)))
                        for k, b in against.items()
                    }
                )
            v["error"][f"{c}x{qp}"] = e
    return {
        "scene": scene,
        **model,
        "draws": draws,
        "quad_points": REFERENCE[1],
        "machine": {"cpus": os.cpu_count()},
        "nonphysical": nonphysical,
        "failed": failed,
        "solved_draws": solved,
        "dofs": {f"{c}x{q}": r["dofs"] for (c, q), r in rows.items()},
        "forward_grad_seconds": {
            f"{c}x{q}": r["forward_grad_seconds"] for (c, q), r in rows.items()
        },
        # each level's quantities per draw, for orders component by component (which radius
        # converges slowest)
        "values": {
            name: {
                f"{r['ctrl_per_patch']}x{r['quad_points']}": q[name].tolist()
                for r, q in zip(levels, map(quantities, levels))
            }
            for name in result["quantities"]
        },
        **result,
    }


# pore corner angles (deg) that split the radii gradient's corner radii
CORNER_BINS = (45.0, 90.0, 180.0)


def radii_by_corner(result: dict, seed: int = 0) -> list[dict] | None:
    """The radii gradient's convergence split by where each radius acts: the corner radii by the
    pore's angle at their corner (GridDesign.pore_corner_angles, on the study's random design: the
    sharper the corner, the stronger its stress singularity; over 180 deg no re-entrant corner), the
    side radii next to a corner and those mid-side.  Per group: its entries' differences between
    levels (relative to the whole finest gradient's norm, worst over the draws, as `refinement`
    measures the whole), the orders from each three levels, and its share of the finest difference
    (squared norms over every draw). None where the result has no per-level radii gradient."""
    from nma.geometry.design import GridDesign, radii_per_side
    from nma.schema import scene_from_config

    values = result.get("values", {}).get("gradient radii")
    if not values:
        return None
    round_corners = result.get("round_corners", False)
    design = GridDesign.from_spec(
        scene_from_config(
            scene_config(result["scene"], result.get("unpinned", False), round_corners)
        )
    )
    geom, _ = study_design(design, seed, result.get("spread", SPREAD))
    # the side's first is its corner's, unless the corners are round
    per_side = radii_per_side(round_corners)
    angle = np.repeat(design.pore_corner_angles(geom), per_side, axis=1).ravel()
    # 0: a corner, 1 .. 3 along the side
    place = np.tile(np.arange(4 * per_side) % per_side + round_corners, len(design.porous))
    corner, middle = place == 0, place == 2
    edges = (0.0, *CORNER_BINS, 360.0)
    groups = {
        f"corner radii, pore angle {lo:g}-{hi:g} deg": corner & (angle >= lo) & (angle < hi)
        for lo, hi in zip(edges[:-1], edges[1:])
    }
    groups["side radii next to a corner"] = ~corner & ~middle
    groups["side radii mid-side"] = middle
    q = np.array([values[k] for k in values])  # (levels, draws, radii)
    steps, scale = np.diff(q, axis=0), np.linalg.norm(q[-1], axis=1)
    rows = []
    for name, mask in groups.items():
        if not mask.any():
            continue
        diffs = [float(np.max(np.linalg.norm(d[:, mask], axis=1) / scale)) for d in steps]
        rows.append(
            {
                "group": name,
                "radii": int(mask.sum()),
                "differences": diffs,
                "orders": [
                    observed_order(diffs[j : j + 2], result["spans"][j : j + 3])["order"]
                    for j in range(len(diffs) - 1)
                ],
                "share_of_finest_difference": float(
                    np.sum(steps[-1][:, mask] ** 2) / np.sum(steps[-1] ** 2)
                ),
            }
        )
    return rows


def variant(
    scene: str,
    grading: float = 1.0,
    unpinned: bool = False,
    spread: float = SPREAD,
    actuation: float = ACTUATION,
    round_corners: bool = False,
) -> str:
    """A result's file stem: the scene, `_unpinned` (its well-posed variant), `_round` (round pore
    corners), `_graded<g>`, `_spread<s>`, `_actuation<a>`."""
    return (
        scene
        + "_unpinned" * bool(unpinned)
        + "_round" * bool(round_corners)
        + (f"_graded{grading:g}" if grading != 1.0 else "")
        + (f"_spread{spread:g}" if spread != SPREAD else "")
        + (f"_actuation{actuation:g}" if actuation != ACTUATION else "")
    )


def stem(result: dict) -> str:
    return variant(
        result["scene"],
        result.get("grading", 1.0),
        result.get("unpinned", False),
        result.get("spread", SPREAD),
        result.get("actuation", ACTUATION),
        result.get("round_corners", False),
    )


def nonphysical_lines(said: str, found: list[tuple[str, dict]]) -> list[str]:
    """A report's list of the states the solver converged to that cannot exist, each (setting, draw
    record); none where every state is physical."""
    if not found:
        return []
    return [
        "",
        "States the solver converged to that cannot exist (nma.geometry.validity: material "
        f"inverted between Gauss points, walls through each other); {said}:",
        "",
    ] + [f"- {setting}, draw {d['draw']}: {'; '.join(d['problems'])}" for setting, d in found]


def convergence_report(result: dict, out: Path) -> str:
    scene, ladder, name = result["scene"], [s + 2 for s in result["spans"]], stem(result)
    fmt = lambda v: "-" if v is None else f"{v:.3g}"
    # a quantity's (or a group's) differences between levels and the orders they give, two table
    # cells
    trend = lambda v: (
        f"{' -> '.join(f'{d:.3g}' for d in v['differences'])} | "
        f"{', '.join(fmt(o) for o in v['orders'])}"
    )
    ref = f"{REFERENCE[0]}x{REFERENCE[1]}"
    held = (
        "held by its actuated segments alone (scene.pinned=[])"
        if result.get("unpinned")
        else "with the paper's pinned corners"
    )
    knots = (
        f"knots graded towards the patch corners (fidelity.grading={result['grading']:g})"
        if result.get("grading", 1.0) != 1.0
        else "uniform knots"
    )
    if result.get("round_corners"):
        held += ", round pore corners (scene.round_pore_corners)"
    design = (
        ""
        if result.get("spread", SPREAD) == SPREAD
        else f", random design's radii over the central {result['spread']:g} of their range"
    )
    design += (
        ""
        if result.get("actuation", ACTUATION) == ACTUATION
        else f", actuations within +-{result['actuation']:g} d_max"
    )
    lines = [
        f"# Fidelity study, reference check: {scene}, {held}, {knots}{design}",
        "",
        f"Successive refinement {' -> '.join(map(str, ladder))} control points per patch at "
        f"{result['quad_points']} Gauss points (tolerance {REFERENCE[2]:g}), {result['draws']} "
        "draws.  "
        "Orders from each three successive levels (e(h) = C h^p, h = 1 / knot spans); the limit "
        "q* is Richardson's from the last two levels with the last order.  Errors: worst over the "
        "draws; "
        "observable in the task's units (max abs), gradients relative to the norm of what they are "
        f"compared with.  Each cell: against the {ref} reference / against q*.",
        "",
        "| quantity | differences between levels | orders | finest level's error (Richardson) | "
        + " | ".join(result["dofs"])
        + " |",
        "|---|---|---|---|" + "---|" * len(result["dofs"]),
    ]
    for quantity, v in result["quantities"].items():
        lines.append(
            f"| {quantity} | {trend(v)} | {fmt(v['finest_error'])} | "
            + " | ".join(
                f"{fmt(e['vs_reference'])} / {fmt(e['vs_limit'])}" for e in v["error"].values()
            )
            + " |"
        )
    lines += [
        "",
        "Gradient cosines (worst over the draws), against the reference / against q*:",
        "",
        "| quantity | " + " | ".join(result["dofs"]) + " |",
        "|---|" + "---|" * len(result["dofs"]),
    ]
    cos = lambda v: "-" if v is None else f"{v:.4f}"
    lines += [
        f"| {quantity} | "
        + " | ".join(
            f"{cos(e['cosine_vs_reference'])} / {cos(e['cosine_vs_limit'])}"
            for e in v["error"].values()
        )
        + " |"
        for quantity, v in result["quantities"].items()
        if quantity != "observable"
    ]
    if result.get("failed"):
        lines += [
            "",
            "Draws whose solve stopped short at some level, left out of every level above (the "
            f"solver's own words; {len(result['solved_draws'])} of {result['draws']} draws kept: "
            f"{', '.join(map(str, result['solved_draws']))}):",
            "",
        ]
        lines += [
            f"- {level}, draw {d['draw']}: load reached {d['load_reached']:.3f}, residual "
            f"{d['residual']:.3g}"
            for level, found in result["failed"].items()
            for d in found
        ]
    lines += nonphysical_lines(
        "every order and error above includes them",
        [
            (level, d)
            for level, found in result.get("nonphysical", {}).items()
            for d in found
            if d["draw"] in result.get("solved_draws", range(result["draws"]))
        ],
    )
    phys = result.get("physical")
    if phys and phys["draws"]:
        lines += [
            "",
            f"Over the draws physical at every level of the ladder ({len(phys['draws'])} of "
            f"{result['draws']}: {', '.join(map(str, phys['draws']))}):",
            "",
            "| quantity | differences between levels | orders | finest level's error (Richardson) "
            "|",
            "|---|---|---|---|",
        ]
        lines += [
            f"| {quantity} | {trend(v)} | {fmt(v['finest_error'])} |"
            for quantity, v in phys["quantities"].items()
        ]
    elif phys:
        lines += [
            "",
            "No draw is physical at every level of the ladder: no order over physical states.",
        ]
    by_corner = radii_by_corner(result)
    if by_corner:
        lines += [
            "",
            "The radii gradient by where each radius acts (the corner radii by the pore's angle "
            "at their "
            "corner: the material around it spans 360 deg minus that, a re-entrant corner), "
            "differences relative to the whole finest gradient:",
            "",
            "| radii | how many | differences between levels | orders | share of the finest "
            "difference |",
            "|---|---|---|---|---|",
        ]
        lines += [
            f"| {g['group']} | {g['radii']} | {trend(g)} | {g['share_of_finest_difference']:.2f} |"
            for g in by_corner
        ]
    lines += ["", "| setting | dofs | forward + gradient s (median) |", "|---|---|---|"]
    lines += [
        f"| {k} | {result['dofs'][k]} | {t['median']:.3g} |"
        for k, t in result["forward_grad_seconds"].items()
    ]
    text = "\n".join(lines) + "\n"
    (out / f"{name}.convergence.json").write_text(json.dumps(result, indent=1))
    (out / f"{name}.convergence.md").write_text(text)
    return text


def pareto(rows: list[dict], error: str) -> list[int]:
    """Indices of the settings no other setting beats in both time and error."""
    pts = [(r["forward_grad_seconds"]["median"], r[error]) for r in rows]
    return [
        i
        for i, (t, e) in enumerate(pts)
        if not any((t2 <= t and e2 <= e) and (t2 < t or e2 < e) for t2, e2 in pts)
    ]


def run_scene(
    scene: str, quick: bool, draws: int, unpinned: bool = False, round_corners: bool = False
) -> dict:
    from nma.fidelity import holds
    from nma.schema import scene_from_config

    grid, reference = (QUICK_GRID, QUICK_REFERENCE) if quick else (GRID, REFERENCE)
    ref = measure(scene, reference, draws, unpinned=unpinned, round_corners=round_corners)
    print(
        f"{scene}: reference {reference}: {ref['dofs']} dofs, forward+gradient "
        f"{ref['forward_grad_seconds']['median']:.2f} s",
        flush=True,
    )
    rows = {}
    for setting in sorted(grid, key=lambda s: (s[0], s[1], -s[2])):
        r = measure(scene, setting, draws, unpinned=unpinned, round_corners=round_corners)
        if not r["failed_draws"]:
            r.update(compare(r, ref))
        rows[setting] = r
        print(
            f"{scene}: {setting}: {r['dofs']} dofs, forward+gradient "
            f"{r['forward_grad_seconds']['median']:.3f} s, "
            + (
                f"gradient error {r['gradient_error']:.2e}, observable error "
                f"{r['observable_error']:.2e}"
                if "gradient_error" in r
                else f"FAILED {r['failed_draws']}"
            ),
            flush=True,
        )
    ladder = [s for s in ((8, 5, DEFAULT_RTOL), (11, 5, DEFAULT_RTOL)) if s in rows]
    held = holds(scene_from_config(scene_config(scene, unpinned, round_corners)))
    result = {
        "scene": scene,
        "unpinned": unpinned,
        "round_corners": round_corners,
        "holds": held,
        "draws": draws,
        "machine": {"cpus": os.cpu_count()},
        "reference": {k: v for k, v in ref.items() if not k.startswith("_")},
        "convergence": refinement([rows[s] for s in ladder] + [ref])[0]
        if len(ladder) == 2
        else None,
        "settings": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows.values()],
    }
    return result


def front_of(result: dict) -> list[dict]:
    """The settings at the default Newton tolerance that converged, with the Pareto front marked."""
    rows = [r for r in result["settings"] if r["rtol"] == DEFAULT_RTOL and "gradient_error" in r]
    on = set(pareto(rows, "gradient_error"))
    return [{**r, "on_front": i in on} for i, r in enumerate(rows)]


def ship(result: dict, data_dir: Path) -> Path:
    """What fidelity=auto reads: how the scene was held, per setting its time and errors, the front
    marked."""
    keep = (
        "ctrl_per_patch",
        "quad_points",
        "dofs",
        "forward_grad_seconds",
        "gradient_error",
        "gradient_cosine",
        "observable_error",
        "on_front",
    )
    body = {
        "scene": result["scene"],
        "holds": result["holds"],
        "rtol": DEFAULT_RTOL,
        "machine": result["machine"],
        "reference": {
            k: result["reference"][k] for k in ("ctrl_per_patch", "quad_points", "rtol", "dofs")
        },
        "settings": [{k: r[k] for k in keep} for r in front_of(result)],
    }
    data_dir.mkdir(parents=True, exist_ok=True)
    path = data_dir / f"{stem(result)}.json"
    path.write_text(json.dumps(body, indent=1) + "\n")
    return path


def report(result: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scene, ref, name = result["scene"], result["reference"], stem(result)
    (out / f"{name}.json").write_text(json.dumps(result, indent=1))
    rows = result["settings"]
    front = {(r["ctrl_per_patch"], r["quad_points"]) for r in front_of(result) if r["on_front"]}
    groups = list(next(r for r in rows if "gradient" in r)["gradient"])
    lines = [
        f"# Fidelity study: {scene}"
        + (
            ", held by its actuated segments alone (scene.pinned=[])"
            if result.get("unpinned")
            else ""
        )
        + (
            ", round pore corners (scene.round_pore_corners)" if result.get("round_corners") else ""
        ),
        "",
        f"Reference: {ref['ctrl_per_patch']} control points per patch, {ref['quad_points']} Gauss "
        f"points, Newton tolerance {ref['rtol']:g} ({ref['dofs']} dofs, forward + gradient "
        f"{ref['forward_grad_seconds']['median']:.2f} s). Times: min / median of "
        f"{result['draws']} draws, "
        "seconds. Errors: worst over the draws; gradient: relative norm error / cosine per group. "
        "Front: Pareto-optimal in (forward + gradient time, gradient error) at tolerance 1e-10.",
        "",
        "| ctrl | quad | rtol | dofs | forward [s] | fwd + grad [s] | peak MB | observable error | "
        + " | ".join(f"grad {g}" for g in groups)
        + " | front |",
        "|---" * (9 + len(groups)) + "|",
    ]
    for r in rows:
        mark = (
            "paper"
            if (r["ctrl_per_patch"], r["quad_points"]) == PAPER
            else ("fast" if (r["ctrl_per_patch"], r["quad_points"]) == FAST else "")
        )
        on = r["rtol"] == DEFAULT_RTOL and (r["ctrl_per_patch"], r["quad_points"]) in front
        cells = (
            [
                f"{r['gradient'][g]['relative_error']:.2e} / {r['gradient'][g]['cosine']:.4f}"
                for g in groups
            ]
            if "gradient" in r
            else ["failed"] * len(groups)
        )
        lines.append(
            f"| {r['ctrl_per_patch']} | {r['quad_points']} | {r['rtol']:g} | {r['dofs']} | "
            f"{r['forward_seconds']['min']:.3f} / {r['forward_seconds']['median']:.3f} | "
            f"{r['forward_grad_seconds']['min']:.3f} / {r['forward_grad_seconds']['median']:.3f} | "
            f"{r['peak_memory_mb']:.0f} | {r.get('observable_error', float('nan')):.2e} | "
            + " | ".join(cells)
            + f" | {'yes' if on else ''} {mark} |"
        )
    lines += nonphysical_lines(
        "their errors are in the table",
        [
            (f"{r['ctrl_per_patch']} x {r['quad_points']}, tolerance {r['rtol']:g}", d)
            for r in rows
            for d in r.get("nonphysical_draws", [])
        ],
    )
    conv = result["convergence"]
    if conv:
        fmt = lambda c: (
            f"differences {c['differences'][0]:.2e} -> {c['differences'][1]:.2e}, observed order "
            + (
                f"{c['orders'][0]:.2f}, estimated reference error {c['finest_error']:.1e}"
                if c["orders"][0]
                else "undetermined (not in the asymptotic range)"
            )
        )
        lines += [
            "",
            f"Reference check, refinement {' -> '.join(str(s + 2) for s in conv['spans'])} "
            "control points "
            "(5 Gauss points):",
            "",
        ]
        lines += [
            f"- {name}{' (relative)' if name != 'observable' else ''}: {fmt(c)}"
            for name, c in conv["quantities"].items()
        ]
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, error, label in (
        (axes[0], "gradient_error", "gradient error (worst relative, over groups)"),
        (axes[1], "observable_error", "observable error (max abs)"),
    ):
        ok = [r for r in rows if error in r and r[error] > 0]
        on = set(pareto([r for r in ok if r["rtol"] == DEFAULT_RTOL], error))
        base = [r for r in ok if r["rtol"] == DEFAULT_RTOL]
        for ctrl, colour in zip((5, 8, 11), ("tab:blue", "tab:orange", "tab:green")):
            sel = [r for r in base if r["ctrl_per_patch"] == ctrl]
            ax.plot(
                [r["forward_grad_seconds"]["median"] for r in sel],
                [r[error] for r in sel],
                "o",
                color=colour,
                label=f"{ctrl} control points",
            )
            for r in sel:
                paper = (r["ctrl_per_patch"], r["quad_points"]) == PAPER
                ax.annotate(
                    f"q{r['quad_points']}" + (" (paper)" if paper else ""),
                    (r["forward_grad_seconds"]["median"], r[error]),
                    fontsize=7,
                    xytext=(3, 3),
                    textcoords="offset points",
                )
        loose = [r for r in ok if r["rtol"] != DEFAULT_RTOL]
        ax.plot(
            [r["forward_grad_seconds"]["median"] for r in loose],
            [r[error] for r in loose],
            "x",
            color="grey",
            label="looser Newton tolerance",
        )
        pts = sorted((base[i]["forward_grad_seconds"]["median"], base[i][error]) for i in on)
        if pts:
            ax.step(*zip(*pts), where="post", color="black", lw=1, label="Pareto front")
        ax.set(
            xscale="log", yscale="log", xlabel="forward + gradient time [s] (median)", ylabel=label
        )
        ax.legend(fontsize=7)
    fig.suptitle(
        f"{name}: speed against accuracy (reference {ref['ctrl_per_patch']} x "
        f"{ref['quad_points']})",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out / f"{name}.png", dpi=120)
    plt.close(fig)


def summary(
    results: list[dict],
    out: Path,
    tolerance: float = 0.1,
    unpinned: bool = False,
    round_corners: bool = False,
) -> str:
    """One table over the scenes: the paper's and the fast preset's cost and error, the cheapest
    setting within `tolerance` (what fidelity=auto picks by default), and how well the reference is
    known."""
    from nma.fidelity import fastest_within

    lines = [
        "| scene | dofs (paper) | paper 5x5: s / grad err / cos | fast 5x3: s / grad err | "
        f"auto (tolerance {tolerance:g}): setting, s / grad err | reference: dofs, s | reference "
        "error (Richardson) |",
        "|---|---|---|---|---|---|---|",
    ]
    for result in results:
        rows = {
            (r["ctrl_per_patch"], r["quad_points"]): r
            for r in result["settings"]
            if r["rtol"] == DEFAULT_RTOL
        }
        cell = lambda r: f"{r['forward_grad_seconds']['median']:.3g} / {r['gradient_error']:.3f}"
        pick = fastest_within(list(rows.values()), tolerance)
        ref, conv = result["reference"], result["convergence"] or {}
        est = [
            c["finest_error"]
            for name, c in conv.get("quantities", {}).items()
            if name.startswith("gradient") and c["finest_error"] is not None
        ]
        lines.append(
            f"| {stem(result)} | {rows[PAPER]['dofs']} | {cell(rows[PAPER])} / "
            f"{rows[PAPER]['gradient_cosine']:.3f} | "
            f"{cell(rows[FAST])} | "
            + (f"{pick['ctrl_per_patch']}x{pick['quad_points']}, {cell(pick)}" if pick else "none")
            + f" | {ref['dofs']}, {ref['forward_grad_seconds']['median']:.3g} | "
            + (f"gradient <= {max(est):.2g} (relative)" if est else "undetermined")
            + " |"
        )
    text = "\n".join(lines) + "\n"
    (out / f"summary{'_unpinned' * unpinned}{'_round' * round_corners}.md").write_text(text)
    return text


def child(args) -> None:
    from nma.runtime import configure_jax

    configure_jax()
    result = (
        richardson(
            args.scenes[0],
            args.draws,
            tuple(args.ladder),
            grading=args.grading,
            unpinned=args.unpinned,
            spread=args.spread,
            actuation=args.actuation,
            round_corners=args.round_corners,
        )
        if args.convergence
        else run_scene(args.scenes[0], args.quick, args.draws, args.unpinned, args.round_corners)
    )
    Path(args.result).write_text(json.dumps(result))


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--scenes", nargs="+", default=SCENES, choices=SCENES)
    ap.add_argument(
        "--draws", type=int, default=3, help="actuation draws per setting (timing runs)"
    )
    ap.add_argument(
        "--quick", action="store_true", help="4 settings against an 11 x 5 reference (a smoke run)"
    )
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="where the results go (default outputs/studies/fidelity; with --quick, "
        "fidelity_quick, so "
        "that a smoke run leaves the study's results as they were)",
    )
    ap.add_argument(
        "--data",
        type=Path,
        default=ROOT / "nma" / "data" / "fidelity",
        help="where the measured fronts for fidelity=auto go",
    )
    ap.add_argument(
        "--replot",
        action="store_true",
        help="redraw tables and figures from the JSON files only (with --convergence: the "
        "reference check's)",
    )
    ap.add_argument(
        "--convergence",
        action="store_true",
        help="check the reference: refinement to 17 x 5, Richardson's limit, errors against it",
    )
    ap.add_argument(
        "--unpinned",
        action="store_true",
        help="each scene's well-posed variant: its pinned corners removed (the front, or with "
        "--convergence the reference check)",
    )
    ap.add_argument(
        "--grading",
        type=float,
        default=1.0,
        help="--convergence with knots graded towards the patch corners (fidelity.grading)",
    )
    ap.add_argument(
        "--ladder",
        type=int,
        nargs="+",
        default=list(LADDER),
        help=f"--convergence: control points per patch of the refinements, {REFERENCE[0]} among "
        "them",
    )
    ap.add_argument(
        "--spread",
        type=float,
        default=SPREAD,
        help="--convergence: the random design's radii (and corner moves) uniform over this "
        f"central part of their ranges (default {SPREAD}; smaller: rounder pores, blunter corners)",
    )
    ap.add_argument(
        "--actuation",
        type=float,
        default=ACTUATION,
        help="--convergence: the actuations uniform in [-a d_max, a d_max] (default "
        f"{ACTUATION:g}; smaller: the same directions, shorter, states further from folding)",
    )
    ap.add_argument(
        "--round-corners",
        action="store_true",
        help="the pores' walls meeting tangent at their corners (scene.round_pore_corners): no "
        "re-entrant pore corner (the front, or with --convergence the reference check)",
    )
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--result", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if not 0.0 < args.spread <= 1.0:
        ap.error(
            f"--spread must be in (0, 1] (the central part of each range), not {args.spread:g}"
        )
    if not 0.0 < args.actuation <= 1.0:
        ap.error(
            "--actuation must be in (0, 1] (a fraction of the task's d_max), not "
            f"{args.actuation:g}"
        )
    if not args.convergence and (
        args.grading != 1.0
        or args.ladder != list(LADDER)
        or args.spread != SPREAD
        or args.actuation != ACTUATION
    ):
        ap.error(
            "--grading, --ladder, --spread and --actuation belong to --convergence (the study's "
            "fronts, which "
            "fidelity=auto reads, are measured with uniform knots on the default random draws)"
        )
    if (
        REFERENCE[0] not in args.ladder
        or args.ladder != sorted(set(args.ladder))
        or len(args.ladder) < 3
    ):
        ap.error(
            f"--ladder must rise through at least 3 levels, {REFERENCE[0]} (the reference) among "
            "them"
        )
    if args.child:
        return child(args)
    if args.out is None:
        args.out = ROOT / "outputs" / "studies" / ("fidelity_quick" if args.quick else "fidelity")
    args.out.mkdir(parents=True, exist_ok=True)
    # scenes whose reference check failed (a level's solve did not converge: said above)
    unchecked = []
    for scene in args.scenes:
        name = variant(
            scene, args.grading, args.unpinned, args.spread, args.actuation, args.round_corners
        )
        if args.replot and args.convergence:
            if (args.out / f"{name}.convergence.json").exists():
                convergence_report(
                    json.loads((args.out / f"{name}.convergence.json").read_text()), args.out
                )
            continue
        if args.replot:
            if (args.out / f"{name}.json").exists():
                report(json.loads((args.out / f"{name}.json").read_text()), args.out)
            continue
        # one process per scene: its settings are timed side by side, its memory is its own
        result_file = args.out / f".{name}.partial.json"
        cmd = [
            sys.executable,
            __file__,
            "--child",
            "--scenes",
            scene,
            "--draws",
            str(args.draws),
            "--result",
            str(result_file),
            *(["--quick"] if args.quick else []),
            *(
                [
                    "--convergence",
                    "--grading",
                    str(args.grading),
                    "--spread",
                    str(args.spread),
                    "--actuation",
                    str(args.actuation),
                    "--ladder",
                    *map(str, args.ladder),
                ]
                if args.convergence
                else []
            ),
            *(["--unpinned"] if args.unpinned else []),
            *(["--round-corners"] if args.round_corners else []),
        ]
        finished = subprocess.run(cmd)
        if finished.returncode and args.convergence:  # the other scenes' checks go on
            unchecked.append(scene)
            continue
        finished.check_returncode()
        result = json.loads(result_file.read_text())
        result_file.unlink()
        if args.convergence:
            print(convergence_report(result, args.out), flush=True)
            continue
        report(result, args.out)
        if not args.quick:  # a smoke run's front must not replace the shipped one
            print(f"{scene}: front for fidelity=auto -> {ship(result, args.data)}")
        print(f"{scene}: -> {args.out / name}.{{json,md,png}}", flush=True)
    if unchecked:
        sys.exit(f"no reference check for {', '.join(unchecked)}: see the error above each")
    if args.convergence:
        return
    stems = [
        variant(scene, unpinned=args.unpinned, round_corners=args.round_corners) for scene in SCENES
    ]
    done = [
        json.loads((args.out / f"{s}.json").read_text())
        for s in stems
        if (args.out / f"{s}.json").exists()
    ]
    print(summary(done, args.out, unpinned=args.unpinned, round_corners=args.round_corners))


if __name__ == "__main__":
    main()
