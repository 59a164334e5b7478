import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma.discretise import Resolution, discretise
from nma.schema import scene_from_config
from nma.mechanics.material import material
from nma.simulator import Simulator
from nma import config
from nma.errors import ConfigError, SolverError
from nma.solver.equations import Equations
from nma.solver.status import Status
from nma.solver.options import NewtonOptions

SMALL = {
    "name": "small",
    "cells": ["PP", "PP"],
    "pinned": [[0, 0], [10, 0], [10, 10], [0, 10]],
    "groups": [
        {"name": "left", "segment": [[0, 2], [0, 8]], "actuation": 0, "direction": [1, 0]},
        {"name": "top", "segment": [[2, 10], [8, 10]], "actuation": 1, "direction": [0, -1]},
    ],
    "tracked": {"centre": [5, 5]},
}


@pytest.mark.parametrize("nu", [0.3, 0.45, 0.49, 0.499])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_extremes_converge(simulator, nu, sign):
    """Translation at +-d_max (4.0), up to nearly incompressible: the structure has an equilibrium
    there and the solver reaches it, finite and balanced (a failure raises SolverError: see
    test_failure_reports_how_far_it_got)."""
    sim = simulator("translation")
    d = sign * jnp.array([4.0, -4.0])
    mat = material(0.07, nu)
    sol = sim.solve(sim.init_params(), d, mat)
    assert sol.converged and sol.message == "converged"
    assert np.all(np.isfinite(sol.u)) and np.isfinite(
        sim.energy(sim.reference_points(sim.init_params()), sol.u, mat)
    )
    assert float(sol.info.residual) <= float(sol.info.tolerance)
    # the Dirichlet groups moved exactly as declared: left by (-d0, 0)
    left = sim.disc.boundary.group_points["left"]
    np.testing.assert_allclose(sol.u[left], np.tile([-float(d[0]), 0.0], (len(left), 1)))


def test_failure_reports_how_far_it_got():
    disc = discretise(scene_from_config(SMALL))
    sim = Simulator(disc, "pardiso", NewtonOptions(max_iters=8, initial_increment=0.25, grow=1.0))
    d, mat = jnp.array([2.0, 2.0]), material(0.07, 0.3)
    with pytest.raises(SolverError, match=r"iteration limit") as err:
        sim.solve(sim.init_params(), d, mat)
    load = float(err.value.info.load)
    assert 0.25 <= load < 1.0 and int(err.value.info.load_steps) >= 1
    assert f"load factor {load:.4g} of 1 after 8 iterations" in str(err.value)
    # the same solve returned instead of raised: its status and error travel with it
    eq = sim.solve(sim.init_params(), d, mat, throw=False)
    assert not eq.converged and eq.message == "the iteration limit solver.max_iters was reached"
    assert str(sim.failure(eq, d, mat)) == str(err.value) and float(eq.info.load) == load


def test_a_failed_solve_returns_the_last_equilibrium_it_reached(simulator):
    """A solve that stops short returns the state it last converged to, at info.load: its prescribed
    points at that fraction of the actuation, the equilibrium a solve to that load finds, and with
    the element bound a physical object.  (It returned the iterate it stopped at, with the
    prescribed points at the full actuation: torn apart at the actuated boundary, det F down to -27
    there.)"""
    from conftest import barrier_case
    from nma.geometry.validity import StateChecker

    disc = discretise(scene_from_config(SMALL))
    sim = Simulator(disc, "pardiso", NewtonOptions(max_iters=8, initial_increment=0.25, grow=1.0))
    d, mat = jnp.array([2.0, 2.0]), material(0.07, 0.3)
    eq = sim.solve(sim.init_params(), d, mat, throw=False)
    load = float(eq.info.load)
    assert not eq.converged and 0.25 <= load < 1.0
    left = disc.boundary.group_points["left"]
    np.testing.assert_allclose(eq.u[left], np.tile([load * 2.0, 0.0], (len(left), 1)))
    reached = Simulator(disc, "pardiso").solve(sim.init_params(), load * d, mat)
    np.testing.assert_allclose(eq.u, reached.u, rtol=0, atol=1e-6 * float(np.abs(reached.u).max()))

    radii, d = barrier_case()  # stops where the material would invert between Gauss points
    bounded = simulator("translation", ctrl_per_patch=5, quad_points=2)
    params = {"radii": jnp.asarray(radii)}
    eq = bounded.solve(params, jnp.asarray(d), mat, throw=False)
    assert not eq.converged and 0.0 < float(eq.info.load) < 1.0
    assert (
        StateChecker(bounded.disc.mesh, np.asarray(bounded.reference_points(params)))
        .check(eq.u)
        .valid
    )


def test_status_is_returned_under_jit_without_nan():
    disc = discretise(scene_from_config(SMALL))
    sim = Simulator(disc, "pardiso", NewtonOptions(max_iters=2))
    X = sim.reference_points(sim.init_params())
    u, info = jax.jit(sim.equilibrium)(X, jnp.array([2.0, 2.0]), material(0.07, 0.3))
    assert int(info.status) != Status.CONVERGED and np.all(np.isfinite(np.asarray(u)))


def test_bad_actuation_is_rejected_before_work(simulator):
    sim = simulator("translation")
    with pytest.raises(ValueError, match="actuation must have 2 entries"):
        sim.solve(sim.init_params(), jnp.zeros(3), material(0.07, 0.3))
    with pytest.raises(ValueError, match="material.nu"):
        material(0.07, 0.5)


def test_auto_backend_is_pardiso_where_mkl_installs_and_superlu_elsewhere(monkeypatch):
    from nma.solver import linear

    disc = discretise(scene_from_config(SMALL))
    assert linear.make_backend("auto", disc).name == "pardiso"  # x86-64 with pypardiso, as in CI
    monkeypatch.setattr(linear, "pardiso_available", lambda: False)
    assert linear.make_backend("auto", disc).name == "superlu"


BACKEND_ACTUATIONS = jnp.array([[1.0, 0.5], [-1.5, 1.0], [0.5, -2.0]])


