"""A reproduction retrained with a minimum feature size, side by side with the same reproduction
unbounded.

    python experiments/min_feature.py translation [--bound 0.8] [--scale 2]   # train, then compare
    # compare the runs there are
    python experiments/min_feature.py translation --summarise

Trains `experiments/repro.py <name> --out outputs/repro_min_feature/<name> part.scale=<scale>
trainer.min_feature=<bound>` (the same stages and baseline as `make repro-<name>`, the bound added)
and writes results/<name>_min_feature/ (report.md, result.json, designs.png): the metric, its
re-evaluation at 14 x 5, the narrowest ligament in mm and the states that are not physical, of the
unbounded design (outputs/repro/<name>, `make repro-<name>`) and of the bounded one.  The bounded
translation part is then checked as made: the paper's load cases solved in a fitted elastomer
(`--made-of`, a file of conf/material/) at `--thickness` mm, its actuators' forces in N
(nma.export's load cases, load_cases.png).

The default bound, 0.8 mm at 2 mm per length unit (a paper cell of 5 units is 10 mm), is a desktop
FDM printer's thinnest supported wall: two perimeters of its usual 0.4 mm nozzle (design guides
agree, e.g. rigidprints.co.uk/design-guide/wall-thickness: "connected to other structures on at
least two sides, safe down to 0.8 mm"; the same guide asks 1.2 mm of printed TPU).  A ligament joins
cells on two sides.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import matplotlib

sys.path.insert(0, str(Path(__file__).resolve().parent))  # experiments/repro.py and results.py
import repro  # noqa: E402
import results  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = repro.ROOT
# as the Makefile's targets
BASELINE_STEPS = {"translation": 80, "rotation_single": 60, "rotation_double": 60}


def compared_run(out: Path, name: str) -> Path:
    """The run a reproduction compares: its last stage's."""
    stages = repro.stages(name)
    return out / (stages[-1][1] if stages else "joint")


def design_record(run: Path, scale: float):
    """The run's metric and validity counts (metrics.json), its 14 x 5 re-evaluation
    (reevaluated.json beside it, where there is one), and its narrowest ligament measured on its
    checkpoint (nma.geometry.features), with the reference points to draw."""
    from nma.runtime import configure_jax

    configure_jax()
    from nma.geometry.features import Ligaments
    from nma.simulator import Simulator
    from nma.train.runs import load_run

    settings, params, _ = load_run(run)
    sim = Simulator.from_settings(settings)
    X = sim.reference_points({k: np.asarray(v) for k, v in params["geom"].items()})
    widths = Ligaments.of(sim.disc.mesh, X, scale=scale).report(X)
    m = json.loads((run / "metrics.json").read_text())
    again = run.parent / "reevaluated.json"
    fine = json.loads(again.read_text()) if again.is_file() else None
    record = {
        "run": str(run.relative_to(ROOT)),
        "metric": m["value"],
        "unit": m["unit"],
        "failed_solves": m["failed_solves"],
        "invalid_states": m["invalid_states"],
        "checked_states": m["checked_states"],
        "min_ligament_mm": widths["min_ligament_mm"],
        "min_ligament_between": widths["min_ligament_between"],
        "min_ligament_at": widths["min_ligament_at"],
        "reevaluated": fine
        and {k: fine[k] for k in ("value", "samples", "failed_solves", "invalid_states")},
    }
    return record, sim, np.asarray(X)


