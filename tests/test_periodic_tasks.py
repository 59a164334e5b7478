"""Tasks on a periodic cell's effective response and the cell made as a part: the response's
gradient against central differences, the tiling's outline against the cell's repeated, the part's
report in millimetres (nma.periodic.response, nma.periodic.fabricate, nma.tasks.periodic)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma import config
from nma.errors import ConfigError
from nma.periodic import circular_holes, periodic_cell, square_array, uniaxial
from nma.periodic.fabricate import export_tiling, tiled_outline


@pytest.fixture(scope="module")
def cell():
    # scene.porosity: the tasks' initial circles
    return periodic_cell({**square_array(2, 2), "porosity": 0.5}, fidelity={"quad_points": 3})


@pytest.fixture(scope="module")
def holes(cell):
    """Circular holes at porosity 0.5, each of the four pores scaled differently (no symmetry
    makes two of them alike)."""
    params, _ = circular_holes(cell, 0.5)
    return {"radii": params["radii"] * jnp.array([[1.0], [0.95], [0.9], [1.05]])}


def _pores(outline):
    """Each pore's control polygon, as a sorted array of rounded points (order-free)."""
    return [np.unique(np.round(p.reshape(-1, 2), 9), axis=0) for p in outline.pores]


def test_tiling_outline_is_the_cells_repeated(cell, holes):
    # the tiling's pores are built by the same nets: each is a pore of the cell shifted by a whole
    # number of periods (exact), and the material is the cell's n x m times
    cell_outline, tiled = tiled_outline(cell, holes, 1, 1), tiled_outline(cell, holes, 3, 2)
    Lx, Ly = cell.period
    assert tiled.bounds == pytest.approx((0.0, 0.0, 3 * Lx, 2 * Ly), abs=1e-12)
    assert tiled.area == pytest.approx(6 * cell_outline.area, rel=1e-12)
    own = _pores(cell_outline)
    assert len(tiled.pores) == 6 * len(own)
    for pore in _pores(tiled):
        shift = np.floor(pore.mean(axis=0) / [Lx, Ly]) * [Lx, Ly]
        back = np.unique(np.round(pore - shift, 9), axis=0)
        assert any(o.shape == back.shape and np.allclose(o, back, atol=1e-9) for o in own)


def test_export_tiling_reports_the_part_in_mm(cell, holes, tmp_path):
    ecoflex = config.load("material", "ecoflex_0030")
    one = export_tiling(cell, holes, 2, 2, tmp_path / "a.dxf", scale=1.0, material=ecoflex)
    ten = export_tiling(cell, holes, 2, 2, tmp_path / "b.svg", scale=10.0, material=ecoflex)
    assert (tmp_path / "a.dxf").stat().st_size > 0 and (tmp_path / "a.dxf.json").is_file()
    assert ten["min_ligament"] == pytest.approx(10.0 * one["min_ligament"], rel=1e-9)
    # the outer sides halve the cell's edge ligaments: the material's own are wider
    assert one["min_ligament"] < one["min_ligament_inside"]
    assert ten["size"] == pytest.approx([40.0, 40.0])
    assert ten["porosity"] == pytest.approx(one["porosity"], rel=1e-12)
    assert one["material"]["unit"] == "MPa" and one["material"]["law"] == "ogden"
    with pytest.raises(ConfigError, match="suffix"):
        export_tiling(cell, holes, 2, 2, tmp_path / "c.step", material=ecoflex)
    with pytest.raises(ConfigError, match="no real units"):
        paper = config.load("material", "neo_hookean")
        export_tiling(cell, holes, 2, 2, tmp_path / "d.dxf", material=paper)
    with pytest.raises(ConfigError, match="n must be an integer"):
        tiled_outline(cell, holes, 0, 1)


