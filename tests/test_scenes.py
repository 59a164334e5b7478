import jax.numpy as jnp
import numpy as np
import pytest

from nma import config
from nma.discretise import Resolution, discretise
from nma.schema import scene_from_config
from nma.mechanics.energy import quadrature

# Patch, point and DOF counts of the authors' five scenes, measured by building them with their code
SIZES = {
    "translation": (97, 1761, 3462),
    "rotation_single": (193, 3481, 6902),
    "rotation_double": (193, 3481, 6850),
    "shape_matching": (172, 3112, 6096),
    "digital_mnist": (126, 2245, 4374),
}


@pytest.mark.parametrize("name", sorted(SIZES))
def test_paper_scene_sizes(name):
    disc = discretise(scene_from_config(config.load("scene", name)))
    assert (disc.mesh.n_patches, disc.mesh.n_points, disc.boundary.n_dofs) == SIZES[name]


def test_scene_holds_only_what_it_needs():
    params = lambda n: set(discretise(scene_from_config(config.load("scene", n))).init_params())
    assert params("translation") == {"radii"}
    assert params("rotation_double") == {"radii", "corners"}
    assert params("shape_matching") == {"radii", "corners", "pore_radii"}
    assert params("digital_mnist") == {"radii", "colours"}


def test_empty_and_solid_cells():
    cfg = {"name": "mini", "cells": ["PS", ".P"], "pinned": [[5, 0], [10, 0]]}
    disc = discretise(scene_from_config(cfg))
    assert disc.mesh.n_patches == 4 + 1 + 4  # two porous cells, one solid, one empty


def test_design_map_is_valid_across_the_radius_box():
    disc = discretise(scene_from_config(config.load("scene", "rotation_double")))
    p = disc.init_params()
    from nma.mechanics.energy import quadrature

    for r in (0.1, 0.9):
        q = {
            **p,
            "radii": jnp.full_like(p["radii"], r),
            "corners": jnp.full_like(p["corners"], 2.25),
        }
        assert float(jnp.min(quadrature(disc.solid, disc.reference_points(q)).det)) > 0


@pytest.mark.parametrize(
    "bad, message",
    [
        ({"radii_init": 1.2}, "radii_init"),
        ({"radii_bounds": [0.5, 1.5]}, "radii_bounds"),
        ({"radii_bounds": [0.0, 0.9]}, "radii_bounds"),
        ({"cells": ["PX"]}, "unknown cell tokens"),
        ({"corner_box": 3.0}, "corner_box"),
    ],
)
def test_bad_scene_config_names_the_field(bad, message):
    cfg = {"name": "bad", "cells": ["PP"], "pinned": [[0, 0]], **bad}
    with pytest.raises(ValueError, match=message):
        scene_from_config(cfg)


PRESS = {"name": "press", "segment": [[0, 2], [0, 8]], "actuation": 0, "direction": [1, 0]}


