"""Do warm starts land on the cold solve's equilibrium?  Training steps with every warm solve
audited.

    # writes outputs/studies/warm_starts.{json,md}
    python experiments/warm_starts.py
    python experiments/warm_starts.py --runs shape_matching --steps 20
    python experiments/warm_starts.py --runs translation=outputs/repro/translation/joint

Each run takes `--steps` training steps of its reproduction config (from the initial network, or
from a trained run's newest checkpoint with `<name>=<run dir>`) with solver.warm_start=true and
every warm solve also solved cold (solver.warm_audit=1), warm starts never stopped: the cold answer
is taken wherever the two differ, so the steps are those of a cold run to the solver's tolerance.
Recorded per run: how many warm solves land on the cold solve's equilibrium (displacements within
1e-6 and 1e-8 of the cold ones, max norm relative to the largest), the energies of the two
equilibria where they differ, and the Newton iterations per solve, warm and cold.  It writes its
results under outputs/.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
EXPERIMENTS = {
    "translation": "repro_translation",
    "rotation_double": "repro_rotation_double",
    "shape_matching": "repro_shape_matching",
    "digital_mnist": "repro_mnist_lookup",
}


def audit(name: str, init_from: str | None, steps: int) -> dict:
    from hydra import compose, initialize_config_dir

    from nma.config import CONF_DIR
    from nma.schema import register
    from nma.train.runs import make_trainer, validate

    register()
    overrides = [
        f"experiment={EXPERIMENTS[name]}",
        "logger=none",
        "trainer.progress=false",
        "solver.warm_start=true",
        "solver.warm_audit=1",
        *([f"trainer.init_from={init_from}"] if init_from else []),
    ]
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    trainer = make_trainer(validate(cfg), Path(tempfile.mkdtemp(prefix="nma-warm-")))
    warm = trainer.sim.warm_starts
    warm.max_other = 1.0  # never stop: count every warm solve
    for _ in range(steps):
        trainer.step()
    st = warm.stats
    others = warm.other_equilibria
    lower = [o for o in others if o["energy_warm"] < o["energy_cold"]]
    return {
        "init_from": init_from or "initial network",
        "steps": steps,
        **st,
        "iterations_per_warm_solve": st["warm_iterations"] / max(st["warm_solves"], 1),
        "iterations_per_cold_solve": st["cold_iterations"] / max(st["cold_solves"], 1),
        "other_equilibria": others,
        "other_with_lower_energy": len(lower),
    }


def table(results: dict) -> str:
    rows = [
        "| run | from | steps | warm solves | on the cold equilibrium (1e-6 / 1e-8) | the others: "
        "warm energy lower | largest difference | Newton iterations per solve, warm / cold |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        rows.append(
            f"| {name} | {r['init_from']} | {r['steps']} | {r['warm_solves']} | "
            f"{r['audits_same']} / "
            f"{r['audits_within_1e-8']} of {r['audits']} | {r['other_with_lower_energy']} of "
            f"{len(r['other_equilibria'])} | {r['audit_largest_difference']:.2g} | "
            f"{r['iterations_per_warm_solve']:.1f} / {r['iterations_per_cold_solve']:.1f} |"
        )
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--runs",
        nargs="+",
        default=list(EXPERIMENTS),
        metavar="NAME[=RUN_DIR]",
        help=f"of {list(EXPERIMENTS)}, each optionally from a trained run",
    )
    ap.add_argument("--steps", type=int, default=12)
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "studies" / "warm_starts.json")
    args = ap.parse_args()
    from nma.runtime import configure_jax

    configure_jax()
    results = {}
    for spec in args.runs:
        name, _, init_from = spec.partition("=")
        if name not in EXPERIMENTS:
            ap.error(f"--runs: {name} is not one of {list(EXPERIMENTS)}")
        label = f"{name} (trained)" if init_from else name
        results[label] = audit(name, init_from or None, args.steps)
        print(table({label: results[label]}).splitlines()[-1], flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))
    args.out.with_suffix(".md").write_text(table(results) + "\n")
    print(table(results))


if __name__ == "__main__":
    main()
