"""Reproduce a paper experiment: the joint design and the geometry-frozen baseline, then compare.

    python experiments/repro.py translation [--baseline-steps 150] [extra Hydra overrides ...]
    # tables and figures again, from the runs
    python experiments/repro.py translation --summarise
    python experiments/repro.py shape_matching --out outputs/repro_contact/shape_matching contact=on

Runs `python -m nma.run experiment=repro_<name>` twice (geometry learned; geometry frozen, the
paper's control-only baseline) into outputs/repro/<name>/{joint,baseline}/ and writes
outputs/repro/<name>/comparison.{md,json,png} (and seconds.json, the runs' wall times). Where
conf/experiment/repro_<name>_refine.yaml exists, the joint design is then fine-tuned at that finer
fidelity into outputs/repro/<name>/refined/, and where repro_<name>_finish.yaml exists too, the
refined design once more into outputs/repro/<name>/finished/; the last stage's design is the one
compared.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import matplotlib

# experiments/results.py, run as a script or imported
sys.path.insert(0, str(Path(__file__).resolve().parent))
import guard  # noqa: E402
import results  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
# stages after the joint run, each fine-tuning the design of the run before it: (config suffix, run
# directory)
STAGES = (("refine", "refined"), ("finish", "finished"))
# the baseline's own settings where they differ from the joint run's.  Shape matching's frozen
# square-pore design cannot train at 5 x 2 under Newton's element bound: by step 33 its network's
# actuations invert the unchanged hinges between Gauss points in every sample of a batch, and a
# frozen design cannot be steered away.  So it trains without the bound; the validity check still
# reports its final states.
BASELINE = {"shape_matching": ["solver.element_bound=false"]}
COMMAND = ["python", "experiments/repro.py", *sys.argv[1:]]  # what a result's stamp says made it


def stages(name: str) -> list[tuple[str, str]]:
    """The experiment's stages after its joint run, in order: a leading run of STAGES, each with a
    conf/experiment/repro_<name>_<suffix>.yaml (a stage continues the one before it, so none may be
    missing)."""
    present = [
        stage
        for stage in STAGES
        if (ROOT / "conf" / "experiment" / f"repro_{name}_{stage[0]}.yaml").exists()
    ]
    if present != list(STAGES[: len(present)]):
        raise SystemExit(
            f"repro_{name}: stages {[suffix for suffix, _ in present]} leave out one before them"
        )
    return present


def digital_mnist(out: Path, overrides: list[str]):
    """The paper's three phases in sequence, each starting from the one before."""
    seconds, t0 = {}, time.perf_counter()
    for phase, extra in (
        ("lookup", []),
        ("fit", [f"task.lookup_run={out / 'lookup'}", f"trainer.init_from={out / 'lookup'}"]),
        ("finetune", [f"trainer.init_from={out / 'fit'}"]),
    ):
        seconds[phase] = train(f"mnist_{phase}", out / phase, [*extra, *overrides])["wall_seconds"]
    (out / "seconds.json").write_text(json.dumps(seconds))
    (out / "stamp.json").write_text(json.dumps(results.stamp(COMMAND, time.perf_counter() - t0)))
    summarise_digital_mnist(out)


def summarise_digital_mnist(out: Path):
    """comparison.{json,md} from the three phases' metrics.json (python experiments/repro.py
    digital_mnist --summarise rewrites them without training)."""
    m = {
        p: json.loads((out / p / "metrics.json").read_text()) for p in ("lookup", "fit", "finetune")
    }
    seconds = json.loads((out / "seconds.json").read_text())
    summary = {
        "experiment": "digital_mnist",
        "lookup_digits_correct": m["lookup"]["value"],
        "digit_exact_match": {p: m[p]["value"] for p in ("fit", "finetune")},
        "digit_segment_accuracy": {p: m[p]["digit_segment_accuracy"] for p in m},
        "seconds": {**seconds, "total": sum(seconds.values())},
        "runs": {p: results.relative(str(out / p)) for p in m},
    }
    (out / "comparison.json").write_text(json.dumps(summary, indent=1))
    labels = {
        "lookup": "1 lookup table (10 actuation vectors + colours)",
        "fit": "2 network fitted to the table",
        "finetune": "3 network + colours fine-tuned end to end",
    }
    lines = [
        "# digital MNIST: the three phases",
        "",
        "| phase | steps | digits of the table shown right | held-out exact match (1,000) | "
        "per-segment accuracy | wall time [s] |",
        "|---|---|---|---|---|---|",
    ]
    for p, label in labels.items():
        table = f"{m[p]['value']}/10" if p == "lookup" else ""
        exact = "" if p == "lookup" else f"{m[p]['value']:.3f}"
        lines.append(
            f"| {label} | {m[p]['step']} | {table} | {exact} | "
            f"{m[p]['digit_segment_accuracy']:.3f} | "
            f"{seconds[p]:.0f} |"
        )
    lines += [
        "",
        f"total {sum(seconds.values()) / 60:.1f} min; figures: lookup/figures/deformed.png (the "
        "ten digits), finetune/figures/deformed.png (held-out images and what the material shows), "
        "*/figures/colours.png (the colour field)",
    ]
    (out / "comparison.md").write_text("\n".join(lines) + "\n")
    publish("digital_mnist", out, summary, [])
    print((out / "comparison.md").read_text())