def test_response_gradient_matches_central_differences(cell):
    # past the bifurcation (about -6.5% for these holes), on the buckled branch; a symmetric
    # change of the pores keeps the two mirror-image branches' responses equal
    from nma.periodic.response import Response

    params, _ = circular_holes(cell, 0.5)
    response = Response(cell, uniaxial("y", -0.1), 5)
    lateral = lambda r: response(cell.disc.reference_points({"radii": r})[None]).lateral[0]
    value, grad = jax.value_and_grad(lateral)(params["radii"])
    out = response(cell.disc.reference_points(params)[None])
    assert int(out.status[0]) == 1 and bool(np.all(np.asarray(out.valid) == 1.0))
    assert float(out.critical[0]) == pytest.approx(-0.065, abs=0.005)  # docs' -6.5%
    assert float(-(value - 1.0) / -0.1) < 0.0  # auxetic after the bifurcation
    dr = jnp.tile(jnp.array([0.3, 1.0, 0.3] * 4), (4, 1))
    h = 1e-4
    fd = (lateral(params["radii"] + h * dr) - lateral(params["radii"] - h * dr)) / (2 * h)
    assert float(jnp.sum(grad * dr)) == pytest.approx(float(fd), rel=1e-5)


def test_a_loss_through_an_output_without_a_gradient_is_refused(cell):
    # the path's stress is reported, not differentiated by Response: a loss that reads it would get
    # a zero gradient, so its backward pass says so instead
    from nma.periodic.response import Response

    params, _ = circular_holes(cell, 0.5)
    response = Response(cell, uniaxial("y", -0.02), 1)
    X = cell.disc.reference_points(params)[None]
    stress = lambda X: jnp.sum(response(X).stress)
    with pytest.raises(Exception, match=r"PathOutput.stress carries no gradient"):
        jax.block_until_ready(jax.grad(stress)(X))

    # reading it beside the lateral stretch, without differentiating it, is fine
    def both(X):
        out = response(X)
        return out.lateral[0] + jax.lax.stop_gradient(jnp.sum(out.stress))

    assert np.isfinite(np.asarray(jax.grad(both)(X))).all()


def test_refined_resolve_maps_the_same_design_and_scores_it(cell, holes):
    # a design's parameters at 8 x 4 give the same geometry (knot insertion is exact: Boehm 1980),
    # so the same porosity and pores; its path is then followed and scored there
    from nma.periodic.designs import porosity
    from nma.tasks.periodic import periodic_poisson
    from nma.tasks.periodic_schema import PeriodicPoissonTask

    scene = {**square_array(2, 2), "porosity": 0.5}
    fine = periodic_cell(scene, fidelity={"ctrl_per_patch": 8, "quad_points": 4})
    patches = np.repeat(np.arange(cell.disc.mesh.n_patches), 25)
    grid = np.stack(np.meshgrid(*[np.linspace(0.0, 1.0, 5)] * 2), -1).reshape(-1, 2)
    xi = np.tile(grid, (cell.disc.mesh.n_patches, 1))

    def at(c):  # material points on every patch, pores' edges included
        idx, w = c.disc.mesh.material_points(patches, xi)
        return np.einsum("nk,nkd->nd", w, np.asarray(c.disc.reference_points(holes))[idx])

    assert np.max(np.abs(at(fine) - at(cell))) < 1e-12
    task = periodic_poisson(PeriodicPoissonTask(steps=5), cell)
    r = task.refined(fine, np.asarray(holes["radii"])[None])
    assert r["porosity"][0] == pytest.approx(porosity(cell, holes), abs=1e-12)
    assert r["fidelity"]["ctrl_per_patch"] == 8 and r["fidelity"]["quad_points"] == 4
    assert r["failed_solves"] == 0 and r["invalid_states"] == 0 and r["checked_states"] == 5
    assert r["value"] == pytest.approx(abs(r["reached"][0] - task.cfg.target), rel=1e-12)
    # the circles at 8 control points: -0.21 at -10%, bifurcating at -6.4%
    # (docs/how-to/periodic-metamaterials.md); -0.149 at the training fidelity
    assert r["baseline_poisson"] == pytest.approx(-0.21, abs=0.005)
    assert r["baseline_critical_strain"] == pytest.approx(-0.064, abs=0.001)
    assert task.baseline_poisson == pytest.approx(-0.149, abs=0.002)
