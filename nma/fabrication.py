"""A design's outline as the files it is made from (SVG, DXF, STL), and the numbers a fabricator
checks first (fabrication_report), in the outline's units; the command that writes them:
nma.export."""

from __future__ import annotations

import logging
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from .errors import ConfigError
from .geometry.outline import Outline, bezier_segments, loop_spline


def fabrication_report(outline: Outline, samples: int) -> dict:
    """Bounding box, material area and porosity (exact), and the minimum ligament width between two
    boundary curves (on polylines through `samples` points per span) of an outline, in its units."""
    import shapely

    polygon = outline.polygon(samples)
    if not polygon.is_valid:
        raise ConfigError(
            f"the design's boundary curves cross each other ({shapely.is_valid_reason(polygon)}); "
            "it cannot be made as one piece"
        )
    rings = [polygon.exterior, *polygon.interiors]
    names = ["outer boundary"] + [f"pore {k}" for k in range(1, len(rings))]
    i, j = np.triu_indices(len(rings), k=1)
    ring_array = np.asarray(rings, dtype=object)
    widths = shapely.distance(ring_array[i], ring_array[j])
    xmin, ymin, xmax, ymax = polygon.bounds
    enclosed = outline.enclosed_areas()
    report = {
        "bounding_box": [xmin, ymin, xmax, ymax],
        "size": [xmax - xmin, ymax - ymin],
        "material_area": outline.area,
        "porosity": -float(np.sum(enclosed[1:])) / float(enclosed[0]),
        "pores": len(rings) - 1,
    }
    if len(widths):
        k = int(np.argmin(widths))
        line = shapely.shortest_line(ring_array[i[k]], ring_array[j[k]])
        report.update(
            min_ligament=float(widths[k]),
            min_ligament_between=[names[i[k]], names[j[k]]],
            min_ligament_at=np.asarray(line.centroid.coords[0]).tolist(),
        )
    return report


def write_svg(outline: Outline, path: Path) -> Path:
    """The outline as one SVG path of quadratic Bezier segments, y up, the page sized in
    millimetres."""
    xmin, ymin, xmax, ymax = outline.bounds
    w, h = xmax - xmin, ymax - ymin
    pad = 0.02 * max(w, h)
    svg = ET.Element(
        "svg",
        xmlns="http://www.w3.org/2000/svg",
        version="1.1",
        width=f"{w + 2 * pad:.6g}mm",
        height=f"{h + 2 * pad:.6g}mm",
        viewBox=f"{xmin - pad:.9g} {-ymax - pad:.9g} {w + 2 * pad:.9g} {h + 2 * pad:.9g}",
    )
    commands = []
    for loop in outline.loops:
        segments = bezier_segments(loop, outline.grading)
        commands.append("M {:.9g} {:.9g}".format(*segments[0, 0]))
        commands += ["Q {:.9g} {:.9g} {:.9g} {:.9g}".format(*s[1], *s[2]) for s in segments]
        commands.append("Z")
    group = ET.SubElement(svg, "g", transform="scale(1,-1)")  # the scene's y axis points up
    ET.SubElement(
        group,
        "path",
        d=" ".join(commands),
        fill="#8fa8c8",
        stroke="#000000",
        style="fill-rule:evenodd;stroke-width:0.1",
    )
    ET.ElementTree(svg).write(path, encoding="utf-8", xml_declaration=True)
    return path


def write_dxf(outline: Outline, path: Path) -> Path:
    """One exact degree-2 SPLINE per closed curve: layer OUTLINE for the outer boundary, PORES for
    the rest."""
    import ezdxf
    from ezdxf import units

    logging.getLogger("ezdxf").setLevel(logging.WARNING)  # it narrates every table it creates
    doc = ezdxf.new("R2010", units=units.MM)
    doc.layers.add("OUTLINE", color=5)  # blue
    doc.layers.add("PORES", color=1)  # red
    msp = doc.modelspace()
    for k, loop in enumerate(outline.loops):
        ctrl, knots = loop_spline(loop, outline.grading)
        msp.add_open_spline(
            [(x, y, 0.0) for x, y in ctrl],
            degree=2,
            knots=knots.tolist(),
            dxfattribs={"layer": "OUTLINE" if k == 0 else "PORES"},
        )
    doc.saveas(path)
    return path


def write_stl(outline: Outline, path: Path, thickness: float, samples: int) -> float:
    """The section extruded to `thickness`; refuses to write a mesh that is not watertight.
    Returns the mesh's volume."""
    import trimesh

    try:
        mesh = trimesh.creation.extrude_polygon(outline.polygon(samples), height=thickness)
    # a height or section the mesh library cannot extrude at its tolerance
    except ValueError as exc:
        raise ConfigError(
            f"thickness={thickness:g} (with scale) does not extrude the section: {exc}"
        ) from None
    if not mesh.is_watertight:
        raise ConfigError(
            f"the extruded mesh of {path.name} is not watertight at thickness={thickness:g} and "
            f"this scale: choose a thickness and scale nearer the part's own size"
        )
    mesh.export(path)
    return float(mesh.volume)