@pytest.mark.parametrize(
    "scene, message",
    [
        # a floating body: the stiffness is singular (one pin leaves a rotation, a sliding support a
        # translation)
        (
            {"cells": ["PP"], "pinned": [[0, 0]]},
            r"scene.pinned .* free to move .* nothing stops it rotating about \(0, 0\)",
        ),
        (
            {"cells": ["PP"]},
            r"nothing stops it moving along \(1, 0\) or moving along \(0, 1\) or rotating",
        ),
        (
            {"cells": ["PP"], "supports": [{"segment": [[0, 0], [10, 0]], "kind": "sliding"}]},
            r"nothing stops it moving along \(1, 0\);",
        ),
        # an actuated group inside the material, off the grid lines, beyond the cells
        (
            {
                "cells": ["PPP"],
                "pinned": [[0, 0], [5, 0]],
                "groups": [{**PRESS, "segment": [[5, 0], [5, 5]]}],
            },
            r"scene.groups of group press \[\[5, 0\], \[5, 5\]\] must lie on the material's outer "
            r"boundary; between 0 and 5 it has material on both sides",
        ),
        (
            {
                "cells": ["PPP"],
                "pinned": [[0, 0], [5, 0]],
                "groups": [{**PRESS, "segment": [[7, 3], [7, 3]]}],
            },
            "it runs along no cell boundary",
        ),
        (
            {"cells": ["PP"], "supports": [{"segment": [[0, 0], [20, 0]]}]},
            r"scene.supports\[0\] .* reaches beyond the cells",
        ),
        (
            {
                "cells": ["P.", "P."],
                "pinned": [[0, 0], [5, 0]],
                "groups": [{**PRESS, "segment": [[10, 0], [10, 5]]}],
            },
            "between 0 and 5 it has no material on either side",
        ),
        # a direction of (0, 0); two groups meeting with different motions; a support under a group
        (
            {
                "cells": ["PP"],
                "pinned": [[0, 0], [5, 0]],
                "groups": [{**PRESS, "direction": [0, 0]}],
            },
            r"scene.groups.direction of group press must not be \[0, 0\]",
        ),
        (
            {
                "cells": ["PP", "PP"],
                "groups": [
                    PRESS,
                    {**PRESS, "name": "other", "segment": [[0, 8], [0, 10]], "actuation": 1},
                ],
            },
            "scene.groups: group press and group other touch but prescribe different motions",
        ),
        (
            {"cells": ["PP", "PP"], "groups": [PRESS], "supports": [{"segment": [[0, 0], [0, 2]]}]},
            r"group press and scene.supports\[0\] touch",
        ),
        # a cell grid in several pieces (cells touching at a corner only are apart)
        (
            {"cells": ["P.", ".P"], "pinned": [[0, 0], [5, 0]]},
            r"scene.cells must be one piece .* \[\(2, 2\)\], counted from the top left",
        ),
        (
            {"cells": ["P", "."], "supports": [{"segment": [[0, 0], [5, 5]]}]},
            "horizontal or vertical segment",
        ),
    ],
)
def test_physically_wrong_scenes_are_refused(scene, message):
    """Well formed but physically wrong: refused when the scene is built, before any work."""
    with pytest.raises(ValueError, match=message):
        scene_from_config({"name": "wrong", **scene})


def test_supports_hold_a_body_without_pins(simulator):
    """A 2 x 1 strip clamped along its left edge and sliding along its bottom, pulled at its right
    edge (which meets the sliding bottom at (10, 0): x moved, y held by both, no contradiction): the
    clamped points do not move, the sliding ones only along the bottom, and the pull stretches
    it."""
    from nma.mechanics.material import material
    from nma.simulator import Simulator

    cfg = {
        "name": "strip",
        "cells": ["PP"],
        "groups": [{**PRESS, "segment": [[10, 0], [10, 5]]}],
        "supports": [
            {"segment": [[0, 0], [0, 5]], "kind": "clamped"},
            {"segment": [[5, 0], [10, 0]], "kind": "sliding"},
        ],
    }
    sim = Simulator(discretise(scene_from_config(cfg), Resolution(5, 3)), "superlu")
    X = np.asarray(sim.reference_points(sim.init_params()))
    u = np.asarray(sim.solve(sim.init_params(), jnp.array([0.5]), material(0.07, 0.3)).u)
    left, bottom = np.abs(X[:, 0]) < 1e-9, (np.abs(X[:, 1]) < 1e-9) & (X[:, 0] > 5 - 1e-9)
    assert np.all(u[left] == 0.0) and np.all(u[bottom, 1] == 0.0)
    assert np.max(np.abs(u[bottom & (X[:, 0] < 10 - 1e-9), 0])) > 1e-3  # free to slide
    assert np.all(u[np.abs(X[:, 0] - 10) < 1e-9, 0] == 0.5)


def test_fidelity_validation():
    from nma.schema import Fidelity

    with pytest.raises(ValueError, match="quad_points"):
        Fidelity(5, 0)
    with pytest.raises(ValueError, match="ctrl_per_patch"):
        Fidelity(7, 3)
    for grading in (0.5, 4.5):
        with pytest.raises(ValueError, match=r"fidelity.grading .* \[1, 4\]"):
            Fidelity(8, 3, grading=grading)