def test_backends_agree():
    """PARDISO, SuperLU and the dense backend's traced Newton reach one equilibrium."""
    disc = discretise(scene_from_config(SMALL))
    mat = material(0.07, 0.3)
    sims = {name: Simulator(disc, name) for name in ("pardiso", "superlu", "dense")}
    ref = [sims["superlu"].solve(disc.init_params(), d, mat).u for d in BACKEND_ACTUATIONS]
    for name in ("pardiso", "dense"):
        for d, u_ref in zip(BACKEND_ACTUATIONS, ref):
            np.testing.assert_allclose(
                sims[name].solve(disc.init_params(), d, mat).u, u_ref, atol=1e-9
            )


# compiles the dense Newton batched and its adjoint; test_backends_agree runs it unbatched
@pytest.mark.slow
def test_the_dense_backend_batches_under_vmap_and_differentiates_as_the_host_does():
    disc = discretise(scene_from_config(SMALL))
    mat = material(0.07, 0.3)
    sims = {name: Simulator(disc, name) for name in ("pardiso", "superlu", "dense")}
    X = disc.reference_points(disc.init_params())
    ds = BACKEND_ACTUATIONS
    ref = [sims["superlu"].solve(disc.init_params(), d, mat).u for d in ds]
    u_batch, info = jax.jit(jax.vmap(sims["dense"].equilibrium, in_axes=(None, 0, None)))(
        X, ds, mat
    )
    assert np.all(np.asarray(info.status) == Status.CONVERGED)
    np.testing.assert_allclose(u_batch, np.stack(ref), atol=1e-9)
    # gradients through the batched dense solve match the host backend's adjoint
    loss = lambda eq: (
        lambda X: jnp.sum(
            jax.vmap(
                lambda d: eq(X, d, mat)[0],
            )(ds)[:, :, 1]
            ** 2
        )
    )
    g_dense = jax.grad(loss(sims["dense"].equilibrium))(X)
    g_host = jax.jit(jax.grad(loss(sims["pardiso"].equilibrium)))(X)
    np.testing.assert_allclose(g_dense, g_host, rtol=1e-7, atol=1e-10)


def test_threads_give_the_sequential_answer_and_reuse_each_samples_factor():
    """A batch solved on two threads gives bit-identical displacements and gradients to one thread
    (samples share nothing; SuperLU, as PARDISO's own round-off depends on its thread count), and
    each sample's adjoint refines from its own last factor: no refactorisation in the backward
    pass."""
    disc = discretise(scene_from_config(SMALL))
    mat = material(0.07, 0.3)
    ds = jnp.array([[1.0, 0.5], [-1.5, 1.0], [0.5, -2.0], [2.0, 2.0]])
    results = []
    for workers in (1, 2):
        sim = Simulator(disc, "superlu", workers=workers)
        X = sim.reference_points(sim.init_params())
        loss = lambda X, ds: jnp.sum(jnp.sin(sim.equilibrium_batch(X, ds, mat)[0]))
        results.append(jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))(X, ds))
        assert sim.backend.stats["adjoint_refactorisations"] == 0
        assert sim.backend.stats["factorisations"] > len(ds)
    (v1, g1), (v2, g2) = results
    assert float(v1) == float(v2)
    for a, b in zip(g1, g2):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_simulators_on_equal_discretisations_share_kernels_that_go_with_them():
    """Newton's compiled kernels are built once per discretisation's content, options and contact
    room (nma.solver.equations.compiled): a second Simulator on the same discretisation, a third on
    another of the same scene, solve with the first one's, traced once; when the discretisations
    go, they go too (they hold them weakly)."""
    import gc
    import weakref

    from nma.solver import equations
    from nma.solver.host import Kernels

    # a scene no other test builds: no other discretisation holds its content's kernels
    scene = {**SMALL, "name": "shares_kernels"}
    first = Simulator(discretise(scene_from_config(scene)), "superlu")
    second = Simulator(first.disc, "pardiso", first.options)
    third = Simulator(discretise(scene_from_config(scene)), "superlu")
    assert third.disc is not first.disc
    for sim in (first, second, third):
        eq = sim.solve(sim.init_params(), jnp.array([0.5, 0.5]), material(0.07, 0.3))
        assert int(eq.info.status) == Status.CONVERGED
    built = equations._BY_DISC[first.disc]
    assert equations._BY_DISC[third.disc] is built
    newton = [key for key in built if key[0] == "newton"]
    assert newton == [("newton", first.options, None)]  # no contact: no room
    assert Kernels.of(third.equations, third.options, None) is built["newton", first.options, None]
    # another fidelity of the scene: kernels of its own
    other = Equations(discretise(scene_from_config(scene), Resolution(5, 3)))
    assert Kernels.of(other, first.options, None) is not built["newton", first.options, None]
    kernels = weakref.ref(built["newton", first.options, None])
    disc = weakref.ref(first.disc)
    del first, second, third, sim, built
    gc.collect()
    assert kernels() is None and disc() is None


def test_jacobian_through_the_host_solver_matches_row_by_row_gradients():
    """jacrev sends several cotangents through one forward's kept workspace at once."""
    disc = discretise(scene_from_config(SMALL))
    sim = Simulator(disc, "superlu", workers=2)
    mat = material(0.07, 0.3)
    X = sim.reference_points(sim.init_params())
    centre = lambda d: sim.tracked(X, sim.equilibrium(X, d, mat)[0])["centre"]
    d = jnp.array([1.0, -0.5])
    jac = jax.jacrev(centre)(d)
    rows = np.stack([jax.grad(lambda d, k=k: centre(d)[k])(d) for k in range(2)])
    np.testing.assert_allclose(jac, rows, rtol=1e-10, atol=1e-12)
    assert sim.backend.stats["adjoint_refactorisations"] == 0


