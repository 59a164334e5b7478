"""Stability map: does the solver reach equilibrium at the extremes a user can ask for?

    # every scene -> outputs/studies/stability/
    python experiments/stability_map.py
    python experiments/stability_map.py --scenes translation --quick
    python experiments/stability_map.py --contact --out outputs/studies/stability_contact
    python experiments/stability_map.py --formulation mixed --nus 0.499 \\
        --out outputs/studies/stability_mixed
    python experiments/stability_map.py --corrector trust_region --nus 0.499 \\
        --out outputs/studies/stability_trust
    python experiments/stability_map.py --formulation mixed --inversion-barrier 0.5 --nus 0.499 \\
        --out outputs/studies/stability_mixed_barrier
    python experiments/stability_map.py --formulation mixed --inversion-barrier 0.5 --nus 0.499 \\
        --mesh 8 5 --not-physical-in outputs/studies/stability_mixed_barrier \\
        --out outputs/studies/stability_mixed_barrier_8x5

Per scene, every combination of
  material   nu in {0.3, 0.4, 0.45, 0.49, 0.499} (E = 0.07, the paper's),
  radii      at the lower bound, the middle, the upper bound, and a random non-uniform field,
  corners    at rest and, where the scene moves corners, at their box limits (alternate nodes
             pushed to opposite corners of their box, projected onto convex cells as training does),
  direction  each sign pattern of the actuations (all of them up to 4 actuations; otherwise both
             uniform ones and 6 random ones), at full magnitude d_max: the solver's load stepping
             ramps the actuation from 0, so "load reached" is how far along the ray it got,
records the outcome (converged, or the solver's status with the load factor reached and the last
residual), iterations, load steps, cuts and wall time, and checks that nothing returned is NaN; for
a converged state, the number of negative eigenvalues of the Hessian there (PARDISO's inertia): 0 is
a stable equilibrium, more is a saddle that a perturbation would leave; and whether it is a physical
object (nma/geometry/validity.py: det F over the whole material, no boundary curve through another).
Writes <scene>.json (every solve), <scene>.md (tables) and <scene>.png (heat maps: fraction of
directions converged per material and design, and the time per solve relative to the scene's median
converged solve).  Fidelity and solver: the paper's 5 x 5 (--mesh: another) and PARDISO.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np

from nma.mechanics.options import FORMULATIONS
from nma.solver.options import CORRECTORS

ROOT = Path(__file__).resolve().parent.parent
SCENES = ["translation", "rotation_single", "rotation_double", "shape_matching", "digital_mnist"]
NUS = [0.3, 0.4, 0.45, 0.49, 0.499]
E = 0.07


def directions(n_act: int, rng) -> np.ndarray:
    if n_act <= 4:
        return np.array(list(itertools.product([1.0, -1.0], repeat=n_act)))
    uniform = [np.ones(n_act), -np.ones(n_act)]
    return np.array(uniform + [rng.choice([-1.0, 1.0], n_act) for _ in range(6)])


def designs(sim, rng) -> dict[str, dict]:
    """Named geometries at the extremes of the design box (and one inside it)."""
    import jax.numpy as jnp

    design = sim.disc.design
    init = sim.init_params()
    bounds = design.bounds()
    out = {}
    if "radii" in init:
        lo, hi = bounds["radii"]
        for name, value in (
            ("radii at lower bound", lo),
            ("radii in the middle", 0.5 * (lo + hi)),
            ("radii at upper bound", hi),
        ):
            out[name] = {**init, "radii": jnp.full_like(init["radii"], value)}
        out["random radii"] = {
            **init,
            "radii": jnp.asarray(rng.uniform(lo, hi, init["radii"].shape)),
        }
    else:
        out["initial design"] = init
    if "corners" in init:
        box = bounds["corners"][1]
        nodes = design.nodes[design.movable]
        # alternate nodes
        parity = ((np.round(nodes[:, 0]) + np.round(nodes[:, 1])) % 2 * 2 - 1)[:, None]
        pushed = {
            **out["radii in the middle"],
            "corners": jnp.asarray(parity * np.array([box, box])),
        }
        projected = design.project(pushed, out["radii in the middle"])
        used = float(np.max(np.abs(np.asarray(projected["corners"])))) / box
        out[f"corners at box limits ({used:.0%} of the box kept cells convex)"] = projected
    return out


def run_scene(
    scene: str,
    quick: bool,
    escape_saddles: bool = False,
    seed: int = 0,
    contact: bool = False,
    formulation: str = "displacement",
    nus: list[float] = NUS,
    max_iters: int | None = None,
    max_step_iters: int | None = None,
    corrector: str = "line_search",
    element_bound: bool = True,
    inversion_barrier: float = 0.0,
    mesh: tuple[int, int] | None = None,
    only: set | None = None,
) -> dict:
    """One scene's map.  `mesh`: (ctrl_per_patch, quad_points) in place of the paper's fidelity;
    `only`: the cells (design, nu, signs) to solve, of all the map's (None: every cell)."""
    import jax
    import jax.numpy as jnp

    from nma import config
    from nma.geometry.validity import StateChecker
    from nma.mechanics.material import material
    from nma.simulator import Simulator
    from nma.solver.status import Status

    rng = np.random.default_rng(seed)
    solver = {
        "escape_saddles": escape_saddles,
        "corrector": corrector,
        "element_bound": element_bound,
    }
    if max_iters is not None:  # else the solver's default budget
        solver["max_iters"] = max_iters
    if max_step_iters is not None:
        solver["max_step_iters"] = max_step_iters
    fidelity = {**config.load("fidelity", "paper"), "inversion_barrier": inversion_barrier}
    if mesh is not None:
        fidelity.update(ctrl_per_patch=mesh[0], quad_points=mesh[1])
    sim = Simulator.from_config(
        config.load("scene", scene), fidelity, solver, {"enabled": contact}, formulation
    )
    d_max = config.load("task", scene)["d_max"]
    solve = jax.jit(lambda X, d, mat: sim.equilibrium(X, d, mat))
    nus = [nus[0], nus[-1]] if quick else nus
    geoms = designs(sim, rng)
    if quick:
        geoms = dict(list(geoms.items())[:2])
    dirs = directions(sim.n_actuations, rng)[: 2 if quick else None]

    X0 = sim.reference_points(sim.init_params())
    jax.block_until_ready(solve(X0, jnp.zeros(sim.n_actuations), material(E, 0.3)))  # compile once
    records = []
    for (gname, geom), nu, s in itertools.product(geoms.items(), nus, dirs):
        if only is not None and (gname, nu, tuple(s.tolist())) not in only:
            continue
        X = sim.reference_points(geom)
        d = jnp.asarray(d_max * s)
        t0 = time.perf_counter()
        u, info = jax.block_until_ready(solve(X, d, material(E, nu)))
        seconds = time.perf_counter() - t0
        info = jax.tree_util.tree_map(np.asarray, info)
        status = int(info.status)
        finite = bool(
            np.all(np.isfinite(np.asarray(u)))
            and np.isfinite(info.residual)
            and np.isfinite(info.load)
        )
        # a converged state may be a saddle (e.g. a symmetric path past a buckling point): count its
        # unstable modes from the inertia of the Hessian there
        unstable = (
            sim.negative_eigenvalues(X, d, material(E, nu), u)
            if status == Status.CONVERGED
            else None
        )
        # a converged state may not be a physical object (material inverted between Gauss points, a
        # wall through a wall): nma/geometry/validity.py
        # a stopped solve returns the last equilibrium it reached: its walls' compression is
        # reported too
        checked = (
            StateChecker(sim.disc.mesh, np.asarray(X)).check(np.asarray(u)) if finite else None
        )
        state = checked if status == Status.CONVERGED else None
        records.append(
            {
                "design": gname,
                "nu": nu,
                "signs": s.tolist(),
                "d": (d_max * s).tolist(),
                "converged": status == Status.CONVERGED,
                "status": Status.describe(status),
                "inverts": status == Status.INVERTS,
                "load_reached": float(info.load),
                "iterations": int(info.iterations),
                "load_steps": int(info.load_steps),
                "cuts": int(info.cuts),
                "residual": float(info.residual),
                "tolerance": float(info.tolerance),
                "seconds": seconds,
                "finite": finite,
                "negative_eigenvalues": unstable,
                "valid": None if state is None else state.valid,
                "min_J": None if state is None else state.min_J,
                "problems": None if state is None else state.problems(),
                # how far the walls are compressed along themselves (an incompressible
                # surface creases below 0.65)
                "min_boundary_stretch": None if checked is None else checked.min_boundary_stretch,
                "min_boundary_stretch_at": None
                if checked is None
                else checked.min_boundary_stretch_at,
            }
        )
        r = records[-1]
        outcome = "STOPPED (inverts)" if r["inverts"] else "FAILED"
        outcome = "ok" if r["converged"] else f"{outcome} at load {r['load_reached']:.3f}"
        saddle = f"(saddle: {unstable} negative eigenvalues) " if unstable else ""
        unphysical = (
            ""
            if state is None or state.valid
            else "(NOT PHYSICAL: " + "; ".join(state.problems()) + ") "
        )
        print(
            f"{scene:16s} {gname[:28]:28s} nu={nu:<6} d={np.round(d_max * s, 1).tolist()}: "
            f"{outcome} {saddle}{unphysical}"
            f"{r['iterations']} it, {r['load_steps']} steps, {seconds:.2f} s",
            flush=True,
        )
    return {
        "scene": scene,
        "dofs": sim.disc.boundary.n_dofs,
        "d_max": d_max,
        "E": E,
        "n_actuations": sim.n_actuations,
        "fidelity": "paper" if mesh is None else f"{mesh[0]} x {mesh[1]}",
        "solver": "pardiso"
        + (", escape_saddles" if escape_saddles else "")
        + (f", {corrector}" if corrector != "line_search" else "")
        + ("" if element_bound else ", no element bound"),
        "max_iters": sim.options.max_iters,
        "max_step_iters": sim.options.max_step_iters,
        "contact": contact,
        "formulation": formulation,
        "inversion_barrier": inversion_barrier,
        "records": records,
    }


