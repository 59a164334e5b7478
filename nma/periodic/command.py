"""nma.simulate's periodic branch: a periodic scene followed along its macroscopic load path.

    python -m nma.simulate scene=square_array load=uniaxial_y load.strain=-0.2 load.steps=20

`run(settings, out_dir)` builds the cell from the command's resolved settings, follows the path
(nma.periodic.path.follow) and writes into the run directory fields.h5 + fields.xdmf (the last
state, as the static run writes its equilibrium), mode.h5 + mode.xdmf (the bifurcation's mode,
where one was crossed) and path.png (the cell tiled at a few strains beside its curves); it returns
the JSON line's object: per state the strains, the average nominal stress, the Poisson's ratios,
the lowest eigenvalue and the validity, then the critical strain.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .cell import COMPONENTS


def _steps(path) -> list[dict]:
    """Each reported state of the path, as the JSON line lists it."""
    return [
        {
            "t": float(path.t[k]),
            "strain": float(path.strain_axial[k]),
            "lateral_strain": float(path.strain_lateral[k]),
            "stress": float(path.P[k, path.axial]),
            "P": dict(zip(COMPONENTS, path.P[k].tolist())),
            "F": dict(zip(COMPONENTS, path.F[k].tolist())),
            "poisson": float(path.poisson[k]),
            "poisson_incremental": float(path.poisson_incremental[k]),
            "lowest": float(path.lowest[k]),
            "valid": bool(path.valid[k]),
            "min_J": float(path.min_J[k]),
        }
        for k in range(len(path.t))
    ]


def run(s, out_dir: Path) -> dict:
    """Follow a periodic scene's load path with resolved SimulateConfig settings `s`; the JSON
    line's object (`converged`: the path reached its end; `valid`: every state physical)."""
    from ..io.fields import write_fields
    from ..resolve import model_record
    from .designs import circular_holes
    from .figures import save_path_figure
    from .front import cell_of
    from .load import load_of
    from .path import follow

    load_cfg = s.load
    t0 = time.perf_counter()
    cell = cell_of(s)
    params, porosity = None, cell.porosity  # the scene's
    if porosity is not None:
        params, porosity = circular_holes(cell, porosity)
    load = load_of(load_cfg.kind, load_cfg.strain, load_cfg.lateral_strain)
    build_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    path = follow(cell, load, load_cfg.steps, params, escape=load_cfg.escape)
    seconds = time.perf_counter() - t0
    X = np.asarray(cell.reference_points(params))
    c = path.critical
    result = {
        "scene": s.scene.name,
        "periodic": True,
        "dofs": int(len(cell.w_dofs) + len(load.free)),
        "contact": s.contact.enabled,
        "material": s.material.record(),
        "model": model_record(s),
        "load": {
            "kind": load.name,
            "strain": load_cfg.strain,
            "lateral_strain": load_cfg.lateral_strain,
            "steps": load_cfg.steps,
            "escape": load_cfg.escape,
            "free": [COMPONENTS[k] for k in load.free],
        },
        "porosity": porosity,
        "steps": _steps(path),
        "critical": None,
        "load_steps": int(path.steps),
        "step_cuts": int(path.cuts),
        "converged": bool(path.completed),
        "valid": bool(path.valid.all()) and len(path.t) > 0,
        "not_physical": [
            {"t": float(t), "problems": list(problems)} for t, problems in path.problems
        ],
        "seconds": seconds,
        "build_seconds": build_seconds,
    }
    if not path.completed:
        result["error"] = f"scene {s.scene.name}, load {load.name}: {path.message}"
    if c is not None:
        result["critical"] = {
            "strain": float(c["strain"]),
            "t": float(c["t"]),
            "lowest_before": float(c["lowest_before"]),
            "lowest_after": float(c["lowest_after"]),
            "branch": "left along the mode, downhill in energy"
            if load_cfg.escape
            else "the symmetric path kept (a saddle past the bifurcation)",
        }
        mode = np.asarray(c["mode_u"])
        mode = 0.1 * float(np.min(cell.period)) * mode / np.abs(mode).max()
        h5, _ = write_fields(
            out_dir / "mode.h5",
            cell.disc,
            X,
            mode,
            s.output.samples,
            attrs={"critical_strain": c["strain"], "scale": "largest entry 0.1 of the period"},
        )
        result["critical"]["mode"] = str(h5)
    if len(path.t):
        h5, xdmf = write_fields(
            out_dir / "fields.h5",
            cell.disc,
            X,
            path.u[-1],
            s.output.samples,
            attrs={"F_bar": path.F[-1], "P_bar": path.P[-1], "strain": path.strain_axial[-1]},
        )
        result.update(fields=str(h5), xdmf=str(xdmf))
        if s.output.figure:
            result["figure"] = str(save_path_figure(out_dir / "path.png", cell, X, path))
    return result
