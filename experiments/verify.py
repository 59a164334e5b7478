"""Verification benchmarks: nma against references from theory and the literature, under refinement
where a benchmark has a mesh, in a report anyone can regenerate.

    python experiments/verify.py                  # make verify: results/verification/
    python experiments/verify.py --only treloar   # some benchmarks only: printed, nothing written

Each benchmark (a module of experiments/verification/: its reference and the reference's source,
its computation, which the tests in tests/ import, its run and its section of the report) states a
tolerance, the one its test holds with the reasons given there; the script exits 1 and names every
benchmark that left its tolerance.  A benchmark has a tolerance, not a best, so it is checked here
rather than recorded in results/record.json (experiments/guard.py).  The benchmarks: the
cantilever's natural frequencies, Cook's membrane, St Venant-Kirchhoff's uniaxial stress, Turek and
Hron's CSM1 and CSM2, a Mooney-Rivlin block in plane-strain compression, and Treloar's data fitted
in uniaxial tension and predicted in the other tests.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
# experiments/results.py and the experiments.verification package, run as a script or imported
sys.path[:0] = [str(HERE), str(HERE.parent)]
import results  # noqa: E402

from experiments.verification import BENCHMARKS  # noqa: E402
from experiments.verification.report import module, report  # noqa: E402

COMMAND = ["python", "experiments/verify.py", *sys.argv[1:]]  # what the result's stamp says made it


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--only",
        nargs="+",
        choices=BENCHMARKS,
        help="run these benchmarks only and print their report (results/verification/ is kept)",
    )
    args = ap.parse_args()
    from nma.runtime import configure_jax

    configure_jax()
    t0 = time.perf_counter()
    r = {}
    for name in args.only or BENCHMARKS:
        print(f"{name} ...", flush=True)
        r[name] = module(name).run()
    r["failures"] = [f for name in list(r) for f in r[name]["failures"]]
    r["passed"] = not r["failures"]
    text = report(r)
    print(text)
    if not args.only:
        stamp = results.stamp(COMMAND, time.perf_counter() - t0)
        out = results.write("verification", r, text, [], stamp)
        print(f"-> {results.relative(str(out))}/")
    for failure in r["failures"]:
        print(f"left its tolerance: {failure}", file=sys.stderr)
    return 1 if r["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
