"""Dynamics benchmark: the cost of a time step against a static solve of the same scene, and a
100-step forward plus adjoint of the translation scene, in one process (ratios from one machine
state).

    python experiments/bench_dynamics.py          # writes outputs/bench/dynamics.json
    python experiments/bench_dynamics.py --repeats 5 --steps 100
    python experiments/bench_dynamics.py --adjoint checkpointed    # or --controller adaptive

The scene is the translation at its own fidelity (2 Gauss points), the paper's material, density 1.
The static solve is the actuation (1, -0.5) from rest.  The trajectory: Newmark's average
acceleration, dt a 20th of the lowest natural period at rest, both actuators driven by a
two-harmonic Fourier waveform (nma.dynamics.waveform) of period 20 dt, started over 5 dt, its
amplitude up to d_max 2; the loss is the pointer's squared distance from its rest position summed
over the steps.  Times are min and median over `--repeats` rounds after one round that compiles.
`--controller` and `--adjoint` choose the step control and the adjoint (nma.dynamics.options; the
defaults: cuts, store_all).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--controller", default="cuts", help="step control: fixed, cuts, adaptive")
    ap.add_argument("--adjoint", default="store_all", help="store_all or checkpointed")
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "bench" / "dynamics.json")
    args = ap.parse_args()

    from nma.runtime import configure_jax

    configure_jax()
    import jax
    import jax.numpy as jnp

    from nma.dynamics.modes import natural_frequencies
    from nma.dynamics.trajectory import Dynamics
    from nma.dynamics.waveform import Fourier
    from nma.simulator import Simulator

    sim = Simulator.from_config("translation", solver="auto")
    X = sim.reference_points(sim.init_params())
    mat = sim.material_params
    d = jnp.array([1.0, -0.5])
    period = 2 * np.pi / natural_frequencies(sim, X, mat, count=1)[0]
    dt = period / 20
    waveform = Fourier(2, 2, 20 * dt, 5 * dt, 2.0)
    dyn = Dynamics(
        sim,
        "newmark",
        dt=dt,
        steps=args.steps,
        waveform=waveform,
        workers=1,
        controller=args.controller,
        adjoint=args.adjoint,
    )
    coeffs = jnp.array([0.2, 0.8, 0.0, 0.5, 0.0, -0.2, -0.8, 0.0, 0.5, 0.0])
    rest = sim.tracked(X, jnp.zeros_like(X))["pointer"]

    def loss(X, coeffs, mat):
        u, _, info = dyn.function(X, coeffs, mat)
        pointer = jax.vmap(lambda ui: sim.tracked(X, ui)["pointer"])(u)
        return jnp.sum((pointer - rest) ** 2), info

    forward = jax.jit(loss)
    both = jax.jit(jax.value_and_grad(loss, argnums=(0, 1, 2), has_aux=True))
    static = jax.jit(lambda X, d, mat: sim.equilibrium(X, d, mat))
    runs = {
        "static_solve": lambda: static(X, d, mat),
        "forward": lambda: forward(X, coeffs, mat),
        "forward_and_adjoint": lambda: both(X, coeffs, mat),
    }
    times = {k: [] for k in runs}
    for r in range(args.repeats + 1):  # the first round compiles
        for name, fn in runs.items():
            t = time.perf_counter()
            out = jax.block_until_ready(fn())
            if r:
                times[name].append(time.perf_counter() - t)
    info = out[0][1]
    stats = {k: {"min": float(np.min(v)), "median": float(np.median(v))} for k, v in times.items()}
    row = {
        "scene": "translation",
        "dofs": sim.disc.boundary.n_dofs,
        "backend": sim.backend.name,
        "controller": args.controller,
        "adjoint": args.adjoint,
        "steps": args.steps,
        "dt": dt,
        "lowest_period": float(period),
        "completed": int(info.status) == 1,
        "newton_iterations": int(info.iterations),
        "time_steps": int(info.steps),
        **stats,
        "time_step_vs_static_median": (
            stats["forward"]["median"] / args.steps / stats["static_solve"]["median"]
        ),
        "static_newton_iterations": int(static(X, d, mat).info.iterations),
    }
    print(json.dumps(row), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(row, indent=1))


if __name__ == "__main__":
    main()
