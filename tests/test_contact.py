"""The pores' self-contact (nma/mechanics/contact.py): nothing changes while the pores are open, a
closing pore converges to a touching state with no overlap, and the force, tangent, step bound and
adjoint are the derivatives they claim to be (central differences).

The scene is one porous cell (radii 0.8) pinned at its bottom and pressed down in the middle of its
top: at 4 of its 5 length units the top wall reaches the bottom wall, so without contact the pore's
boundary passes through itself (nma/geometry/validity.py sees it) while the solver reports
convergence."""

import weakref

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma import config
from nma.errors import ConfigError
from nma.discretise import discretise
from nma.schema import scene_from_config
from nma.geometry.validity import StateChecker
from nma.mechanics import contact
from nma.mechanics.energy import energy_force_tangents, quadrature
from nma.mechanics.material import material
from nma.mechanics.options import ContactSettings
from nma.schema import ContactConfig, Fidelity, build
from nma.simulator import Simulator
from nma.solver.assembly import sparse_pattern
from nma.solver.equations import Equations
from nma.solver.linear import DenseBackend
from nma.solver import equations, host, loading
from nma.solver.status import Status
from nma.solver.options import NewtonOptions

CELL = {
    "name": "cell",
    "cells": "P",
    "radii_init": 0.8,
    "pinned": [[0, 0], [5, 0], [2.5, 0]],
    "groups": [
        {"name": "press", "segment": [[1.25, 5], [3.75, 5]], "actuation": 0, "direction": [0, -1]}
    ],
}
MAT = material(0.07, 0.3)
# press depths: the pore's walls 15 x d_hat apart, and pressed onto each other
OPEN, CLOSED = 2.0, 4.0
TIGHT = NewtonOptions(rtol=1e-12, max_iters=500)


def fresh_kernels(monkeypatch):
    """An empty table of compiled kernels (nma.solver.equations.compiled) for the rest of the test:
    those traced from here see its patches (a solver built before keeps its own)."""
    monkeypatch.setattr(equations, "_BY_CONTENT", weakref.WeakValueDictionary())
    monkeypatch.setattr(equations, "_BY_DISC", weakref.WeakKeyDictionary())


@pytest.fixture(scope="module")
def cell():
    spec = scene_from_config(CELL)
    sims = {
        on: Simulator(
            discretise(spec, Fidelity(5, 3), ContactSettings() if on else None), "superlu", TIGHT
        )
        for on in (False, True)
    }
    params = sims[True].init_params()
    X = sims[True].reference_points(params)
    return sims, params, X, StateChecker(sims[True].disc.mesh, X)


def test_the_model_is_the_pores_walls(cell):
    sims, _, X, _ = cell
    model = sims[True].disc.contact
    # one pore, 4 patch edges of 3 knot spans: 12 segments, each paired with all but itself and its
    # 2 neighbours
    assert model.pores == 1 and len(model.segments) == 12 and model.n_blocks == 12 * 9 // 2
    # d_hat: 2% of the pore's width in the scene's canonical design (radii mid-range: 0.5 of the
    # 5-unit cell), a constant of the discretisation while training moves the radii
    assert model.d_hat == pytest.approx(0.02 * 0.5 * 5.0)
    assert sims[True].disc.solid.block_points.shape == (
        sims[False].disc.solid.block_points.shape[0] + model.n_blocks,
        9,
    )


@pytest.mark.slow  # the contact force and tangent tests check in part that open pores add nothing
def test_open_pores_change_nothing(cell):
    """Walls further apart than d_hat: the same equilibrium and the same gradient, to round-off."""
    sims, params, X, _ = cell
    d = jnp.array([OPEN])
    w = jax.random.normal(jax.random.PRNGKey(0), X.shape)

    def loss(sim):
        return lambda p: jnp.sum(w * sim.equilibrium(sim.reference_points(p), d, MAT).u)

    off, on = (sims[k].solve(params, d, MAT) for k in (False, True))
    assert (
        contact.smallest_gap(sims[True].disc.contact, X + on.u, X)
        > 10 * sims[True].disc.contact.d_hat
    )
    np.testing.assert_allclose(on.u, off.u, rtol=0, atol=1e-10)
    g_off, g_on = (jax.grad(loss(sims[k]))(params)["radii"] for k in (False, True))
    np.testing.assert_allclose(g_on, g_off, rtol=1e-10, atol=1e-14)