@pytest.mark.parametrize("escape", [False, True])
def test_a_batch_factorises_its_designs_tangent_at_rest_once(escape):
    """Every cold solve's first iteration linearises and factorises the tangent at rest, which
    depends on the design only: a batch of one design does that once and shares it.  Its answers are
    bit for bit those of the samples solved one at a time, with n - 1 fewer factorisations (and,
    escaping saddles, the rest state's inertia check taken from the shared factor)."""
    disc = discretise(scene_from_config(SMALL))
    mat = material(0.07, 0.3)
    ds = jnp.array([[1.0, 0.5], [-1.5, 1.0], [0.5, -2.0], [2.0, 2.0]])
    one_by_one = Simulator(disc, "pardiso", NewtonOptions(escape_saddles=escape))
    X = one_by_one.reference_points(one_by_one.init_params())
    alone = [one_by_one.equilibrium_batch(X, d[None], mat) for d in ds]
    batched = Simulator(disc, "pardiso", NewtonOptions(escape_saddles=escape))
    batch = batched.equilibrium_batch(X, ds, mat)
    np.testing.assert_array_equal(
        np.asarray(batch.u), np.concatenate([np.asarray(a.u) for a in alone])
    )
    np.testing.assert_array_equal(
        np.asarray(batch.info.residual_history),
        np.concatenate([np.asarray(a.info.residual_history) for a in alone]),
    )
    assert batched.backend.stats["factorisations"] == one_by_one.backend.stats["factorisations"] - (
        len(ds) - 1
    )
    assert (
        batched.backend.stats["newton_iterations"] == one_by_one.backend.stats["newton_iterations"]
    )


@pytest.mark.slow  # the stability-map cells run the load-step cuts in the fast suite
def test_heavily_damped_load_steps_are_cut_early_and_reach_the_same_equilibrium(simulator):
    """Nearly incompressible (nu = 0.499) at full actuation: the first load steps are beyond
    Newton's reach, and the line search keeps cutting their corrector steps to a few percent.
    Cutting such a step after 3 of them in a row (instead of after max_step_iters) reaches the same
    equilibrium in fewer iterations."""
    fast = simulator("translation", quad_points=3)  # the default options: max_damped_steps 3
    # the patient solve spends 100 corrector iterations on a hopeless step: allow it enough in total
    patient = Simulator(
        fast.disc, "pardiso", NewtonOptions(max_damped_steps=100000, max_iters=1000)
    )
    assert fast.options.max_damped_steps == 3
    d, mat = jnp.array([4.0, 4.0]), material(0.07, 0.499)
    sols = {
        name: sim.solve(sim.init_params(), d, mat)
        for name, sim in (("fail fast", fast), ("patient", patient))
    }
    assert sols["fail fast"].info.cuts >= 1  # the case does cut load steps
    assert sols["fail fast"].info.iterations < sols["patient"].info.iterations
    X = np.asarray(fast.reference_points(fast.init_params()))
    np.testing.assert_allclose(X + sols["fail fast"].u, X + sols["patient"].u, atol=1e-8)


def test_trust_region_corrector_reaches_the_same_equilibrium_in_fewer_iterations(simulator):
    """solver.corrector=trust_region, nearly incompressible (nu = 0.499) at full actuation, the case
    above: where the line search shortens the whole Newton step because a soft mode's part of it is
    far too long, the trust region's shift damps that part only (nma/solver/correctors.py,
    TrustRegion). It reaches the line search's equilibrium, in fewer iterations."""
    line_search = simulator("translation", quad_points=3)
    trust = Simulator(line_search.disc, "pardiso", NewtonOptions(corrector="trust_region"))
    d, mat = jnp.array([4.0, 4.0]), material(0.07, 0.499)
    sols = {
        name: sim.solve(sim.init_params(), d, mat)
        for name, sim in (("line search", line_search), ("trust region", trust))
    }
    assert sols["trust region"].info.iterations < sols["line search"].info.iterations
    X = np.asarray(trust.reference_points(trust.init_params()))
    np.testing.assert_allclose(X + sols["trust region"].u, X + sols["line search"].u, atol=1e-8)


def test_a_step_is_linearised_at_its_full_length_and_again_only_where_it_ends_short():
    """A step that speculates linearises at its full length before the search, which takes the
    energy from there (nma.solver.newton.advance).  Where the step ends there (`landed`: every
    predictor and corrector of this solve), that is the next linearisation, to the bit; a step four
    times Newton's, which the line search shortens short of convergence, does not land.  Speculating
    or not, a step reaches the same state, to the bit."""
    from functools import partial

    from nma.solver import newton
    from nma.solver.host import Kernels

    sim = Simulator(discretise(scene_from_config(SMALL)), "superlu")
    eqs, opts, ws = sim.equations, sim.options, sim.backend.workspace()
    kernels = Kernels.of(eqs, opts, None)
    fresh = jax.jit(partial(newton.linearise, eqs, opts))
    X, d = sim.reference_points(sim.init_params()), jnp.array([1.0, -0.5])
    p, s, lin = kernels.start(X, d, material(0.07, 0.3))
    landed = []  # (predictor, step scaled by, landed, went its full length)
    yes, no = jnp.asarray(True), jnp.asarray(False)
    while int(lin.state.status) == Status.RUNNING:
        ws.factorise(lin.kel, float(lin.state.shift))
        du = jnp.asarray(ws.solve(lin.rhs))
        predictor = bool(lin.state.predictor)
        for scale in (1.0,) if predictor else (4.0, 1.0):
            plain, _, plain_landed, plain_full = kernels.step(p, lin, scale * du, no)
            s, lin1, hit, full = kernels.step(p, lin, scale * du, yes)
            landed.append((predictor, scale, bool(hit), bool(full)))
            assert not bool(plain_landed) and bool(plain_full) == bool(full)
            for a, b in zip(jax.tree.leaves(s), jax.tree.leaves(plain)):
                np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
            if hit:
                for a, b in zip(jax.tree.leaves(lin1), jax.tree.leaves(fresh(p, s))):
                    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        lin = lin1
    assert int(lin.state.status) == Status.CONVERGED
    assert all(hit and full for _, scale, hit, full in landed if scale == 1.0)
    assert any(predictor for predictor, *_ in landed)
    assert not all(hit for _, scale, hit, _ in landed if scale == 4.0)


