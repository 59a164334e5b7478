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
guard's record (experiments/guard.py), as experiments/repro.py does for the paper's tasks.
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


def train(name: str, run_dir: Path, overrides: list[str]) -> float:
    if run_dir.exists():  # this script's own earlier run: a reproduction starts afresh
        shutil.rmtree(run_dir)
    cmd = [sys.executable, "-m", "nma.run", f"experiment=repro_{name}"]
    cmd += [f"hydra.run.dir={run_dir}", "trainer.progress=false", *overrides]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT)
    return time.perf_counter() - t0


def designs(run_dir: Path):
    """(the task rebuilt from the run's settings, the evaluation's targets, the reference points of
    each evaluated design, the learned cell's design params for export)."""
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
        side = np.asarray(d)[len(d) // 2]  # the middle target's pore, for the part
        r0 = np.asarray(task.params0["radii"])
        lo, hi = cell.disc.design.bounds()["radii"]
        radii = np.clip(r0 + np.tile([side[0], side[1], side[0]], r0.shape[1] // 3), lo, hi)
        geom = {"radii": jnp.asarray(radii)}
    else:
        geom = {"radii": jnp.asarray(params["geom"]["radii"])}
        X = np.asarray(cell.disc.reference_points(geom))[None]
    return task, cell, ts, X, geom


def figures(out: Path, task, cell, ts, X) -> tuple[list[Path], dict]:
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
    ax.axvline(task.cfg.strain, color="grey", lw=0.5)
    ax.set_xlabel("axial nominal strain")
    ax.set_ylabel("secant Poisson's ratio")
    ax.set_title("Poisson's ratio along the path; stars: the targets", fontsize=9)
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
    final = metrics
    task, cell, ts, X, geom = designs(run)
    files, numbers = figures(out, task, cell, ts, X)
    ecoflex = config.load("material", "ecoflex_0030")
    part = export_tiling(
        cell, geom, *TILES, out / "tiling.dxf", scale=MM_PER_UNIT, material=ecoflex
    )
    summary = {
        "task": name,
        "metric": task.metric_name,
        "unit": "Poisson's ratio",
        "joint": final[task.metric_name],
        "baseline": metrics["no_actuation"],
        "failed_solves": final["failed_solves"],
        "invalid_states": final["invalid_states"],
        "checked_states": final["checked_states"],
        "steps": metrics["steps"],
        **numbers,
        "part": {
            k: part[k]
            for k in ("size", "min_ligament", "min_ligament_inside", "porosity", "tiling", "units")
        },
    }
    if wall is not None:
        (out / "stamp.json").write_text(json.dumps(results.stamp(COMMAND, wall)))
    (out / "result.json").write_text(json.dumps(summary, indent=1))
    pairs = "\n".join(
        f"| {t:+.3f} | {r:+.3f} | {abs(r - t):.3f} | {abs(summary['baseline_poisson'] - t):.3f} |"
        for t, r in zip(numbers["targets"], numbers["reached"])
    )
    report = (
        f"# {name}\n\n{cell.disc.spec.name}, compressed to nominal strain {task.cfg.strain} along "
        f"{task.cfg.axis} under uniaxial nominal stress, {metrics['steps']} training steps. "
        f"Mean |Poisson's ratio - target| on the evaluation targets: **{summary['joint']:.4g}** "
        f"learned, {summary['baseline']:.4g} for the baseline (circular holes, porosity "
        f"{task.cfg.porosity}: Poisson's ratio {summary['baseline_poisson']:+.3f}, bifurcation "
        f"at strain {summary['baseline_critical_strain'] or float('nan'):.4f}). "
        f"{summary['failed_solves']} failed "
        f"paths; {summary['invalid_states']} of {summary['checked_states']} evaluated states "
        "not physical.\n\n| target | learned | error | baseline's error |\n|---|---|---|---|\n"
        f"{pairs}\n\nThe learned cell tiled {TILES[0]} x {TILES[1]} at {MM_PER_UNIT:g} mm per "
        f"cell in Ecoflex 00-30 (tiling.dxf): {part['size'][0]:.0f} x {part['size'][1]:.0f} mm, "
        f"minimum ligament {part['min_ligament']:.3g} mm at its outer sides (they halve the "
        f"cell's edge ligaments), {part['min_ligament_inside']:.3g} mm between two pores.\n\n"
        + "".join(f"![{f.stem}]({f.name})\n" for f in files)
    )
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