def test_a_closing_pore_touches_instead_of_passing_through(cell):
    sims, params, X, checker = cell
    d = jnp.array([CLOSED])
    without = sims[False].solve(params, d, MAT)
    # the pore passes through itself
    assert without.converged and not checker.check(without.u).valid
    assert checker.check(without.u).self_crossing == ["pore at (2.5, 2.5)"]
    eq = sims[True].solve(params, d, MAT)
    state = checker.check(eq.u)
    assert eq.converged and state.valid, state.problems()
    gap = contact.smallest_gap(sims[True].disc.contact, X + eq.u, X)
    assert 0 < gap < sims[True].disc.contact.d_hat  # touching: the barrier carries the load


@pytest.mark.slow  # solver.path_rtol's default (0) is what the fast suite runs
def test_a_looser_path_reaches_the_same_touching_state_in_fewer_iterations(cell):
    """solver.path_rtol closes the load steps before the last at a looser residual: the closing
    pore's walls come into contact over several load steps, and the solve ends at the same touching
    state (to the tolerance at full load) in fewer iterations."""
    sims, params, X, checker = cell
    d = jnp.array([CLOSED])
    strict = sims[True].solve(params, d, MAT)
    loose_sim = Simulator(
        sims[True].disc, "superlu", NewtonOptions(rtol=1e-12, path_rtol=1e-4, max_iters=500)
    )
    loose = loose_sim.solve(params, d, MAT)
    assert int(strict.info.load_steps) > 1  # the path is walked in steps: the option acts
    assert loose.converged and checker.check(loose.u).valid
    assert float(loose.info.residual) <= float(loose.info.tolerance)  # the last step meets rtol
    assert int(loose.info.iterations) < int(strict.info.iterations)
    np.testing.assert_allclose(
        loose.u, strict.u, rtol=0, atol=1e-8 * float(jnp.abs(strict.u).max())
    )


# test_a_closing_pore_touches_instead_of_passing_through runs this predictor in part
@pytest.mark.slow
def test_a_predictor_the_walls_stop_keeps_its_load(cell, monkeypatch):
    """A load step's linearised response does not see the barrier until the walls are within d_hat,
    so its time of impact stops it short; the load then goes on without the free dofs
    (nma.solver.loading.past_the_walls) and the correctors press the walls into contact at that
    load.  The same touching state as a path whose load stops with the predictor (the code before),
    in fewer load steps."""
    sims, params, X, checker = cell
    d = jnp.array([CLOSED])
    on = sims[True].solve(params, d, MAT)
    monkeypatch.setattr(loading, "past_the_walls", lambda *args: jnp.zeros(()))
    fresh_kernels(monkeypatch)  # traced without it
    stopped = Simulator(sims[True].disc, "superlu", TIGHT).solve(params, d, MAT)
    assert on.converged and stopped.converged and checker.check(on.u).valid
    assert int(on.info.load_steps) < int(stopped.info.load_steps)
    np.testing.assert_allclose(on.u, stopped.u, rtol=0, atol=1e-8 * float(jnp.abs(stopped.u).max()))


@pytest.mark.slow  # test_solver checks warm starts and their audits in the fast suite
def test_a_warm_start_whose_walls_cross_under_the_new_design_is_redone_from_rest(cell):
    """A warm start carries a kept equilibrium's displacements to a design that has moved since.
    Where the pore's walls, touching in that equilibrium, cross under the new design, the barrier
    (which sees distances, not sides) would hold them crossed: that warm solve converged to a state
    passing through itself (0.28 from the cold answer) before setup checked the walls' time of
    impact on the way from the old design to the new one.  Now it ends at once (WALLS_CROSS) and is
    redone from rest; a start whose walls do not cross is taken."""
    sims, params, X, _ = cell
    d = jnp.array([[CLOSED]])
    warm = Simulator(
        sims[True].disc,
        "superlu",
        NewtonOptions(rtol=1e-12, max_iters=500, warm_start=True, warm_audit=0),
    )
    u_with = warm.equilibrium_batch(X, d, MAT).u[0]  # from rest, kept: the walls touching
    u_without = sims[False].solve(params, d[0], MAT).u  # passes through itself
    stats = warm.warm_starts.stats
    for shift, crosses in ((1.0, True), (0.2, False)):
        moved = X + shift * (u_without - u_with)  # the top wall lowered towards the bottom one
        checker = StateChecker(warm.disc.mesh, moved)
        assert checker.check(u_with).valid != crosses  # the start, under the moved design
        before = dict(stats)
        eq = warm.equilibrium_batch(moved, d, MAT)
        cold = sims[True].equilibrium_batch(moved, d, MAT)
        assert stats["warm_solves"] - before["warm_solves"] == 1
        assert stats["warm_converged"] - before["warm_converged"] == int(not crosses)
        assert int(eq.info.status[0]) == Status.CONVERGED and checker.check(eq.u[0]).valid
        np.testing.assert_allclose(eq.u, cold.u, rtol=0, atol=1e-8 * float(jnp.abs(cold.u).max()))