def figure(path: Path, name: str, drawn, bound: float, scale: float) -> Path:
    from nma.viz.plot import MATERIAL, draw_shape

    fig, axes = plt.subplots(1, 2, figsize=(10, 5.2), sharex=True, sharey=True)
    for ax, (label, record, sim, X) in zip(axes, drawn):
        draw_shape(
            ax,
            sim.disc,
            X,
            f"{label}: narrowest ligament {record['min_ligament_mm']:.2f} mm",
            colour=MATERIAL["learned"],
            frame=True,
        )
        ax.plot(*record["min_ligament_at"], "o", ms=12, mfc="none", mec="#c0392b", mew=2)
        ax.set_xlabel("x [length units]")
    axes[0].set_ylabel("y [length units]")
    fig.suptitle(
        f"{name}: the learned design without and with trainer.min_feature = {bound:g} mm at "
        f"part.scale = {scale:g} mm per unit (red: the narrowest ligament)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def made_part(run: Path, made_of: str, scale: float, thickness: float, out: Path):
    """The paper's load cases of the part made of `made_of` (nma.export.write_load_cases) and their
    table."""
    from nma import config
    from nma.export import write_load_cases
    from nma.schema import MaterialConfig

    material = MaterialConfig(**config.load("material", made_of))
    cases = write_load_cases(run, 0.5, out / "load_cases.png", scale, thickness, material)
    lines = [
        "",
        f"The bounded part as made: {material.name or made_of} (`material={made_of}`, nu "
        f"{material.nu:g}), "
        f"{thickness:g} mm thick, under the paper's load cases at half the task's largest "
        "actuation (`nma.export load_cases=true`; load_cases.png):",
        "",
        f"| load case | pointer moves [mm] | actuators push [{cases['units']['force']}] | "
        "physical |",
        "|---|---|---|---|",
    ]
    for case, c in cases["cases"].items():
        if not c["converged"]:
            lines.append(f"| {case} | solve failed: {c['error']} | | |")
            continue
        move = ", ".join(f"{v:+.2f}" for v in c["pointer_displacement_mm"])
        push = ", ".join(f"{v:+.3g}" for v in c.get("actuation_forces_N", c["actuation_forces"]))
        lines.append(f"| {case} | ({move}) | {push} | {'yes' if c['valid'] else 'no'} |")
    return cases, lines, out / "load_cases.png"


def summarise(
    name: str,
    out: Path,
    bound: float,
    scale: float,
    made_of: str | None = None,
    thickness: float = 10.0,
) -> None:
    unbounded_out = ROOT / "outputs" / "repro" / name
    rows, drawn = {}, []
    for label, where in (("unbounded", unbounded_out), (f"min_feature {bound:g} mm", out)):
        record, sim, X = design_record(compared_run(where, name), scale)
        rows[label] = record
        drawn.append((label, record, sim, X))
    fig = figure(out / "designs.png", name, drawn, bound, scale)
    lines = [
        f"# {name} with a minimum feature size",
        "",
        f"The reproduction (`make repro-{name.replace('_', '-')}`) retrained with "
        f"`part.scale={scale:g}` (mm per "
        f"length unit) and `trainer.min_feature={bound:g}` (mm): a desktop FDM printer's thinnest "
        "supported wall "
        "(two perimeters of a 0.4 mm nozzle). Each design is its reproduction's compared stage; "
        "the narrowest ligament is "
        "measured on its checkpoint (nma.geometry.features).",
        "",
        "| design | metric | at 14 x 5 | narrowest ligament | states not physical | failed solves "
        "|",
        "|---|---|---|---|---|---|",
    ]
    for label, r in rows.items():
        fine = r["reevaluated"]
        again = (
            f"{fine['value']:.4g} ({fine['invalid_states']} of {fine['samples']} not physical)"
            if fine
            else ""
        )
        lines.append(
            f"| {label} | {r['metric']:.4g} {r['unit']} | {again} | {r['min_ligament_mm']:.3f} mm "
            f"({' - '.join(r['min_ligament_between'])}) | {r['invalid_states']} of "
            f"{r['checked_states']} | "
            f"{r['failed_solves']} |"
        )
    summary = {
        "experiment": f"{name}_min_feature",
        "min_feature_mm": bound,
        "scale_mm_per_unit": scale,
        "designs": rows,
    }
    figures = [fig]
    if made_of:
        summary["as_made"], more, png = made_part(
            compared_run(out, name), made_of, scale, thickness, out
        )
        lines, figures = lines + more, figures + [png]
    (out / "comparison_min_feature.json").write_text(json.dumps(summary, indent=1))
    results.write(
        f"{name}_min_feature",
        summary,
        "\n".join(lines) + "\n",
        figures,
        json.loads((out / "stamp.json").read_text()),
    )
    print("\n".join(lines))


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("name", choices=sorted(BASELINE_STEPS))
    ap.add_argument("--bound", type=float, default=0.8, help="trainer.min_feature, mm")
    ap.add_argument("--scale", type=float, default=2.0, help="part.scale, mm per length unit")
    ap.add_argument(
        "--summarise", action="store_true", help="compare the runs there are, training none"
    )
    ap.add_argument(
        "--made-of",
        default="ecoflex_0030",
        help="translation: the elastomer (conf/material/) the "
        "bounded part's load cases are solved in",
    )
    ap.add_argument(
        "--thickness", type=float, default=10.0, help="translation: the part's thickness, mm"
    )
    args = ap.parse_args()
    out = ROOT / "outputs" / "repro_min_feature" / args.name
    if not args.summarise:
        subprocess.run(
            [
                sys.executable,
                "experiments/repro.py",
                args.name,
                "--baseline-steps",
                str(BASELINE_STEPS[args.name]),
                "--out",
                str(out),
                f"part.scale={args.scale:g}",
                f"trainer.min_feature={args.bound:g}",
            ],
            check=True,
            cwd=ROOT,
        )
    summarise(
        args.name,
        out,
        args.bound,
        args.scale,
        args.made_of if args.name == "translation" else None,
        args.thickness,
    )


if __name__ == "__main__":
    main()
