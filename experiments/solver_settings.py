"""Two values of one solver setting on the stability map's cells: Newton's correctors (line search
against trust region) or its element bound (off against on).

    python experiments/solver_settings.py --nus 0.499 --out outputs/studies/correctors
    python experiments/solver_settings.py --setting element_bound --nus 0.3 \\
        --out outputs/studies/element_bound

For every cell of experiments/stability_map.py at the given Poisson's ratios (the same designs, seed
and actuations, the paper's 5 x 5, PARDISO, without contact), solves once with each value, one after
the other, everything else at the solver's defaults, and records for each whether it converged (or
how it ended), its iterations and wall time, the energy and the unstable modes (negative eigenvalues
of the Hessian) of its equilibrium and whether that is a physical object (nma/geometry/validity.py);
where both converged, the largest difference of their displacements relative to the largest
displacement: two settings can end on different equilibria of a buckling structure.  Writes
<setting>.json (every cell) and <setting>.md (a table per scene).
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np

import stability_map  # the sibling script (this directory is on the path when run as a script)
from nma.mechanics.options import FORMULATIONS

ROOT = Path(__file__).resolve().parent.parent
# the two values compared
SETTINGS = {"corrector": ("line_search", "trust_region"), "element_bound": (False, True)}


def label(setting: str, value) -> str:
    return value if isinstance(value, str) else f"{setting}={str(value).lower()}"


def run_scene(
    scene: str,
    nus: list[float],
    formulation: str,
    setting: str = "corrector",
    others: dict | None = None,
) -> list[dict]:
    """Every map cell of `scene` at `nus`, solved with each value of `setting` (`others`: further
    solver settings, the same for both)."""
    import jax
    import jax.numpy as jnp

    from nma import config
    from nma.geometry.validity import StateChecker
    from nma.mechanics.material import material
    from nma.simulator import Simulator
    from nma.solver.status import Status

    sims = {
        label(setting, v): Simulator.from_config(
            config.load("scene", scene),
            config.load("fidelity", "paper"),
            {**(others or {}), setting: v},
            {"enabled": False},
            formulation,
        )
        for v in SETTINGS[setting]
    }
    sim = next(iter(sims.values()))
    d_max = config.load("task", scene)["d_max"]
    rng = np.random.default_rng(0)  # the map's seed: its designs and directions, in its order
    designs, directions = (
        stability_map.designs(sim, rng),
        stability_map.directions(sim.n_actuations, rng),
    )
    solves = {c: jax.jit(lambda X, d, mat, s=s: s.equilibrium(X, d, mat)) for c, s in sims.items()}
    X0 = sim.reference_points(sim.init_params())
    for solve in solves.values():  # compile once
        jax.block_until_ready(
            solve(X0, jnp.zeros(sim.n_actuations), material(stability_map.E, 0.3))
        )
    records = []
    for (name, design), nu, s in itertools.product(designs.items(), nus, directions):
        X, d, mat = (
            sim.reference_points(design),
            jnp.asarray(d_max * s),
            material(stability_map.E, nu),
        )
        checker = StateChecker(sim.disc.mesh, np.asarray(X))
        record, states = {"scene": scene, "design": name, "nu": nu, "d": (d_max * s).tolist()}, {}
        for c, solve in solves.items():
            t0 = time.perf_counter()
            u, info = jax.block_until_ready(solve(X, d, mat))
            seconds = time.perf_counter() - t0
            converged = int(info.status) == Status.CONVERGED
            states[c] = np.asarray(u) if converged else None
            record[c] = {
                "converged": converged,
                "iterations": int(info.iterations),
                "seconds": seconds,
                "load_reached": float(info.load),
                "status": Status.describe(info.status),
                "physical": checker.check(np.asarray(u)).valid if converged else None,
                "energy": float(sim.energy(X, u, mat)) if converged else None,
                "negative_eigenvalues": sim.negative_eigenvalues(X, d, mat, u)
                if converged
                else None,
            }
        if all(u is not None for u in states.values()):
            a, b = states.values()
            record["difference"] = float(np.max(np.abs(a - b)) / np.max(np.abs(a)))
        records.append(record)
        print(
            f"{scene:16s} {name[:28]:28s} nu={nu:<6} d={np.round(d_max * s, 1).tolist()}: "
            + ", ".join(
                f"{c} {'ok' if record[c]['converged'] else 'FAILED'} {record[c]['iterations']} it "
                f"{record[c]['seconds']:.2f} s"
                for c in sims
            )
            + (f", difference {record['difference']:.1e}" if "difference" in record else ""),
            flush=True,
        )
    return records


def table(records: list[dict], setting: str = "corrector") -> list[str]:
    # one equilibrium: displacements this close, relative
    from nma.solver.warm import SAME_EQUILIBRIUM

    values = [label(setting, v) for v in SETTINGS[setting]]
    lines = [
        f"| scene | converged: {' / '.join(values)} | iterations, all solves | seconds, all "
        "solves | both converged: same equilibrium | saddles | physical of the converged |",
        "|---|---|---|---|---|---|---|",
    ]
    scenes = list(dict.fromkeys(r["scene"] for r in records))
    for scene in scenes + ["all"]:
        rs = [r for r in records if scene in ("all", r["scene"])]
        total = {
            k: {c: sum(r[c][k] for r in rs) for c in values}
            for k in ("converged", "iterations", "seconds")
        }
        both = [r["difference"] for r in rs if "difference" in r]
        saddles = {c: sum(bool(r[c]["negative_eigenvalues"]) for r in rs) for c in values}
        # earlier files: no field
        physical = {c: sum(bool(r[c].get("physical")) for r in rs) for c in values}
        pair = lambda k, f="{}": " / ".join(f.format(total[k][c]) for c in values)
        lines.append(
            f"| {scene} | {pair('converged')} of {len(rs)} | {pair('iterations')} | "
            f"{pair('seconds', '{:.1f}')} | "
            f"{sum(x <= SAME_EQUILIBRIUM for x in both)} of {len(both)} | "
            f"{' / '.join(str(saddles[c]) for c in values)} | "
            f"{' / '.join(str(physical[c]) for c in values)} |"
        )
    other = [r for r in records if r.get("difference", 0.0) > SAME_EQUILIBRIUM]
    if other:
        lines += [
            "",
            "Cells where the two converged to different equilibria (energy, unstable modes):",
            "",
        ]
        lines += [
            f"- {r['scene']}, {r['design']}, nu {r['nu']}, d = {np.round(r['d'], 1).tolist()}: "
            f"difference {r['difference']:.2g}; "
            + "; ".join(f"{c} {r[c]['energy']:.6g}, {r[c]['negative_eigenvalues']}" for c in values)
            for r in other
        ]
    return lines


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--scenes", nargs="+", default=stability_map.SCENES, choices=stability_map.SCENES
    )
    ap.add_argument("--nus", nargs="+", type=float, default=[0.499], help="Poisson's ratios")
    ap.add_argument("--formulation", default="displacement", choices=FORMULATIONS)
    ap.add_argument(
        "--setting", default="corrector", choices=list(SETTINGS), help="the solver setting compared"
    )
    ap.add_argument(
        "--no-element-bound",
        dest="element_bound",
        action="store_false",
        help="both solves with solver.element_bound=false (the corrector study unbounded)",
    )
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="default: outputs/studies/correctors or outputs/studies/element_bound",
    )
    args = ap.parse_args()
    from nma.runtime import configure_jax

    configure_jax()
    # the corrector study's names as before
    name = "correctors" if args.setting == "corrector" else args.setting
    args.out = args.out or ROOT / "outputs" / "studies" / name
    args.out.mkdir(parents=True, exist_ok=True)
    if args.setting == "element_bound" and not args.element_bound:
        ap.error(
            "--no-element-bound with --setting element_bound: the setting compared is the bound "
            "itself"
        )
    others = {} if args.element_bound else {"element_bound": False}
    records = [
        r
        for scene in args.scenes
        for r in run_scene(scene, args.nus, args.formulation, args.setting, others)
    ]
    (args.out / f"{name}.json").write_text(json.dumps(records, indent=1))
    lines = table(records, args.setting)
    (args.out / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
