"""Periodic cells (nma.periodic): the tie across opposite edges, mixed macroscopic control, the
effective response against closed forms, and the square array of circular holes' pattern
transformation."""

import json
import subprocess
import sys

import h5py

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.spatial import cKDTree

from nma.errors import ConfigError
from nma.periodic import (
    MacroLoad,
    biaxial,
    circular_holes,
    follow,
    periodic_cell,
    shear,
    square_array,
    uniaxial,
)


@pytest.fixture(scope="module")
def solid():
    return periodic_cell(square_array(1, 1, solid=True))


@pytest.fixture(scope="module")
def porous():
    """One cell of the square array of circular holes at porosity 0.5, at 3 Gauss points."""
    cell = periodic_cell(square_array(1, 1), {"quad_points": 3})
    params, phi = circular_holes(cell, 0.5)
    return cell, params, phi


def _plane_tangent(cell):
    """The law's own plane-strain tangent at rest, C_ijkl = dP_ij/dF_kl at F = I (as
    Material.plane_moduli reads it)."""
    return np.asarray(cell.disc.material.point_terms(cell.material_params)[2](jnp.eye(2)))


def test_solid_cell_at_small_strain_has_the_law_tangent_modulus_and_poisson(solid):
    # uniaxial stress in plane strain: E' = C1111 - C1122^2 / C2222, nu' = C1122 / C2222
    # (nu / (1 - nu) and E / (1 - nu^2) for an isotropic law with a 3D-consistent volume term)
    C = _plane_tangent(solid)
    for axis, (a, b) in (("x", (0, 1)), ("y", (1, 0))):
        path = follow(solid, uniaxial(axis, -1e-5), steps=1)
        E_expected = C[a, a, a, a] - C[a, a, b, b] ** 2 / C[b, b, b, b]
        nu_expected = C[a, a, b, b] / C[b, b, b, b]
        k = 3 * a  # F11 or F22 in COMPONENTS order
        assert path.P[0, k] / path.strain_axial[0] == pytest.approx(E_expected, rel=1e-4)
        assert path.poisson[0] == pytest.approx(nu_expected, rel=1e-4)
        assert path.valid.all() and path.lowest[0] > 0


def _homogeneous_uniaxial(cell, lam1):
    """The exact homogeneous plane-strain uniaxial state F = diag(lam1, lam2) with P22 = 0, by
    root finding on the law's first Piola-Kirchhoff stress: (lam2, P11)."""
    P = cell.disc.material.point_terms(cell.material_params)[1]
    P_of = lambda l2: np.asarray(P(jnp.diag(jnp.array([lam1, l2]))))
    lam2 = brentq(lambda l2: P_of(l2)[1, 1], 0.5, 2.0, xtol=1e-14)
    return lam2, P_of(lam2)[0, 0]


@pytest.mark.parametrize("material", [None, "yeoh"])
def test_solid_cell_at_large_strain_follows_the_exact_homogeneous_response(solid, material):
    # a pore-free cell deforms homogeneously: its response is the law's own uniaxial plane-strain
    # state, found here by root finding on P22 = 0 (the paper's Neo-Hookean, and Yeoh's law)
    cell = (
        solid if material is None else periodic_cell(square_array(1, 1, solid=True), None, material)
    )
    path = follow(cell, uniaxial("x", -0.2), steps=4)
    assert path.completed and path.valid.all()
    for k in range(len(path.t)):
        lam2, P11 = _homogeneous_uniaxial(cell, path.F[k, 0])
        assert path.F[k, 3] == pytest.approx(lam2, rel=1e-9)
        assert path.P[k, 0] == pytest.approx(P11, rel=1e-7)
        assert abs(path.P[k, 3]) < 1e-9 * abs(P11)