@pytest.mark.parametrize("grading", [1.0, 3.0])
def test_refined_discretisation_keeps_geometry(grading):
    """Refined (uniformly or with graded knots) the geometry is the same map, and graded patches
    still meet point to point (as many merged points as uniform knots give)."""
    spec = scene_from_config(config.load("scene", "translation"))
    coarse, fine = (
        discretise(spec, Resolution(5, 3)),
        discretise(spec, Resolution(8, 3, grading=grading)),
    )
    from nma.geometry.sampling import sample_positions

    Xc = coarse.reference_points(coarse.init_params())
    Xf = fine.reference_points(fine.init_params())
    np.testing.assert_allclose(
        sample_positions(coarse.mesh, Xc, 7), sample_positions(fine.mesh, Xf, 7), atol=1e-12
    )
    assert fine.mesh.n_points == discretise(spec, Resolution(8, 3)).mesh.n_points


def test_graded_knots_describe_the_same_body():
    """Graded knots re-parametrise, they do not change the body: at 8 x 3 with grading 3 against
    uniform knots, the boundary curves (sampled, as Bezier segments, as one DXF spline), their
    enclosed areas, the tracked points, the pore's boundary points and a traction's total force and
    moment are the same, and the rest state passes the validity check."""
    from scipy.interpolate import BSpline

    from nma.geometry.bspline import basis_matrix
    from nma.geometry.outline import Outline, bezier_segments, loop_spline, sample_loop
    from nma.geometry.scene import cooks_membrane
    from nma.geometry.validity import StateChecker

    for name in ("translation", "shape_matching"):
        spec = scene_from_config(config.load("scene", name))
        uniform, graded = (discretise(spec, Resolution(8, 3, grading=g)) for g in (1.0, 3.0))
        X = {d: np.asarray(d.reference_points(d.init_params())) for d in (uniform, graded)}
        outlines = [Outline.of(d.mesh, X[d]) for d in (uniform, graded)]
        np.testing.assert_allclose(
            outlines[1].enclosed_areas(), outlines[0].enclosed_areas(), rtol=1e-12
        )
        # the same curve: its corners match too
        for a, b in zip(outlines[0].loops, outlines[1].loops):
            np.testing.assert_allclose(b[:, [0, -1]], a[:, [0, -1]], atol=1e-12)
            # each span's Bezier: ends and mid-curve
            bez = bezier_segments(b, 3.0)
            mid = 0.25 * bez[:, 0] + 0.5 * bez[:, 1] + 0.25 * bez[:, 2]
            # per span: its start and its midpoint
            points = sample_loop(b, 2, 3.0).reshape(-1, 2, 2)
            np.testing.assert_allclose(bez[:, 0], points[:, 0], atol=1e-12)
            np.testing.assert_allclose(mid, points[:, 1], atol=1e-12)
            # the DXF spline through the whole loop
            ctrl, knots = loop_spline(b, 3.0)
            t = np.concatenate([k + np.asarray([0.1, 0.5, 0.9]) for k in range(len(b))])
            edge = np.repeat(np.arange(len(b)), 3)
            local = t - edge
            on_edge = np.einsum("nk,nkd->nd", basis_matrix(local, b.shape[1], grading=3.0), b[edge])
            np.testing.assert_allclose(BSpline(knots, ctrl, 2)(t), on_edge, atol=1e-12)
        for key in uniform.tracked:
            np.testing.assert_allclose(
                graded.tracked_points(X[graded])[key],
                uniform.tracked_points(X[uniform])[key],
                atol=1e-12,
            )
        if name == "shape_matching":
            (iu, wu), (ig, wg) = uniform.pore_boundary(), graded.pore_boundary()
            np.testing.assert_allclose(
                np.einsum("nk,nkd->nd", wg, X[graded][ig]),
                np.einsum("nk,nkd->nd", wu, X[uniform][iu]),
                atol=1e-12,
            )
        assert StateChecker(graded.mesh, X[graded]).check(np.zeros_like(X[graded])).valid
    forces = []
    for g in (1.0, 3.0):
        cook = discretise(cooks_membrane(), Resolution(8, 3, grading=g))
        X, f = np.asarray(cook.reference_points({})), cook.boundary.external_force.reshape(-1, 2)
        forces.append([*f.sum(axis=0), np.sum(X[:, 0] * f[:, 1] - X[:, 1] * f[:, 0])])
    np.testing.assert_allclose(forces[1], forces[0], rtol=1e-12)