@pytest.fixture(scope="module")
def touching(cell):
    sims, params, X, _ = cell
    sim = sims[True]
    return sim, params, X, jnp.asarray(sim.solve(params, jnp.array([CLOSED]), MAT).u)


def test_force_and_tangent_against_central_differences(cell, touching):
    sim, _, X, u = touching
    disc = sim.disc
    quad = quadrature(disc.solid, X)
    model, walls, mu = disc.contact, quad.walls, MAT[0] / (2 * (1 + MAT[1]))
    energy = lambda x: contact.energy(model, walls, x, mu)
    e, force, blocks, which, near = contact.force_and_blocks(model, walls, X + u, mu)
    assert float(e) > 0 and float(e) == pytest.approx(float(energy(X + u)), rel=1e-12)
    # the near blocks fill the first slots, in order; the rest are empty (-1, zero)
    which, near = np.asarray(which), int(near)
    assert (
        0 < near < model.n_blocks
        and np.all(np.diff(which[:near]) > 0)
        and np.all(which[near:] == -1)
    )
    assert not np.asarray(blocks)[near:].any()
    rng = np.random.default_rng(1)
    pts = disc.solid.block_points[len(disc.mesh.elem_points.reshape(-1, 9)) :][which[:near]]
    dofs = (2 * pts[:, :, None] + np.arange(2)).reshape(len(pts), 18)
    for _ in range(3):
        v = jnp.asarray(rng.standard_normal(X.shape))
        h = 1e-6
        fd = (energy(X + u + h * v) - energy(X + u - h * v)) / (2 * h)
        assert float(jnp.sum(force * v)) == pytest.approx(float(fd), rel=1e-6)
        # K v from the blocks against the force's central difference
        Kv = np.zeros(2 * disc.mesh.n_points)
        np.add.at(
            Kv,
            dofs,
            np.einsum("eab,eb->ea", np.asarray(blocks)[:near], np.asarray(v).reshape(-1)[dofs]),
        )
        f = lambda x: contact.force_and_blocks(model, walls, x, mu)[1]
        fd_K = (f(X + u + h * v) - f(X + u - h * v)).reshape(-1) / (2 * h)
        np.testing.assert_allclose(Kv, fd_K, rtol=1e-5, atol=1e-7 * np.abs(fd_K).max())
    # the tangents: the elastic blocks (bit for bit those of the same scene without contact), then
    # these
    _, _, kel = energy_force_tangents(disc.solid, quad, u, MAT)
    np.testing.assert_array_equal(kel.contact, blocks)
    np.testing.assert_array_equal(kel.which, which)
    plain = cell[0][False].disc
    np.testing.assert_array_equal(
        kel.elements,
        energy_force_tangents(plain.solid, quadrature(plain.solid, X), u, MAT)[2].elements,
    )
    # the sparse assembly (the near blocks) and the dense one: the same matrix
    K = sparse_pattern(disc, upper=False).matrix(kel).toarray()
    dense = np.asarray(DenseBackend(disc)._matrix(kel, 0.0))
    np.testing.assert_allclose(K, dense, rtol=1e-12, atol=1e-12 * np.abs(dense).max())