def test_a_third_corrector_registered_by_name_needs_no_edit_of_the_loop(monkeypatch):
    """A corrector is an object with search / cut / next_shift (nma.solver.correctors), chosen by
    name from nma.registry.CORRECTORS.  A trivial third one, the bounded Newton step always taken,
    runs in the loop as it is; from a small actuation its full steps reach the line search's
    equilibrium."""
    from nma.registry import CORRECTORS
    from nma.solver.correctors import LineSearch

    class FullStep(LineSearch):
        def search(self, eqs, opts, kel, energy, u, step, E0, slope, a0):
            return (
                a0,
                jnp.isfinite(energy(u + a0 * step)),
                jnp.ones_like(slope),
                jnp.zeros_like(slope),
            )

    monkeypatch.setitem(CORRECTORS._items, "full_step", FullStep)
    disc = discretise(scene_from_config(SMALL))
    sims = {
        c: Simulator(disc, "superlu", NewtonOptions(corrector=c))
        for c in ("line_search", "full_step")
    }
    d, mat = jnp.array([1.0, -0.5]), material(0.07, 0.3)
    sols = {c: sim.solve(sim.init_params(), d, mat) for c, sim in sims.items()}
    assert sols["full_step"].converged and int(sols["full_step"].info.iterations) > 1
    np.testing.assert_allclose(sols["full_step"].u, sols["line_search"].u, atol=1e-9)
    with pytest.raises(ValueError, match="corrector must be one of .*'full_step'.*, got 'dogleg'"):
        NewtonOptions(corrector="dogleg")


def test_the_front_door_names_a_wrong_argument_and_takes_other_precisions(simulator):
    """sim.equilibrium checks each argument's shape and dtype before any work, naming it; float32
    (or integer) input is taken as float64, so it meets the same kernels and answers as float64
    input."""
    sim = simulator("translation")
    X, d, mat = sim.reference_points(sim.init_params()), jnp.array([1.0, -1.0]), material(0.07, 0.3)
    ref = sim.equilibrium(X, d, mat)
    low = sim.equilibrium(X.astype(jnp.float32), jnp.array([1, -1]), mat.astype(jnp.float32))
    assert int(low.info.status) == Status.CONVERGED and low.u.dtype == jnp.float64
    np.testing.assert_allclose(low.u, ref.u, atol=1e-5)  # X and [E, nu] rounded to float32
    for args, message in [
        ((X, jnp.array(1.0), mat), "d must have shape (2,), got ()"),
        ((X, jnp.zeros(3), mat), "d must have shape (2,), got (3,)"),
        ((X[:-1], d, mat), f"X must have shape ({X.shape[0]}, 2), got ({X.shape[0] - 1}, 2)"),
        ((X, d, jnp.array([0.07])), "mat must have shape (2,), got (1,)"),
    ]:
        with pytest.raises(ValueError, match=re.escape(f"equilibrium: {message}")):
            sim.equilibrium(*args)
    with pytest.raises(
        TypeError, match="equilibrium: d must hold real numbers, got dtype complex128"
    ):
        sim.equilibrium(X, d.astype(jnp.complex128), mat)
    with pytest.raises(
        ValueError, match=re.escape("equilibrium: mat must be finite, got [0.07, nan]")
    ):
        sim.equilibrium(X, d, jnp.array([0.07, np.nan]))
    # under jit: the status says it
    traced = jax.jit(sim.equilibrium)(X, jnp.array([np.nan, 0.0]), mat)
    assert int(traced.info.status) == Status.NONFINITE_INPUT
    # nothing solved: the state is rest, the last equilibrium
    assert np.all(np.asarray(traced.u) == 0.0)
    with pytest.raises(
        ValueError, match=r"X must be finite, got 1 entries that are not, the first at \[3, 1\]$"
    ):
        # a large argument's message names where, not all of it
        sim.equilibrium(X.at[3, 1].set(np.nan), d, mat)
    with pytest.raises(
        ValueError,
        match=re.escape(
            "equilibrium_batch: ds must have shape (n, 2), a row of actuations per sample, got (2,)"
        ),
    ):
        sim.equilibrium_batch(X, d, mat)
    with pytest.raises(
        ValueError, match=re.escape(f"tracked: u must have shape ({X.shape[0]}, 2), got (5, 2)")
    ):
        sim.tracked(X, jnp.zeros((5, 2)))


def test_the_eager_door_checks_the_design_and_material_naming_them(simulator):
    """sim.solve and sim.reference_points check the design parameters (the keys, shapes and box that
    init_params and scene.radii_bounds give) and sim.solve the material's physical range, before any
    work: a radius outside the box is an error, not a solve that runs out of iterations."""
    sim = simulator("translation")
    p, d, mat = sim.init_params(), jnp.array([1.0, 0.0]), material(0.07, 0.3)
    X = sim.reference_points(p)
    cases = [
        (X, TypeError, "params must be a mapping of the design's parameters ['radii']"),
        ({}, ValueError, "params must have the keys ['radii']"),
        ({**p, "extra": 1.0}, ValueError, "got ['extra', 'radii']"),
        (
            {"radii": p["radii"][:3]},
            ValueError,
            "params['radii'] must have shape (24, 16), got (3, 16)",
        ),
        ({"radii": p["radii"] * 3}, ValueError, "params['radii'] must lie in [0.1, 0.9]"),
        ({"radii": p["radii"] * np.nan}, ValueError, "params['radii'] must be finite"),
    ]
    for params, kind, message in cases:
        with pytest.raises(kind, match=re.escape(message)):
            sim.solve(params, d, mat)
    with pytest.raises(ValueError, match=re.escape("params['radii'] must lie in [0.1, 0.9]")):
        sim.reference_points({"radii": p["radii"] * 0.0})
    with pytest.raises(
        ValueError, match=re.escape("mat = [E, nu] must have nu in (-1, 0.5), got 0.6")
    ):
        sim.solve(p, d, jnp.array([0.07, 0.6]))
    with pytest.raises(
        ValueError, match=re.escape("mat = [E, nu] must have E in [1e-30, 1e30], got -1")
    ):
        sim.equilibrium(X, d, jnp.array([-1.0, 0.3]))
    with pytest.raises(
        TypeError, match="mat must be an array of shape \\(2,\\) of real numbers, got str"
    ):
        sim.solve(p, d, "rubber")
    with pytest.raises(ConfigError, match="actuation must be 2 numbers, got str"):
        sim.solve(p, "up", mat)
    with pytest.raises(
        TypeError, match="from_config: fidelity must be a mapping, a fidelity preset's name"
    ):
        Simulator.from_config(config.load("scene", "translation"), 5)