@pytest.mark.parametrize("lo, init", [(1e-6, 1e-6), (0.05, 0.999999)])
def test_merging_follows_the_topology_not_the_radii(lo, init):
    """A radius at its bound must not merge a pore's sides into one point (nor split anything)."""
    cfg = {
        **config.load("scene", "translation"),
        "radii_bounds": [lo, 0.999999],
        "radii_init": init,
    }
    disc = discretise(scene_from_config(cfg))
    assert (disc.mesh.n_patches, disc.mesh.n_points, disc.boundary.n_dofs) == SIZES["translation"]


@pytest.mark.parametrize("scene", ["rotation_double", "shape_matching"])
def test_projection_keeps_every_cell_convex(scene):
    """The paper's corner box (0.45 of a cell) admits non-convex cells (and a central polygon that
    is not star-shaped); projection never does, and lets a valid step through whole (shape
    matching's central polygon has straight corners: a turn-based test there once froze every
    corner)."""
    import jax

    from nma.geometry.design import MIN_TURN

    disc = discretise(scene_from_config(config.load("scene", scene)))
    design, p = disc.design, disc.init_params()
    assert float(jnp.min(design.corner_turns(p))) == pytest.approx(1.0)
    for seed in range(5):
        step = 3.0 * jax.random.normal(jax.random.PRNGKey(seed), p["corners"].shape)
        q = design.project({**p, "corners": p["corners"] + step}, p)
        assert float(jnp.min(design.corner_turns(q))) >= MIN_TURN - 1e-9
        assert float(jnp.max(jnp.abs(q["corners"]))) <= 2.25
        assert float(jnp.min(quadrature(disc.solid, disc.reference_points(q)).det)) > 0
    small = {**p, "corners": p["corners"] + 0.1}
    # a valid step stays
    np.testing.assert_array_equal(design.project(small, p)["corners"], small["corners"])
    unprojected = {**p, "corners": jnp.clip(p["corners"] + step, -2.25, 2.25)}
    # the box alone would have folded a cell
    assert float(jnp.min(design.corner_turns(unprojected))) < 0


def test_pore_corner_angles():
    """A square pore (every radius 0.5) has 90 deg corners.  Raising one corner radius to 0.7 moves
    that corner along the cell's diagonal: in a unit cell with its bottom-left node at the origin
    (angles do not depend on the cell's size, and by the square's symmetry any corner will do: the
    test moves the top-right one), the corner
    goes to (0.15, 0.15) and its two walls leave it towards the next wall points (0.375, 0.25) and
    (0.25, 0.375) (each 0.5 of the way from the centre to the quarter points of the cell's sides),
    so the pore's angle there is 90 deg - 2 atan(0.1 / 0.225) = 42.07 deg; the cell's other corners
    stay 90. Lowered to 0.3 instead, the corner goes to (0.35, 0.35), inside the line between those
    wall points: the wall dents into the pore, whose angle there is 90 deg + 2 atan(0.1 / 0.025) =
    241.93 deg."""
    from nma.geometry.design import GridDesign

    design = GridDesign.from_spec(scene_from_config(config.load("scene", "rotation_single")))
    params = {"radii": jnp.full((len(design.porous), 16), 0.5)}
    np.testing.assert_allclose(design.pore_corner_angles(params), 90.0, atol=1e-9)
    cell, side = 10, 2  # the corner of side 2 (top): the cell's top-right node
    sharp = design.pore_corner_angles({"radii": params["radii"].at[cell, 4 * side].set(0.7)})
    expected = np.full(sharp.shape, 90.0)
    expected[cell, side] = 90.0 - 2.0 * np.degrees(np.arctan(0.1 / 0.225))
    np.testing.assert_allclose(sharp, expected, atol=1e-9)
    dented = design.pore_corner_angles({"radii": params["radii"].at[cell, 4 * side].set(0.3)})
    expected[cell, side] = 90.0 + 2.0 * np.degrees(np.arctan(0.1 / 0.025))
    np.testing.assert_allclose(dented, expected, atol=1e-9)