def test_porous_cell_is_periodic_to_round_off_under_shear(porous):
    cell, params, _ = porous
    path = follow(cell, shear(0.15, free_normal=True), steps=3, params=params)
    assert path.completed and path.valid.all()
    X = np.asarray(cell.reference_points(params))
    pairs = cell.tied_pairs()
    assert len(pairs) > 0
    assert path.strain_axial[-1] == pytest.approx(0.15)  # shear's axial strain is gamma
    for k in range(len(path.t)):
        H = path.F[k].reshape(2, 2) - np.eye(2)
        u = path.u[k]
        jump = u[pairs[:, 0]] - u[pairs[:, 1]] - (X[pairs[:, 0]] - X[pairs[:, 1]]) @ H.T
        assert np.max(np.abs(jump)) < 1e-12 * cell.period.max()
        # the free normal components carry zero average stress (their energy is minimised)
        assert np.max(np.abs(path.P[k, [0, 3]])) < 1e-7 * abs(path.P[k, 1])


def test_average_stress_is_the_energy_derivative_by_central_differences(porous):
    # Hill's lemma: at equilibrium dW_avg/dF_bar = <P>, whatever the fluctuation does
    cell, params, _ = porous
    F0, h = np.array([0.96, 0.03, 0.0, 1.02]), 1e-4
    general = lambda F: MacroLoad("general", F, (), 0)
    P = follow(cell, general(F0), steps=1, params=params).P[0]
    for c in range(4):
        e = np.zeros(4)
        e[c] = h
        Wp, Wm = (follow(cell, general(F0 + s * e), 1, params).energy[0] for s in (1, -1))
        assert (Wp - Wm) / (2 * h) == pytest.approx(P[c], abs=1e-6 * np.abs(P).max())


def test_scene_whose_opposite_edges_do_not_match_is_refused():
    with pytest.raises(ConfigError, match="not periodic.*no partner"):
        periodic_cell({"name": "notch", "cells": "PP\nP."})


def test_periodic_scene_with_supports_or_groups_is_refused():
    held = {
        "name": "held",
        "cells": "PP",
        "supports": [{"segment": [[0, 0], [10, 0]], "kind": "clamped"}],
    }
    with pytest.raises(ConfigError, match="scene.supports must be empty"):
        periodic_cell(held)
    with pytest.raises(ConfigError, match="scene.groups must be empty"):
        periodic_cell("translation")  # a finite scene, its sides pushed by actuated groups
    with pytest.raises(ConfigError, match="F12 and F21 cannot both be free"):
        MacroLoad("spin", np.array([1.0, 0.0, 0.0, 1.0]), (1, 2), 0)
    # what a periodic path would ignore: a weight per cell, points to track
    with pytest.raises(ConfigError, match="scene.gravity must be null in a periodic scene"):
        periodic_cell({"name": "heavy", "cells": "PP", "gravity": [0.0, -1.0]})
    with pytest.raises(ConfigError, match="scene.tracked must be empty in a periodic scene"):
        periodic_cell({"name": "watched", "cells": "PP", "tracked": {"c": [5.0, 5.0]}})


def test_circular_holes_reach_the_target_porosity(porous):
    """0.5 is reached; 0.74, beyond the largest circles the radii bounds allow (0.659 on the
    square array's cell), is refused rather than approximated."""
    assert porous[2] == pytest.approx(0.5, abs=1e-6)
    with pytest.raises(ConfigError, match=r"porosity 0.74 is out of reach .* to 0.659"):
        circular_holes(porous[0], 0.74)


# the 2 x 2 supercell; its one interior grid node (the cells' shared corner) may move by 0.05
SUPERCELL = {**square_array(2, 2), "corner_box": 0.05}


@pytest.fixture(scope="module")
def supercell():
    """A 2 x 2 supercell of the square array of circular holes at porosity 0.5, at 3 Gauss
    points."""
    cell = periodic_cell(SUPERCELL, {"quad_points": 3})
    return cell, circular_holes(cell, 0.5)[0]