def test_from_config_takes_a_presets_name():
    """A group's option by name, as on the command line: fidelity "fast" is
    conf/fidelity/fast.yaml."""
    from nma.schema import Fidelity, build

    sim = Simulator.from_config("strip", "fast")
    fast = build(Fidelity, config.load("fidelity", "fast"))
    assert (
        sim.disc.mesh.fidelity.ctrl_per_patch == fast.ctrl_per_patch
        and sim.disc.spec.name == "strip"
    )
    with pytest.raises(ConfigError, match="fidelity='quick' is unknown; choose one of"):
        Simulator.from_config("strip", "quick")
    # every group by name
    assert Simulator.from_config("strip", "fast", contact="on").disc.contact is not None


@pytest.mark.parametrize("linear", ["superlu", "dense"])
def test_a_failed_sample_keeps_its_last_equilibrium_and_a_masked_loss_zero_gradient(linear):
    """A batch whose second sample fails (Newton given 6 iterations): that sample's u is the last
    equilibrium it reached (finite, at info.load), and a loss that masks it out has an exactly zero,
    finite gradient there, on the host and the traced driver alike."""
    disc = discretise(scene_from_config(SMALL))
    sim = Simulator(disc, linear, NewtonOptions(max_iters=6))
    X, mat = sim.reference_points(sim.init_params()), material(0.07, 0.3)
    ds = jnp.array([[0.5, 0.5], [4.0, -4.0]])
    eq = sim.equilibrium_batch(X, ds, mat)
    assert list(np.asarray(eq.info.status)) == [Status.CONVERGED, Status.ITERATION_LIMIT]
    assert np.all(np.isfinite(np.asarray(eq.u)))

    def masked(ds):
        solved = sim.equilibrium_batch(X, ds, mat)
        return jnp.sum(
            jnp.where((solved.info.status == Status.CONVERGED)[:, None, None], solved.u, 0.0) ** 2
        )

    grad = np.asarray(jax.grad(masked)(ds))
    assert np.all(np.isfinite(grad)) and np.all(grad[1] == 0.0) and np.any(grad[0] != 0.0)


def test_a_status_carries_its_words():
    assert Status.CONVERGED.message == "converged" and Status(5) is Status.INVERTS
    assert Status.describe(np.asarray(3)) == "the iteration limit solver.max_iters was reached"
    assert Status.describe(99) == "status 99"


def test_trust_region_solve_has_the_line_search_gradient():
    """The adjoint solves with the Hessian at the converged state (not the trust region's shifted
    matrix), so the gradient of a quantity of the equilibrium does not depend on the corrector that
    reached it.  Both solve to 1e-12 (the default 1e-10 leaves the two states, and so their
    gradients, 3e-8 apart)."""
    disc = discretise(scene_from_config(SMALL))
    sims = [
        Simulator(disc, "pardiso", NewtonOptions(rtol=1e-12, corrector=c))
        for c in ("line_search", "trust_region")
    ]
    mat = material(0.07, 0.45)
    X = sims[0].reference_points(sims[0].init_params())
    grads = [
        jax.grad(lambda d, sim=sim: sim.tracked(X, sim.equilibrium(X, d, mat)[0])["centre"][0])(
            jnp.array([2.0, -1.5])
        )
        for sim in sims
    ]
    assert np.all(np.abs(np.asarray(grads[0])) > 1e-6)  # both actuations move the centre
    np.testing.assert_allclose(grads[1], grads[0], rtol=1e-8)


def test_trust_region_ratio_of_a_quadratic_energy_is_one_and_round_off_is_taken():
    """_trust_region's test on E(u) = g.u + u^T K u / 2, whose quadratic model is exact: any step's
    actual fall over its predicted fall is 1.  A step whose predicted fall is below the energy's
    round-off is taken where the energy does not rise beyond it, and counts as agreeing with the
    model (read as noise it would raise the shift just before convergence)."""
    from nma.solver.correctors import _trust_region

    rng = np.random.default_rng(0)
    A = rng.standard_normal((6, 6))
    K, g = A @ A.T + 6 * np.eye(6), rng.standard_normal(6)
    energy = lambda u: jnp.dot(g, u) + 0.5 * u @ K @ u
    step = -np.linalg.solve(K + 0.3 * np.eye(6), g)  # a shifted Newton step from u = 0
    for a in (1.0, 0.4):
        _, ok, ratio = _trust_region(energy, jnp.zeros(6), step, 0.0, g @ step, step @ K @ step, a)
        assert bool(ok) and float(ratio) == pytest.approx(1.0, rel=1e-12)
    # a step that raises the energy is rejected
    _, ok, ratio = _trust_region(
        energy, jnp.zeros(6), -step, 0.0, -(g @ step), step @ K @ step, 1.0
    )
    assert not bool(ok) and float(ratio) < 0
    # at E0 = 1e6 a step predicted to lower it by 1e-9 is round-off: taken, agreement 1
    E = lambda u: 1e6 + 1e-9 * energy(u) / abs(float(energy(step)))
    _, ok, ratio = _trust_region(
        E,
        jnp.zeros(6),
        step,
        1e6,
        1e-9 * (g @ step) / abs(float(energy(step))),
        1e-9 * (step @ K @ step) / abs(float(energy(step))),
        1.0,
    )
    assert bool(ok) and float(ratio) == 1.0