def reevaluate(out: Path, run: str, extra: list[str] = (), solve: bool = True) -> None:
    """The compared design re-solved at 14 x 5 (nma.evaluate) -> out/reevaluated.json: the metric
    where the model is finer than any it trained at.  An evaluation nma.evaluate wrote there already
    is read, not solved again (and with solve=False, --summarise, none is solved).  A task in time
    re-solves every trajectory of its evaluation set, each time step at 14 x 5."""
    done = sorted((out / run / "evaluate").glob("14x5*.json"))
    if not done and not solve:
        return
    if not done:
        cmd = [
            sys.executable,
            "-m",
            "nma.evaluate",
            f"run={out / run}",
            "fidelity.ctrl_per_patch=14",
            "fidelity.quad_points=5",
            *extra,
        ]
        done = [
            Path(
                json.loads(
                    subprocess.run(cmd, check=True, cwd=ROOT, capture_output=True, text=True).stdout
                )["file"]
            )
        ]
    record = json.loads(done[-1].read_text())
    at = record["evaluated_fidelity"]
    (out / "reevaluated.json").write_text(
        json.dumps(
            {
                "run": run,
                "file": results.relative(str(done[-1])),
                "fidelity": "14 x 5",
                "value": at["metric"],
                "samples": record["samples"],
                "failed_solves": at["failed_solves"],
                "invalid_states": at.get("invalid_states"),
            },
            indent=1,
        )
    )


def publish(name: str, out: Path, summary: dict, figures: list[Path]) -> None:
    """results/<name>/ from a reproduction's summary, where its runs were stamped when they
    trained."""
    # a variant (--out): not the result
    if out.resolve() != (ROOT / "outputs" / "repro" / name).resolve():
        return
    if not (out / "stamp.json").is_file():
        print(f"{out}: no stamp.json (runs not made by this script): results/{name} not written")
        return
    again = out / "reevaluated.json"
    report = (out / "comparison.md").read_text()
    if again.is_file():
        r = json.loads(again.read_text())
        summary = {**summary, "reevaluated": r}
        report += (
            f"\nThe compared design ({r['run']}) re-evaluated at {r['fidelity']}: "
            f"{r['value']:.4g} over "
            f"{r['samples']} samples, {r['failed_solves']} failed solves, {r['invalid_states']} "
            "states not physical.\n"
        )
    results.write(name, summary, report, figures, json.loads((out / "stamp.json").read_text()))
    record = guard.load_record()  # the record rises with a better result; a worse one is said
    for line in guard.update(record, [name]):
        print(f"record raised: {line}")
    guard.save_record(record)
    for problem in guard.check(record):
        if problem.startswith(f"{name}."):
            print(f"worse than the record: {problem}", file=sys.stderr)


