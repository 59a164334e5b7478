"""Designs you can make: the boundary curves of a design and the SVG / DXF / STL files written from
them."""

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from omegaconf import OmegaConf

from nma import config
from nma.export import (
    ExportConfig,
    export,
    fabrication_report,
    validate,
    write_dxf,
    write_stl,
    write_svg,
)
from nma.geometry.bspline import DESIGN_CTRL, basis_matrix
from nma.discretise import discretise
from nma.geometry.outline import Outline, bezier_segments
from nma.schema import scene_from_config
from nma.errors import ConfigError
from nma.schema import Fidelity
from nma.train import checkpoint


def quadrature_area(spec, geom) -> float:
    """The design's area as the solver integrates it: det J at 5 x 5 Gauss points per element."""
    disc = discretise(spec, Fidelity(5, 5))
    x = np.asarray(disc.reference_points(geom))[disc.mesh.elem_points]  # (P, S2, 9, 2)
    J = np.einsum("sqkc,pskd->psqdc", disc.mesh.basis_grads, x)
    return float(np.sum(np.linalg.det(J) * disc.mesh.quad_weights[None]))


@pytest.fixture(scope="module")
def design():
    """rotation_double with random radii in their bounds and corners moved: curved, uneven pores."""
    spec = scene_from_config(config.load("scene", "rotation_double"))
    disc = discretise(spec, Fidelity(5, 2))
    geom = disc.init_params()
    k1, k2 = jax.random.split(jax.random.PRNGKey(3))
    geom["radii"] = jax.random.uniform(k1, geom["radii"].shape, minval=0.15, maxval=0.85)
    geom["corners"] = jax.random.uniform(k2, geom["corners"].shape, minval=-1.0, maxval=1.0)
    geom = disc.design.project(geom, disc.init_params())
    return spec, geom, Outline.of(disc.mesh, disc.reference_points(geom))


def test_outline_area_equals_the_quadrature_area(design):
    spec, geom, outline = design
    # one closed curve per pore, plus the outer boundary
    assert len(outline.pores) == len(geom["radii"])
    areas = outline.enclosed_areas()
    assert areas[0] > 0 and np.all(areas[1:] < 0)  # outer counter-clockwise, pores clockwise
    np.testing.assert_allclose(outline.area, quadrature_area(spec, geom), rtol=1e-12)
    # the polylines a mesh is built from converge to it (chord error ~ h^2)
    errors = [abs(outline.polygon(n).area - outline.area) for n in (4, 8, 16)]
    assert errors[2] < errors[1] < errors[0] < 1e-2 * outline.area
    assert 3.0 < errors[0] / errors[1] < 5.0


def test_bezier_segments_are_the_spline(design):
    loop = design[2].pores[0]
    segments = bezier_segments(loop)  # (edges * 3, 3, 2)
    s = np.linspace(0.0, 1.0, 7)
    bern = np.stack([(1 - s) ** 2, 2 * s * (1 - s), s**2], axis=1)
    on_bezier = np.einsum("nk,skd->snd", bern, segments)  # (edges * 3, 7, 2)
    # each span's parameters
    t = (np.arange(3)[:, None] + s[None]) / 3
    on_spline = np.einsum("nk,ekd->end", basis_matrix(t.ravel(), DESIGN_CTRL), loop).reshape(
        -1, 7, 2
    )
    np.testing.assert_allclose(on_bezier, on_spline, atol=1e-12)


def test_svg_holds_every_curve_in_millimetres(design, tmp_path):
    outline = design[2].scaled(2.0)
    path = write_svg(outline, tmp_path / "d.svg")
    root = ET.parse(path).getroot()
    ns = {"s": "http://www.w3.org/2000/svg"}
    d = root.find(".//s:path", ns).get("d").split()
    assert d.count("M") == d.count("Z") == len(outline.loops)
    assert d.count("Q") == sum(3 * len(loop) for loop in outline.loops)
    xmin, ymin, xmax, ymax = outline.bounds
    assert float(root.get("width")[:-2]) == pytest.approx((xmax - xmin) * 1.04, rel=1e-5)


def test_dxf_reads_back_as_the_same_splines(design, tmp_path):
    import ezdxf

    outline = design[2]
    doc = ezdxf.readfile(write_dxf(outline, tmp_path / "d.dxf"))
    splines = list(doc.modelspace().query("SPLINE"))
    assert len(splines) == len(outline.loops)
    assert [s.dxf.layer for s in splines].count("OUTLINE") == 1
    for spline, loop in zip(splines, outline.loops):
        tool = spline.construction_tool()
        assert tool.degree == 2
        t = np.linspace(0.0, len(loop), 8 * len(loop), endpoint=False)
        read = np.array([tool.point(v) for v in t])[:, :2]
        np.testing.assert_allclose(read, _on_loop(loop, t), atol=1e-9)


