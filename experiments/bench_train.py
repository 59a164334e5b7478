"""Training-step benchmark: what a user waits for, per scene, at the reproductions' settings.

    python experiments/bench_train.py                        # writes outputs/bench/train.{json,md}
    python experiments/bench_train.py --scenes translation --steps 6
    python experiments/bench_train.py --init-from translation=outputs/repro/translation/learned

digital_mnist times its reproduction's lookup phase (repro_mnist_lookup: the ten digits every step).

Each scene runs in two fresh processes sharing an empty compilation cache: the first pays the
compilation (its first step is `first_step_seconds`), the second finds the kernels in JAX's
persistent cache (`second_process_first_step_seconds`).  The second then times `--steps` further
steps three times in alternation, on one thread, on the default (one per core) and with
solver.warm_start=true, so that their ratios come from one process on the same machine state; each
variant's Newton iterations per sample count every solve (a warm one redone from rest and an audit's
included).  Early in training the network's actuations are small and solves are cheap; `--init-from
scene=<run dir>` starts from a trained run's newest checkpoint instead (the steps a long run spends
most of its time in).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
EXPERIMENTS = {
    "translation": "repro_translation",
    "rotation_double": "repro_rotation_double",
    "shape_matching": "repro_shape_matching",
    "digital_mnist": "repro_mnist_lookup",
}


def stats(xs):
    return {"min": float(np.min(xs)), "median": float(np.median(xs)), "n": len(xs)}


def trainer_for(scene: str, workers: int, init_from: str | None, *more: str):
    from hydra import compose, initialize_config_dir

    from nma.config import CONF_DIR
    from nma.train.runs import make_trainer, validate
    from nma.schema import register

    register()
    overrides = [
        f"experiment={EXPERIMENTS[scene]}",
        "logger=none",
        "trainer.progress=false",
        f"solver.workers={workers}",
        *more,
    ] + ([f"trainer.init_from={init_from}"] if init_from else [])
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    return make_trainer(validate(cfg), Path(tempfile.mkdtemp(prefix="nma-bench-")))


def timed_step(trainer):
    wall, cpu = time.perf_counter(), time.process_time()
    trainer.step()
    return time.perf_counter() - wall, time.process_time() - cpu


def child(scene: str, steps: int, init_from: str | None, compare: bool) -> dict:
    """One process: time to the end of the first step; then, if `compare`, alternating steps."""
    t0 = time.perf_counter()
    from nma.runtime import configure_jax

    configure_jax()
    trainer = trainer_for(scene, 0, init_from)
    built = time.perf_counter() - t0
    first, _ = timed_step(trainer)
    out = {
        "build_seconds": built,
        "first_step_seconds": first,
        "to_first_step_seconds": built + first,
        "batch_size": trainer.cfg.batch_size,
        "dofs": trainer.sim.disc.boundary.n_dofs,
        "workers": trainer.sim.workers,
    }
    if compare:
        single = trainer_for(scene, 1, init_from)
        timed_step(single)  # its own compile
        warm = trainer_for(scene, 0, init_from, "solver.warm_start=true")
        timed_step(warm)  # its first step keeps equilibria, its second compiles the warm start
        timed_step(warm)
        single.state = warm.state = trainer.state
        variants = {"one_thread": single, "threads": trainer, "warm": warm}
        runs = {name: ([], []) for name in variants}
        clocks = {name: tr.sim.backend.clock.seconds for name, tr in variants.items()}
        before = {name: dict(c) for name, c in clocks.items()}
        counts = {name: dict(tr.sim.backend.stats) for name, tr in variants.items()}
        for _ in range(steps):
            state = trainer.state  # every variant takes the same step from the same state
            for name, tr in variants.items():
                tr.state = state
                wall, cpu = timed_step(tr)
                runs[name][0].append(wall)
                runs[name][1].append(cpu / wall)
        for name, (walls, util) in runs.items():
            spent = {k: (v - before[name].get(k, 0.0)) / steps for k, v in clocks[name].items()}
            outside = (
                np.mean(walls)
                - spent.pop("forward_batches", 0.0)
                - spent.pop("backward_batches", 0.0)
            )
            solved = variants[name].sim.backend.stats
            out[name] = {
                "step_seconds": stats(walls),
                "per_sample_seconds": stats(np.array(walls) / out["batch_size"]),
                "cpu_utilisation": float(np.median(util)),
                # every Newton iteration spent, a warm start's that was redone cold included
                "newton_iterations_per_sample": (
                    solved["newton_iterations"] - counts[name]["newton_iterations"]
                )
                / (steps * out["batch_size"]),
                # per step; solver phases summed over threads, the rest is wall time outside the
                # solver
                "where_the_time_goes": {**spent, "outside_the_solver": float(outside)},
            }
        out["warm"]["warm_starts"] = dict(warm.sim.warm_starts.stats)
        out["speedup"] = (
            out["one_thread"]["step_seconds"]["median"] / out["threads"]["step_seconds"]["median"]
        )
        out["warm_speedup"] = (
            out["threads"]["step_seconds"]["median"] / out["warm"]["step_seconds"]["median"]
        )
        out["linear_solver_counts"] = dict(trainer.sim.backend.stats)
    return out


def run_scene(scene: str, steps: int, init_from: str | None) -> dict:
    with tempfile.TemporaryDirectory(prefix="nma-xla-cache-") as cache:
        env = {**os.environ, "NMA_CACHE_DIR": cache}
        results = []
        for compare in (False, True):
            cmd = [sys.executable, __file__, "--child", scene, "--steps", str(steps)]
            cmd += ["--init-from", f"{scene}={init_from}"] if init_from else []
            cmd += ["--compare"] if compare else []
            proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=ROOT)
            if proc.returncode:
                raise RuntimeError(f"{scene}: {proc.stderr[-2000:]}")
            results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    cold, warm = results
    return {
        **warm,
        "first_step_seconds": cold["first_step_seconds"],
        "to_first_step_seconds": cold["to_first_step_seconds"],
        "second_process_first_step_seconds": warm["first_step_seconds"],
        "second_process_to_first_step_seconds": warm["to_first_step_seconds"],
        "init_from": init_from or "initial network",
    }


PHASES = {
    "newton_kernels": "Newton kernels (tangents, line search, step bound)",
    "assembly": "assembly",
    "factorisation": "factorisation",
    "back_substitution": "back-substitution",
    "adjoint_kernels": "adjoint kernels (tangents, pullback)",
    "adjoint_solve": "adjoint solve (refinement)",
    "outside_the_solver": "outside the solver (network, design map, loss, optimiser)",
}


def breakdown(results: dict) -> str:
    scenes = list(results)
    rows = [
        "| seconds per step, one thread | " + " | ".join(scenes) + " |",
        "|---" * (len(scenes) + 1) + "|",
    ]
    for key, label in PHASES.items():
        rows.append(
            f"| {label} | "
            + " | ".join(
                f"{results[s]['one_thread']['where_the_time_goes'].get(key, 0.0):.3f}"
                for s in scenes
            )
            + " |"
        )
    return "\n".join(rows)


def table(results: dict) -> str:
    rows = [
        "| scene | dofs | batch | step s (min / median), threads | one thread | speedup | CPU use "
        "| warm starts: step s | Newton iterations per sample, cold / warm | audits on the cold "
        "equilibrium | first step s | 2nd process first step s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for scene, r in results.items():
        t, o, w = (
            r["threads"]["step_seconds"],
            r["one_thread"]["step_seconds"],
            r["warm"]["step_seconds"],
        )
        ws = r["warm"]["warm_starts"]
        rows.append(
            f"| {scene} | {r['dofs']} | {r['batch_size']} | {t['min']:.3f} / {t['median']:.3f} "
            f"({r['workers']} threads) | {o['min']:.3f} / {o['median']:.3f} | {r['speedup']:.2f}x "
            f"| {r['threads']['cpu_utilisation']:.2f} cores | {w['min']:.3f} / {w['median']:.3f} "
            f"({r['warm_speedup']:.2f}x) | {r['threads']['newton_iterations_per_sample']:.1f} / "
            f"{r['warm']['newton_iterations_per_sample']:.1f} | {ws['audits_same']} of "
            f"{ws['audits']}"
            f"{' (stopped)' if ws['stops'] else ''} | {r['first_step_seconds']:.2f} | "
            f"{r['second_process_first_step_seconds']:.2f} |"
        )
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--scenes", nargs="+", default=list(EXPERIMENTS), choices=list(EXPERIMENTS))
    ap.add_argument("--steps", type=int, default=8, help="timed steps per variant")
    ap.add_argument("--init-from", nargs="*", default=[], metavar="SCENE=RUN_DIR")
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "bench" / "train.json")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--compare", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    starts = dict(item.split("=", 1) for item in args.init_from)
    if args.child:
        print(json.dumps(child(args.child, args.steps, starts.get(args.child), args.compare)))
        return
    results = {}
    for scene in args.scenes:
        results[scene] = run_scene(scene, args.steps, starts.get(scene))
        print(f"{scene}: {json.dumps(results[scene])}", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2))
    report = table(results) + "\n\n" + breakdown(results) + "\n"
    args.out.with_suffix(".md").write_text(report)
    print(report)


if __name__ == "__main__":
    main()