# the trust region's host solve and its gradient are fast tests; test_backends_agree runs the traced
# driver
@pytest.mark.slow
def test_trust_region_traced_and_host_solves_agree():
    """The same corrector as one traced loop (the dense backend, the GPU path) and driven from the
    host (PARDISO): the same equilibrium; and a misspelt corrector is refused, not run as the line
    search."""
    disc = discretise(scene_from_config(SMALL))
    opts = NewtonOptions(corrector="trust_region")
    sols = [
        Simulator(disc, linear, opts).solve(
            Simulator(disc, linear, opts).init_params(),
            jnp.array([2.0, -1.5]),
            material(0.07, 0.45),
        )
        for linear in ("dense", "pardiso")
    ]
    np.testing.assert_allclose(sols[0].u, sols[1].u, atol=1e-9)
    with pytest.raises(
        ValueError,
        match=r"corrector must be one of \['line_search', 'trust_region'\], got 'trust-region'",
    ):
        NewtonOptions(corrector="trust-region")


# test_escape_saddles_reaches_a_stable_equilibrium_below_the_saddle counts unstable modes fast
@pytest.mark.slow
def test_inertia_counts_the_negative_eigenvalues_of_the_hessian():
    """PARDISO's LDL^T inertia against a dense eigendecomposition, on the Hessian at a converged
    state (stable: none negative) and on the same element blocks shifted down until many are
    negative."""
    from nma.solver.equations import tangents_at
    from nma.solver.linear import DenseBackend

    disc = discretise(scene_from_config(SMALL))
    sim = Simulator(disc, "pardiso")
    X, d, mat = sim.reference_points(sim.init_params()), jnp.array([1.0, 1.0]), material(0.07, 0.3)
    u, info = jax.jit(sim.equilibrium)(X, d, mat)
    assert int(info.status) == Status.CONVERGED and sim.negative_eigenvalues(X, d, mat, u) == 0
    kel = tangents_at(sim.equations, X, d, mat, np.asarray(u).reshape(-1)[sim.equations.free])
    Ke = np.asarray(kel.elements)
    shifted = kel._replace(
        elements=Ke - np.median(np.abs(np.diagonal(Ke, axis1=1, axis2=2))) * np.eye(18)
    )
    expected = int(
        np.sum(np.linalg.eigvalsh(np.asarray(DenseBackend(disc)._matrix(shifted, 0.0))) < 0)
    )
    assert (
        0 < expected < disc.boundary.n_dofs
        and sim.backend.negative_eigenvalues(shifted) == expected
    )


def test_pardiso_refines_a_solve_only_where_its_factorisation_perturbed_a_pivot():
    """PardisoBackend sets MKL's iparm[7] to 0: a solve takes no step of iterative refinement where
    the factorisation's pivots are exact (MKL's default for this matrix type, 2, refined every
    solve: three back-substitutions' time for a residual already at round-off), and still two where
    pivots were perturbed (a symmetric indefinite matrix with zero diagonal entries), the residual
    at round-off either way.  iparm[6] (zero-based) is the number of refinement steps MKL performed,
    iparm[13] the perturbed pivots (MKL's PARDISO iparm reference)."""
    import scipy.sparse as sp

    from nma.solver.equations import tangents_at
    from nma.solver.linear import PardisoBackend

    disc = discretise(scene_from_config(SMALL))
    sim = Simulator(disc, "pardiso")
    X, d, mat = sim.reference_points(sim.init_params()), jnp.array([1.0, 1.0]), material(0.07, 0.3)
    u, info = jax.jit(sim.equilibrium)(X, d, mat)
    assert int(info.status) == Status.CONVERGED
    kel = tangents_at(sim.equations, X, d, mat, np.asarray(u).reshape(-1)[sim.equations.free])
    rng = np.random.default_rng(0)
    hessian = sim.backend.pattern.matrix(kel)
    # zero diagonal entries stored explicitly: MKL's symmetric storage keeps every diagonal entry
    off = sp.triu(sp.random(300, 300, density=0.03, random_state=1, format="coo"), k=1)
    diag = np.tile([0.0, 1.0], 150)
    indefinite = sp.csr_matrix(
        (
            np.concatenate([off.data, diag]),
            (np.concatenate([off.row, np.arange(300)]), np.concatenate([off.col, np.arange(300)])),
        ),
        shape=(300, 300),
    )
    indefinite.sort_indices()
    backend = PardisoBackend(disc)
    for A, perturbed in ((hessian, False), (indefinite, True)):
        ws = backend.workspace()
        # a new handle (none is idle), analysed for this matrix
        ws.factor = backend.factorise(A, None)
        b = rng.normal(size=A.shape[0])
        x = ws.solve(b)
        iparm = ws.factor.solver.iparm
        assert (iparm[13] > 0) == perturbed
        assert iparm[6] == (2 if perturbed else 0)
        # with perturbed pivots the refined residual depends on the matrix's conditioning (1e-13
        # here)
        residual = backend.matvec(A, x) - b  # A holds the upper triangle
        assert np.linalg.norm(residual) <= (1e-8 if perturbed else 1e-11) * np.linalg.norm(b)


def test_nearly_incompressible_failure_says_why():
    disc = discretise(scene_from_config(SMALL))
    sim = Simulator(disc, "pardiso", NewtonOptions(max_iters=3))
    with pytest.raises(
        SolverError,
        match=r"material.nu = 0.499 is nearly incompressible "
        r".*solver.corrector=trust_region.*raise solver.max_iters",
    ):
        sim.solve(sim.init_params(), jnp.array([2.0, 2.0]), material(0.07, 0.499))