def _stats(values) -> dict | None:
    """Smallest and median of the values known (None: none known)."""
    known = [v for v in values if v is not None]
    return (
        {"min": float(np.min(known)), "median": float(np.median(known)), "n": len(known)}
        if known
        else None
    )


def summarise(result: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    recs = result["records"]
    geoms = list(dict.fromkeys(r["design"] for r in recs))
    nus = sorted({r["nu"] for r in recs})
    conv_time = np.median([r["seconds"] for r in recs if r["converged"]] or [np.nan])
    frac = np.zeros((len(geoms), len(nus)))
    cost = np.zeros_like(frac)
    for i, g in enumerate(geoms):
        for j, nu in enumerate(nus):
            cell = [r for r in recs if r["design"] == g and r["nu"] == nu]
            frac[i, j] = np.mean([r["converged"] for r in cell])
            cost[i, j] = np.max([r["seconds"] for r in cell]) / conv_time
    failed = [r for r in recs if not r["converged"]]
    # a failure's cost against the converged solves of the same material (the budget a user expects)
    conv_at = {
        nu: np.median([r["seconds"] for r in recs if r["converged"] and r["nu"] == nu] or [np.nan])
        for nu in nus
    }
    saddles = [r for r in recs if r["converged"] and r.get("negative_eigenvalues")]
    result["summary"] = {
        "solves": len(recs),
        "converged": len(recs) - len(failed),
        "nonfinite": sum(not r["finite"] for r in recs),
        "converged_by_nu": {
            str(nu): sum(r["converged"] for r in recs if r["nu"] == nu) for nu in nus
        },
        "solves_by_nu": {str(nu): sum(r["nu"] == nu for r in recs) for nu in nus},
        "saddles": len(saddles),
        # stopped by the element bound where the material would invert between Gauss
        # points (maps from before the bound have no "inverts" field: 0)
        "stopped_inverting": sum(bool(r.get("inverts")) for r in recs),
        # older maps (before the validity check) have no "valid" field: None
        "invalid": (
            sum(r.get("valid") is False for r in recs) if any("valid" in r for r in recs) else None
        ),
        # older maps have no "min_boundary_stretch": None
        "converged_min_boundary_stretch": _stats(
            [r.get("min_boundary_stretch") for r in recs if r["converged"]]
        ),
        "failed_min_boundary_stretch": _stats([r.get("min_boundary_stretch") for r in failed]),
        "median_converged_seconds": float(conv_time),
        "median_failed_seconds": float(np.median([r["seconds"] for r in failed]))
        if failed
        else None,
        "failed_over_converged_same_nu": (
            float(np.max([r["seconds"] / conv_at[r["nu"]] for r in failed])) if failed else None
        ),
    }
    (out / f"{result['scene']}.json").write_text(json.dumps(result, indent=1))

    s = result["summary"]
    formulation = result.get("formulation", "displacement")
    formulation = f", formulation {formulation}" if formulation != "displacement" else ""
    barrier = result.get("inversion_barrier")
    barrier = f", inversion barrier at det F {barrier}" if barrier else ""
    lines = [
        f"# Stability map: {result['scene']} ({result['dofs']} dofs, d_max {result['d_max']}, E "
        f"{result['E']}, "
        f"{result.get('fidelity', 'paper')} fidelity, {result['solver']}"
        f"{', contact' if result.get('contact') else ''}"
        f"{formulation}{barrier})",
        "",
        f"{s['converged']} of {s['solves']} solves converged; {s['nonfinite']} returned "
        "non-finite values; "
        + (
            f"{s['stopped_inverting']} stopped where the material would invert between Gauss "
            "points (solver.element_bound); "
            if s.get("stopped_inverting")
            else ""
        )
        + f"median time {s['median_converged_seconds']:.2f} s converged"
        + (
            f", {s['median_failed_seconds']:.2f} s failed (at most "
            f"{s['failed_over_converged_same_nu']:.1f}x the "
            f"median converged solve at the same nu)"
            if failed
            else ""
        )
        + ". "
        f"{s['saddles']} converged states are saddles (negative eigenvalues of the Hessian: "
        f"unstable equilibria, e.g. a symmetric path past a buckling point)."
        + (
            ""
            if s["invalid"] is None
            else f" {s['invalid']} converged states are not physical objects "
            "(material inverted somewhere, or a boundary curve through itself or another)."
        )
        + "".join(
            f" The {which} states' boundaries are compressed along themselves to a stretch of "
            f"{v['min']:.3f} at least, {v['median']:.3f} in the median state."
            for which, v in (
                ("converged", s["converged_min_boundary_stretch"]),
                ("failed solves' last", s["failed_min_boundary_stretch"]),
            )
            if v
        ),
        "",
        "| design | " + " | ".join(f"nu {nu}" for nu in nus) + " |",
        "|---|" + "---|" * len(nus),
    ]
    for i, g in enumerate(geoms):
        lines.append(f"| {g} | " + " | ".join(f"{frac[i, j]:.0%}" for j in range(len(nus))) + " |")
    if failed:
        # older maps
        stretch = lambda r: (
            "-" if r.get("min_boundary_stretch") is None else f"{r['min_boundary_stretch']:.3f}"
        )
        lines += [
            "",
            "Failures (boundary stretch: the smallest stretch of a boundary curve along itself in "
            "the last "
            "equilibrium reached; an incompressible neo-Hookean surface creases below 0.65):",
            "",
            "| design | nu | d | status | load reached | residual | iterations | s | boundary "
            "stretch |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for r in failed:
            lines.append(
                f"| {r['design']} | {r['nu']} | {np.round(r['d'], 2).tolist()} | {r['status']} | "
                f"{r['load_reached']:.3f} | {r['residual']:.2e} | {r['iterations']} | "
                f"{r['seconds']:.2f} | {stretch(r)} |"
            )
    (out / f"{result['scene']}.md").write_text("\n".join(lines) + "\n")

    fig, axes = plt.subplots(1, 2, figsize=(11, 1.2 + 0.6 * len(geoms)), sharey=True)
    for ax, data, title, cmap, vmax in (
        (axes[0], frac, "fraction of directions converged", "RdYlGn", 1.0),
        (axes[1], cost, "slowest solve / median converged solve", "magma_r", None),
    ):
        im = ax.imshow(data, cmap=cmap, vmin=0.0, vmax=vmax, aspect="auto")
        for (i, j), v in np.ndenumerate(data):
            dark = sum(im.cmap(im.norm(v))[:3]) < 1.2  # light text on dark cells
            ax.text(
                j,
                i,
                f"{v:.0%}" if vmax else f"{v:.1f}x",
                ha="center",
                va="center",
                fontsize=8,
                color="white" if dark else "black",
            )
        ax.set_xticks(range(len(nus)), [str(nu) for nu in nus])
        ax.set_xlabel("Poisson's ratio nu")
        ax.set_title(title, fontsize=9)
        fig.colorbar(im, ax=ax, fraction=0.04)
    axes[0].set_yticks(range(len(geoms)), geoms, fontsize=8)
    fig.suptitle(
        f"{result['scene']}: actuations at d_max = {result['d_max']} along each sign pattern",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out / f"{result['scene']}.png", dpi=120)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=SCENES, choices=SCENES)
    ap.add_argument(
        "--quick", action="store_true", help="2 materials, 2 designs, 2 directions (a smoke run)"
    )
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "studies" / "stability")
    ap.add_argument(
        "--replot", action="store_true", help="redraw tables and figures from the JSON files only"
    )
    ap.add_argument(
        "--escape-saddles",
        action="store_true",
        help="solve with solver.escape_saddles (write to a separate --out to compare)",
    )
    ap.add_argument(
        "--contact",
        action="store_true",
        help="solve with the pores' self-contact, contact=on (write to a separate --out to "
        "compare)",
    )
    ap.add_argument(
        "--formulation",
        default="displacement",
        choices=FORMULATIONS,
        help="material.formulation (write to a separate --out to compare)",
    )
    ap.add_argument("--nus", nargs="+", type=float, default=NUS, help="Poisson's ratios to map")
    ap.add_argument(
        "--corrector",
        default="line_search",
        choices=CORRECTORS.names(),
        help="solver.corrector (write to a separate --out to compare)",
    )
    ap.add_argument(
        "--max-iters",
        type=int,
        help="solver.max_iters, Newton's budget per solve (default: the solver's)",
    )
    ap.add_argument(
        "--max-step-iters",
        type=int,
        help="solver.max_step_iters, corrector iterations before a load step is cut "
        "(default: the solver's)",
    )
    ap.add_argument(
        "--no-element-bound",
        dest="element_bound",
        action="store_false",
        help="solver.element_bound=false: Newton steps on where the material inverts between Gauss "
        "points (maps without the bound; write to a separate --out)",
    )
    ap.add_argument(
        "--inversion-barrier",
        type=float,
        default=0.0,
        metavar="J_HAT",
        help="fidelity.inversion_barrier: a barrier on det F below J_HAT at every element's check "
        "points (0: none, the default; write to a separate --out)",
    )
    ap.add_argument(
        "--mesh",
        type=int,
        nargs=2,
        metavar=("CTRL", "QUAD"),
        help="fidelity.ctrl_per_patch and fidelity.quad_points in place of the paper's 5 x 5",
    )
    ap.add_argument(
        "--not-physical-in",
        type=Path,
        metavar="DIR",
        help="solve only the cells whose converged state was not a physical object in the map in "
        "DIR (with --mesh: do they hold on a finer mesh?)",
    )
    args = ap.parse_args()
    if args.replot:
        for scene in args.scenes:
            if (args.out / f"{scene}.json").exists():
                summarise(json.loads((args.out / f"{scene}.json").read_text()), args.out)
        return
    from nma.runtime import configure_jax

    configure_jax()
    args.out.mkdir(parents=True, exist_ok=True)
    for scene in args.scenes:
        only = None
        if args.not_physical_in is not None:
            previous = json.loads((args.not_physical_in / f"{scene}.json").read_text())["records"]
            only = {
                (r["design"], r["nu"], tuple(r["signs"]))
                for r in previous
                if r["converged"] and r.get("valid") is False
            }
            if not only:
                continue
        result = run_scene(
            scene,
            args.quick,
            args.escape_saddles,
            contact=args.contact,
            formulation=args.formulation,
            nus=args.nus,
            max_iters=args.max_iters,
            max_step_iters=args.max_step_iters,
            corrector=args.corrector,
            element_bound=args.element_bound,
            inversion_barrier=args.inversion_barrier,
            mesh=args.mesh,
            only=only,
        )
        summarise(result, args.out)
        s = result["summary"]
        print(
            f"{scene}: {s['converged']}/{s['solves']} converged, {s['stopped_inverting']} stopped "
            "where the material "
            f"would invert, {s['nonfinite']} non-finite -> "
            f"{args.out / scene}.{{json,md,png}}",
            flush=True,
        )


if __name__ == "__main__":
    main()
