"""How loose may the load steps before the last be?  Newton iterations and equilibria at several
`solver.path_rtol` (nma.solver.newton: the residual that closes a load step short of full load).

    python experiments/path_tolerance.py --init-from outputs/repro/rotation_double/joint \\
        experiment=repro_rotation_double_refine contact=on
    python experiments/path_tolerance.py --values 0 1e-4 --batches 3 --init-from <run> experiment=<name>

For each value, the run's config (the Hydra overrides given, trainer.init_from=<run>) is built with
solver.path_rtol=<value>, and the actuations the restored network gives the first --batches training
batches are solved from rest, a batch at a time.  Reported per value: Newton iterations and load
steps in all, failed solves, and for every sample the largest difference of its displacement from the
first value's, relative to the largest displacement (the same equilibrium differs by what the final
tolerance leaves; another branch by much more).  Writes outputs/studies/path_tolerance.{json,md}.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def solve_batches(overrides: list[str], batches: int) -> dict:
    import tempfile

    import jax

    from nma import cli
    from nma.run import validate
    from nma.train.runs import make_trainer

    settings = validate(cli.without_hydra(cli.compose("config", [*overrides, "trainer.progress=false"])))
    trainer = make_trainer(settings, Path(tempfile.mkdtemp(prefix="path_tolerance_")))
    params = trainer.state["params"]
    X = trainer.sim.reference_points(params["geom"])
    u, iterations, load_steps, status = [], [], [], []
    for b in range(batches):
        ts = trainer.task.sample(jax.random.fold_in(trainer.data_key, b), trainer.cfg.batch_size)
        d = trainer.model.apply(params["net"], trainer.task.net_input(ts))
        eq = trainer.sim.equilibrium_batch(X, d, trainer.mat)
        u.append(np.asarray(eq.u))
        iterations += np.asarray(eq.info.iterations).tolist()
        load_steps += np.asarray(eq.info.load_steps).tolist()
        status += np.asarray(eq.converged).tolist()
    return {"u": np.concatenate(u), "iterations": iterations, "load_steps": load_steps, "converged": status}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--init-from", required=True, help="a run directory whose parameters are solved with")
    ap.add_argument("--values", nargs="+", type=float, default=[0.0, 1e-6, 1e-4, 1e-3],
                    help="solver.path_rtol values; the first is the reference (0: every load step at rtol)")
    ap.add_argument("--batches", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "outputs" / "studies" / "path_tolerance"))
    ap.add_argument("overrides", nargs="*", help="Hydra overrides (experiment=..., contact=on, ...)")
    args = ap.parse_intermixed_args()

    results = {}
    for value in args.values:
        r = solve_batches([*args.overrides, f"trainer.init_from={args.init_from}", f"solver.path_rtol={value}"],
                          args.batches)
        results[value] = r
        print(f"path_rtol {value:g}: {sum(r['iterations'])} iterations, {sum(r['load_steps'])} load steps, "
              f"{len(r['converged']) - sum(r['converged'])} failed", flush=True)
    ref = results[args.values[0]]
    scale = np.abs(ref["u"]).reshape(len(ref["u"]), -1).max(axis=1)
    rows = []
    for value, r in results.items():
        diff = np.abs(r["u"] - ref["u"]).reshape(len(scale), -1).max(axis=1) / scale
        rows.append({"path_rtol": value, "iterations": sum(r["iterations"]), "load_steps": sum(r["load_steps"]),
                     "failed": len(r["converged"]) - sum(r["converged"]),
                     "iterations_per_sample": r["iterations"], "relative_difference": diff.tolist(),
                     "largest_difference": float(diff.max())})
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    summary = {"init_from": args.init_from, "overrides": args.overrides, "batches": args.batches, "rows": rows}
    out.with_suffix(".json").write_text(json.dumps(summary, indent=1))
    lines = [f"# solver.path_rtol on {args.init_from} ({' '.join(args.overrides)}), {len(scale)} samples", "",
             "| path_rtol | Newton iterations | ratio | load steps | failed | largest difference | samples > 1e-6 |",
             "|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['path_rtol']:g} | {row['iterations']} | {row['iterations'] / rows[0]['iterations']:.2f} "
                     f"| {row['load_steps']} | {row['failed']} | {row['largest_difference']:.1e} "
                     f"| {sum(d > 1e-6 for d in row['relative_difference'])} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