def test_escape_saddles_reaches_a_stable_equilibrium_below_the_saddle(simulator):
    """Translation, uniform middle radii, d = (-4, 4): the symmetric structure buckles, and plain
    Newton stops on the symmetric path, a saddle (the Hessian's inertia shows an unstable mode).
    With solver.escape_saddles it leaves along that mode to an equilibrium that is stable (no
    negative eigenvalue, checked by PARDISO's inertia) and lower in energy."""
    plain = simulator("translation")
    leaving = Simulator(plain.disc, "pardiso", NewtonOptions(escape_saddles=True))
    lo, hi = plain.disc.design.bounds()["radii"]
    params = {
        **plain.init_params(),
        "radii": jnp.full_like(plain.init_params()["radii"], 0.5 * (lo + hi)),
    }
    d, mat = jnp.array([-4.0, 4.0]), material(0.07, 0.3)
    sols = {
        name: sim.solve(params, d, mat) for name, sim in (("plain", plain), ("leaving", leaving))
    }
    X = plain.reference_points(params)
    unstable = {
        name: plain.negative_eigenvalues(X, d, mat, jnp.asarray(sol.u))
        for name, sol in sols.items()
    }
    energy = {name: plain.energy(X, sol.u, mat) for name, sol in sols.items()}
    assert unstable["plain"] >= 1 and unstable["leaving"] == 0
    assert energy["leaving"] < energy["plain"] - 1e-3 * abs(energy["plain"])
    assert float(sols["leaving"].info.residual) <= float(sols["leaving"].info.tolerance)
    assert leaving.backend.stats["saddles_left"] >= 1


def _warm_and_cold(disc, **options):
    opts = NewtonOptions(warm_start=True, **options)
    return Simulator(disc, "superlu", opts, workers=1), Simulator(disc, "superlu", workers=1)


def test_a_warm_start_reaches_the_cold_equilibrium_in_fewer_iterations():
    """A solve started from a nearby actuation's equilibrium (and from one of a slightly different
    design: the first predictor's right-hand side carries the start's residual at this design) lands
    on the equilibrium the solve from rest finds, in fewer iterations; the same actuation again
    costs two linearisations.  sim.solve solves from rest."""
    warm, cold = _warm_and_cold(discretise(scene_from_config(SMALL)))
    mat = material(0.07, 0.3)
    params = warm.init_params()
    X = warm.reference_points(params)
    first = warm.equilibrium_batch(X, jnp.array([[1.5, 1.0]]), mat)  # nothing kept: from rest
    assert warm.warm_starts.stats["warm_solves"] == 0 and warm.warm_starts.stats["cold_solves"] == 1
    moved = {**params, "radii": params["radii"] + 0.02}
    for Xs in (X, warm.reference_points(moved)):
        d = jnp.array([[1.8, 1.3]])
        w, c = warm.equilibrium_batch(Xs, d, mat), cold.equilibrium_batch(Xs, d, mat)
        assert bool(w.converged.all()) and bool(c.converged.all())
        np.testing.assert_allclose(w.u, c.u, rtol=0, atol=1e-8 * float(jnp.max(jnp.abs(c.u))))
        assert int(w.info.iterations[0]) < int(c.info.iterations[0])
    assert warm.warm_starts.stats["warm_solves"] == 2
    again = warm.equilibrium_batch(X, jnp.array([[1.5, 1.0]]), mat)
    assert int(again.info.iterations[0]) <= 2
    np.testing.assert_allclose(
        again.u, first.u, rtol=0, atol=1e-9 * float(jnp.max(jnp.abs(first.u)))
    )
    assert (
        warm.solve(params, jnp.array([1.5, 1.0]), mat).info.iterations
        == cold.solve(params, jnp.array([1.5, 1.0]), mat).info.iterations
    )


def test_warm_starts_take_the_nearest_equilibrium_nearer_than_rest_and_audit_it():
    """The kept equilibrium nearest in actuation is taken, none where rest is nearer; every
    warm_audit-th warm solve is also solved cold; once more than a tenth of at least eight audits
    found another equilibrium, warm starts stop (and say why) for the rest of the run: clear() (a
    checkpoint) drops what is kept but not the run's tallies, which restore() puts back on
    resume."""
    from nma.solver.warm import Audit, WarmStarts

    kept = WarmStarts(size=2, audit_every=2)
    for k, d in enumerate(([1.0, 0.0], [0.0, 1.0], [3.0, 3.0])):
        kept.keep(np.array(d), np.array([float(k)]), np.full(3, float(k)), np.zeros((2, 2)))
    # [1, 0] was dropped (size 2), [0, 1] is farther than rest
    assert kept.start(np.array([1.0, 0.1])) is None
    near = kept.start(np.array([2.5, 2.5]))
    assert near.u_D[0] == 2.0 and not near.audit
    assert kept.start(np.array([0.1, 1.2])).audit  # the second warm start
    for _ in range(9):
        kept.audited(Audit(1e-12))
    kept.audited(Audit(0.3, 1.0, 1.1))
    assert not kept.stopped  # 1 of 10
    kept.audited(Audit(0.3, 1.2, 1.1))
    assert kept.stopped.startswith("2 of 11 audited") and kept.stats["stops"] == 1
    assert kept.start(np.array([2.5, 2.5])) is None and kept.stats["audits_same"] == 9
    assert [o["energy_warm"] for o in kept.other_equilibria] == [1.0, 1.2]
    with kept.paused():
        assert kept.start(np.array([2.5, 2.5])) is None
    kept.clear()  # a checkpoint: nothing kept, the run's tallies and so the stop stay
    assert not kept.enabled and kept.stopped and kept.verdict == (11, 2)
    kept.restore(20, 1)  # a resumed run whose checkpoint had 1 of 20: on
    # nothing kept
    assert kept.enabled and not kept.stopped and kept.start(np.array([2.5, 2.5])) is None
    kept.keep(np.array([3.0, 3.0]), np.array([2.0]), np.zeros(3), np.zeros((2, 2)))
    assert kept.start(np.array([2.5, 2.5])) is not None
    kept.audited(Audit(0.3, 1.0, 1.1))
    assert kept.enabled and kept.verdict == (21, 2)  # under a tenth
    kept.audited(Audit(0.3, 1.0, 1.1))
    assert kept.stopped.startswith("3 of 22 audited") and kept.stats["stops"] == 2
    # a checkpoint written after the stop: stopped again, not counted as another
    kept.restore(11, 2)
    assert not kept.enabled and kept.stats["stops"] == 2

    warm, cold = _warm_and_cold(discretise(scene_from_config(SMALL)), warm_audit=1)
    mat = material(0.07, 0.3)
    X = warm.reference_points(warm.init_params())
    warm.equilibrium_batch(X, jnp.array([[1.0, 0.5]]), mat)
    # warm, then audited against a cold solve
    w = warm.equilibrium_batch(X, jnp.array([[1.2, 0.4]]), mat)
    st = warm.warm_starts.stats
    assert st["audits"] == 1 and st["audits_same"] == 1 and st["audits_within_1e-8"] == 1
    assert st["cold_solves"] == 2 and st["warm_solves"] == 1
    np.testing.assert_allclose(
        w.u, cold.equilibrium_batch(X, jnp.array([[1.2, 0.4]]), mat).u, atol=1e-9
    )


