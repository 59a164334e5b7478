"""Reproduce a paper experiment: the joint design and the geometry-frozen baseline, then compare.

    python experiments/repro.py translation [--baseline-steps 150] [extra Hydra overrides ...]

Runs `python -m nma.run experiment=repro_<name>` twice (geometry learned; geometry frozen, the
paper's control-only baseline) into outputs/repro/<name>/{joint,baseline}/ and writes
outputs/repro/<name>/comparison.{md,json,png}.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def train(name: str, run_dir: Path, overrides: list[str]) -> dict:
    cmd = [sys.executable, "-m", "nma.run", f"experiment=repro_{name}", f"hydra.run.dir={run_dir}",
           "trainer.progress=false", *overrides]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    metrics["wall_seconds"] = time.perf_counter() - t0
    return metrics


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("name", choices=["translation", "rotation_single", "rotation_double"])
    ap.add_argument("--baseline-steps", type=int, default=150)
    ap.add_argument("overrides", nargs="*", help="Hydra overrides for both runs")
    args = ap.parse_args()
    out = ROOT / "outputs" / "repro" / args.name
    t0 = time.perf_counter()
    joint = train(args.name, out / "joint", args.overrides)
    baseline = train(args.name, out / "baseline",
                     ["trainer.freeze_geometry=true", f"trainer.steps={args.baseline_steps}", *args.overrides])
    total = time.perf_counter() - t0
    name, unit = joint["metric"], joint["unit"]
    ratio = joint["value"] / baseline["value"]
    summary = {"experiment": args.name, "metric": name, "unit": unit, "joint": joint["value"],
               "baseline": baseline["value"], "joint_over_baseline": ratio,
               "joint_steps": joint["step"], "baseline_steps": baseline["step"],
               "joint_seconds": joint["wall_seconds"], "baseline_seconds": baseline["wall_seconds"],
               "total_seconds": total, "failed_solves": [joint["failed_solves"], baseline["failed_solves"]],
               "runs": {"joint": str(out / "joint"), "baseline": str(out / "baseline")}}
    (out / "comparison.json").write_text(json.dumps(summary, indent=1))
    (out / "comparison.md").write_text(
        f"# {args.name}: learned design vs geometry-frozen baseline\n\n"
        f"| run | steps | {name} [{unit}] | wall time [s] |\n|---|---|---|---|\n"
        f"| joint (network + geometry) | {joint['step']} | {joint['value']:.4g} | {joint['wall_seconds']:.0f} |\n"
        f"| baseline (network only) | {baseline['step']} | {baseline['value']:.4g} | {baseline['wall_seconds']:.0f} |\n\n"
        f"joint / baseline = {ratio:.3f}; total {total / 60:.1f} min\n")
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    for m, label in ((joint, "joint"), (baseline, "baseline")):
        ax[0].plot(np.sort(m["per_sample"]), label=label)
        ev = [(h["step"], h[name]) for h in m["history"] if name in h]
        ax[1].plot(*zip(*ev), "o-", ms=3, label=label)
    ax[0].set(xlabel="evaluation sample (sorted)", ylabel=f"{name} [{unit}]", title="final error per target")
    ax[1].set(xlabel="step", ylabel=f"{name} [{unit}]", title="evaluation during training")
    for a in ax:
        a.legend()
    fig.tight_layout()
    fig.savefig(out / "comparison.png", dpi=130)
    print((out / "comparison.md").read_text())


if __name__ == "__main__":
    main()
