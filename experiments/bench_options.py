"""What an option costs: solve and gradient time with it off and on, per paper scene.  The
options: the pores' self-contact (contact=off / on) and Newton's element bound
(solver.element_bound=false / true).

    # contact, every scene -> outputs/bench/contact.{json,md}
    python experiments/bench_options.py
    python experiments/bench_options.py --option element_bound --scenes translation --repeats 3

Per scene, at the paper's discretisation (5 x 5) and PARDISO, one process builds the scene twice
(the option off, then on) and times a training step's forward solve with its gradient (the loss of
experiments/bench_solver.py) for the same actuations, drawn uniformly within the task's d_max, the
two models interleaved so that the machine's load affects both alike.  Reported: min and median
seconds, the ratio of the medians, Newton iterations, the first call (compilation), the solves that
converged and how many of their states are physical objects (nma/geometry/validity.py) in each
model, where both converged whether they reached the same state, and with contact how many had walls
within the contact distance (where the two models differ by design).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench_solver import objective, stats

ROOT = Path(__file__).resolve().parent.parent
SCENES = ["translation", "rotation_single", "rotation_double", "shape_matching", "digital_mnist"]
OPTIONS = ("contact", "element_bound")


def build(scene: str, option: str, on: bool):
    """The scene's simulator with `option` off or on, everything else at its default."""
    from nma import config
    from nma.simulator import Simulator

    solver = {"linear": "pardiso", "rtol": 1e-10}
    if option == "element_bound":
        solver["element_bound"] = on
    return Simulator.from_config(
        config.load("scene", scene),
        config.load("fidelity", "paper"),
        solver,
        {"enabled": on} if option == "contact" else {"enabled": False},
    )


def bench_scene(scene: str, repeats: int, option: str = "contact") -> dict:
    import jax
    import jax.numpy as jnp

    from nma import config
    from nma.geometry.validity import StateChecker
    from nma.mechanics.contact import smallest_gap
    from nma.mechanics.material import material

    # one equilibrium: displacements this close, relative
    from nma.solver.warm import SAME_EQUILIBRIUM

    mat = material(0.07, 0.3)
    d_max = config.load("task", scene)["d_max"]
    rng = np.random.default_rng(0)
    out = {"scene": scene, "option": option, "d_max": d_max}
    sims, steps, first = {}, {}, {}
    for mode in ("off", "on"):
        t0 = time.perf_counter()
        sims[mode] = build(scene, option, mode == "on")
        out[f"build_seconds_{mode}"] = time.perf_counter() - t0
        steps[mode] = jax.jit(
            jax.value_and_grad(objective(sims[mode]), argnums=(0, 1), has_aux=True)
        )
    params = sims["on"].init_params()
    X = np.asarray(sims["on"].reference_points(params))
    checker = StateChecker(sims["on"].disc.mesh, X)
    draws = [
        jnp.asarray(rng.uniform(-d_max, d_max, sims["on"].n_actuations)) for _ in range(repeats)
    ]
    for mode in ("off", "on"):
        t0 = time.perf_counter()
        jax.block_until_ready(steps[mode](params, draws[0], mat))
        first[mode] = time.perf_counter() - t0
    seconds = {m: [] for m in steps}
    iters = {m: [] for m in steps}
    valid = {m: 0 for m in steps}
    converged = {m: 0 for m in steps}
    touching, same = 0, 0
    model = sims["on"].disc.contact
    for d in draws:
        states = {}
        for mode in ("off", "on"):
            t0 = time.perf_counter()
            (_, eq), _ = jax.block_until_ready(steps[mode](params, d, mat))
            seconds[mode].append(time.perf_counter() - t0)
            iters[mode].append(int(eq.info.iterations))
            if eq.converged:
                converged[mode] += 1
                states[mode] = np.asarray(eq.u)
                valid[mode] += checker.check(states[mode]).valid
                if model is not None and mode == "on":
                    touching += smallest_gap(model, X + states[mode], X) < model.d_hat
        if len(states) == 2:
            same += np.max(np.abs(states["on"] - states["off"])) <= SAME_EQUILIBRIUM * np.max(
                np.abs(states["off"])
            )
    out.update(
        {
            "dofs": sims["on"].disc.boundary.n_dofs,
            "first_call_seconds": first,
            "seconds": {m: stats(v) for m, v in seconds.items()},
            "median_ratio": float(np.median(seconds["on"]) / np.median(seconds["off"])),
            "newton_iterations": {m: stats(v) for m, v in iters.items()},
            "converged": converged,
            "valid": valid,
            "same_state": int(same),
            "states": repeats,
        }
    )
    if model is not None:
        out.update(
            {
                "contact_blocks": model.n_blocks,
                "d_hat": model.d_hat,
                "touching_with_contact": int(touching),
            }
        )
    return out


def child(args):
    import jax

    jax.config.update("jax_enable_x64", True)
    print(json.dumps(bench_scene(args.scene, args.repeats, args.option)))


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--scene", default="translation", help=argparse.SUPPRESS)
    ap.add_argument("--scenes", nargs="+", default=SCENES, choices=SCENES)
    ap.add_argument("--option", default="contact", choices=OPTIONS)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--out", type=Path, help="default: outputs/bench/<option>.json")
    args = ap.parse_args()
    args.out = args.out or ROOT / "outputs" / "bench" / f"{args.option}.json"
    if args.child:
        return child(args)
    results = []
    for scene in args.scenes:  # each scene in its own process
        proc = subprocess.run(
            [
                sys.executable,
                __file__,
                "--child",
                "--scene",
                scene,
                "--repeats",
                str(args.repeats),
                "--option",
                args.option,
            ],
            capture_output=True,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        if proc.returncode:
            raise RuntimeError(f"{scene} failed:\n{proc.stderr[-3000:]}")
        results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        r = results[-1]
        print(
            f"{scene}: {args.option} off {r['seconds']['off']['median']:.3f} s, on "
            f"{r['seconds']['on']['median']:.3f} s "
            f"(x{r['median_ratio']:.2f}); converged {r['converged']['off']} -> "
            f"{r['converged']['on']}, physical "
            f"{r['valid']['off']} -> {r['valid']['on']} of {r['states']}",
            flush=True,
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps({"machine": {"cpus": os.cpu_count()}, "scenes": results}, indent=1)
    )
    contact = args.option == "contact"
    lines = [
        f"{args.option} off / on, per scene",
        "",
        "| scene | dofs | step off (min / median s) | step on | median ratio | iterations off / "
        "on (median) | "
        "first call off / on (s) | converged off / on | physical off / on | same state |"
        + (" contact blocks | touching |" if contact else ""),
        "|---|" + "---|" * (9 + 2 * contact),
    ]
    for r in results:
        s, it, f, c, v = (
            r["seconds"],
            r["newton_iterations"],
            r["first_call_seconds"],
            r["converged"],
            r["valid"],
        )
        lines.append(
            f"| {r['scene']} | {r['dofs']} | {s['off']['min']:.3f} / {s['off']['median']:.3f} | "
            f"{s['on']['min']:.3f} / {s['on']['median']:.3f} | {r['median_ratio']:.2f} | "
            f"{it['off']['median']:.0f} / {it['on']['median']:.0f} | {f['off']:.1f} / "
            f"{f['on']:.1f} | "
            f"{c['off']} / {c['on']} of {r['states']} | {v['off']} / {v['on']} | "
            f"{r['same_state']} |"
            + (f" {r['contact_blocks']} | {r['touching_with_contact']} |" if contact else "")
        )
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
