"""A periodic cell made: its design tiled n x m as one finite grid scene, exported as the files a
part is made from (DXF, STL, SVG: nma.fabrication) in millimetres, with the tiling's minimum
ligament and the elastomer it is cast in.

```python
from nma import config
from nma.periodic import circular_holes, periodic_cell, square_array
from nma.periodic.fabricate import export_tiling
cell = periodic_cell(square_array(2, 2))
params, _ = circular_holes(cell, 0.5)
elastomer = config.load("material", "ecoflex_0030")
export_tiling(cell, params, 3, 2, "out/tiling.dxf", scale=10.0, material=elastomer)
```

The tiling is the grid scene of (n k) x (m l) cells for a k x l cell, each carrying the pore of the
cell it repeats, so its outline is built by the same B-spline nets as the cell's (exactly the
cell's curves, shifted by whole periods) and its pores meet the straight outer sides the cell's
periodic edges become.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..geometry.outline import Outline
from .cell import PeriodicCell

FORMATS = ("dxf", "stl", "svg")


def _count(name: str, v) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 100:
        raise ConfigError(f"tiling: {name} must be an integer in [1, 100], got {v!r}")
    return int(v)


def _centres(design) -> np.ndarray:
    """(n_porous, 2) the centre of each porous cell's node quad."""
    return design.nodes[design.porous].mean(axis=1)


def tiled_design(cell: PeriodicCell, params, n: int, m: int):
    """(the discretisation of the cell's scene tiled n x m, its design params): every porous
    cell of the tiling carries the radii of the cell's porous cell one whole number of periods
    away.  ConfigError for a design with parameters other than pore radii (corner moves would
    move the periodic edges' nodes, which the tiling shares between neighbours)."""
    from ..discretise import discretise

    n, m = _count("n", n), _count("m", m)
    extra = sorted(set(params) - {"radii"})
    if extra:
        raise ConfigError(
            f"tiling: only pore radii can be tiled; the design also has {extra} (corner moves)"
        )
    spec = cell.disc.spec
    if spec.central_pore or spec.groups or spec.supports:
        raise ConfigError(f"tiling: scene {spec.name} has a central pore, groups or supports")
    L = cell.box[1] - cell.box[0]

    def breaks(b, copies, period):
        b = np.asarray(b, float)
        return tuple(
            np.concatenate(
                [b[:-1] + c * period for c in range(copies)] + [b[-1:] + (copies - 1) * period]
            )
        )

    tiled_spec = dataclasses.replace(
        spec,
        name=f"{spec.name}_tiled_{n}x{m}",
        x_breaks=breaks(spec.x_breaks, n, L[0]),
        y_breaks=breaks(spec.y_breaks, m, L[1]),
        cells=tuple(row * n for row in spec.cells) * m,
    )
    disc = discretise(tiled_spec, cell.disc.mesh.fidelity)
    # each tiled cell's centre folded back into the cell's box, matched to the cell's own
    src = _centres(cell.disc.design)
    folded = cell.box[0] + np.mod(_centres(disc.design) - cell.box[0], L)
    dist = np.linalg.norm(folded[:, None, :] - src[None, :, :], axis=-1)
    which = np.argmin(dist, axis=1)
    if np.any(dist[np.arange(len(which)), which] > 1e-9 * L.max()):
        raise ConfigError(f"tiling: scene {spec.name}'s cells do not repeat on its periodic box")
    radii = jnp.asarray(np.asarray(params["radii"])[which])
    return disc, {"radii": radii}


def tiled_outline(cell: PeriodicCell, params, n: int, m: int) -> Outline:
    """The outline of the cell's design tiled n x m, in the scene's length units."""
    disc, tparams = tiled_design(cell, params, n, m)
    return Outline.of(disc.mesh, disc.reference_points(tparams))


def _inner_ligament(outline: Outline, samples: int) -> float | None:
    """The narrowest ligament between two pores: the tiling's outer sides cut the cell's edge
    ligaments in half, so fabrication_report's minimum is there; this is the material's own."""
    import shapely

    rings = np.asarray(outline.polygon(samples).interiors, dtype=object)
    i, j = np.triu_indices(len(rings), k=1)
    return float(np.min(shapely.distance(rings[i], rings[j]))) if len(i) else None


def export_tiling(
    cell: PeriodicCell,
    params,
    n: int,
    m: int,
    path,
    scale: float = 1.0,
    thickness: float = 10.0,
    material: Mapping | None = None,
    samples: int = 32,
) -> dict:
    """Write the tiling to `path` (its suffix: .dxf, .stl or .svg) at `scale` mm per length unit
    (an STL extruded to `thickness` mm) and its fabrication report beside it (`<path>.json`): the
    bounding box, porosity, the minimum ligament in mm and where (at the outer sides, which cut the
    edge ligaments in half), the narrowest between two pores, and the elastomer it is cast in
    (`material`: a shipped elastomer's settings, conf/material/, as nma.config.load("material",
    "ecoflex_0030") reads them) with its law and parameters.  Returns the report."""
    from ..fabrication import fabrication_report, write_dxf, write_stl, write_svg

    path = Path(path)
    fmt = path.suffix.lstrip(".").lower()
    if fmt not in FORMATS:
        raise ConfigError(f"tiling: the file's suffix must be one of {list(FORMATS)}, got {fmt!r}")
    for name, v in (("scale", scale), ("thickness", thickness)):
        if not (isinstance(v, (int, float)) and 0 < v <= 1e4):
            raise ConfigError(f"tiling: {name} must be in (0, 10000] mm, got {v!r}")
    mat = dict(material or {})
    if not mat.get("unit"):  # the scene's units: no real stiffness to report
        raise ConfigError(
            f"tiling: material {mat.get('name')!r} has no real units: give an elastomer's settings "
            "(nma.config.load('material', 'ecoflex_0030'))"
        )
    outline = tiled_outline(cell, params, n, m).scaled(float(scale))
    path.parent.mkdir(parents=True, exist_ok=True)
    report = fabrication_report(outline, samples)
    report["min_ligament_inside"] = _inner_ligament(outline, samples)
    if fmt == "dxf":
        write_dxf(outline, path)
    elif fmt == "svg":
        write_svg(outline, path)
    else:
        report["thickness_mm"] = float(thickness)
        report["volume_mm3"] = write_stl(outline, path, float(thickness), samples)
    report.update(
        file=str(path),
        format=fmt,
        units="mm",
        scale_mm_per_unit=float(scale),
        tiling=[n, m],
        cell=cell.disc.spec.name,
        material={
            "name": mat.get("name"),
            "law": mat.get("law"),
            "parameters": dict(mat.get("parameters") or {}),
            "unit": mat["unit"],
        },
    )
    Path(f"{path}.json").write_text(json.dumps(report, indent=1, default=float))
    return report
