"""Every reproduction (`make repro-*`: the paper's, those in time and the periodic ones), in lanes
that run side by side.

    # make repro-all: two lanes on a machine with 2+ cores
    python experiments/repro_all.py
    # one after the other, as each time in results/ was taken
    python experiments/repro_all.py --lanes 1

One reproduction alone keeps a 2-core machine about 1.5 cores busy (the double rotation: 150% CPU
under /usr/bin/time): a batch's samples end at different times and leave a thread idle, and a run's
setup, evaluation and figures are serial.  Two lanes fill that, each run with one Newton thread
(solver.workers=1) so that together they keep two.  What a run computes does not depend on its
Newton threads (nma.solver.batch), so each reproduction writes what it writes alone; the lanes
change only when it finishes.  (Pinning each lane to one core would deadlock: a training step's
compiled program calls back into the host Newton, whose kernels need a second thread of XLA's CPU
pool.) Each lane runs its experiments in order, the lanes balanced by the experiments' measured
times (LANES).  Writes outputs/repro/seconds_all.json: each experiment's wall time, and the whole.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# longest first; two lanes balanced by each experiment's wall time in a two-lane run on a 2-core
# AMD EPYC (solver.workers=1, minutes): the dynamic follow (35.8) with the shape matching (24.6),
# the energy focus (8.0) and the translation (7.1), 75.5 in all; the single (26.8) and double
# (16.5) rotations with the amortised (17.4) and single (3.9) periodic designs and digital MNIST
# (11.6), 76.2
LANES = {
    1: [
        [
            "dynamic_follow",
            "rotation_single",
            "shape_matching",
            "periodic_poisson_amortised",
            "rotation_double",
            "digital_mnist",
            "dynamic_energy",
            "translation",
            "periodic_poisson",
        ]
    ],
    2: [
        [
            "rotation_single",
            "periodic_poisson_amortised",
            "rotation_double",
            "digital_mnist",
            "periodic_poisson",
        ],
        ["dynamic_follow", "shape_matching", "dynamic_energy", "translation"],
    ],
}


def run_lane(names: list[str], overrides: str) -> dict[str, float]:
    seconds = {}
    for name in names:
        t0 = time.perf_counter()
        subprocess.run(
            ["make", "repro-" + name.replace("_", "-"), f"REPRO_ARGS={overrides}"],
            cwd=ROOT,
            check=True,
        )
        seconds[name] = time.perf_counter() - t0
    return seconds


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--lanes", type=int, choices=sorted(LANES), default=2 if (os.cpu_count() or 1) >= 2 else 1
    )
    args = ap.parse_args()
    busy = [ROOT / "outputs" / "repro" / name for lane in LANES[args.lanes] for name in lane]
    busy = [str(p) for p in busy if p.exists()]
    # each reproduction refuses a directory it would overwrite: say so before any lane starts
    if busy:
        raise SystemExit(
            "move these aside first (a reproduction does not overwrite its runs): "
            f"{', '.join(busy)}"
        )
    t0 = time.perf_counter()
    with ThreadPoolExecutor(args.lanes) as pool:
        done = list(
            pool.map(
                run_lane,
                LANES[args.lanes],
                ["solver.workers=1" if args.lanes > 1 else ""] * args.lanes,
            )
        )
    total = time.perf_counter() - t0
    record = {
        "lanes": LANES[args.lanes],
        "seconds": {k: v for lane in done for k, v in lane.items()},
        "total_seconds": total,
    }
    out = ROOT / "outputs" / "repro" / "seconds_all.json"
    out.write_text(json.dumps(record, indent=1))
    print(json.dumps(record, indent=1))
    print(f"the reproductions: {total / 60:.1f} min in {args.lanes} lane(s) -> {out}")


if __name__ == "__main__":
    main()