def test_square_array_2x2_buckles_and_its_poisson_ratio_turns_negative(supercell):
    # Mullin et al., PRL 99, 084301 (2007); Bertoldi et al., Adv. Mater. 22, 361 (2010), Fig. 2:
    # under uniaxial compression a square array of circular holes at porosity ~0.5 buckles into
    # alternating ellipses (a 2 x 2 cell pattern) and its Poisson's ratio falls below zero
    cell, params = supercell
    path = follow(cell, uniaxial("y", -0.1), steps=5, params=params)
    assert path.completed and path.valid.all()
    assert path.critical is not None and -0.1 < path.critical["strain"] < -0.01
    after = path.strain_axial < path.critical["strain"]
    assert np.all(np.diff(path.poisson[after]) < 0)
    assert path.poisson[-1] < 0 < path.poisson[0]
    assert np.all(path.lowest > 0)  # every reported state on the followed branch is stable
    # the mode alternates: neighbouring cells' pores turn opposite ways, so the mode is not
    # periodic on a single cell (its displacement differs one cell apart)
    mode, X = path.critical["mode_u"], np.asarray(cell.reference_points(params))
    shifted = cKDTree(X).query(X + [1.0, 0.0])
    inside = shifted[0] < 1e-9
    assert np.max(np.abs(mode[inside] + mode[shifted[1][inside]])) < 1e-6 * np.abs(mode).max()


def test_symmetric_path_past_the_bifurcation_is_a_saddle(supercell):
    # without leaving the saddle the path stays on the unbuckled branch: an unstable equilibrium
    # (a negative eigenvalue), its Poisson's ratio still positive
    cell, params = supercell
    path = follow(cell, uniaxial("y", -0.1), steps=2, params=params, escape=False)
    assert path.completed and path.critical is not None
    assert path.lowest[-1] < 0 and path.poisson[-1] > 0


def _simulate(tmp_path, *overrides):
    cmd = [sys.executable, "-m", "nma.simulate", f"hydra.run.dir={tmp_path}", *overrides]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600)


def test_simulate_follows_a_periodic_scene_and_writes_path_fields_figure(tmp_path):
    # the shipped periodic scene through the Hydra command: the JSON line's path, the critical
    # strain of the supercell's bifurcation (as test_square_array_2x2_buckles... finds it), the
    # fields of the last state and of the mode, and the figure
    proc = _simulate(
        tmp_path, "scene=square_array", "load=uniaxial_y", "load.strain=-0.1", "load.steps=4"
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    (line,) = proc.stdout.strip().splitlines()
    result = json.loads(line)
    assert result["periodic"] and result["converged"] and result["valid"]
    assert result["porosity"] == pytest.approx(0.5, abs=1e-6)
    assert result["load"]["free"] == ["F11"]
    steps = result["steps"]
    assert [k["strain"] for k in steps] == pytest.approx([-0.025, -0.05, -0.075, -0.1])
    assert all(k["valid"] and k["stress"] < 0 for k in steps)
    assert all(abs(k["P"]["F11"]) < 1e-9 * abs(k["stress"]) for k in steps)  # uniaxial stress
    assert steps[0]["poisson"] > 0 > steps[-1]["poisson"]
    crit = result["critical"]
    assert -0.1 < crit["strain"] < -0.01 and crit["lowest_before"] > 0 > crit["lowest_after"]
    with h5py.File(tmp_path / "fields.h5") as f:
        assert f.attrs["F_bar"][3] == pytest.approx(0.9) and np.all(f["fields/J"][()] > 0)
    with h5py.File(crit["mode"]) as f:
        assert f.attrs["critical_strain"] == pytest.approx(crit["strain"])
    assert (tmp_path / "path.png").stat().st_size > 10_000


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["scene=square_array"], "scene=square_array is periodic: give its macroscopic load"),
        (["scene=translation", "load=shear"], "load=shear loads a periodic scene"),
        (
            ["scene=square_array", "load=shear", "load.lateral_strain=0.1"],
            "load.lateral_strain is biaxial's second strain",
        ),
        (["scene=square_array", "load=uniaxial_y", "load.steps=0"], r"load.steps must be"),
        (
            ["scene=square_array", "load=uniaxial_y", "dynamics=newmark"],
            "scene=square_array is periodic, and its load path is static",
        ),
        (
            ["scene=square_array", "load=uniaxial_y", "solver.rtol=1e-8"],
            r"solver.rtol=1e-08: scene=square_array is periodic, .* takes no solver settings",
        ),
    ],
)
def test_simulate_refuses_what_a_periodic_scene_cannot_take(overrides, message):
    from nma import cli
    from nma.simulate import validate

    with pytest.raises(ConfigError, match=message):
        validate(cli.without_hydra(cli.compose("simulate", overrides)))


