"""Solver benchmark: speed per paper scene at the paper's discretisation, and the linear backends.

    python experiments/bench_solver.py            # everything; writes outputs/bench/solver.json
    python experiments/bench_solver.py --quick    # fewer repeats (smoke run)

The speed/accuracy trade of the discretisation knobs is experiments/fidelity_study.py.

Each scene runs in its own process so that its peak memory is its own.  Times are wall-clock
seconds on this machine: min and median over actuations drawn as in training, d ~ U(-2, 2).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCENES = ["translation", "rotation_single", "rotation_double", "shape_matching", "digital_mnist"]


def stats(xs):
    return {"min": float(np.min(xs)), "median": float(np.median(xs)), "n": len(xs)}


def build(scene, linear="pardiso"):
    from nma import config
    from nma.discretise import Resolution, discretise
    from nma.schema import scene_from_config
    from nma.simulator import Simulator
    from nma.solver.options import NewtonOptions

    disc = discretise(scene_from_config(config.load("scene", scene)), Resolution(5, 5))
    return Simulator(disc, linear, NewtonOptions(rtol=1e-10))


def objective(sim):
    """The loss of a training step: tracked points for tasks that track, else a fixed functional."""
    import jax
    import jax.numpy as jnp

    w = (
        jax.random.normal(jax.random.PRNGKey(0), (sim.disc.mesh.n_points, 2))
        / sim.disc.mesh.n_points
    )

    def loss(params, d, mat):
        X = sim.reference_points(params)
        eq = sim.equilibrium(X, d, mat)
        tracked = sim.tracked(X, eq.u)
        out = (
            sum(jnp.sum(jnp.abs(p - 1.0)) for p in tracked.values())
            if tracked
            else jnp.sum(w * (X + eq.u))
        )
        return out, eq

    return loss


def bench_scene(scene, repeats, linear="pardiso"):
    import jax
    import jax.numpy as jnp

    from nma.mechanics.material import material

    t0 = time.perf_counter()
    sim = build(scene, linear=linear)
    build_s = time.perf_counter() - t0
    params, mat = sim.init_params(), material(0.07, 0.3)
    loss = objective(sim)
    fwd = jax.jit(lambda p, d: loss(p, d, mat))
    fwd_grad = jax.jit(jax.value_and_grad(loss, argnums=(0, 1), has_aux=True))
    rng = np.random.default_rng(0)
    draws = [jnp.asarray(rng.uniform(-2, 2, sim.n_actuations)) for _ in range(repeats)]
    t0 = time.perf_counter()
    jax.block_until_ready(fwd_grad(params, draws[0], mat))
    first = time.perf_counter() - t0
    jax.block_until_ready(fwd(params, draws[0]))
    t_fwd, t_grad, iters, steps = [], [], [], []
    for d in draws:
        t0 = time.perf_counter()
        jax.block_until_ready(fwd(params, d))
        t_fwd.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        (_, eq), _ = jax.block_until_ready(fwd_grad(params, d, mat))
        t_grad.append(time.perf_counter() - t0)
        info = eq.info
        if not eq.converged:
            raise eq.error(f"{scene} d={np.asarray(d).round(3).tolist()}: ")
        iters.append(int(info.iterations))
        steps.append(int(info.load_steps))
    out = {
        "scene": scene,
        "linear": linear,
        "dofs": sim.disc.boundary.n_dofs,
        "build_seconds": build_s,
        "first_call_seconds": first,
        "forward_seconds": stats(t_fwd),
        "forward_grad_seconds": stats(t_grad),
        "newton_iterations": stats(iters),
        "load_steps": stats(steps),
    }
    if scene == "translation":  # the largest actuation of the task, |d| = d_max = 4
        big = []
        for d in ([4.0, -4.0], [-4.0, 4.0], [4.0, 4.0], [-4.0, -4.0]):
            t0 = time.perf_counter()
            (_, eq), _ = jax.block_until_ready(fwd_grad(params, jnp.array(d), mat))
            info = eq.info
            big.append(
                {
                    "actuation": d,
                    "seconds": time.perf_counter() - t0,
                    "converged": bool(eq.converged),
                    "newton_iterations": int(info.iterations),
                    "load_steps": int(info.load_steps),
                }
            )
        out["largest_actuation"] = big
    # adjoint_refactorisations 0: factor reused
    out["linear_solver_counts"] = dict(sim.backend.stats)
    out["peak_memory_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def child(args):
    import jax

    jax.config.update("jax_enable_x64", True)
    print(json.dumps(bench_scene(args.scene, args.repeats, args.linear)))


def spawn(*extra):
    cmd = [sys.executable, __file__, "--child", *extra]
    proc = subprocess.run(
        cmd, capture_output=True, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"}
    )
    if proc.returncode:
        raise RuntimeError(f"{' '.join(extra)} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def fmt(s):
    return f"{s['min']:.3f} / {s['median']:.3f}"


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--scene", default="translation")
    ap.add_argument("--linear", default="pardiso")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--quick", action="store_true", help="3 repeats")
    ap.add_argument("--out", default=str(ROOT / "outputs" / "bench" / "solver.json"))
    args = ap.parse_args()
    if args.child:
        return child(args)
    repeats = 3 if args.quick else args.repeats
    report = {"machine": {"cpus": os.cpu_count()}, "scenes": {}, "backends": {}}
    print(
        f"{'scene':16s} {'dofs':>5s} {'build':>6s} {'first':>6s} {'forward min/med':>16s} "
        f"{'fwd+grad min/med':>17s} {'iters':>6s} {'steps':>5s} {'peak MB':>8s}"
    )
    for scene in SCENES:
        r = spawn("--scene", scene, "--repeats", str(repeats))
        report["scenes"][scene] = r
        print(
            f"{scene:16s} {r['dofs']:5d} {r['build_seconds']:6.2f} {r['first_call_seconds']:6.2f} "
            f"{fmt(r['forward_seconds']):>16s} {fmt(r['forward_grad_seconds']):>17s} "
            f"{r['newton_iterations']['median']:6.1f} {r['load_steps']['median']:5.1f} "
            f"{r['peak_memory_mb']:8.0f}",
            flush=True,
        )
    big = report["scenes"]["translation"]["largest_actuation"]
    print(
        "\ntranslation at |d| = 4:",
        ", ".join(
            f"{b['actuation']}: {b['seconds']:.2f}s ({b['newton_iterations']} it, "
            f"{b['load_steps']} steps)"
            for b in big
        ),
    )
    print("\nlinear backends on translation (forward+gradient, min / median s):")
    for linear in ("pardiso", "superlu"):
        r = spawn("--scene", "translation", "--linear", linear, "--repeats", str(repeats))
        report["backends"][linear] = {
            k: r[k] for k in ("forward_seconds", "forward_grad_seconds", "first_call_seconds")
        }
        print(
            f"  {linear:8s} forward {fmt(r['forward_seconds'])}   forward+grad "
            f"{fmt(r['forward_grad_seconds'])}"
        )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2))
    print(f"\nwrote {out}")


if __name__ == "__main__":
    main()