def _on_loop(loop, t):
    """The loop at parameters t in [0, n_edges): edge floor(t) at local t - floor(t)."""
    k = np.minimum(np.floor(t).astype(int), len(loop) - 1)
    B = basis_matrix(t - k, DESIGN_CTRL)
    return np.einsum("nk,nkd->nd", B, loop[k])


def test_stl_is_watertight_with_volume_area_times_thickness(design, tmp_path):
    import trimesh

    outline = design[2]
    volume = write_stl(outline, tmp_path / "d.stl", thickness=3.0, samples=16)
    mesh = trimesh.load(tmp_path / "d.stl")
    # binary STL stores single-precision coordinates: the read-back volume agrees to float32
    # round-off
    assert mesh.is_watertight and mesh.volume == pytest.approx(volume, rel=1e-6)
    assert volume == pytest.approx(3.0 * outline.polygon(16).area, rel=1e-12)
    assert mesh.volume == pytest.approx(3.0 * outline.area, rel=1e-3)
    np.testing.assert_allclose(mesh.bounds[:, 2], [0.0, 3.0])


def test_report_of_square_pores_is_known_in_closed_form():
    """Radii 0.5 on a square grid: every pore is a square of half the cell's side (its inner edges
    are the cell's sides scaled by 0.5 about the centre), so walls and porosity follow by hand."""
    spec = scene_from_config(config.load("scene", "translation"))  # 5 x 5 cells of side 5
    disc = discretise(spec, Fidelity(5, 2))
    geom = {**disc.init_params(), "radii": jnp.full_like(disc.init_params()["radii"], 0.5)}
    report = fabrication_report(Outline.of(disc.mesh, disc.reference_points(geom)), samples=8)
    n_pores = len(geom["radii"])
    assert report["pores"] == n_pores
    assert report["porosity"] == pytest.approx(n_pores * 2.5**2 / 25.0**2, rel=1e-12)
    assert report["material_area"] == pytest.approx(625.0 - n_pores * 2.5**2, rel=1e-12)
    assert report["min_ligament"] == pytest.approx(1.25, rel=1e-9)  # a pore to the outer boundary
    assert "outer boundary" in report["min_ligament_between"]
    np.testing.assert_allclose(report["bounding_box"], [0, 0, 25, 25], atol=1e-12)


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory, design):
    """A run directory as training leaves it: its composed config and a checkpoint of the
    geometry."""
    from hydra import compose, initialize_config_dir

    run = tmp_path_factory.mktemp("run")
    with initialize_config_dir(config_dir=str(config.CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=["task=rotation_double"])
    (run / ".hydra").mkdir()
    OmegaConf.save(cfg, run / ".hydra" / "config.yaml")
    geom = {k: np.asarray(v) for k, v in design[1].items()}
    checkpoint.save(run / "checkpoints", 7, {"params": {"net": {}, "geom": geom}, "step": 7})
    return run


def test_export_command_writes_the_file_and_report(trained_run, design):
    # states=false: this run directory holds a geometry but no network to drive it (a real run's
    # states: test_train.py)
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "nma.export",
            f"run={trained_run}",
            "format=dxf",
            "scale=2.5",
            "states=false",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])  # stdout is the JSON line only
    assert report["file"] == str(trained_run / "export" / "design.dxf")
    assert json.loads((trained_run / "export" / "fabrication.json").read_text()) == report
    again = export(
        validate(
            OmegaConf.create(
                {"run": str(trained_run), "format": "dxf", "scale": 2.5, "states": False}
            )
        )
    )
    assert again["file"] == str(trained_run / "export" / "design_2.dxf")  # the first export stays
    assert again["report"] == str(trained_run / "export" / "fabrication_2.json") and report[
        "report"
    ].endswith("fabrication.json")
    with pytest.raises(ConfigError, match="lies inside run=.*among the run's own files"):
        validate(
            OmegaConf.create({"run": str(trained_run), "output": str(trained_run / "metrics.svg")})
        )
    spec, geom, _ = design
    assert report["material_area"] == pytest.approx(2.5**2 * quadrature_area(spec, geom), rel=1e-12)
    assert 0.0 < report["min_ligament"] < 2.5 * 5 and 0.0 < report["porosity"] < 1.0


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"format": "obj"}, "format must be one of ['svg', 'dxf', 'stl']"),
        ({"scale": 0.0}, "scale must be a finite number in [0.001, 10000]"),
        ({"run": "/nonexistent/run"}, "is not a training run directory"),
        (
            {"load_cases": True},
            "load_cases=true: the load cases (tension, compression, one-sided compression) are the "
            "translation part's",
        ),
        (
            {
                "material": {
                    "law": "yeoh",
                    "E": None,
                    "parameters": {"C10": 0.1, "C20": 0.0, "C30": 0.0},
                }
            },
            "material chooses the material the load cases are solved in: give load_cases=true too",
        ),
    ],
)
def test_bad_export_settings_name_the_field(trained_run, overrides, message):
    with pytest.raises(
        ConfigError, match=message.replace("[", r"\[").replace("(", r"\(").replace(")", r"\)")
    ):
        validate(OmegaConf.create({"run": str(trained_run), **overrides}))