def test_training_and_the_simulator_refuse_a_periodic_scene():
    from conftest import compose_cfg
    from nma.simulator import Simulator
    from nma.train.runs import validate

    with pytest.raises(ConfigError, match="scene=square_array is periodic.*finite scene"):
        validate(compose_cfg("scene=square_array"))
    with pytest.raises(ConfigError, match="scene square_array is periodic: the Simulator"):
        Simulator.from_config("square_array")


def test_effective_response_gradient_matches_central_differences(porous):
    # implicit differentiation of the reduced equations (nma.periodic.gradients) against central
    # differences of whole path solves, along every radius at once and along E
    from nma.periodic.gradients import path_gradient

    cell, params, _ = porous
    load, h = uniaxial("y", -0.03), 1e-5
    solve = lambda params, mat=None: follow(cell, load, 2, params, mat, check_states=False)
    path = solve(params)
    m = np.asarray(cell.material_params)
    for kind, component, read in (
        ("stress", 3, lambda r: r.P[1, 3]),
        ("free", 0, lambda r: r.F[1, 0]),
    ):
        q, d_params, d_mat = path_gradient(cell, load, path, 1, params, kind, component)
        assert q == pytest.approx(read(path), rel=1e-10)
        up, down = ({"radii": params["radii"] + s * h} for s in (1, -1))
        fd = (read(solve(up)) - read(solve(down))) / (2 * h)
        assert float(jnp.sum(d_params["radii"])) == pytest.approx(fd, rel=1e-5)
        E_up, E_down = (m * [1 + s * h, 1] for s in (1, -1))
        fd = (read(solve(params, E_up)) - read(solve(params, E_down))) / (2 * h * m[0])
        assert d_mat[0] == pytest.approx(fd, rel=1e-5, abs=1e-9 * abs(q))


def test_effective_response_gradient_in_a_corner_move_matches_central_differences(supercell):
    # the supercell's shared interior corner moved off the square grid (a sheared pattern): the
    # lateral stretch's derivative in that move by implicit differentiation against central
    # differences of whole path solves
    from nma.periodic.gradients import path_gradient

    cell, params = supercell
    params = {**params, "corners": jnp.array([[0.02, -0.01]])}
    load, h = uniaxial("y", -0.03), 1e-5
    solve = lambda params: follow(cell, load, 2, params, check_states=False)
    path = solve(params)
    _, d_params, _ = path_gradient(cell, load, path, 1, params, "free", 0)
    for axis in (0, 1):
        up, down = (
            {**params, "corners": params["corners"].at[0, axis].add(s * h)} for s in (1, -1)
        )
        fd = (solve(up).F[1, 0] - solve(down).F[1, 0]) / (2 * h)
        assert float(d_params["corners"][0, axis]) == pytest.approx(fd, rel=1e-5, abs=1e-9)


def test_bad_load_or_steps_are_refused_naming_the_field(solid):
    with pytest.raises(ConfigError, match=r"steps must be an integer in \[1, 10000\], got 0"):
        follow(solid, uniaxial("x", -0.1), steps=0)
    with pytest.raises(ConfigError, match=r"load.axis must be one of \['x', 'y'\]"):
        uniaxial("z", -0.1)
    with pytest.raises(
        ConfigError, match=r"load.strain must be a nominal strain in \(-0.9, 10.0\)"
    ):
        uniaxial("x", -1.5)
    with pytest.raises(ConfigError, match=r"load.strain must not be 0"):
        uniaxial("y", 0.0)
    with pytest.raises(ConfigError, match=r"load.strain must not be 0"):
        shear(0.0)
    with pytest.raises(ConfigError, match=r"load.lateral_strain must be a nominal strain"):
        biaxial(0.1, -2.0)
    with pytest.raises(ValueError, match=r"params\['radii'\] must have shape \(0, 12\)"):
        follow(solid, uniaxial("x", -0.1), params={"radii": jnp.zeros((1, 12))})


