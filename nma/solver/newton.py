"""Static equilibrium by Newton's method with adaptive incremental loading, as one jitted loop.

Each iteration assembles the force and element tangents at the current state and does one of:
  predictor  (start of a load step): solve K_ff du = -(g + K_fD dU_D - dlam f_ext), the consistent
             linearised response to the next load increment, and move the load as far as the
             exact J > 0 step bound allows (the increment is cut to what keeps every point valid);
             with contact, one that the walls' time of impact stops short moves the load on, the
             prescribed displacements alone, as far as that keeps every point valid
             (loading.past_the_walls);
  corrector  (at fixed load): Newton step with backtracking Armijo line search on the energy, the
             step first bounded so that J > 0 at every Gauss point (det F is quadratic in the step),
             and with element_bound (or the inversion barrier) at each element's 4 x 4 check points
             too; with contact, far from equilibrium the tangent takes contact's normal stiffness
             only (_contact_normal).  With corrector="trust_region" the step of K + shift I instead,
             taken or rejected by how well the energy's quadratic model predicted its fall, the
             shift adapted (nma.solver.correctors; the predictor is then solved with the kept
shift). A load step fails when its line search cannot decrease the energy, when several corrector
steps in a row are cut to a small fraction of the Newton step (the increment is beyond the reach of
Newton's model: fail fast), or when it takes too many iterations; then the state returns to the last
converged load and the increment is halved.  Increments grow after a load step that converged within
a third of max_step_iters (a slow one says the next should be no larger).  A non-descent corrector
direction means an indefinite Hessian (a buckling structure): du^T K du < 0, so -du descends with
negative curvature and the iteration line-searches along it (a snap-through makes progress instead
of stalling); the next step is shifted by a diagonal term sized from the curvature the direction
revealed (twice -du^T K du / du^T du) and from the shift that last gave descent in this solve, and
the shift then decays tenfold per step back towards the pure Newton step.  A load step that keeps
descending is given max_step_iters iterations: cutting it much earlier throws away snap-throughs
about to converge and the slow descent along the soft valley of a nearly-mechanism design; one whose
residual is, or just was, within FINISHING_RESIDUAL (1000) times the tolerance gets up to
FINISHING_ITERS more.  Convergence: ||g_f|| <= rtol * f_ref + atol * k_ref * L, where f_ref is the
norm of the linearised out-of-balance force of the full load and k_ref * L a force scale of the
structure, never below tolerance_floor; the norms are taken scaled (norm), so that a very soft
material's residual does not underflow to 0.  The load steps before the last may close at a looser
path_rtol instead (0, the default:
rtol): the next predictor's right-hand side carries the residual left, but where several equilibria
lie near one actuation (walls in contact) the looser path can end on another
(docs/explanation/physical-states.md).  A warm solve (nma.solver.starts.setup's `start`) walks the
same way from another sample's equilibrium: the prescribed displacements from that sample's to this
one's.  The converged state is a stationary point of the energy, usually a minimum; where a
symmetric path has passed a buckling point it can be a saddle (Simulator.negative_eigenvalues counts
its unstable modes).  How a solve starts (cold, warm, a time step) is nma.solver.starts's; the
scales and tolerance it converges against, nma.solver.scales's.
"""

from __future__ import annotations

import inspect
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..mechanics.energy import Tangents
from ..mechanics.options import NEARLY_INCOMPRESSIBLE
from ..registry import CORRECTORS
from . import loading
from .correctors import Trial
from .equations import Equations, Problem, State
from .options import NewtonOptions
from .scales import _energy_noise, _scales, _step_scales, norm
from .starts import setup
from .status import NewtonInfo, Status


class Linearised(NamedTuple):
    """A state linearised, its load step closed if it converged, and the right-hand side of its
    step."""

    state: State
    energy: jnp.ndarray
    g: jnp.ndarray
    kel: Tangents
    rhs: jnp.ndarray