# the sparse assembly's contact blocks are checked against dense ones in the fast suite
@pytest.mark.slow
def test_contact_slots_hold_the_near_blocks_or_say_they_cannot(touching, monkeypatch):
    """Tangents with room for fewer contact blocks than are near are incomplete: the assembly
    refuses them; with room for all of them, the same blocks as with a slot for every block.  Newton
    that starts with too few slots asks again with more and ends on the same state (to round-off:
    each room is a
    program of its own)."""
    from nma.solver.batch import HostBatches

    sim, params, X, u = touching
    disc, model = sim.disc, sim.disc.contact
    quad = quadrature(disc.solid, X)
    _, _, full = energy_force_tangents(disc.solid, quad, u, MAT)
    near = int(full.near)
    _, _, few = energy_force_tangents(disc.solid, quad, u, MAT, capacity=near - 1)
    assert not bool(few.complete) and few.which.shape == (near - 1,)
    with pytest.raises(
        RuntimeError, match=f"room for {near - 1} contact blocks, but {near} are near"
    ):
        sparse_pattern(disc, upper=False).matrix(few)
    _, _, room = energy_force_tangents(disc.solid, quad, u, MAT, capacity=near)
    assert bool(room.complete)
    np.testing.assert_array_equal(room.contact, np.asarray(full.contact)[:near])
    np.testing.assert_array_equal(room.which, np.asarray(full.which)[:near])
    d = jnp.array([CLOSED])
    solved = {}
    for slots in (2, None):  # far fewer than touch; every block
        monkeypatch.setattr(host, "CONTACT_SLOTS", slots or model.n_blocks)
        fresh_kernels(monkeypatch)  # the kernels built are this solve's alone
        newton = host.HostNewton(Equations(sim.disc), sim.backend, sim.options)
        u, info, _ = HostBatches(newton, workers=1).forward_batch(
            X[None], d[None], MAT[None], keep=False
        )
        assert int(info.status[0]) == Status.CONVERGED
        # the rooms its linearisations took (None: the kernels that need none, energy and pullback)
        built = equations._BY_DISC[sim.disc]
        rooms = {key[2] for key in built if key[0] == "newton"} - {None}
        solved[slots] = u[0], rooms
    rooms = solved[2][1]  # 2, then 4x as much until they hold the near blocks
    assert (
        2 in rooms
        and max(rooms) >= near
        and rooms <= {min(2 * 4**k, model.n_blocks) for k in range(8)}
    )
    np.testing.assert_allclose(
        solved[2][0], solved[None][0], rtol=0, atol=1e-13 * np.abs(solved[None][0]).max()
    )


# test_backends_agree runs the traced driver, the touching-state tests the host one
@pytest.mark.slow
def test_the_traced_driver_reaches_the_same_touching_state(cell, touching):
    """The dense backend's Newton (one traced while_loop, a batch under vmap) assembles the contact
    blocks from the same Tangents: its touching state is the host driver's, its open one that
    without contact."""
    sims, params, X, _ = cell
    sim, _, _, u = touching
    dense = Simulator(sim.disc, "dense", TIGHT)
    ds = jnp.array([[OPEN], [CLOSED]])
    (us, info) = jax.jit(jax.vmap(dense.equilibrium, in_axes=(None, 0, None)))(X, ds, MAT)
    assert np.all(np.asarray(info.status) == Status.CONVERGED)
    np.testing.assert_allclose(us[1], u, rtol=0, atol=1e-8 * float(jnp.abs(u).max()))
    np.testing.assert_allclose(
        us[0], sims[False].solve(params, ds[0], MAT).u, rtol=0, atol=1e-8 * float(jnp.abs(u).max())
    )


@pytest.mark.slow  # the touching-state tests run this corrector path in part
def test_far_from_equilibrium_newton_takes_normal_stiffness_and_ends_as_exact_does(cell, touching):
    """contact.force_and_blocks(normal=...): the same energy and force, and tangent blocks that keep
    each term's normal stiffness only, positive semi-definite where the exact blocks are not.
    Newton takes them while its residual is large (solver.contact_exact_below) and ends on the same
    touching state as with the exact tangent throughout."""
    sim, params, X, u = touching
    quad = quadrature(sim.disc.solid, X)
    model, walls, mu = sim.disc.contact, quad.walls, MAT[0] / (2 * (1 + MAT[1]))
    e, force, exact, which, _ = contact.force_and_blocks(model, walls, X + u, mu)
    e_n, force_n, normal, which_n, _ = contact.force_and_blocks(
        model, walls, X + u, mu, normal=jnp.asarray(True)
    )
    np.testing.assert_array_equal(which_n, which)
    assert float(e_n) == float(e)
    np.testing.assert_array_equal(force_n, force)
    lowest = lambda blocks: np.linalg.eigvalsh(np.asarray(blocks)).min(axis=1)
    scale = float(np.abs(np.asarray(exact)).max())
    # the exact blocks are indefinite in this touching state
    assert lowest(exact).min() < -1e-3 * scale
    assert lowest(normal).min() > -1e-12 * scale
    # only the blocks of walls within d_hat carry terms, and each of them changes
    differ = np.any(np.asarray(exact) != np.asarray(normal), axis=(1, 2))
    assert 0 < differ.sum() == np.count_nonzero(np.any(np.asarray(exact) != 0, axis=(1, 2)))
    d = jnp.array([CLOSED])
    exact_sim = Simulator(
        sim.disc, "superlu", NewtonOptions(rtol=1e-12, max_iters=500, contact_exact_below=0.0)
    )
    a, b = sim.solve(params, d, MAT), exact_sim.solve(params, d, MAT)
    assert sim.options.contact_exact_below > 0 and a.converged and b.converged
    # it acts
    assert not np.array_equal(
        np.asarray(a.info.residual_history), np.asarray(b.info.residual_history)
    )
    np.testing.assert_allclose(a.u, b.u, rtol=0, atol=1e-8 * float(jnp.abs(b.u).max()))


