"""Dynamics (nma.dynamics): the consistent mass, the time-stepping schemes, natural frequencies,
step control (fixed, cut and adaptive steps) and the adjoint through time (stored and
checkpointed).  References are named where each is used."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse.linalg as spla

from nma.dynamics.mass import kinetic_energy, mass_blocks
from nma.dynamics.modes import natural_frequencies, natural_modes, static_suffices
from nma.dynamics.schemes import Scheme, _apply
from nma.dynamics.trajectory import Dynamics
from nma.dynamics.waveform import Fourier, Pulse
from nma.mechanics import contact
from nma.mechanics.energy import Tangents, quadrature, strain_energy
from nma.simulator import Simulator
from nma.solver.status import Status, failure

# BEAM: a clamped strip of 20 solid cells of 5 x 5, L = 100, h = 5 (slenderness 20)
from experiments.verification.cantilever import BEAM, H, L


def no_actuation(coeffs, t):
    return jnp.zeros(0) + 0.0 * coeffs[0]


@pytest.fixture(scope="module")
def beam():
    sim = Simulator.from_config(BEAM, fidelity={"quad_points": 3}, solver="superlu")
    X = sim.reference_points(sim.init_params())
    omega, modes = natural_modes(sim, X, sim.material_params, count=2)
    return sim, X, omega, modes


def _energy(sim, X, mat, u, v):
    """Kinetic plus strain energy (density 1)."""
    quad = quadrature(sim.equations.solid, X)
    return float(
        kinetic_energy(sim.equations, X, v, 1.0)
        + strain_energy(sim.equations.solid, quad, jnp.asarray(u), mat)
    )


def _mode_velocity(sim, mode, omega, tip):
    """Every dof's initial velocity along the first mode, scaled so that the tip swings about
    `tip`."""
    v0 = np.zeros(2 * sim.disc.mesh.n_points)
    v0[np.asarray(sim.equations.free)] = mode
    return v0 * tip * omega / np.max(np.abs(v0))


def _tip(sim, X, u):
    return np.asarray([sim.tracked(X, jnp.asarray(ui))["tip"][1] - H / 2 for ui in u])


def test_mass_integrates_the_density_exactly(beam, simulator):
    """Total mass and a rigid translation's kinetic energy: rho times the area (partition of unity),
    exact at any Gauss rule.  References: the strip's area L h; the porous translation design's area
    from its outline (the shoelace formula on its boundary loops sampled 64 points a span, converged
    to 1e-6)."""
    sim, X, _, _ = beam
    rho = 1.3
    for s, area in ((sim, L * H), (simulator("translation", "superlu"), None)):
        Xs = s.reference_points(s.init_params())
        M = mass_blocks(s.equations.solid, quadrature(s.equations.solid, Xs), rho)
        edofs = s.equations.edofs[: s.equations.elements]
        if area is None:
            from nma.geometry.outline import Outline

            polygon = Outline.of(s.disc.mesh, np.asarray(Xs)).polygon(per_span=64)
            area = polygon.area
        v = jnp.tile(jnp.array([0.3, -0.7]), (s.disc.mesh.n_points, 1))
        kinetic = kinetic_energy(s.equations, Xs, v, rho)
        np.testing.assert_allclose(
            float(kinetic), 0.5 * rho * area * 0.58, rtol=1e-6 if s is not sim else 1e-12
        )
        ex = jnp.tile(jnp.array([1.0, 0.0]), s.disc.mesh.n_points)
        np.testing.assert_allclose(
            float(ex @ _apply(M, edofs, ex)), rho * area, rtol=1e-6 if s is not sim else 1e-12
        )
        sym = np.asarray(M)
        assert np.allclose(sym, np.swapaxes(sym, 1, 2))


def test_first_frequency_of_a_clamped_strip(beam):
    """The time-stepped strip vibrates at the K/M eigenproblem's first frequency: undamped average
    acceleration started along the first mode is that mode exactly, at the discrete frequency
    2 arctan(omega dt / 2) / dt (the trapezoidal rule's period elongation).  Refined (8 control
    points a span, 4 Gauss points), the eigenproblem meets Euler-Bernoulli's cantilever, omega_1 =
    1.8751^2 sqrt(E' I / (rho h L^4)) (Rao, Vibration of Continuous Systems, 2007, Table 11.1), with
    E' = 4 mu (mu + kappa) / (2 mu + kappa) the small-strain plane modulus of the model's energy;
    the rest (shear and rotary inertia, Timoshenko's corrections at slenderness 20, and the 2D
    clamped root) within 0.5%."""
    sim, X, omega, modes = beam
    mat = sim.material_params
    dt = 2 * np.pi / omega[0] / 20
    v0 = _mode_velocity(sim, modes[0], omega[0], 1e-4 * L)
    u, _, info, _ = Dynamics(
        sim, "newmark", dt=dt, steps=30, waveform=no_actuation, v0=v0, workers=1
    ).run(X, jnp.zeros(1), mat)
    assert int(info.status) == 1
    y = _tip(sim, X, u)
    # a sampled sinusoid y_n = A sin(n theta) has y_{n+1} + y_{n-1} = 2 cos(theta) y_n
    theta = np.arccos(np.sum(y[1:-1] * (y[2:] + y[:-2])) / (2 * np.sum(y[1:-1] ** 2)))
    np.testing.assert_allclose(theta, 2 * np.arctan(omega[0] * dt / 2), rtol=1e-8)

    fine = Simulator.from_config(BEAM, fidelity="fine", solver="superlu")
    w1 = natural_frequencies(fine, fine.reference_points(fine.init_params()), mat, count=1)[0]
    mu, kappa = fine.disc.solid.material.moduli(jnp.asarray(mat))
    E_plane = 4 * mu * (mu + kappa) / (2 * mu + kappa)
    euler_bernoulli = 1.8751040687**2 * np.sqrt(E_plane * H**3 / 12 / (H * L**4))
    np.testing.assert_allclose(w1, euler_bernoulli, rtol=5e-3)


def test_average_acceleration_conserves_a_linear_systems_energy(beam):
    """The scheme on the strip's linearised system (K at rest, M), each step solved exactly: the
    energy 1/2 v.M v + 1/2 u.K u is constant to round-off (the trapezoidal rule is symplectic and,
    for a linear system, conserves its quadratic energy exactly)."""
    sim, X, omega, _ = beam
    eqs, mat = sim.equations, sim.material_params
    quad = quadrature(eqs.solid, X)
    from nma.solver.equations import tangents_at

    kel = tangents_at(eqs, X, jnp.zeros(0), mat, jnp.zeros(sim.disc.boundary.n_dofs))
    M = mass_blocks(eqs.solid, quad, 1.0)
    edofs = eqs.edofs[: eqs.elements]
    scheme, dt = Scheme.of("newmark"), 2 * np.pi / omega[0] / 7
    free = np.asarray(eqs.free)
    K_apply = lambda x: _apply(kel.elements, edofs, x)
    none = (jnp.zeros((0, 18, 18)), jnp.zeros(0, int), jnp.asarray(0))
    rng = np.random.default_rng(0)
    u = np.zeros(2 * sim.disc.mesh.n_points)
    v = np.zeros_like(u)
    v[free] = rng.normal(size=len(free))  # every mode, the highest included
    a = np.zeros_like(u)
    a[free] = -spla.spsolve(
        sim.backend.pattern.matrix(Tangents(M, *none)).tocsc(), np.asarray(K_apply(u))[free]
    )
    energies = []
    for _ in range(40):
        inertia = scheme.inertia(u, v, a, K_apply(u), M, jnp.zeros_like(M), edofs, dt)
        A = sim.backend.pattern.matrix(Tangents(kel.elements + inertia.blocks, *none)).tocsc()
        u1 = np.zeros_like(u)
        u1[free] = spla.spsolve(A, np.asarray(inertia.b)[free])
        v, a = (np.asarray(x) for x in scheme.update(u1, u, v, a, dt))
        u = u1
        energies.append(0.5 * v @ _apply(M, edofs, v) + 0.5 * u @ K_apply(u))
    energies = np.asarray(energies)
    assert np.max(np.abs(energies / energies[0] - 1)) < 1e-12


@pytest.mark.parametrize(
    "tip, steps, bound",
    [(1e-3 * L, 20, 1e-6), pytest.param(0.05 * L, 100, 1e-3, marks=pytest.mark.slow)],
)
def test_energy_of_the_nonlinear_strip(beam, tip, steps, bound):
    """The full model (Neo-Hookean, Newton per step): undamped average acceleration keeps a small
    vibration's energy to 1e-6 (the geometric nonlinearity at a tip swing of 0.1% of L, and the
    strain energy's round-off at strains of 1e-5) and a large one's (tip swing 5% of L) bounded,
    within 0.1% over 5 periods."""
    sim, X, omega, modes = beam
    mat = sim.material_params
    dt = 2 * np.pi / omega[0] / 20
    v0 = _mode_velocity(sim, modes[0], omega[0], tip)
    u, v, info, _ = Dynamics(
        sim, "newmark", dt=dt, steps=steps, waveform=no_actuation, v0=v0, workers=1
    ).run(X, jnp.zeros(1), mat)
    assert int(info.status) == 1
    E = np.asarray([_energy(sim, X, mat, ui, vi) for ui, vi in zip(u, v)])
    assert np.max(np.abs(E / E[0] - 1)) < bound, (tip, np.max(np.abs(E / E[0] - 1)))


@pytest.mark.parametrize(
    "scheme", ["newmark", pytest.param("generalised_alpha", marks=pytest.mark.slow)]
)
def test_second_order_in_the_time_step(beam, scheme):
    """The tip's position after half a period at dt = T/8, T/16, T/32, against T/128: the error
    falls 4x per halving (second order; generalised-alpha at rho_inf = 0.5 too, Chung & Hulbert
    1993)."""
    sim, X, omega, modes = beam
    T = 2 * np.pi / omega[0]
    v0 = _mode_velocity(sim, modes[0], omega[0], 0.02 * L)

    def tip_at_half_period(n):
        dyn = Dynamics(
            sim,
            scheme,
            rho_inf=0.5,
            dt=T / n,
            steps=n // 2,
            waveform=no_actuation,
            v0=v0,
            workers=1,
        )
        u, _, info, _ = dyn.run(X, jnp.zeros(1), sim.material_params)
        assert int(info.status) == 1
        return _tip(sim, X, u[-1:])[0]

    reference = tip_at_half_period(128)
    errors = np.abs([tip_at_half_period(n) - reference for n in (8, 16, 32)])
    orders = np.log2(errors[:-1] / errors[1:])
    assert np.all(orders > 1.7) and 1.9 < orders[-1] < 2.1, orders


BLOCK = {
    "name": "block",
    "cell_size": 5.0,
    "cells": "PP\nPP",
    "radii_init": 0.45,
    "groups": [
        {"name": "top", "segment": [[0, 10], [10, 10]], "actuation": 0, "direction": [0, -1]}
    ],
    "supports": [{"segment": [[0, 0], [10, 0]], "kind": "clamped"}],
    "tracked": {"wall": [2.5, 5]},
    "volumetric": "bulk",  # the paper's volume term, which its time steps are sized for
}


@pytest.fixture(scope="module")
def block():
    """BLOCK with contact, at a random asymmetric design (the symmetric block buckles sideways, to a
    side that a perturbation of its radii decides: there a trajectory is not differentiable), and
    its lowest natural period."""
    sim = Simulator.from_config(
        BLOCK,
        fidelity={"ctrl_per_patch": 5, "quad_points": 2},
        solver={"linear": "superlu", "rtol": 1e-12},
        contact={"enabled": True, "distance": 0.25},
    )
    geom, mat = sim.init_params(), jnp.asarray(sim.material_params)
    geom = {
        **geom,
        "radii": jnp.asarray(np.random.default_rng(5).uniform(0.38, 0.46, geom["radii"].shape)),
    }
    return (
        sim,
        geom,
        mat,
        2 * np.pi / natural_frequencies(sim, sim.reference_points(geom), mat, count=1)[0],
    )


def test_a_time_step_begins_from_the_last_steps_linearisation(block):
    """A time step's first linearisation is the last step's at its end with the Inertia swapped
    (nma.solver.starts.continue_in_time), not another pass over the elements: the same energy,
    residual, tangents (contact's exact ones, where the last were not) and first right-hand side as
    that pass, to round-off.  Three generalised-alpha steps of the block pressed until the barrier
    acts between its walls, the third half as long."""
    sim, geom, mat, T1 = block
    X = sim.reference_points(geom)
    dyn = Dynamics(
        sim,
        "generalised_alpha",
        rho_inf=0.8,
        dt=T1 / 4,
        steps=3,
        alpha=1e-4,
        beta=0.5,
        waveform=Fourier(1, 1, 2 * T1, T1 / 2, 3.0),
        workers=1,
    )
    k, coeffs, free, fixed = dyn.kernels, jnp.array([1.5, 0.0, 0.0]), dyn.free, dyn.dirichlet
    design, ws = k.design(X, mat), sim.backend.workspace()
    z = (k.full(jnp.zeros(len(free)), k.actuation(coeffs, 0.0)), jnp.zeros(dyn.n), jnp.zeros(dyn.n))
    last, acts = None, []
    # the last step as a cut interval's, half as long: its B another
    for t, h in ((dyn.dt, dyn.dt), (2 * dyn.dt, dyn.dt), (2.5 * dyn.dt, 0.5 * dyn.dt)):
        inertia, d = k.inertia(*design, mat, *z, h), k.actuation(coeffs, t)
        start = (z[0][free], z[0][fixed], None, X)
        if last is not None:
            _, s0, lin0 = dyn.newton.linearised(
                lambda kk: kk.start_warm(X, d, mat, *start, inertia)
            )
            acts.append(float(jnp.max(jnp.abs(lin0.kel.contact))) > 0)
            # as if the last tangent's contact blocks were of the normal stiffness only: taken
            # again, exact
            p1, lin1 = last
            last = (p1, lin1._replace(kel=lin1.kel._replace(contact=0.5 * lin1.kel.contact)))
            _, s, lin = dyn.newton.linearised(
                lambda kk: kk.start_step(*last, d, inertia), last[1].kel.which.shape[-1]
            )
            scale = float(jnp.max(jnp.abs(lin0.kel.elements)))
            for a, b in (
                (lin.kel.elements, lin0.kel.elements),
                (lin.kel.contact, lin0.kel.contact),
            ):
                np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=1e-12 * scale)
            np.testing.assert_array_equal(np.asarray(lin.kel.which), np.asarray(lin0.kel.which))
            np.testing.assert_allclose(float(lin.energy), float(lin0.energy), rtol=1e-12)
            for a, b in ((lin.g, lin0.g), (lin.rhs, lin0.rhs)):
                np.testing.assert_allclose(
                    np.asarray(a), np.asarray(b), rtol=0, atol=1e-10 * float(jnp.max(jnp.abs(b)))
                )
            np.testing.assert_allclose(float(lin.state.tol), float(lin0.state.tol), rtol=1e-10)
        u_free, info, last = dyn.newton.time_step(X, d, mat, ws, start, inertia, last)
        assert int(info.status) == Status.CONVERGED
        u1 = k.full(u_free, d)
        z = (u1, *k.update(u1, *z, h))
    sim.backend.release(ws)
    assert acts[-1]  # the barrier acts in the half step


def test_adjoint_through_time_matches_central_differences(block):
    """A loss over 50 steps of a 2 x 2 porous block pressed from the top (generalised-alpha,
    Rayleigh damping; contact on, its barrier acting in most steps: walls within d_hat): its
    gradient in the pores' radii, the waveform's coefficients and the material by the adjoint sweep,
    against central differences along a random direction in all of them at once (at the fixture's
    asymmetric design)."""
    sim, geom, mat, T1 = block
    dyn = Dynamics(
        sim,
        "generalised_alpha",
        rho_inf=0.8,
        dt=T1 / 10,
        steps=50,
        alpha=1e-4,
        beta=0.5,
        waveform=Fourier(1, 1, 2 * T1, T1 / 2, 3.0),
        workers=1,
    )
    model = sim.disc.solid.contact

    def run(radii, coeffs, mat):
        X = sim.reference_points({**geom, "radii": radii})
        u, v, info = dyn.function(X, coeffs, mat)
        wall = jax.vmap(lambda ui: sim.tracked(X, ui)["wall"])(u)
        return jnp.sum(wall**2) + 1e3 * jnp.sum(v[-10:] ** 2), (u, info)

    x0 = (geom["radii"], jnp.array([1.0, 0.0, 0.0]), mat)
    (value, (u, info)), grads = jax.value_and_grad(run, argnums=(0, 1, 2), has_aux=True)(*x0)
    assert int(info.status) == 1 and int(info.cuts) == 0
    X = np.asarray(sim.reference_points(geom))
    gaps = np.asarray([contact.smallest_gap(model, X + np.asarray(ui), X) for ui in u])
    assert np.sum(gaps < model.d_hat) >= 10  # the barrier acts in most of the steps
    rng = np.random.default_rng(0)
    direction = (
        jnp.asarray(rng.normal(size=x0[0].shape)),
        jnp.asarray(rng.normal(size=3)),
        mat * rng.normal(size=2),
    )
    h = 1e-7
    moved = lambda s: [x + s * d for x, d in zip(x0, direction)]
    (plus, (_, i_plus)), (minus, (_, i_minus)) = run(*moved(h)), run(*moved(-h))
    assert int(i_plus.cuts) == int(i_minus.cuts) == 0
    along = sum(float(jnp.sum(g * d)) for g, d in zip(grads, direction))
    np.testing.assert_allclose(along, (plus - minus) / (2 * h), rtol=1e-6)


def test_static_suffices_for_slow_actuation():
    """An actuation 20x slower than the lowest natural period lags its static response by (1/20)^2 /
    (1 - (1/20)^2) = 0.25%: the static model is said to suffice; at 3x it is not (12.5%)."""
    omega = 2 * np.pi / 10.0
    assert "0.25%" in static_suffices(omega, 200.0)
    assert static_suffices(omega, 30.0) is None


def _pressed(T1):
    """The block's top pressed down as (t / T1)^2 times the coefficient: at 3, the material inverts
    between Gauss points (INVERTS) in the fifth time step of T1 / 4."""
    return lambda c, t: c[:1] * (t / T1) ** 2


def test_a_trajectory_says_by_index_which_states_it_solved(block, beam):
    """A completed trajectory reports all steps + 1 states, its end at the last grid time exactly
    (0.1 x 6, which six sums of 0.1 fall short of); one whose step fails says which interval: its
    states up to that interval's start are solved, the later ones hold the last."""
    sim, X = beam[0], beam[1]
    dyn = Dynamics(sim, dt=0.1, steps=6, waveform=no_actuation, workers=1)
    u, _, info, _ = dyn.run(X, jnp.zeros(1), sim.material_params)
    assert int(info.status) == Status.CONVERGED and int(info.intervals) == 6 and len(u) == 7
    assert float(info.time) == dyn.times[-1] == 0.1 * 6 > sum([0.1] * 6)
    sim, geom, mat, T1 = block
    dyn = Dynamics(sim, "newmark", dt=T1 / 4, steps=6, waveform=_pressed(T1), max_cuts=0, workers=1)
    u, v, info, trace = dyn.run(sim.reference_points(geom), jnp.array([3.0]), mat)
    assert int(info.status) == Status.INVERTS and int(info.intervals) == 4
    assert float(info.time) == dyn.times[4]  # the failed step starts at the last state solved
    assert trace.counts.tolist() == [1, 1, 1, 1, 0, 0]  # a step each, none past the failure
    np.testing.assert_array_equal(u[5:], np.broadcast_to(u[4], u[5:].shape))
    assert np.abs(u[4] - u[3]).max() > 0
    assert "(time step 5) did not converge" in str(failure(info))


def test_the_adjoint_of_a_failed_trajectory_holds_its_last_state(block):
    """Past a failed step every state is the last one solved, so its cotangents are that state's:
    the gradient of a loss over all the states of a trajectory that fails in its fifth step, against
    central differences in the radii and the waveform (the failure where it was for both)."""
    sim, geom, mat, T1 = block
    dyn = Dynamics(sim, "newmark", dt=T1 / 4, steps=6, waveform=_pressed(T1), max_cuts=0, workers=1)

    def run(radii, coeffs):
        X = sim.reference_points({**geom, "radii": radii})
        u, v, info = dyn.function(X, coeffs, mat)
        wall = jax.vmap(lambda ui: sim.tracked(X, ui)["wall"])(u)
        return jnp.sum(wall**2) + 1e3 * jnp.sum(v**2), info

    x0 = (geom["radii"], jnp.array([3.0]))
    (_, info), grads = jax.value_and_grad(run, argnums=(0, 1), has_aux=True)(*x0)
    assert int(info.status) == Status.INVERTS and int(info.intervals) == 4
    rng = np.random.default_rng(0)
    direction = (jnp.asarray(rng.normal(size=x0[0].shape)), jnp.asarray(rng.normal(size=1)))
    h = 1e-7
    (plus, i_plus), (minus, i_minus) = (
        run(*[x + s * d for x, d in zip(x0, direction)]) for s in (h, -h)
    )
    assert int(i_plus.intervals) == int(i_minus.intervals) == 4
    along = sum(float(jnp.sum(g * d)) for g, d in zip(grads, direction))
    np.testing.assert_allclose(along, (plus - minus) / (2 * h), rtol=1e-6)


def test_the_dense_backend_steps_through_time_as_the_host_ones(block):
    """solver.linear=dense serves dynamics: its time steps' Newton is driven from the host with
    dense LU factors, to the same trajectory and gradient as SuperLU's, to round-off; its natural
    frequencies come from the scene's sparse pattern as the host backends' do."""
    sim, geom, mat, T1 = block
    dense = Simulator(sim.disc, "dense", sim.options)
    X = sim.reference_points(geom)
    np.testing.assert_allclose(
        natural_frequencies(dense, X, mat, count=2),
        natural_frequencies(sim, X, mat, count=2),
        rtol=1e-9,
    )
    out = []
    for s in (sim, dense):
        dyn = Dynamics(s, "newmark", dt=T1 / 4, steps=3, waveform=_pressed(T1), workers=1)

        def loss(coeffs, dyn=dyn):
            u, v, info = dyn.function(X, coeffs, mat)
            return jnp.sum(u[-1] ** 2) + jnp.sum(v**2), (u, info)

        (_, (u, info)), g = jax.value_and_grad(loss, has_aux=True)(jnp.array([2.0]))
        assert int(info.status) == Status.CONVERGED and int(info.intervals) == 3
        out.append((np.asarray(u), np.asarray(g)))
    np.testing.assert_allclose(out[1][0], out[0][0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(out[1][1], out[0][1], rtol=1e-7)
    assert dense.backend.stats["factorisations"] > 0


TIP = {"name": "tip", "segment": [[L, 0], [L, H]], "actuation": 0, "direction": [0, -1]}
STRUCK = {**BEAM, "groups": [TIP], "tracked": {"mid": [L / 2, H / 2]}}


@pytest.fixture(scope="module")
def struck():
    """BEAM with its tip struck: moved down and back by a bump over a 16th of the lowest natural
    period T1 (then held, the strip clamped at both ends), its vibration damped by stiffness-
    proportional Rayleigh damping, 30% of critical at the lowest frequency.  Generalised-alpha at
    rho_inf 0.5 (numerical damping of the highest frequencies, whose accelerations Newmark's
    average acceleration leaves ringing: no local error estimate of it settles)."""
    sim = Simulator.from_config(STRUCK, fidelity={"quad_points": 3}, solver="superlu")
    X, mat = sim.reference_points(sim.init_params()), sim.material_params
    omega = float(natural_frequencies(sim, X, mat, count=1)[0])
    return sim, X, mat, 2 * np.pi / omega, 2 * 0.3 / omega


def _strike(struck, per_period: int, steps: int, sim=None, bump=16, **kw) -> Dynamics:
    """The struck strip's Dynamics, reported every T1 / per_period; the bump over T1 / bump."""
    _, _, _, T1, beta = struck
    pulse = Pulse(1.0, T1 / bump)
    return Dynamics(
        sim or struck[0],
        "generalised_alpha",
        0.5,
        dt=T1 / per_period,
        steps=steps,
        beta=beta,
        waveform=lambda c, t: c * pulse(t),
        workers=1,
        **kw,
    )


def test_adaptive_steps_meet_their_tolerance_in_fewer_steps(struck):
    """Two periods of the struck strip, reported every T1/8: the adaptive controller at rtol 1e-2
    lands on every report time (by index) within 1% of the largest displacement of a fixed-step
    reference at T1/256; fixed steps of T1/64, more of them than it takes, are 3x further off.  Its
    steps are short about the strike and long after it."""
    sim, X, mat, _, _ = struck

    def run(per_period, steps, **kw):
        dyn = _strike(struck, per_period, steps, **kw)
        u, _, info, trace = dyn.run(X, jnp.ones(1), mat)
        assert int(info.status) == Status.CONVERGED and float(info.time) == dyn.times[-1]
        return u, info, trace

    reference = run(8 * 32, 16 * 32, controller="fixed")[0][::32]
    scale = np.max(np.abs(reference))
    u, info, trace = run(8, 16, controller="adaptive", rtol=1e-2, max_cuts=7)
    error = np.max(np.abs(u - reference)) / scale
    assert len(u) == 17 and error < 1e-2
    assert trace.counts[0] > 10 * trace.counts[-1] >= 10 and int(info.steps) == trace.counts.sum()
    fixed, fixed_info, _ = run(8 * 8, 16 * 8, controller="fixed")
    assert int(fixed_info.steps) > int(info.steps)
    assert np.max(np.abs(fixed[::8] - reference)) / scale > 3 * error


def _loss(sim, X, dyn):
    def loss(X, coeffs, mat):
        u, v, info = dyn.function(X, coeffs, mat)
        mid = jax.vmap(lambda ui: sim.tracked(X, ui)["mid"])(u)
        return jnp.sum(mid[:, 1] ** 2) + 1e6 * jnp.sum(v**2), info

    return loss


def _along_central_differences(loss, x0, grads, h, seed=0):
    """The gradient along a random direction in every argument at once, and central differences
    of the loss along it; the infos of the two runs."""
    rng = np.random.default_rng(seed)
    direction = [
        jnp.asarray(rng.normal(size=np.shape(x))) * (1e-3 if i == 0 else 1.0)
        for i, x in enumerate(x0)
    ]
    (plus, i_plus), (minus, i_minus) = (
        loss(*[x + s * d for x, d in zip(x0, direction)]) for s in (h, -h)
    )
    along = sum(float(jnp.sum(g * d)) for g, d in zip(grads, direction))
    return along, (plus - minus) / (2 * h), (i_plus, i_minus)


@pytest.mark.parametrize("controller", ["adaptive", "cuts"])
def test_adjoint_with_step_control_matches_central_differences(struck, controller):
    """The gradient through the steps a controller took (the step sequence fixed, as diffrax's
    adjoints take it): adaptive steps about the strike; and intervals cut in 2 or 4 where Newton,
    held to 4 iterations a step, does not converge in one (a bump 3x as high over T1/4).  Both are
    solved again from their interval's start in the backward pass.  Against central differences
    in the control points, the waveform and the material along a random direction, over which the
    steps taken do not change."""
    sim, X, mat, _, _ = struck
    if controller == "adaptive":
        dyn, c = _strike(struck, 8, 4, controller="adaptive", rtol=1e-2, max_cuts=7), 1.0
    else:
        sim = Simulator(sim.disc, "superlu", dataclasses.replace(sim.options, max_iters=4))
        dyn, c = _strike(struck, 8, 4, sim, bump=4, controller="cuts", max_cuts=3), 3.0
    loss = _loss(sim, X, dyn)
    x0 = (X, jnp.full(1, c), jnp.asarray(mat))
    (_, info), grads = jax.value_and_grad(loss, argnums=(0, 1, 2), has_aux=True)(*x0)
    assert int(info.status) == Status.CONVERGED and int(info.cuts) >= 2
    along, central, infos = _along_central_differences(loss, x0, grads, 1e-6)
    for other in infos:
        assert (int(other.steps), int(other.rejected)) == (int(info.steps), int(info.rejected))
    np.testing.assert_allclose(along, central, rtol=1e-6)


@pytest.mark.parametrize("controller", ["cuts", "adaptive"])
def test_checkpointed_adjoint_is_store_alls_in_sqrt_of_the_memory(struck, controller):
    """checkpointed keeps the states at every ceil(sqrt(9)) = 3rd report time (or its budget's),
    solves the rest again in the backward pass, and gives store_all's gradient to round-off (to
    the bit with adaptive steps, whose intervals start afresh either way: at a kept state the
    forward pass starts afresh, not from the last linearisation).  Either's gradient asked twice
    of one forward pass is the same to the bit (the records are the residuals', not popped)."""
    sim, X, mat, _, _ = struck
    kw = {
        "controller": controller,
        **({"rtol": 1e-2, "max_cuts": 7} if controller == "adaptive" else {"bump": 4}),
    }
    x0 = (X, jnp.ones(1), jnp.asarray(mat))
    out = {}
    for adjoint in ("store_all", "checkpointed"):
        dyn = _strike(struck, 8, 9, adjoint=adjoint, **kw)
        u, vjp = jax.vjp(lambda *x: dyn.function(*x)[:2], *x0)
        rng = np.random.default_rng(1)
        cotangents = tuple(jnp.asarray(rng.normal(size=a.shape)) for a in u)
        out[adjoint] = u, vjp(cotangents), vjp(cotangents)
    checkpointed = _strike(struck, 8, 9, adjoint="checkpointed", **kw).adjoint
    assert checkpointed.kept(9).tolist() == [0, 3, 6]
    budget = _strike(struck, 8, 9, adjoint="checkpointed", checkpoints=2, **kw).adjoint
    assert budget.kept(9).tolist() == [0, 5]
    (u_s, g_s, _), (u_c, g_c, again) = out["store_all"], out["checkpointed"]
    assert float(jnp.max(jnp.abs(u_s[0]))) > 0
    for a, b in zip(u_c, u_s):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * float(jnp.max(jnp.abs(b))))
    for a, b, c, d in zip(g_c, g_s, again, out["store_all"][2]):
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, d)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-10 * float(jnp.max(jnp.abs(b))))
        if controller == "adaptive":
            np.testing.assert_array_equal(a, b)


def test_fixed_steps_are_cuts_that_never_cut(block):
    """controller=fixed takes the same steps as cuts, to the bit, and where one fails ends the
    trajectory there (one step tried and rejected) as cuts with max_cuts 0 does."""
    sim, geom, mat, T1 = block
    X = sim.reference_points(geom)
    runs = [
        Dynamics(sim, "newmark", dt=T1 / 4, steps=6, waveform=_pressed(T1), workers=1, **kw).run(
            X, jnp.array([3.0]), mat
        )
        for kw in ({"controller": "fixed"}, {"controller": "cuts", "max_cuts": 0})
    ]
    (u, v, info, _), (u0, v0, info0, _) = runs
    np.testing.assert_array_equal(u, u0)
    np.testing.assert_array_equal(v, v0)
    assert int(info.status) == Status.INVERTS and int(info.intervals) == 4
    assert int(info.rejected) == int(info0.rejected) == 1


def test_dynamics_of_one_scene_and_settings_share_their_step_kernels(beam):
    """A Dynamics' jitted step pieces are built once per discretisation's content, scheme, density,
    damping and waveform (nma.solver.equations.compiled): a Dynamics on another Simulator of the
    same scene takes the first one's; another scheme, damping or waveform gets its own."""
    sim, _, omega, _ = beam
    again = Simulator.from_config(BEAM, fidelity={"quad_points": 3}, solver="superlu")
    assert again.disc is not sim.disc
    dt = 2 * np.pi / omega[0] / 10

    def kernels(s, scheme="newmark", waveform=no_actuation, **kw):
        return Dynamics(s, scheme, dt=dt, steps=2, waveform=waveform, workers=1, **kw).kernels

    first = kernels(sim)
    assert kernels(again) is first
    assert kernels(sim, "generalised_alpha") is not first
    assert kernels(sim, alpha=1e-3) is not first
    assert kernels(sim, waveform=lambda c, t: no_actuation(c, t)) is not first


@pytest.mark.parametrize("adjoint", ["store_all", "checkpointed"])
def test_each_steps_factor_computed_ahead_gives_the_same_gradient(struck, adjoint):
    """The sweep factorises each step's matrix beside the pullback of the step after it
    (nma.dynamics.backward.sweep_back's `ahead`; here with cut intervals, solved again in the
    backward pass): the same computations in another order, so the gradient of one step at a time
    to the bit."""
    sim, X, mat, _, _ = struck
    sim = Simulator(sim.disc, "superlu", dataclasses.replace(sim.options, max_iters=4))
    dyn = _strike(struck, 8, 4, sim, bump=4, controller="cuts", max_cuts=3, adjoint=adjoint)
    c = jnp.full(1, 3.0)
    u, v, info, trace = dyn.run(X, c, mat)
    assert int(info.status) == Status.CONVERGED and int(info.cuts) > 0
    rng = np.random.default_rng(0)
    bars = rng.normal(size=u.shape), rng.normal(size=v.shape)
    index = dyn.adjoint.kept(dyn.steps)
    kept = tuple(x if index is None else x[index] for x in (u, v, trace.a))
    ahead, in_turn = (
        dyn.backward(X, c, mat, kept, *trace[1:], int(info.intervals), *bars, ahead=a)
        for a in (True, False)
    )
    for one, other in zip(ahead, in_turn):
        assert np.any(one != 0) and np.array_equal(one, other)