def linearise(eqs: Equations, opts: NewtonOptions, p: Problem, s: State, at=None) -> Linearised:
    """First half of an iteration: linearise at the state (or take `at`, its potential, free
    residual and element tangents, already computed); a corrector that meets the tolerance closes
    its load step (and the solve, at full load); the right-hand side of the next step."""
    E0, g, kel = (
        eqs.linearise(
            p.quad,
            s.u,
            p.boundary(s.lam),
            p.load(s.lam),
            p.mat,
            _contact_normal(eqs, opts, s),
            p.inertia,
        )
        if at is None
        else at
    )
    rnorm = norm(g)
    # a cold start, at rest, or a time step: the scales come from this tangent
    first = (s.it == 0) & (s.tol == 0)
    scales = (
        (lambda _: _scales(eqs, opts, p, kel))
        if p.inertia is None
        else (lambda _: _step_scales(eqs, opts, p, kel, g))
    )
    tol, k_ref, f_ref = jax.lax.cond(first, scales, lambda _: (s.tol, s.k_ref, s.f_ref), None)
    closed = loading.close_step(opts, s, rnorm, tol)
    rhs = loading.step_rhs(eqs, p, closed, g, kel)
    return Linearised(
        closed._replace(tol=tol, k_ref=k_ref, f_ref=f_ref, rnorm=rnorm), E0, g, kel, rhs
    )


def _contact_normal(eqs: Equations, opts: NewtonOptions, s: State):
    """Whether this iteration's tangent takes contact's normal stiffness only (positive
    semi-definite): in a load step's first corrector (the predictor has just pressed the walls
    together along a line that ignored how the barrier stiffens) and in every corrector whose last
    residual was above contact_exact_below times the force scale.  The exact Hessian's indefinite
    part swings the walls in and out of the barrier there (shape matching's trained design at
    14 x 5: 4 evaluation targets take 98-119 iterations with it, 200 and more without).  Near
    equilibrium the exact one, so that Newton converges quadratically and a converged state's
    factor is of the exact Hessian (its inertia, the adjoint).  False (a static branch) without
    contact or with contact_exact_below = 0."""
    if not (eqs.solid.contact and opts.contact_exact_below > 0):
        return False
    return (
        (s.it > 0)
        & ~s.predictor
        & ((s.step_it == 0) | (s.rnorm > opts.contact_exact_below * s.f_ref))
    )


def _tick(s: State, opts: NewtonOptions) -> State:
    it = s.it + 1
    status = jnp.where(
        (s.status == Status.RUNNING) & (it >= opts.max_iters), Status.ITERATION_LIMIT, s.status
    )
    return s._replace(it=it, status=status, history=s.history.at[s.it].set(s.rnorm))


def hold(opts: NewtonOptions, lin: Linearised) -> State:
    """Second half of an iteration that takes no step (the solve has ended)."""
    return _tick(lin.state._replace(predictor=jnp.asarray(False)), opts)


def advance(eqs: Equations, opts: NewtonOptions, p: Problem, lin: Linearised, du, speculate=True):
    """Second half of an iteration: take the step du (the solution of K_ff du = rhs), a predictor's
    as far as the bounds allow, a corrector's as solver.corrector finds (nma.solver.correctors).
    With `speculate`, first linearise where the step is bound to end, at its full length: the search
    takes the energy there from that linearisation.  Returns (State, Linearised, landed, full):
    `full` where the step went its full length; `landed` where it did and speculated, else the
    Linearised is not the State's, and the caller linearises it afresh (`linearise`).  Steps that
    fall short come in runs (a line search cutting step after step), so a caller speculates only
    after a step that went its full length."""
    s, at, full = _move(eqs, opts, p, lin, du, speculate)
    return s, linearise(eqs, opts, p, s, at), speculate & full, full