def test_adjoint_in_contact_against_central_differences(touching):
    """The gradient of the contact equilibrium with respect to the radii, through the adjoint."""
    sim, params, X, _ = touching
    d = jnp.array([CLOSED])
    w = jax.random.normal(jax.random.PRNGKey(2), X.shape)

    def loss(radii):
        p = {**params, "radii": radii}
        return jnp.sum(w * sim.equilibrium(sim.reference_points(p), d, MAT).u)

    radii = params["radii"]
    g = jax.grad(loss)(radii)
    v = jax.random.normal(jax.random.PRNGKey(3), radii.shape)
    h = 1e-5
    fd = (loss(radii + h * v) - loss(radii - h * v)) / (2 * h)
    assert float(jnp.sum(g * v)) == pytest.approx(float(fd), rel=1e-5)


def test_time_of_impact_stops_at_the_first_touch(cell):
    """Moving from rest towards the no-contact state at CLOSED, whose pore has passed through
    itself: the step bound is where a wall vertex first reaches a chord, and not before."""
    sims, params, X, _ = cell
    model = sims[True].disc.contact
    du = jnp.asarray(sims[False].solve(params, jnp.array([CLOSED]), MAT).u)
    walls = contact.reference_walls(model, X)
    t = float(contact.time_of_impact(model, walls, X, du))
    assert 0 < t < 1
    assert contact.smallest_gap(model, X + (1 - 1e-6) * t * du, X) > 0
    assert contact.smallest_gap(model, X + t * du, X) < 1e-9 * model.d_hat
    assert float(contact.time_of_impact(model, walls, X, du, horizon=0.5 * t)) == np.inf


def test_settings_are_checked():
    from nma.resolve import contact_options

    with pytest.raises(ConfigError, match=r"contact.distance must be .* \(0, 0.25\]"):
        build(ContactConfig, {"enabled": True, "distance": 0.5})
    assert contact_options(build(ContactConfig, {})) is None
    # the widest contact distance allowed leaves every paper scene's pores open at rest
    disc = discretise(
        scene_from_config(config.load("scene", "shape_matching")),
        Fidelity(5, 2),
        ContactSettings(distance=0.25),
    )
    X = disc.reference_points(disc.init_params())
    assert contact.smallest_gap(disc.contact, X, X) > disc.contact.d_hat


@pytest.mark.slow  # test_the_model_is_the_pores_walls checks the model at rest
def test_short_segments_of_one_wall_do_not_touch_at_rest():
    """At a fine discretisation with the smallest pores the design box allows, a pore's wall is cut
    into segments shorter than d_hat; pieces of one wall are not walls that touch (their terms are
    left out along EXCLUDED_ARC d_hat of wall), so nothing acts at rest, in any of the 24 pores."""
    spec = scene_from_config(config.load("scene", "translation"))
    disc = discretise(spec, Fidelity(14, 2), ContactSettings())
    model = disc.contact
    params = {**disc.init_params(), "radii": jnp.full_like(disc.init_params()["radii"], 0.1)}
    X = disc.reference_points(params)
    quad = quadrature(disc.solid, X)
    # vertices closer than d_hat
    assert model.pores == 24 and float(jnp.max(quad.walls.weights)) < model.d_hat
    assert contact.smallest_gap(model, X, X) > model.d_hat
    e, force, *_ = contact.force_and_blocks(model, quad.walls, X, 0.02)
    assert float(e) == 0.0 and float(jnp.abs(force).max()) == 0.0