def test_contact_keeps_the_closing_pores_apart_where_without_it_they_cross(supercell):
    # at 30% compression the buckled pores close to slits: without contact their walls pass
    # through each other (nma.geometry.validity says so), with the pores' contact they touch
    cell, params = supercell
    load = uniaxial("y", -0.3)
    without = follow(cell, load, steps=3, params=params)
    assert not without.valid[-1]
    assert any("crosses itself" in p for p in without.problems[-1][1])
    touching = periodic_cell(SUPERCELL, {"quad_points": 3}, contact={"enabled": True})
    path = follow(touching, load, steps=3, params=params)
    assert path.completed and path.valid.all()
    # the walls in contact carry load: the cell stiffens against the one without contact
    assert path.P[-1, 3] < without.P[-1, 3] < 0


@pytest.mark.slow
def test_nearly_incompressible_critical_strain_converges_under_refinement():
    # The square array of circular holes at porosity 0.5 in a nearly incompressible Neo-Hookean
    # solid (nu = 0.49, the mixed formulation), as the elastomers of Mullin et al., PRL 99, 084301
    # (2007) and Bertoldi et al., JMPS 56, 2642 (2008): nma's own critical strain under
    # refinement, 5 -> 8 control points per patch side.  No published critical strain for this
    # geometry could be found in a citable source here (docs/how-to/periodic-metamaterials.md), so
    # the reference is the finer model's value, -0.0642 (measured: 5: -0.06405, 8: -0.06421,
    # 11: -0.06411, with 10 load steps to -10%).
    mat = {"law": "neo_hookean", "E": 1.0, "nu": 0.49, "formulation": "mixed"}
    found = {}
    for n in (5, 8):
        cell = periodic_cell(square_array(2, 2), {"ctrl_per_patch": n, "quad_points": 4}, mat)
        params, _ = circular_holes(cell, 0.5)
        path = follow(cell, uniaxial("y", -0.1), steps=10, params=params)
        assert path.completed and path.valid.all()
        assert path.poisson[0] > 0.3 and path.poisson[-1] < -0.05  # auxetic after buckling
        found[n] = path.critical["strain"]
    assert found[8] == pytest.approx(-0.0642, rel=0.01)
    assert found[5] == pytest.approx(found[8], rel=0.005)


@pytest.mark.slow  # four cells up to 14 control points per patch side: about 20 s
def test_porous_cells_small_strain_moduli_converge_under_refinement():
    """The square array of circular holes at porosity 0.5 (one cell, 4 Gauss points): its
    effective modulus and Poisson's ratio under 1e-5 uniaxial strain at 5, 8, 11 and 14 control
    points per patch side.  The successive changes fall (measured: 1.2e-4, 8e-6, 2e-6 in the
    modulus 0.0229) at an observed order above 2 in the control-point spacing, the quadratic
    splines' O(h^3) in energy-norm terms, and the last change is below 1e-4 relative."""
    ladder, moduli, poisson = (5, 8, 11, 14), [], []
    for m in ladder:
        cell = periodic_cell(square_array(1, 1), {"ctrl_per_patch": m, "quad_points": 4})
        path = follow(cell, uniaxial("y", -1e-5), steps=1, params=circular_holes(cell, 0.5)[0])
        moduli.append(path.P[0, 3] / path.strain_axial[0])
        poisson.append(path.poisson[0])
    for values in (np.array(moduli), np.array(poisson)):
        changes = np.abs(np.diff(values))
        assert np.all(np.diff(changes) < 0), values
        h = 1.0 / (np.array(ladder) - 2.0)  # spans per patch side
        order = np.log(changes[0] / changes[1]) / np.log(h[0] / h[1])
        assert order > 2.0, (values, order)
        assert changes[-1] < 1e-4 * abs(values[-1]), values