def _move(eqs: Equations, opts: NewtonOptions, p: Problem, lin: Linearised, du, speculate):
    """advance's State, the linearisation at the full step (where `speculate`; None where it is
    False itself) and whether the State is there."""
    s, E0, g = lin.state, lin.energy, lin.g
    predictor, dlam = s.predictor, s.dlam
    corrector = CORRECTORS.get(opts.corrector)()
    finite = jnp.all(jnp.isfinite(du))
    du = jnp.where(finite, du, jnp.zeros_like(du))
    slope = jnp.dot(g, du)
    # a corrector direction that climbs (g.du > 0) has negative curvature, du^T K du < -shift
    # |du|^2: its reverse descends with negative curvature too, so the iteration steps along -du
    # (and the next one is shifted) instead of being spent on a retry
    flipped = ~predictor & finite & (slope > 0)
    step = jnp.where(flipped, -du, du)
    # the step may go a fraction of the way to J = 0 or to the walls' impact (predictor: load moves
    # along)
    gauss, checks, walls = loading.bounds(
        eqs, p, s.u, s.lam, step, jnp.where(predictor, dlam, 0.0), 1.0 / opts.step_fraction
    )
    material = jnp.minimum(gauss, checks)
    a0 = jnp.minimum(1.0, opts.step_fraction * jnp.minimum(material, walls))
    # the step stopped where the material would invert between Gauss points (the element bound's
    # doing)
    inverting = s.inverting | ((checks < jnp.minimum(gauss, walls)) & (a0 < 1.0))

    # the state the full step reaches (a predictor's load moved along), and its tangent's kind
    trial_u, trial_lam = s.u + a0 * step, jnp.where(predictor, s.lam + a0 * dlam, s.lam)
    trial_normal = _contact_normal(
        eqs,
        opts,
        s._replace(
            it=s.it + 1,
            predictor=jnp.asarray(False),
            step_it=jnp.where(predictor, 0, s.step_it + 1),
        ),
    )

    def trial_linearised():
        return eqs.linearise(
            p.quad,
            trial_u,
            p.boundary(trial_lam),
            p.load(trial_lam),
            p.mat,
            trial_normal,
            p.inertia,
        )

    # without speculating, `at` is the current linearisation's (of its shapes; not used)
    current = lambda: (lin.energy, lin.g, lin.kel)
    at = None if speculate is False else jax.lax.cond(speculate, trial_linearised, current)

    def predict(_):
        return (
            a0,
            finite & (a0 * dlam >= opts.min_increment),
            jnp.asarray(True),
            jnp.ones_like(slope),
            jnp.zeros_like(slope),
        )

    def correct(_):
        descent = finite & (slope < 0)
        energy = lambda u: eqs.potential(
            p.quad, u, p.boundary(s.lam), p.load(s.lam), p.mat, p.inertia
        )
        # a time step's only: a corrector serves static solves without it
        noise = _energy_noise(eqs, p)
        a, ok, agreement, curvature = corrector.search(
            eqs,
            opts,
            lin.kel,
            energy,
            s.u,
            step,
            E0,
            -jnp.abs(slope),
            a0,
            *(() if noise is None else (noise,)),
            **(
                {"first": (speculate, at[0])}
                if at is not None and "first" in inspect.signature(corrector.search).parameters
                else {}
            ),
        )
        return a, (descent | flipped) & ok, descent, agreement, curvature

    a, ok, descent, agreement, curvature = jax.lax.cond(predictor, predict, correct, None)
    trial = Trial(du, step, slope, finite, flipped, descent, a, ok, agreement, curvature)
    step_it, damped, cut = corrector.cut(s, opts, trial)
    moved = ok & ~cut
    # the fraction of the increment the load goes (the free dofs go a of the predictor)
    reach = (
        loading.past_the_walls(
            eqs,
            opts,
            p,
            s.u + a * step,
            s.lam + a * dlam,
            (1.0 - a) * dlam,
            predictor & (walls < material) & (eqs.solid.material.nu(p.mat) < NEARLY_INCOMPRESSIBLE),
        )
        if eqs.solid.contact
        else 0.0
    )
    a_load = a + reach * (1.0 - a)
    u_new, lam_new, dlam_new, dlam_cut = loading.after_step(s, s.u + a * step, moved, cut, a_load)
    shift_new, shift_memory = corrector.next_shift(s, trial, cut)
    why = (
        jnp.where(inverting, Status.INVERTS, Status.INCREMENT_TOO_SMALL)
        if opts.element_bound
        else Status.INCREMENT_TOO_SMALL
    )
    status = jnp.where(cut & (dlam_cut < opts.min_increment), why, s.status)
    new = _tick(
        s._replace(
            u=u_new,
            lam=lam_new,
            dlam=dlam_new,
            predictor=cut,
            shift=shift_new,
            step_it=jnp.where(cut, 0, step_it),
            cuts=s.cuts + cut,
            status=status,
            damped=jnp.where(cut, 0, damped),
            shift_memory=shift_memory,
            inverting=inverting,
        ),
        opts,
    )
    # the full step's linearisation is the new state's where its inputs are the same
    full = (
        jnp.all(new.u == trial_u)
        & (new.lam == trial_lam)
        & (jnp.asarray(_contact_normal(eqs, opts, new)) == jnp.asarray(trial_normal))
    )
    return new, at, full


