"""A periodic cell's effective response along a load path, without Hydra:

    python -m nma.periodic --cells 2 2 --porosity 0.5 --load uniaxial_y --strain -0.2 --steps 20

prints, at each output point, the nominal strains, the secant and incremental Poisson's ratios,
the average nominal (first Piola-Kirchhoff) stress along the load, the reduced Hessian's lowest
eigenvalue and whether the state is physical; then the critical strain of a bifurcation crossed and
how the buckled branch was chosen.  `--json FILE` writes the arrays, `--figure FILE` draws the cell
tiled at a few strains beside its curves.  Exit codes as nma's commands
(0 done, 1 the path could not be completed, 2 bad input).
"""

from __future__ import annotations

import argparse
import json
import sys

from .load import LOADS


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m nma.periodic",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--cells", nargs=2, type=int, default=[2, 2], metavar=("K", "M"))
    ap.add_argument("--porosity", type=float, default=0.5, help="circular holes' target porosity")
    ap.add_argument("--solid", action="store_true", help="pore-free cells")
    ap.add_argument("--load", choices=list(LOADS), default="uniaxial_y")
    ap.add_argument(
        "--strain", type=float, default=-0.2, help="axial nominal strain (shear: gamma)"
    )
    ap.add_argument("--lateral-strain", type=float, default=0.0, help="biaxial's second strain")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--material", default=None, help="a conf/material preset's name")
    ap.add_argument("--ctrl-per-patch", type=int, default=None)
    ap.add_argument("--quad-points", type=int, default=None)
    ap.add_argument("--no-escape", action="store_true", help="stay on the symmetric path")
    ap.add_argument("--json", default=None, help="write the path's arrays to this file")
    ap.add_argument("--figure", default=None, help="draw the tiled cell and its curves (PNG)")
    return ap


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    from ..runtime import configure_jax

    configure_jax()
    from ..errors import ConfigError
    from . import circular_holes, periodic_cell, follow, load_of, square_array

    try:
        k, m = args.cells
        scene = square_array(k, m, solid=args.solid)
        fidelity = {
            key: v
            for key, v in (
                ("ctrl_per_patch", args.ctrl_per_patch),
                ("quad_points", args.quad_points),
            )
            if v is not None
        }
        cell = periodic_cell(scene, fidelity or None, args.material)
        params, phi = (None, 0.0) if args.solid else circular_holes(cell, args.porosity)
        load = load_of(args.load, args.strain, args.lateral_strain)
        path = follow(cell, load, args.steps, params, escape=not args.no_escape)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{scene['name']}: porosity {phi:.4f}, load {load.name} to {args.strain:g}")
    print(path.table())
    c = path.critical
    if c:
        how = "the symmetric path kept" if args.no_escape else "left along the mode, downhill"
        print(f"bifurcation at nominal strain {c['strain']:.4f} (t = {c['t']:.4f}); branch: {how}")
    else:
        print("no bifurcation on the path (the reduced Hessian stayed positive definite)")
    print(f"{int((~path.valid).sum())} of {len(path.valid)} states not physical")
    if args.json:
        keys = ("t", "F", "P", "energy", "strain_axial", "strain_lateral", "poisson")
        out = {key: getattr(path, key).tolist() for key in keys + ("poisson_incremental", "lowest")}
        out["critical"] = None if c is None else {a: b for a, b in c.items() if a != "mode_u"}
        out.update(porosity=phi, valid=path.valid.tolist(), message=path.message)
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    if args.figure:
        from .figures import save_path_figure

        X = cell.reference_points(params)
        print(f"figure: {save_path_figure(args.figure, cell, X, path, tiles=(2, 2))}")
    if not path.completed:
        print(f"error: {path.message}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
