"""Newton-kernel benchmark: one linearisation (energy, force, element tangents) per scene, its
elements in cache-sized chunks (the default on a CPU, nma.mechanics.energy.ELEMENT_CHUNK) and all at
once, interleaved in one process so that the ratio comes from one machine state.

    python experiments/bench_kernels.py                  # writes outputs/bench/kernels.{json,md}
    python experiments/bench_kernels.py --repeats 5 --scenes translation:14x5

A scene is `name` (the paper's 5 x 5) or `name:<ctrl>x<quad>`.  The state is the scene's initial
design under a homogeneous strain of about 1% (J > 0 everywhere), its quadrature computed
once as in a solve; times are min and median over `--repeats` rounds of 10 calls.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCENES = [
    "translation",
    "rotation_single",
    "rotation_double",
    "shape_matching",
    "digital_mnist",
    "translation:14x5",
]


def linearisation(scene: str):
    """(jitted linearise, its arguments, dofs, elements) of a scene at its fidelity."""
    import jax
    import jax.numpy as jnp

    from nma import config
    from nma.mechanics.energy import energy_force_tangents, quadrature
    from nma.mechanics.material import material
    from nma.simulator import Simulator

    name, _, fid = scene.partition(":")
    ctrl, quad = (int(v) for v in (fid or "5x5").split("x"))
    sim = Simulator.from_config(
        config.load("scene", name), {"ctrl_per_patch": ctrl, "quad_points": quad}
    )
    X = sim.reference_points(sim.init_params())
    # a homogeneous strain: J > 0
    u = (X - jnp.mean(X, axis=0)) @ jnp.array([[0.02, 0.01], [0.0, -0.01]])
    # the design's part: once per solve, not timed
    quad = jax.jit(lambda X: quadrature(sim.disc.solid, X))(X)
    fn = jax.jit(lambda quad, u, mat: energy_force_tangents(sim.disc.solid, quad, u, mat))
    elements = int(np.prod(sim.disc.mesh.elem_points.shape[:2]))
    return fn, (quad, u, material(0.07, 0.3)), sim.disc.boundary.n_dofs, elements


def measure(scene: str, repeats: int) -> dict:
    import jax

    from nma.mechanics import energy

    variants = {}
    defaults = energy.ELEMENT_CHUNK, energy.CHUNK_ABOVE
    # chunks whatever the scene's size (the default skips them below CHUNK_ABOVE), and none
    for name, setting in (("chunked", (defaults[0], 0)), ("whole", (None, defaults[1]))):
        energy.ELEMENT_CHUNK, energy.CHUNK_ABOVE = setting
        try:  # traced and compiled now, with this setting
            fn, args, dofs, elements = linearisation(scene)
            jax.block_until_ready(fn(*args))
        finally:
            energy.ELEMENT_CHUNK, energy.CHUNK_ABOVE = defaults
        variants[name] = (fn, args)
    chunked, whole = (jax.tree_util.tree_leaves(fn(*args)) for fn, args in variants.values())
    difference = max(
        float(np.max(np.abs(a - b)) / np.max(np.abs(b)))
        for a, b in zip(chunked, whole)
        if np.size(b)
    )
    times = {name: [] for name in variants}
    for _ in range(repeats):
        for name, (fn, args) in variants.items():
            t = time.perf_counter()
            for _ in range(10):
                jax.block_until_ready(fn(*args))
            times[name].append((time.perf_counter() - t) / 10)
    stats = {
        name: {"min": float(np.min(v)), "median": float(np.median(v))} for name, v in times.items()
    }
    return {
        "scene": scene,
        "dofs": dofs,
        "elements": elements,
        "chunk": energy.ELEMENT_CHUNK,
        **stats,
        "median_ratio": stats["whole"]["median"] / stats["chunked"]["median"],
        "relative_difference": difference,
    }


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--scenes", nargs="+", default=SCENES)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "bench" / "kernels.json")
    args = ap.parse_args()

    import jax

    jax.config.update("jax_enable_x64", True)
    rows = []
    for scene in args.scenes:
        rows.append(measure(scene, args.repeats))
        print(json.dumps(rows[-1]), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))
    ms = lambda s: f"{1e3 * s['min']:.1f} / {1e3 * s['median']:.1f}"
    table = [
        "| scene | dofs | elements | chunked (ms, min / median) | whole | median ratio | largest "
        "difference (relative) |",
        "|---|---|---|---|---|---|---|",
    ]
    table += [
        f"| {r['scene']} | {r['dofs']} | {r['elements']} | {ms(r['chunked'])} | {ms(r['whole'])} | "
        f"{r['median_ratio']:.2f} | {r['relative_difference']:.0e} |"
        for r in rows
    ]
    args.out.with_suffix(".md").write_text("\n".join(table) + "\n")
    print("\n".join(table))


if __name__ == "__main__":
    main()