def test_stl_export_reports_the_mesh_volume(trained_run, tmp_path):
    report = export(
        ExportConfig(
            run=str(trained_run),
            format="stl",
            thickness=2.0,
            samples=8,
            output=str(tmp_path / "d.stl"),
            states=False,
        )
    )
    assert report["volume"] == pytest.approx(2.0 * report["material_area"], rel=1e-3)


def test_export_never_replaces_a_file_and_reads_a_damaged_metrics_file_as_absent(
    tmp_path, translation_run
):
    """output= naming a file that exists, or lying below a file, is refused before any work; a
    metrics.json that is not the run's record (a list, counts that are not counts) is not trusted:
    the states are
    solved again, and the report names the checkpoint exported."""
    from conftest import copy_run
    from nma.errors import ConfigError
    from nma.export import evaluation_states
    from nma.schema import ExportConfig, build

    mine = tmp_path / "mine.svg"
    mine.write_text("precious")
    with pytest.raises(ConfigError, match="output names a file that exists"):
        build(ExportConfig, {"run": str(translation_run), "output": str(mine)})
    with pytest.raises(ConfigError, match="lies below .*mine.svg, which is a file"):
        build(ExportConfig, {"run": str(translation_run), "output": str(mine / "x.dxf")})
    d = copy_run(translation_run, tmp_path / "run")
    logged = json.loads((d / "metrics.json").read_text())
    for damaged in ([1, 2], {**logged, "invalid_states": "many", "checked_states": None}):
        (d / "metrics.json").write_text(json.dumps(damaged))
        assert evaluation_states(d)["source"].startswith("solved again")


def _logged(run, failed: int, checked: int, invalid: int = 0):
    """The run's final evaluation as metrics.json records it (at the checkpoint's step, 7)."""
    (run / "metrics.json").write_text(
        json.dumps(
            {
                "step": 7,
                "invalid_states": invalid,
                "checked_states": checked,
                "failed_solves": failed,
                "min_J": 0.5 if checked else None,
                "min_gap": 0.3 if checked else None,
                "invalid_samples": {},
            }
        )
    )


def test_states_nobody_checked_never_vouch_for_the_design(trained_run, tmp_path):
    """The fabrication report's `valid` holds only where every state of the evaluation set was
    reached and checked: none checked (every solve failed) is not valid, nor are some failed;
    `unchecked` says why.  Every state checked and physical is valid."""
    import shutil

    from nma.export import evaluation_states

    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    for failed, checked, valid, why in (
        (4, 0, False, "4 of the evaluation set's solves failed"),
        (1, 27, False, "1 of the evaluation set's solves failed"),
        (0, 0, False, "no state was checked"),
        (0, 36, True, None),
    ):
        _logged(run, failed, checked)
        found = evaluation_states(run)
        assert found["valid"] is valid and found["checked_states"] == checked
        assert "unchecked" not in found if why is None else why in found["unchecked"]
        assert found["source"].startswith("the run's final evaluation")


def test_export_of_a_run_whose_every_solve_failed_writes_the_file_and_exits_1(
    trained_run, tmp_path
):
    """The file is written and the report says valid false with 0 states checked; the command exits
    1 with one line: the state check it was asked for (states=true) says nothing of the design."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    _logged(run, 9, 0)
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "nma.export",
            f"run={run}",
            "format=stl",
            "thickness=2",
            "samples=8",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 1, proc.stderr[-2000:]
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith("error: ")
    assert "no state of its task's evaluation set was checked" in line
    assert "9 failed solves" in line and "states=false" in line
    said = json.loads(proc.stdout.strip().splitlines()[-1])
    report = json.loads(Path(said["report"]).read_text())
    assert report == said and report["evaluation_states"]["checked_states"] == 0
    assert report["evaluation_states"]["valid"] is False
    assert Path(report["file"]).stat().st_size > 1000