def test_round_pore_corners():
    """scene.round_pore_corners: 3 design radii per side, each corner's derived so that the walls
    meet tangent.  A square pore's sides at radius 0.5 put the corner's neighbouring control points
    at (0.25, -0.5) and (0.5, -0.25) of a cell [-1, 1]^2 (half of the way from the centre to the
    points a quarter along each side); the chord between them, x - y = 0.75, crosses the diagonal
    towards the node (1, -1) at radius 0.375.  On a random design every pore corner is 180 deg (no
    re-entrant corner), and the derived corner radius stays inside the cell."""
    from nma.geometry.design import GridDesign

    spec = config.load("scene", "shape_matching")
    design = GridDesign.from_spec(scene_from_config({**spec, "round_pore_corners": True}))
    p = design.init_params()
    assert p["radii"].shape == (len(design.porous), 12) and p["pore_radii"].shape == (
        3 * len(design.central),
    )
    square = {**p, "radii": jnp.full_like(p["radii"], 0.5)}
    nets = np.asarray(design.nets(square))[: 4 * len(design.porous)].reshape(
        len(design.porous), 4, 5, 5, 2
    )
    nodes = design.nodes[design.porous]
    centre = nodes.mean(axis=1)
    np.testing.assert_allclose(
        nets[:, :, 0, -1], centre[:, None] + 0.375 * (nodes - centre[:, None]), atol=1e-12
    )
    geom = design.random_params(np.random.default_rng(0), 1.0)
    np.testing.assert_allclose(design.pore_corner_angles(geom), 180.0, atol=1e-6)
    nets = np.asarray(design.nets(geom))[: 4 * len(design.porous)].reshape(
        len(design.porous), 4, 5, 5, 2
    )
    moved = np.asarray(design.node_positions(geom))[design.porous]
    centre = moved.mean(axis=1)
    radius = np.linalg.norm(nets[:, :, 0, -1] - centre[:, None], axis=-1) / np.linalg.norm(
        moved - centre[:, None], axis=-1
    )
    assert 0.0 < radius.min() and radius.max() < 1.0
    sharp = GridDesign.from_spec(scene_from_config(spec))
    assert (
        np.min(sharp.pore_corner_angles(sharp.random_params(np.random.default_rng(0), 1.0))) < 30.0
    )


@pytest.mark.parametrize(
    "task, actuations",
    [
        ("translation", [[3.0, -1.0], [-2.0, -3.5]]),
        pytest.param(
            "rotation_double",
            [[2.5, -1.0], [-1.5, 2.0]],
            # the same rule on another scene
            marks=pytest.mark.slow,
        ),
    ],
)
def test_frozen_floor_holds_by_symmetry(simulator, task, actuations):
    """The frozen initial design's floor rests on a symmetry: its pointer moves only sideways
    (translation), its stick does not turn (rotation), whatever the actuations."""
    import jax.numpy as jnp

    from nma.mechanics.material import material
    from nma import tasks  # noqa: F401  (declares the tasks)
    from nma.registry import TASKS
    from nma.schema import TASK_SCHEMAS, build

    sim = simulator(task, quad_points=3)
    t = TASKS.get(task)(build(TASK_SCHEMAS[task], config.load("task", task)), sim)
    geom = sim.init_params()
    X = sim.reference_points(geom)
    for d in actuations:
        mat = material(0.07, 0.3)
        sol = sim.solve(geom, jnp.asarray(d), mat)
        out = np.asarray(t.observe(sim, geom, X, sol.u, mat))
        assert np.max(np.abs(sol.u)) > 0.5  # it does deform
        if task == "translation":
            assert abs(out[1] - float(t.start[1])) < 1e-9
        else:
            # the stick stays level
            np.testing.assert_allclose(out[1, 1] - out[0, 1], 0.0, atol=1e-9)
    floor, why = t.frozen_floor()
    # doing nothing is no better than the floor
    assert why and 0.0 < floor <= t.rest_metric(sim, mat) + 1e-12