def train(name: str, run_dir: Path, overrides: list[str]) -> dict:
    cmd = [
        sys.executable,
        "-m",
        "nma.run",
        f"experiment=repro_{name}",
        f"hydra.run.dir={run_dir}",
        "trainer.progress=false",
        *overrides,
    ]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    metrics["wall_seconds"] = time.perf_counter() - t0
    return metrics


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "name",
        choices=[
            "translation",
            "rotation_single",
            "rotation_double",
            "shape_matching",
            "digital_mnist",
            "dynamic_follow",
            "dynamic_energy",
        ],
    )
    ap.add_argument("--baseline-steps", type=int, default=150)
    ap.add_argument(
        "--summarise", action="store_true", help="rewrite the tables and figures from the runs only"
    )
    ap.add_argument(
        "--out",
        type=Path,
        help="where the runs go (default outputs/repro/<name>; e.g. "
        "outputs/repro_contact/<name> with the override contact=on)",
    )
    ap.add_argument("overrides", nargs="*", help="Hydra overrides for both runs")
    args = ap.parse_intermixed_args()  # overrides may follow the options
    out = args.out or ROOT / "outputs" / "repro" / args.name
    if args.name == "digital_mnist":
        return (
            summarise_digital_mnist
            if args.summarise
            else lambda o: digital_mnist(o, args.overrides)
        )(out)
    later = stages(args.name)
    if not args.summarise:
        seconds, before = {}, None
        runs = [(args.name, "joint")] + [(f"{args.name}_{suffix}", run) for suffix, run in later]
        for i, (experiment, run) in enumerate(runs):
            extra = [f"trainer.init_from={out / before}"] if before else []
            # a later stage fine-tunes this one: its sweep animation supersedes this one's (24
            # solves, about 20 s at 8 x 2 with contact)
            if i + 1 < len(runs):
                extra.append("trainer.animation_frames=0")
            seconds[run] = train(experiment, out / run, [*extra, *args.overrides])["wall_seconds"]
            before = run
        t0 = time.perf_counter() - sum(seconds.values())
        seconds["baseline"] = train(
            args.name,
            out / "baseline",
            [
                "trainer.freeze_geometry=true",
                f"trainer.steps={args.baseline_steps}",
                *BASELINE.get(args.name, []),
                *args.overrides,
            ],
        )["wall_seconds"]
        (out / "seconds.json").write_text(json.dumps(seconds))
        (out / "stamp.json").write_text(
            json.dumps(results.stamp(COMMAND, time.perf_counter() - t0))
        )
        reevaluate(out, later[-1][1] if later else "joint")
    else:
        reevaluate(out, later[-1][1] if later else "joint", solve=False)
    summarise(out, args.name, [run for _, run in later])


