"""Where a discretisation's error sits: the deformed state of one draw solved on a refinement
ladder, and the differences of successive levels at the same material points (the error of the
coarser level, to leading order), as a map and per region.

    python experiments/error_map.py rotation_single --unpinned --gradings 1 2 3 4
    python experiments/error_map.py translation --unpinned --gradings 3 --ladder 11 14 17 20

The draw is the fidelity study's first (experiments/fidelity_study.py: its random design, its first
actuation).  Per grading: each level's solve (control points per patch at 5 Gauss points, tolerance
1e-12, without Newton's element bound, as the study solves), then for each pair of levels the
largest and the root-mean-square difference of the deformed positions at S x S material points per
patch, the same root mean square within `--radius` of the ends of the scene's actuated segments (a
prescribed displacement meeting a free edge: a singular point) and elsewhere, and the observed order
of each (h = 1 / spans, as the study's).  Writes
outputs/studies/error_map/<scene>[_unpinned].{json,md} and one map per grading (<...>_graded<g>.png:
log10 of the last difference on the reference and on the finest deformed state).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
# the sibling script, also where a test imports this one
sys.path.insert(0, str(ROOT / "experiments"))
from fidelity_study import SCENES, observed_order, scene_config, study_draws  # noqa: E402

SAMPLES = 41  # material points per patch side


def solve_ladder(scene: str, ladder: list[int], grading: float, unpinned: bool) -> dict:
    """Reference and deformed positions (P, S, S, 2) at every level, the segments' ends, the solves'
    counts."""
    from nma.runtime import configure_jax

    configure_jax()
    import jax.numpy as jnp

    from nma import config
    from nma.discretise import discretise
    from nma.geometry.sampling import sample_positions
    from nma.mechanics.material import material
    from nma.schema import Fidelity, scene_from_config
    from nma.simulator import Simulator
    from nma.solver.status import Status, failure
    from nma.solver.options import NewtonOptions

    spec = scene_config(scene, unpinned)
    out = {"levels": {}, "ends": [p for g in spec["groups"] for p in g["segment"]]}
    for m in ladder:
        sim = Simulator(
            discretise(scene_from_config(spec), Fidelity(m, 5, grading=grading)),
            "auto",
            NewtonOptions(rtol=1e-12, element_bound=False),
        )
        # the study's first draw
        geom, ds = study_draws(sim, float(config.load("task", scene)["d_max"]), 1)
        d = ds[0]
        X = sim.reference_points(geom)
        t0 = time.perf_counter()
        u, info = sim.equilibrium(X, jnp.asarray(d), material(0.07, 0.3))
        if int(info.status) != Status.CONVERGED:  # how far it got and why
            raise SystemExit(str(failure(info, f"{scene} at {m} x 5, grading {grading:g}: ")))
        out["levels"][m] = {
            "reference": np.asarray(sample_positions(sim.disc.mesh, X, SAMPLES)),
            "deformed": np.asarray(sample_positions(sim.disc.mesh, X + u, SAMPLES)),
            "dofs": sim.disc.boundary.n_dofs,
            "iterations": int(info.iterations),
            "seconds": time.perf_counter() - t0,
        }
        print(
            f"  {m} x 5: {sim.disc.boundary.n_dofs} DOFs, {int(info.iterations)} iterations",
            flush=True,
        )
    return out


def regions(solved: dict, ladder: list[int], radius: float) -> dict:
    """Per region (all, near the segments' ends, elsewhere): the differences of successive levels
    and their observed orders."""
    spans = [m - 2 for m in ladder]
    ref = solved["levels"][ladder[-1]]["reference"].reshape(-1, 2)
    ends = np.asarray(solved["ends"], float)
    near = np.min(np.linalg.norm(ref[:, None] - ends[None], axis=-1), axis=1) < radius
    diffs = [
        np.linalg.norm(
            solved["levels"][b]["deformed"] - solved["levels"][a]["deformed"], axis=-1
        ).ravel()
        for a, b in zip(ladder[:-1], ladder[1:])
    ]
    rows = {}
    for name, pick, reduce in (
        ("max", np.ones_like(near), np.max),
        ("rms", np.ones_like(near), None),
        ("rms near the segments' ends", near, None),
        ("rms elsewhere", ~near, None),
    ):
        values = [
            float(reduce(d[pick]) if reduce else np.sqrt(np.mean(d[pick] ** 2))) for d in diffs
        ]
        orders = [
            observed_order(values[j : j + 2], spans[j : j + 3])["order"]
            for j in range(len(values) - 1)
        ]
        rows[name] = {"differences": values, "orders": orders}
    return {"rows": rows, "last": diffs[-1], "near_fraction": float(near.mean())}


def draw(path: Path, solved: dict, last: np.ndarray, ladder: list[int], title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    finest = solved["levels"][ladder[-1]]
    value = np.log10(last + 1e-300)
    fig, ax = plt.subplots(1, 2, figsize=(12, 6))
    for a, where, name in (
        (ax[0], finest["reference"], "reference"),
        (ax[1], finest["deformed"], "deformed"),
    ):
        xy = where.reshape(-1, 2)
        sc = a.scatter(
            xy[:, 0], xy[:, 1], c=value, s=1, cmap="viridis", vmin=value.max() - 3, vmax=value.max()
        )
        a.set_aspect("equal")
        a.set_title(f"{title}: log10 |x{ladder[-1]} - x{ladder[-2]}|, {name}", fontsize=9)
    fig.colorbar(sc, ax=ax, shrink=0.8)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("scene", choices=SCENES)
    ap.add_argument(
        "--unpinned", action="store_true", help="the well-posed variant (scene.pinned=[])"
    )
    ap.add_argument("--gradings", type=float, nargs="+", default=[1.0, 2.0, 3.0])
    ap.add_argument("--ladder", type=int, nargs="+", default=[11, 14, 17, 20])
    ap.add_argument(
        "--radius", type=float, default=2.5, help="'near the segments' ends': within this distance"
    )
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "studies" / "error_map")
    args = ap.parse_args()
    if len(args.ladder) < 3 or args.ladder != sorted(set(args.ladder)):
        ap.error(
            "--ladder must be at least three increasing levels (an order takes three), got "
            f"{args.ladder}"
        )
    if args.radius <= 0:
        ap.error(f"--radius must be > 0, got {args.radius}")
    from nma.errors import ConfigError
    from nma.schema import Fidelity

    try:  # every setting checked before the first solve
        for g in args.gradings:
            for m in args.ladder:
                Fidelity(m, 5, grading=g)
    except ConfigError as e:
        ap.error(str(e))
    args.out.mkdir(parents=True, exist_ok=True)
    stem = args.scene + ("_unpinned" if args.unpinned else "")
    result = {
        "scene": args.scene,
        "unpinned": args.unpinned,
        "ladder": args.ladder,
        "radius": args.radius,
        "samples_per_patch_side": SAMPLES,
        "gradings": {},
    }
    lines = [
        f"# Where the error sits: {stem}, levels {' -> '.join(map(str, args.ladder))} x 5",
        "",
        "| grading | quantity | differences | orders |",
        "|---|---|---|---|",
    ]
    for g in args.gradings:
        print(f"grading {g:g}", flush=True)
        solved = solve_ladder(args.scene, args.ladder, g, args.unpinned)
        found = regions(solved, args.ladder, args.radius)
        draw(
            args.out / f"{stem}_graded{g:g}.png",
            solved,
            found["last"],
            args.ladder,
            f"{stem}, grading {g:g}",
        )
        result["gradings"][f"{g:g}"] = {
            "rows": found["rows"],
            "near_fraction": found["near_fraction"],
            "levels": {
                m: {k: v for k, v in lv.items() if k in ("dofs", "iterations", "seconds")}
                for m, lv in solved["levels"].items()
            },
        }
        for name, row in found["rows"].items():
            orders = ", ".join("-" if o is None else f"{o:.2f}" for o in row["orders"])
            lines.append(
                f"| {g:g} | {name} | {', '.join(f'{v:.3g}' for v in row['differences'])} | "
                f"{orders} |"
            )
    (args.out / f"{stem}.json").write_text(json.dumps(result, indent=1))
    (args.out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