def leave_saddle(eqs: Equations, opts: NewtonOptions, p: Problem, lin: Linearised, v, curvature):
    """Move a converged state off a saddle along an unstable mode v (unit length, v^T K v =
    curvature < 0), as far as the energy keeps falling at least half as fast as its quadratic model
    says (from at most a tenth of the structure's size, within the J > 0 bound), and linearise
    there.  Newton goes on from there: with the next load step, or with correctors at full load,
    towards the equilibrium the buckled structure settles in.  Returns (linearised state, whether
    the energy fell)."""
    s, E0 = lin.state, lin.energy
    v = jnp.where(jnp.dot(lin.g, v) > 0, -v, v)  # downhill (at a saddle g ~ 0: either sign)
    slope = jnp.dot(lin.g, v)
    reach = 0.1 * p.size / jnp.max(jnp.abs(v))
    a0 = jnp.minimum(
        reach,
        opts.step_fraction * loading.bound(eqs, p, s.u, s.lam, v, 0.0, reach / opts.step_fraction),
    )

    def falls(a, Ea):
        return Ea <= E0 + 0.5 * (slope * a + 0.5 * curvature * a * a)

    def body(c):
        a, _, k = c
        a = 0.5 * a
        return (
            a,
            eqs.potential(p.quad, s.u + a * v, p.boundary(s.lam), p.load(s.lam), p.mat, p.inertia),
            k + 1,
        )

    a, Ea, _ = jax.lax.while_loop(
        lambda c: ~falls(c[0], c[1]) & (c[2] < opts.max_backtracks), body, (2.0 * a0, jnp.inf, 0)
    )
    ok = falls(a, Ea) & (a0 > 0)
    # at full load the state continues as a corrector; below it, as the predictor it was
    state = s._replace(
        u=jnp.where(ok, s.u + a * v, s.u),
        status=jnp.asarray(Status.RUNNING),
        step_it=jnp.asarray(0),
        damped=jnp.asarray(0),
        shift=jnp.zeros_like(s.shift),
        predictor=s.predictor & (s.lam < 1.0),
    )
    return linearise(eqs, opts, p, state), ok


def result(s: State) -> tuple[jnp.ndarray, NewtonInfo]:
    # a solve that did not converge returns the last state it did converge to (at info.load), not
    # the iterate it stopped at: an equilibrium, if not the one asked for
    u = jnp.where(s.status == Status.CONVERGED, s.u, s.u_conv)
    return u, NewtonInfo(s.status, s.it, s.steps, s.cuts, s.lam_conv, s.rnorm, s.tol, s.history)


def newton_solve(eqs: Equations, backend, opts: NewtonOptions, X, d, mat):
    """Solve for the free displacements at full load as one traced loop (a traceable linear backend,
    e.g. dense on a GPU). Returns (u_free, NewtonInfo). Host backends drive the same two halves of
    an iteration from Python instead (HostNewton), so that no compiled program holds a host
    callback.  It does not speculate (advance): under vmap a batch runs both sides of a branch."""
    p, init = setup(eqs, opts, X, d, mat)

    def body(s: State) -> State:
        lin = linearise(eqs, opts, p, s)
        return jax.lax.cond(
            lin.state.status == Status.RUNNING,
            lambda _: _move(
                eqs, opts, p, lin, backend.solve(lin.kel, lin.rhs, lin.state.shift), False
            )[0],
            lambda _: hold(opts, lin),
            None,
        )

    return result(jax.lax.while_loop(lambda s: s.status == Status.RUNNING, body, init))