def summarise(out: Path, experiment: str, refinements: list[str]):
    """comparison.{json,md,png} from the runs' metrics.json and seconds.json."""
    seconds = json.loads((out / "seconds.json").read_text())
    runs = ("joint", *refinements, "baseline")
    missing = [r for r in runs if r not in seconds or not (out / r / "metrics.json").exists()]
    # e.g. a directory holding fewer stages than the experiment: its last stage's design is compared
    if missing:
        raise SystemExit(
            f"{out}: no complete run (metrics.json, and its time in seconds.json) for {missing}; "
            f"rerun the experiment, or each missing stage into its directory with "
            f"trainer.init_from=<the stage before>"
        )
    m = {
        r: {**json.loads((out / r / "metrics.json").read_text()), "wall_seconds": seconds[r]}
        for r in runs
    }
    coarse, baseline = m["joint"], m["baseline"]
    joint = m[refinements[-1]] if refinements else coarse  # the design compared: the last stage's
    total = sum(seconds.values())
    name, unit = joint["metric"], joint["unit"]
    ratio = joint["value"] / baseline["value"]
    fid = lambda r: (
        f"{r['fidelity']['ctrl_per_patch']} x {r['fidelity']['quad_points']}"
        + (
            f", grading {r['fidelity']['grading']:g}"
            if r["fidelity"].get("grading", 1.0) != 1.0
            else ""
        )
        + (", contact" if r["fidelity"].get("contact") else "")
    )
    # older runs: unknown
    physical = lambda r: (
        f"{r['invalid_states']} of {r['checked_states']}"
        if "invalid_states" in r
        else "not checked"
    )
    summary = {
        "experiment": experiment,
        "metric": name,
        "unit": unit,
        "joint": joint["value"],
        "baseline": baseline["value"],
        "joint_over_baseline": ratio,
        "joint_steps": coarse["step"],
        "baseline_steps": baseline["step"],
        "joint_seconds": coarse["wall_seconds"],
        "baseline_seconds": baseline["wall_seconds"],
        "no_actuation": joint["no_actuation"],
        "total_seconds": total,
        "failed_solves": [joint["failed_solves"], baseline["failed_solves"]],
        "invalid_states": [joint.get("invalid_states"), baseline.get("invalid_states")],
        "runs": {r: results.relative(str(out / r)) for r in runs},
    }
    rows = [("joint (network + geometry)", coarse)]
    if refinements:
        summary.update(
            joint_before_refinement=coarse["value"],
            refined_steps=sum(m[r]["step"] for r in refinements),
            refined_seconds=sum(m[r]["wall_seconds"] for r in refinements),
            refined_fidelity=joint["fidelity"],
            stages={
                r: {
                    "steps": m[r]["step"],
                    "value": m[r]["value"],
                    "fidelity": m[r]["fidelity"],
                    "seconds": m[r]["wall_seconds"],
                }
                for r in refinements
            },
        )
        rows += [(f"joint, {r} (fine-tuned at a finer fidelity)", m[r]) for r in refinements]
    rows.append(("baseline (network only)", baseline))
    (out / "comparison.json").write_text(json.dumps(summary, indent=1))
    (out / "comparison.md").write_text(
        f"# {experiment}: learned design vs geometry-frozen baseline\n\n"
        f"| run | fidelity | steps | {name} [{unit}] | states not physical | wall time [s] "
        "|\n|---|---|---|---|---|---|\n"
        + "".join(
            f"| {label} | {fid(r)} | {r['step']} | {r['value']:.4g} | {physical(r)} | "
            f"{r['wall_seconds']:.0f} |\n"
            for label, r in rows
        )
        + f"| no actuation (initial design at rest) | {fid(joint)} | 0 | "
        f"{joint['no_actuation']:.4g} | | 0 |\n\n"
        f"joint / baseline = {ratio:.3f}; total {total / 60:.1f} min\n"
    )
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    evals = lambda r, offset=0: [(h["step"] + offset, h[name]) for h in r["history"] if name in h]
    joint_evals, offset, before = evals(coarse), coarse["step"], coarse
    for r in refinements:  # each stage's evaluations after the steps of the stages before it
        ax[1].axvline(
            offset, color="grey", lw=0.8, ls="--", label=f"{fid(before)} -> {fid(m[r])} ({r})"
        )
        joint_evals += evals(m[r], offset)
        offset, before = offset + m[r]["step"], m[r]
    for r, ev, label in ((joint, joint_evals, "joint"), (baseline, evals(baseline), "baseline")):
        ax[0].plot(np.sort(r["per_sample"]), "o-", ms=4, label=label)  # a single sample shows too
        ax[1].plot(*zip(*ev), "o-", ms=3, label=label)
    ax[0].set(
        xlabel="evaluation sample (sorted)",
        ylabel=f"{name} [{unit}]",
        title="final value per evaluation sample",
    )
    samples = max(len(joint["per_sample"]), len(baseline["per_sample"]))
    ax[0].set_xlim(-0.5, samples - 0.5)
    ax[0].set_xticks(range(0, samples, max(1, samples // 8)))  # whole samples
    ax[1].set(xlabel="step", ylabel=f"{name} [{unit}]", title="evaluation during training")
    ax[1].axhline(joint["no_actuation"], color="grey", ls=":", label="no actuation")
    for a in ax:
        a.legend()
    fig.tight_layout()
    fig.savefig(out / "comparison.png", dpi=130)
    plt.close(fig)
    figures = [out / "comparison.png"]
    if experiment == "shape_matching":
        figures.append(figure_shapes_side_by_side(out))
    if experiment == "dynamic_follow":
        figures.append(figure_paths_side_by_side(out))
    publish(experiment, out, summary, figures)
    print((out / "comparison.md").read_text())


def figure_shapes_side_by_side(out: Path, n: int = 8) -> Path:
    """The same held-out targets reached by the joint design (top) and the frozen one (bottom)."""
    import h5py

    from nma.tasks.shape_matching import fit_onto

    fig, axes = plt.subplots(2, n, figsize=(1.9 * n, 4.3))
    for row, run in enumerate(("joint", "baseline")):
        errors = json.loads((out / run / "metrics.json").read_text())["per_sample"]
        for i, ax in enumerate(axes[row]):
            ax.axis("off")
            path = out / run / "fields" / f"eval_{i:03d}.h5"
            if not path.exists():
                continue
            with h5py.File(path) as f:
                observed, target = f.attrs["observed"], f.attrs["descriptor"].reshape(-1, 2)
            shown = np.asarray(fit_onto(observed, target))
            close = lambda a: np.concatenate([a, a[:1]])
            ax.plot(*close(shown).T, "--", color="#1f3fbf", lw=1.1, label="target")
            ax.plot(*close(observed).T, "-", color="#2ca02c", lw=1.1, label="reached")
            ax.set_aspect("equal")
            ax.set_title(f"{'joint' if row == 0 else 'frozen'}: {errors[i]:.3f}", fontsize=8)
    axes[0, 0].legend(loc="lower left", fontsize=6)
    fig.suptitle(
        "pore shape matching: held-out targets (dashed) and reached pores; error in mean pore "
        "radii",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out / "shapes.png", dpi=130)
    plt.close(fig)
    return out / "shapes.png"


def follow_paths(run: Path) -> list[dict]:
    """Each converged evaluation sample of a follow_path run, from its saved fields (eval_<i>.h5:
    the descriptor and the tracked point over the window; trajectories.h5: the times) and its
    config: the path the point traced, its target (nma.tasks.timed.FollowPath.targets: the circle
    of radius r through the point's rest position, from direction phi, once per
    task.period_steps) and their mean distance."""
    import h5py
    from omegaconf import OmegaConf

    cfg = OmegaConf.load(run / ".hydra" / "config.yaml")
    first, last = cfg.task.window
    start = np.asarray(cfg.scene.tracked[cfg.task.point], float)  # the tracked point at rest
    with h5py.File(run / "fields" / "trajectories.h5") as f:
        times = np.asarray(f["times"])
    omega = 2 * np.pi / (cfg.task.period_steps * (times[1] - times[0]))
    paths = []
    for path in sorted((run / "fields").glob("eval_*.h5")):
        with h5py.File(path) as f:
            reached, (r, phi) = np.asarray(f.attrs["observed"]), np.asarray(f.attrs["descriptor"])
        angle = omega * times[first : last + 1] + phi
        circle = np.stack([np.cos(angle) - np.cos(phi), np.sin(angle) - np.sin(phi)], -1)
        target = start + r * circle
        paths.append(
            {
                "sample": int(path.stem.split("_")[1]),
                "r": float(r),
                "phi": float(phi),
                "rest": start,
                "reached": reached,
                "target": target,
                "error": float(np.mean(np.linalg.norm(reached - target, axis=-1))),
            }
        )
    return paths


def figure_paths_side_by_side(out: Path, n: int = 8) -> Path:
    """The path the tracked point traces against its moving target over the goal's window, for
    the same evaluation samples, by the joint design (top) and the frozen one (bottom):
    out/paths.png."""
    runs = {run: follow_paths(out / run)[:n] for run in ("joint", "baseline")}
    cols = max(1, *(len(p) for p in runs.values()))
    fig, axes = plt.subplots(2, cols, figsize=(max(7.0, 1.9 * cols + 0.8), 4.5), squeeze=False)
    for row, (run, paths) in enumerate(runs.items()):
        for ax in axes[row]:
            ax.axis("off")
        for ax, p in zip(axes[row], paths):
            ax.axis("on")
            ax.plot(*p["rest"], "+", color="black", ms=6, label="at rest")
            ax.plot(*p["target"].T, "--", color="#1f3fbf", lw=1.1, label="target")
            ax.plot(*p["reached"].T, "-", color="#2ca02c", lw=1.1, label="traced")
            ax.plot(*p["target"][0], "o", color="#1f3fbf", ms=3)
            ax.plot(*p["reached"][0], "o", color="#2ca02c", ms=3)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=5)
            ax.set_title(
                f"{'joint' if row == 0 else 'frozen'}: r {p['r']:.2f}, phi "
                f"{np.degrees(p['phi']):.0f} deg\nerror {p['error']:.3f}",
                fontsize=7,
            )
    axes[0, 0].legend(loc="lower left", fontsize=6)
    fig.suptitle(
        "follow_path: the pointer over the goal's window (solid) against its moving "
        "target (dashed)\ndots: the window's start; +: the pointer at rest; error: their "
        "mean distance (cell = 5)",
        fontsize=8,
    )
    fig.tight_layout()
    fig.savefig(out / "paths.png", dpi=130)
    plt.close(fig)
    return out / "paths.png"


if __name__ == "__main__":
    main()
