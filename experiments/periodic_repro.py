"""Reproduce a task on a periodic material's effective response: train it, then draw and publish.

    python experiments/periodic_repro.py periodic_poisson [extra Hydra overrides ...]
    python experiments/periodic_repro.py periodic_poisson_amortised
    python experiments/periodic_repro.py periodic_poisson --summarise   # figures again, no training

Runs `python -m nma.run experiment=repro_<name>` into outputs/repro/<name>/joint/, then follows the
load path of the learned design(s) and of the baseline (the initial circular holes) again and
writes outputs/repro/<name>/: path_<which>.png (the cell tiled 2 x 2 at rest, half way and at the
end, beside its stress and Poisson's ratio curves), poisson.png (the Poisson's ratio along the path
against the target), tiling.dxf and tiling.json (the learned cell tiled 4 x 4 at 10 mm per cell in
Ecoflex 00-30, its minimum ligament), comparison.md and result.json; then results/<name>/ and the
guard's record (experiments/guard.py), as experiments/repro.py does for the paper's tasks.  Every
evaluated design and the baseline are re-solved at the finer fidelities REFINED (the same design
parameters, refined exactly); the finest one's metric is the headline the guard checks.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import matplotlib

sys.path.insert(0, str(Path(__file__).resolve().parent))
import guard  # noqa: E402
import results  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
NAMES = ("periodic_poisson", "periodic_poisson_amortised")
COMMAND = ["python", "experiments/periodic_repro.py", *sys.argv[1:]]
TILES, MM_PER_UNIT = (4, 4), 10.0  # the exported part: 4 x 4 supercells, 10 mm per cell
# the finer fidelities every design is re-solved at (control points per patch side, Gauss points),
# the last the headline: between them the circles' critical strain moves 0.03% and their Poisson's
# ratio at -10% 0.2% (11 x 4 to 14 x 4), where 5 x 3 to 8 x 4 moves it from -0.149 to -0.208
REFINED = ((11, 4), (14, 5))
MET = 0.01  # a target is met within this much of Poisson's ratio (the guard's band)


def train(name: str, run_dir: Path, overrides: list[str]) -> float:
    if run_dir.exists():  # this script's own earlier run: a reproduction starts afresh
        shutil.rmtree(run_dir)
    cmd = [sys.executable, "-m", "nma.run", f"experiment=repro_{name}"]
    cmd += [f"hydra.run.dir={run_dir}", "trainer.progress=false", *overrides]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT)
    return time.perf_counter() - t0


def designs(run_dir: Path):
    """(the task rebuilt from the run's settings, its cell, the evaluation's targets, the reference
    points of each evaluated design, the learned cell's design params for export, each evaluated
    design's radii, the run's settings)."""
    from nma.runtime import configure_jax

    configure_jax()
    import jax.numpy as jnp

    from nma.periodic.front import cell_of
    from nma.registry import TASKS
    from nma.train.runs import load_run

    settings, params, _ = load_run(run_dir)
    cell = cell_of(settings)
    task = TASKS.get(settings.task.factory)(settings.task, cell)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    d = jnp.asarray(metrics["eval_actuations"])
    ts = np.asarray(task.eval_set())[:, 0]
    if task.amortised:
        X = np.asarray(task.design_points(task.X0, d))
        radii = np.asarray(task.design_radii(d))
        side = np.asarray(d)[len(d) // 2]  # the middle target's pore, for the part
        r0 = np.asarray(task.params0["radii"])
        lo, hi = cell.disc.design.bounds()["radii"]
        part = np.clip(r0 + np.tile([side[0], side[1], side[0]], r0.shape[1] // 3), lo, hi)
        geom = {"radii": jnp.asarray(part)}
    else:
        geom = {"radii": jnp.asarray(params["geom"]["radii"])}
        X = np.asarray(cell.disc.reference_points(geom))[None]
        radii = np.asarray(geom["radii"])[None]
    return task, cell, ts, X, geom, radii, settings


def refine(task, settings, radii) -> list[dict]:
    """Each evaluated design and the baseline re-solved at each of REFINED (nma.tasks.periodic's
    PeriodicPoisson.refined: the same design parameters on the run's scene at that fidelity)."""
    import dataclasses

    from nma.periodic.front import cell_of

    out = []
    for ctrl, quad in REFINED:
        fid = dataclasses.replace(settings.fidelity, ctrl_per_patch=ctrl, quad_points=quad)
        out.append(task.refined(cell_of(dataclasses.replace(settings, fidelity=fid)), radii))
    return out


def convergence(coarse: dict, fine: dict) -> dict:
    """The largest relative change between the two finest fidelities of the Poisson's ratios
    reached (the baseline's too) and of the critical strains crossed."""

    def change(a, b):
        pairs = [(x, y) for x, y in zip(a, b) if x is not None and y is not None]
        return max((abs(y - x) / abs(y) for x, y in pairs), default=None)

    both = lambda r, k, b: [r[b], *r[k]]
    return {
        "poisson": change(
            both(coarse, "reached", "baseline_poisson"), both(fine, "reached", "baseline_poisson")
        ),
        "critical_strain": change(
            both(coarse, "critical_strains", "baseline_critical_strain"),
            both(fine, "critical_strains", "baseline_critical_strain"),
        ),
    }


def figures(out: Path, task, cell, ts, X, fine: dict) -> tuple[list[Path], dict]:
    """The path figures of the baseline and each learned design, the Poisson's ratio curves against
    the targets; the numbers they show."""
    from nma.periodic import follow, uniaxial
    from nma.periodic.figures import save_path_figure

    load = uniaxial(task.cfg.axis, task.cfg.strain)
    steps = 2 * task.cfg.steps
    base = follow(cell, load, steps, points=task.X0)
    files = [save_path_figure(out / "path_baseline.png", cell, task.X0, base, 3)]
    paths = [follow(cell, load, steps, points=x) for x in X]
    shown = [0] if len(paths) == 1 else [0, len(paths) // 2, len(paths) - 1]
    for i in shown:
        files.append(save_path_figure(out / f"path_learned_{i}.png", cell, X[i], paths[i], 3))
    fig, ax = plt.subplots(figsize=(5.5, 4))
    ax.plot(base.strain_axial, base.poisson, "k.-", label="baseline: circular holes")
    for i, (t, p) in enumerate(zip(ts, paths)):
        line = ax.plot(p.strain_axial, p.poisson, ".-", label=f"learned for {t:+.2f}")[0]
        ax.plot([task.cfg.strain], [t], "*", ms=11, color=line.get_color())
        if fine["reached"][i] is not None:  # where the finest model ends
            ax.plot(
                [task.cfg.strain], [fine["reached"][i]], "o", mfc="none", color=line.get_color()
            )
    ax.axvline(task.cfg.strain, color="grey", lw=0.5)
    ax.set_xlabel("axial nominal strain")
    ax.set_ylabel("secant Poisson's ratio")
    at = fine["fidelity"]
    ax.set_title(
        "Poisson's ratio along the path; stars: the targets; circles: at "
        f"{at['ctrl_per_patch']} x {at['quad_points']}",
        fontsize=9,
    )
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(out / "poisson.png", dpi=150)
    plt.close(fig)
    files.append(out / "poisson.png")
    reached = [float(p.poisson[-1]) for p in paths]
    numbers = {
        "targets": ts.tolist(),
        "reached": reached,
        "baseline_poisson": float(base.poisson[-1]),
        "baseline_critical_strain": base.critical and base.critical["strain"],
        "critical_strains": [p.critical and p.critical["strain"] for p in paths],
        "paths_not_physical": int(sum((~p.valid).any() for p in paths)),
    }
    return files, numbers


def summarise(name: str, out: Path, wall: float | None):
    from nma import config
    from nma.periodic.fabricate import export_tiling

    run = out / "joint"
    metrics = json.loads((run / "metrics.json").read_text())
    task, cell, ts, X, geom, radii, settings = designs(run)
    refined = refine(task, settings, radii)
    fine = refined[-1]
    files, numbers = figures(out, task, cell, ts, X, fine)
    ecoflex = config.load("material", "ecoflex_0030")
    part = export_tiling(
        cell, geom, *TILES, out / "tiling.dxf", scale=MM_PER_UNIT, material=ecoflex
    )
    at = lambda r: f"{r['fidelity']['ctrl_per_patch']} x {r['fidelity']['quad_points']}"
    trained = np.abs(np.asarray(numbers["reached"]) - ts)
    missed = [
        float(t) for t, a, b in zip(ts, trained, fine["per_sample"]) if a <= MET and not b <= MET
    ]
    summary = {
        "task": name,
        "metric": task.metric_name,
        "unit": "Poisson's ratio",
        "joint": metrics[task.metric_name],
        "baseline": metrics["no_actuation"],
        "training_fidelity": f"{cell.disc.mesh.fidelity.ctrl_per_patch} x "
        f"{cell.disc.mesh.fidelity.quad_points}",
        "failed_solves": metrics["failed_solves"],
        "invalid_states": metrics["invalid_states"],
        "checked_states": metrics["checked_states"],
        "steps": metrics["steps"],
        **numbers,
        # the headline: the designs at the finest fidelity (results.py's brackets, guard.py's)
        "reevaluated": {
            "run": "joint",
            "fidelity": at(fine),
            "value": fine["value"],
            "samples": len(ts),
            "failed_solves": fine["failed_solves"],
            "invalid_states": fine["invalid_states"],
            "baseline": fine["baseline_error"],
        },
        "refined": {at(r): r for r in refined},
        "convergence": {"between": [at(r) for r in refined[-2:]], **convergence(*refined[-2:])},
        "met_within": MET,
        "missed_when_refined": missed,
        "part": {
            k: part[k]
            for k in ("size", "min_ligament", "min_ligament_inside", "porosity", "tiling", "units")
        },
    }
    if wall is not None:
        (out / "stamp.json").write_text(json.dumps(results.stamp(COMMAND, wall)))
    (out / "result.json").write_text(json.dumps(summary, indent=1))
    report = _report(name, task, cell, summary, refined, part, files)
    (out / "comparison.md").write_text(report)
    if (
        out.resolve() == (ROOT / "outputs" / "repro" / name).resolve()
        and (out / "stamp.json").is_file()
    ):
        results.write(name, summary, report, files, json.loads((out / "stamp.json").read_text()))
        record = guard.load_record()
        for line in guard.update(record, [name]):
            print(f"record raised: {line}")
        guard.save_record(record)
    print(report)


def _report(name, task, cell, summary, refined, part, files) -> str:
    fine, fid = summary["reevaluated"], summary["training_fidelity"]
    f = lambda v, fmt="+.3f": "failed" if v is None else format(v, fmt)
    heads = " | ".join(f"{k}" for k in summary["refined"])
    rows = "\n".join(
        f"| {t:+.3f} | {r:+.3f} | {abs(r - t):.3f} | "
        + " | ".join(f(x["reached"][i]) for x in refined)
        + f" | {refined[-1]['per_sample'][i]:.3f} | {abs(summary['baseline_poisson'] - t):.3f} "
        f"| {abs((refined[-1]['baseline_poisson'] or np.nan) - t):.3f} |"
        for i, (t, r) in enumerate(zip(summary["targets"], summary["reached"]))
    )
    crit = lambda v: "none" if v is None else f"{v:.4f}"
    fids = [fid, *summary["refined"]]
    base_p = [summary["baseline_poisson"], *(r["baseline_poisson"] for r in refined)]
    base_c = [
        summary["baseline_critical_strain"],
        *(r["baseline_critical_strain"] for r in refined),
    ]
    conv = summary["convergence"]
    pct = lambda v: "n/a" if v is None else f"{100 * v:.2g}%"
    missed = summary["missed_when_refined"]
    verdict = (
        f"**Refined, the design{'s' if len(missed) > 1 else ''} for target"
        f"{'s' if len(missed) > 1 else ''} {', '.join(f'{t:+.2f}' for t in missed)} "
        f"met {'their' if len(missed) > 1 else 'its'} target within {MET:g} at {fid} but "
        f"miss{'' if len(missed) > 1 else 'es'} it at {fine['fidelity']}**: the training "
        "fidelity's post-buckling response is not converged, and the design was tuned to its "
        "error."
        if missed
        else f"No design that met its target within {MET:g} at {fid} misses it at "
        f"{fine['fidelity']}."
    )
    return (
        f"# {name}\n\n{cell.disc.spec.name}, compressed to nominal strain {task.cfg.strain} along "
        f"{task.cfg.axis} under uniaxial nominal stress, trained {summary['steps']} steps at "
        f"{fid} (control points per patch side x Gauss points). Mean |Poisson's ratio - target| "
        f"on the evaluation targets, every design re-solved at {fine['fidelity']} (the same "
        f"design parameters through the same B-spline nets, refined): **{fine['value']:.4g}** "
        f"learned, {fine['baseline']:.4g} for the baseline (circular holes, porosity "
        f"{task.porosity0:.3g}); at the training fidelity {summary['joint']:.4g} learned, "
        f"{summary['baseline']:.4g} baseline. {verdict}\n\n"
        f"At {fine['fidelity']}: {fine['failed_solves']} failed paths, {fine['invalid_states']} "
        f"of {refined[-1]['checked_states']} states not physical; at {fid}: "
        f"{summary['failed_solves']} failed, {summary['invalid_states']} of "
        f"{summary['checked_states']} not physical.\n\n"
        f"| target | learned at {fid} | error | {heads} | error at {fine['fidelity']} | "
        f"baseline's error at {fid} | at {fine['fidelity']} |\n"
        + "|---"
        * (6 + len(refined))
        + f"|\n{rows}\n\n"
        "The baseline (circular holes): Poisson's ratio "
        + ", ".join(f"{f(p)} at {k}" for p, k in zip(base_p, fids))
        + "; bifurcation at strain "
        + ", ".join(f"{crit(c)} at {k}" for c, k in zip(base_c, fids))
        + ". The learned designs' critical strains at "
        + "; ".join(
            f"{k}: {', '.join(crit(c) for c in cs)}"
            for k, cs in zip(
                fids,
                [summary["critical_strains"], *(r["critical_strains"] for r in refined)],
            )
        )
        + " (none: the path bends onto the pattern without an exact bifurcation). Between "
        f"{' and '.join(conv['between'])} the Poisson's ratios reached move at most "
        f"{pct(conv['poisson'])} and the critical strains {pct(conv['critical_strain'])}.\n\n"
        f"The learned cell tiled {TILES[0]} x {TILES[1]} at {MM_PER_UNIT:g} mm per "
        f"cell in Ecoflex 00-30 (tiling.dxf): {part['size'][0]:.0f} x {part['size'][1]:.0f} mm, "
        f"minimum ligament {part['min_ligament']:.3g} mm at its outer sides (they halve the "
        f"cell's edge ligaments), {part['min_ligament_inside']:.3g} mm between two pores.\n\n"
        + "".join(f"![{f.stem}]({f.name})\n" for f in files)
    )


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("name", choices=NAMES)
    ap.add_argument("--summarise", action="store_true", help="figures and tables from the run")
    ap.add_argument("--out", type=Path, help="where the run goes (outputs/repro/<name>)")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of the run")
    args = ap.parse_intermixed_args()
    out = args.out or ROOT / "outputs" / "repro" / args.name
    out.mkdir(parents=True, exist_ok=True)
    wall = None
    if not args.summarise:
        t0 = time.perf_counter()
        train(args.name, out / "joint", args.overrides)
        wall = time.perf_counter() - t0
    summarise(args.name, out, wall)


if __name__ == "__main__":
    main()
