"""Periodic benchmark: one solve of the 2 x 2 square array of circular holes as a periodic cell
against the finite scene of the same cells.

    python experiments/bench_periodic.py [--repeats 7]   # make bench-periodic
                                                         # -> outputs/bench/periodic.json

Both at 5 control points per patch side and 3 Gauss points, the holes at porosity 0.5
(nma.periodic.circular_holes), the paper's Neo-Hookean, 1% nominal compression along y in one load
step:
- periodic: nma.periodic.follow(cell, uniaxial("y", -0.01), steps=1), F_bar's lateral component a
  free unknown, with and without the stability check (the reduced Hessian's lowest eigenvalue),
  every state's validity checked as the path checks it;
- finite: the same cells as a block clamped along its bottom and pressed down 1% of its height
  along its top (an actuated group), Simulator.solve on the host backend auto chooses.
Times are wall-clock seconds of warm solves (each first compiled once): min and median of
--repeats runs, alone on the machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import results  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
FIDELITY = {"ctrl_per_patch": 5, "quad_points": 3}
STRAIN = -0.01


def stats(xs) -> dict:
    return {"min": float(np.min(xs)), "median": float(np.median(xs)), "n": len(xs)}


def timed(fn, repeats: int) -> list[float]:
    fn()  # compiles
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    t_start = time.perf_counter()

    from nma.runtime import configure_jax

    configure_jax()
    import jax.numpy as jnp

    from nma.periodic import circular_holes, follow, periodic_cell, square_array, uniaxial
    from nma.simulator import Simulator

    scene = square_array(2, 2)
    cell = periodic_cell(scene, FIDELITY)
    params, porosity = circular_holes(cell, 0.5)
    load = uniaxial("y", STRAIN)
    height = 2.0 * scene["cell_size"]
    block = {
        **scene,
        "name": "square_array_block",
        "supports": [{"segment": [[0, 0], [height, 0]], "kind": "clamped"}],
        "groups": [
            {
                "name": "top",
                "segment": [[0, height], [height, height]],
                "actuation": 0,
                "direction": [0, -1],
            }
        ],
        "volumetric": "lame",  # the periodic cell's (a scene without a statement)
    }
    sim = Simulator.from_config(block, fidelity=FIDELITY)
    d = jnp.array([-STRAIN * height])
    finite_params = {**sim.init_params(), "radii": jnp.asarray(params["radii"])}

    def periodic(stability: bool):
        path = follow(cell, load, steps=1, params=params, stability=stability)
        assert path.completed and path.valid.all(), path.message

    def finite():
        sim.solve(finite_params, d, sim.material_params)  # raises SolverError where it fails

    out = {
        "what": __doc__.splitlines()[0],
        "fidelity": FIDELITY,
        "porosity": porosity,
        "strain": STRAIN,
        "unknowns": {
            "periodic": cell_unknowns(cell, params, load),
            "finite": int(len(sim.equations.free)),
        },
        "seconds": {
            "periodic": stats(timed(lambda: periodic(False), args.repeats)),
            "periodic_with_stability": stats(timed(lambda: periodic(True), args.repeats)),
            "finite": stats(timed(finite, args.repeats)),
        },
    }
    s = out["seconds"]
    out["periodic_over_finite_median"] = s["periodic"]["median"] / s["finite"]["median"]
    out["stamp"] = results.stamp(
        ["python", "experiments/bench_periodic.py", *sys.argv[1:]], time.perf_counter() - t_start
    )
    path = ROOT / "outputs" / "bench" / "periodic.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1))
    print(json.dumps(out, indent=1))
    return 0


def cell_unknowns(cell, params, load) -> int:
    """The periodic solve's unknowns: the fluctuation's free dofs and F_bar's free components."""
    from nma.periodic.problem import PeriodicProblem

    X = cell.disc.reference_points(params)
    return int(PeriodicProblem(cell, X, cell.material_params, load).nz)


if __name__ == "__main__":
    sys.exit(main())