def test_the_element_bound_fails_an_inverting_solve_and_changes_no_other(simulator):
    """solver.element_bound (the default): Newton's step keeps det F > 0 at each element's 4 x 4
    check points, not only at its Gauss points.  conftest.barrier_case converges without it to a
    state inverted between Gauss points (nma.geometry.validity); with it the solve stops short and
    says so.  A solve that never inverts is the same, iterate for iterate."""
    from conftest import barrier_case
    from nma.geometry.validity import StateChecker

    radii, d = barrier_case()
    params, mat = {"radii": jnp.asarray(radii)}, material(0.07, 0.3)
    bounded = simulator("translation", ctrl_per_patch=5, quad_points=2)
    plain = simulator(
        "translation", solver={"element_bound": False}, ctrl_per_patch=5, quad_points=2
    )
    assert bounded.options.element_bound and not plain.options.element_bound
    checker = StateChecker(plain.disc.mesh, np.asarray(plain.reference_points(params)))
    inverted = plain.solve(params, jnp.asarray(d), mat)
    assert checker.check(inverted.u).inverted_elements > 0
    with pytest.raises(
        SolverError,
        match="where the material would invert between Gauss points.*converged up to load factor 0",
    ):
        bounded.solve(params, jnp.asarray(d), mat)
    a, b = (sim.solve(params, 0.3 * jnp.asarray(d), mat) for sim in (plain, bounded))
    assert checker.check(a.u).valid
    assert int(a.info.iterations) == int(b.info.iterations)
    np.testing.assert_array_equal(a.u, b.u)


def test_the_trust_region_stops_where_the_element_bound_holds_the_load(simulator):
    """A predictor that the element bound cuts below solver.min_increment cuts the load step with
    the trust-region corrector as with the line search: conftest.barrier_case ends with INVERTS, not
    by re-trying the same predictor up to the iteration limit."""
    from conftest import barrier_case

    radii, d = barrier_case()
    sim = simulator(
        "translation", solver={"corrector": "trust_region"}, ctrl_per_patch=5, quad_points=2
    )
    eq = sim.solve({"radii": jnp.asarray(radii)}, jnp.asarray(d), material(0.07, 0.3), throw=False)
    assert int(eq.info.status) == Status.INVERTS and int(eq.info.iterations) < 50, eq.message


def test_the_residual_norm_neither_underflows_nor_changes_a_normal_one():
    """scales.norm: the same bits as jnp.linalg.norm for vectors of every ordinary size (a power of
    two scales exactly), and right where the plain norm's squares underflow (a material of E ~
    1e-160: its norm was 0, and such a solve converged at once) or overflow; 0, inf and nan stay."""
    from nma.solver.scales import norm

    rng = np.random.default_rng(1)
    for scale in (1e-30, 1e-12, 1e-3, 1.0, 7.0, 1e8, 1e30):
        v = jnp.asarray(scale * rng.normal(size=2000))
        assert float(norm(v)) == float(jnp.linalg.norm(v))
    v = rng.normal(size=50)
    for scale in (1e-170, 1e-300, 1e200):
        got = float(norm(jnp.asarray(scale * v)))
        assert got > 0 and np.isfinite(got)
        np.testing.assert_allclose(got / scale, np.linalg.norm(v), rtol=1e-14)
    assert float(jnp.linalg.norm(jnp.asarray(1e-170 * v))) == 0.0  # what the plain norm says
    assert float(norm(jnp.zeros(3))) == 0.0
    assert np.isnan(float(norm(jnp.array([1.0, np.nan]))))
    assert float(norm(jnp.array([1.0, np.inf]))) == np.inf


def test_a_soft_material_converges_as_a_stiff_one_against_a_floored_tolerance(simulator):
    """Neo-Hookean under prescribed displacements: the equilibrium does not depend on E, so the
    softest material in range (E = 1e-30) reaches the same state in the same iterations as E = 1,
    its residual and tolerance scaled by E, neither 0; the tolerance's floor is far below both.  A
    modulus outside float64's reach (1e-300: its residual's round-off underflows) is refused, naming
    the range."""
    from nma.solver.scales import tolerance_floor

    sim = simulator("translation", "superlu", ctrl_per_patch=5, quad_points=2)
    X, d = sim.reference_points(sim.init_params()), jnp.array([2.0, -1.0])
    (u1, i1), (u2, i2) = (sim.equilibrium(X, d, material(E, 0.3)) for E in (1.0, 1e-30))
    assert int(i1.status) == int(i2.status) == Status.CONVERGED
    assert int(i1.iterations) == int(i2.iterations)
    np.testing.assert_allclose(np.asarray(u2), np.asarray(u1), rtol=0, atol=1e-12)
    assert 0 < float(i2.residual) <= float(i2.tolerance)
    np.testing.assert_allclose(float(i2.tolerance), 1e-30 * float(i1.tolerance), rtol=1e-9)
    assert 0 < tolerance_floor(jnp.float64) < 1e-280
    for E in (1e-300, 1e-31, 1e31):
        with pytest.raises(
            ConfigError, match=re.escape("material.E must be a finite number in [1e-30, 1e30]")
        ):
            material(E, 0.3)
        with pytest.raises(ValueError, match=re.escape("must have E in [1e-30, 1e30]")):
            sim.equilibrium(X, d, jnp.array([E, 0.3]))
