"""Which equilibrium does a load path reach?  Newton iterations and equilibria of one design's
solves along several load paths (nma.solver.newton: load steps, their tolerance, their size).

    python experiments/load_path.py --init-from outputs/repro/rotation_double/joint \\
        --paths "" solver.path_rtol=1e-6 solver.path_rtol=1e-4 solver.path_rtol=1e-3 \\
        experiment=repro_rotation_double_refine contact=on
    python experiments/load_path.py --init-from outputs/repro/shape_matching/joint --eval 16 \\
        --paths "" "solver.initial_increment=0.02 solver.grow=1 solver.max_iters=2000" \\
        --save outputs/studies/load_path.npz experiment=repro_shape_matching

Each path is a set of solver overrides (quoted, space-separated; "" is the run's config as given).
For each, the run's config (the Hydra overrides given, trainer.init_from=<run>) is built with them,
and the actuations the restored network gives the first --batches training batches (or, with --eval
N, N targets evenly spaced through the evaluation set) are solved from rest.  Reported per path:
Newton iterations and load steps in all, failed solves, the task's metric over the samples, and for
every sample the largest difference of its displacement from the first path's, relative to the
largest displacement (the same equilibrium differs by what the final tolerance leaves; another by
much more). --save keeps every path's displacements; --compare-to adds the first path of such a file
(another version of the code, say) as a row.  Writes outputs/studies/load_path.{json,md}.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def solve(overrides: list[str], batches: int, evaluate: int) -> dict:
    import tempfile

    import jax

    from nma import cli
    from nma.run import validate
    from nma.train.runs import make_trainer

    settings = validate(
        cli.without_hydra(cli.compose("config", [*overrides, "trainer.progress=false"]))
    )
    trainer = make_trainer(settings, Path(tempfile.mkdtemp(prefix="load_path_")), exact_init=True)
    params = trainer.state["params"]
    X = trainer.sim.reference_points(params["geom"])
    if evaluate:
        targets = trainer.task.eval_set()
        picked = np.linspace(0, len(targets), evaluate, endpoint=False).astype(int)
        groups = [targets[picked]]
    else:
        groups = [
            trainer.task.sample(jax.random.fold_in(trainer.data_key, b), trainer.cfg.batch_size)
            for b in range(batches)
        ]
    r = {"u": [], "iterations": [], "load_steps": [], "converged": [], "metric": []}
    for ts in groups:
        d = trainer.model.apply(params["net"], trainer.task.net_input(ts))
        eq = trainer.sim.equilibrium_batch(X, d, trainer.mat)
        out = jax.lax.map(
            lambda u: trainer.task.observe(trainer.sim, params["geom"], X, u, trainer.mat), eq.u
        )
        r["u"].append(np.asarray(eq.u))
        r["iterations"] += np.asarray(eq.info.iterations).tolist()
        r["load_steps"] += np.asarray(eq.info.load_steps).tolist()
        r["converged"] += np.asarray(eq.converged).tolist()
        r["metric"] += np.asarray(jax.vmap(trainer.task.metric)(out, ts)).tolist()
    r["u"] = np.concatenate(r["u"])
    return r


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--init-from", required=True, help="a run directory whose parameters are solved with"
    )
    ap.add_argument(
        "--paths",
        nargs="+",
        default=[""],
        help="solver overrides of each path, quoted and space-separated; the first is the "
        "reference",
    )
    ap.add_argument("--batches", type=int, default=1, help="training batches to solve")
    ap.add_argument(
        "--eval", type=int, default=0, help="solve N evaluation targets instead (evenly spaced)"
    )
    ap.add_argument("--save", help="an .npz to keep every path's displacements in")
    ap.add_argument("--compare-to", help="an .npz written by --save: its first path becomes a row")
    ap.add_argument("--out", default=str(ROOT / "outputs" / "studies" / "load_path"))
    ap.add_argument(
        "overrides", nargs="*", help="Hydra overrides (experiment=..., contact=on, ...)"
    )
    args = ap.parse_intermixed_args()

    results = {}
    for path in args.paths:
        r = solve(
            [*args.overrides, f"trainer.init_from={args.init_from}", *path.split()],
            args.batches,
            args.eval,
        )
        results[path or "as configured"] = r
        print(
            f"{path or 'as configured'}: {sum(r['iterations'])} iterations, "
            f"{sum(r['load_steps'])} load steps, "
            f"{len(r['converged']) - sum(r['converged'])} failed",
            flush=True,
        )
    if args.save:
        np.savez(args.save, **{f"path{i}": r["u"] for i, r in enumerate(results.values())})
    ref = next(iter(results.values()))
    scale = np.abs(ref["u"]).reshape(len(ref["u"]), -1).max(axis=1)
    rows = []

    def row(name, u, r=None):
        diff = np.abs(u - ref["u"]).reshape(len(scale), -1).max(axis=1) / scale
        entry = {
            "path": name,
            "relative_difference": diff.tolist(),
            "largest_difference": float(diff.max()),
            "same": int(np.sum(diff <= 1e-6)),
        }
        if r is not None:
            entry.update(
                iterations=sum(r["iterations"]),
                load_steps=sum(r["load_steps"]),
                failed=len(r["converged"]) - sum(r["converged"]),
                metric=float(np.mean(r["metric"])),
                iterations_per_sample=r["iterations"],
                metric_per_sample=r["metric"],
            )
        rows.append(entry)

    for name, r in results.items():
        row(name, r["u"], r)
    if args.compare_to:
        row(f"first path of {args.compare_to}", np.load(args.compare_to)["path0"])
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    summary = {
        "init_from": args.init_from,
        "overrides": args.overrides,
        "batches": args.batches,
        "eval": args.eval,
        "rows": rows,
    }
    out.with_suffix(".json").write_text(json.dumps(summary, indent=1))
    what = f"{args.eval} evaluation targets" if args.eval else f"{args.batches} training batch(es)"
    lines = [
        f"# Load paths on {args.init_from} ({' '.join(args.overrides)}), {what}, {len(scale)} "
        "samples",
        "",
        "| path | Newton iterations | ratio | load steps | failed | metric | same state as the "
        "first (1e-6) | largest difference |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "iterations" in r:
            lines.append(
                f"| {r['path']} | {r['iterations']} | "
                f"{r['iterations'] / rows[0]['iterations']:.2f} "
                f"| {r['load_steps']} | {r['failed']} | {r['metric']:.5g} | {r['same']} of "
                f"{len(scale)} | {r['largest_difference']:.1e} |"
            )
        else:
            lines.append(
                f"| {r['path']} | | | | | | {r['same']} of {len(scale)} | "
                f"{r['largest_difference']:.1e} |"
            )
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
