"""Static equilibrium by Newton's method with adaptive incremental loading, as one jitted loop.

Each iteration assembles the force and element tangents at the current state and does one of:
  predictor  (start of a load step): solve K_ff du = -(g + K_fD dU_D - dlam f_ext), the consistent
             linearised response to the next load increment, and move the load as far as the
             exact J > 0 step bound allows (the increment is cut to what keeps every point valid);
             with contact, one that the walls' time of impact stops short moves the load on, the
             prescribed displacements alone, as far as that keeps every point valid (loading.past_the_walls);
  corrector  (at fixed load): Newton step with backtracking Armijo line search on the energy, the
             step first bounded so that J > 0 at every Gauss point (det F is quadratic in the step),
             and with element_bound (or the inversion barrier) at each element's 4 x 4 check points too;
             with contact, far from equilibrium the tangent takes contact's normal stiffness only
             (_contact_normal).  With corrector="trust_region" the step of K + shift I instead, taken
             or rejected by how well the energy's quadratic model predicted its fall, the shift adapted
             (nma.solver.correctors; the predictor is then solved with the kept shift).
A load step fails when its line search cannot decrease the energy, when several corrector steps in a
row are cut to a small fraction of the Newton step (the increment is beyond the reach of Newton's
model: fail fast), or when it takes too many iterations; then the state returns to the last converged
load and the increment is halved.  Increments grow after a load step that converged within a third
of max_step_iters (a slow one says the next should be no larger).  A non-descent corrector direction
means an indefinite Hessian (a buckling structure): du^T K du < 0, so -du descends with negative
curvature and the iteration line-searches along it (a snap-through makes progress instead of
stalling); the next step is shifted by a diagonal term sized from the curvature the direction revealed
(twice -du^T K du / du^T du) and from the shift that last gave descent in this solve, and the shift
then decays tenfold per step back towards the pure Newton step.  A load step that keeps descending is
given max_step_iters iterations: cutting it much earlier throws away snap-throughs about to converge
and the slow descent along the soft valley of a nearly-mechanism design; one whose
residual is, or just was, within FINISHING_RESIDUAL (1000) times the tolerance gets up to
FINISHING_ITERS more.  Convergence: ||g_f|| <= rtol * f_ref + atol * k_ref * L, where f_ref is the
norm of the linearised out-of-balance force of the full load and k_ref * L a force scale of the
structure, never below tolerance_floor; the norms are taken scaled (norm), so that a very soft
material's residual does not underflow to 0.  The load steps before the last may close at a looser
path_rtol instead (0, the default:
rtol): the next predictor's right-hand side carries the residual left, but where several equilibria
lie near one actuation (walls in contact) the looser path can end on another (docs/explanation/physical-states.md).  A
warm solve (setup's `start`) walks the same way from another sample's equilibrium: the prescribed
displacements from that sample's to this one's.  The converged state is a stationary point of the
energy, usually a minimum; where a symmetric path has passed a buckling point it can be a saddle
(Simulator.negative_eigenvalues counts its unstable modes).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..mechanics import contact
from ..mechanics.energy import Tangents, check_point_dets, quadrature
from ..mechanics.options import NEARLY_INCOMPRESSIBLE
from ..registry import CORRECTORS
from . import loading
from .correctors import Trial
from .equations import Equations, Problem, State
from .options import NewtonOptions
from .status import NewtonInfo, Status


class Linearised(NamedTuple):
    """A state linearised, its load step closed if it converged, and the right-hand side of its step."""
    state: State
    energy: jnp.ndarray
    g: jnp.ndarray
    kel: Tangents
    rhs: jnp.ndarray


def setup(eqs: Equations, opts: NewtonOptions, X, d, mat, start=None, inertia=None) -> tuple[Problem, State]:
    """The problem data and the initial state (NONFINITE_INPUT at once for non-finite input, INVERTS for
    a warm start inverted at the check points under this design, with element_bound, WALLS_CROSS for one
    whose pores' walls cross under it, with contact).  Cold (start None): at rest.  Warm (start =
    (u_free0, u_D0, kel_rest, X0): another sample's equilibrium, under the full dead load, this design's
    element tangents at rest, and the reference points X0 it was solved on): the load walks from u_D0 to this
    sample's u_D.  Either way the first iteration is a
    predictor, whose right-hand side -(g + K_fD (u_D - u_D0)) also carries the start's own residual g
    where the design moved since: the first-order response to the change of design and actuation
    together.  The tolerance is the cold solve's either way (the force scale of the full load, from
    the tangent at rest), so a warm answer meets the same test as a cold one.  A time step (`inertia`,
    nma.dynamics) starts warm at the previous state (kel_rest unused); its scales come from its first
    linearisation (_step_scales)."""
    quad = quadrature(eqs.solid, X, check_points=opts.element_bound)
    u_D = eqs.A @ d
    finite = jnp.all(jnp.isfinite(X)) & jnp.all(jnp.isfinite(d)) & jnp.all(jnp.isfinite(mat))
    scalar = lambda v: jnp.asarray(v, X.dtype)  # noqa: E731
    zero = jnp.zeros(eqs.boundary.n_dofs, X.dtype)
    size = jnp.max(jnp.ptp(X, axis=0))
    if start is None:
        p = Problem(quad, u_D, mat, size, jnp.zeros_like(u_D), scalar(0.0))
        u0, tol, k_ref, f_ref = zero, scalar(0.0), scalar(1.0), scalar(0.0)
    else:
        u0, u_D0, kel_rest, X0 = start
        finite = finite & jnp.all(jnp.isfinite(u0)) & jnp.all(jnp.isfinite(u_D0)) & jnp.all(jnp.isfinite(X0))
        p = Problem(quad, u_D, mat, size, u_D0, scalar(1.0), inertia)
        # a time step's scales come from its first linearisation (_step_scales), as a cold solve's do
        tol, k_ref, f_ref = _scales(eqs, opts, p, kel_rest) if inertia is None else (scalar(0.0), scalar(1.0), scalar(0.0))
    status = jnp.where(finite, Status.RUNNING, Status.NONFINITE_INPUT)
    if start is not None and opts.element_bound:
        # a start inverted between Gauss points under this design (it moved since): no bound holds from
        # there, so the warm solve ends at once (INVERTS) and is redone cold
        J, defined = check_point_dets(eqs.solid.mesh, X, eqs.full(u0, u_D0))
        status = jnp.where(finite & jnp.any((J <= 0) & defined), Status.INVERTS, status)
    if start is not None and eqs.solid.contact:
        # the start's displacements carried from the design it was solved on to this one: where a wall
        # vertex meets a chord on the way, the start is interpenetrated here (the barrier sees distances,
        # not sides, and would keep it so), so the warm solve ends at once and is redone cold
        x0 = X0 + eqs.full(u0, u_D0)
        crossed = contact.time_of_impact(eqs.solid.contact, quad.walls, x0, X - X0, horizon=1.0) <= 1.0
        status = jnp.where(finite & crossed, Status.WALLS_CROSS, status)
    return p, _initial(opts, u0, status, tol, k_ref, f_ref)


def _initial(opts: NewtonOptions, u0, status, tol, k_ref, f_ref) -> State:
    """A solve's first state: at u0, load factor 0, its first step a predictor."""
    scalar = lambda v: jnp.asarray(v, u0.dtype)  # noqa: E731
    return State(u=u0, lam=scalar(0.0), u_conv=u0, lam_conv=scalar(0.0), dlam=scalar(opts.initial_increment),
                 predictor=jnp.asarray(True), shift=scalar(0.0), it=jnp.asarray(0), step_it=jnp.asarray(0),
                 steps=jnp.asarray(0), cuts=jnp.asarray(0), status=status, tol=tol, k_ref=k_ref, rnorm=scalar(jnp.inf),
                 history=jnp.full(opts.max_iters, jnp.nan, u0.dtype), damped=jnp.asarray(0),
                 shift_memory=scalar(0.0), f_ref=f_ref, inverting=jnp.asarray(False))


def continue_in_time(eqs: Equations, opts: NewtonOptions, p: Problem, lin: Linearised, d, inertia):
    """The next time step from the converged end (p, lin) of the last: its Problem (the same design and
    material, the boundary from its end to eqs.A d, this step's `inertia`), its first State (at that end,
    as setup starts a time step) and its first linearisation without another pass over the elements: the
    strain energy, force and element tangents at that state are the last step's, only the Inertia's terms
    change (returned as linearise's `at`; contact's blocks are taken again, exact)."""
    q = Problem(p.quad, eqs.A @ d, p.mat, p.size, p.u_D, jnp.asarray(1.0, p.size.dtype), inertia)
    u = eqs.full(lin.state.u, p.u_D).reshape(-1)
    edofs = eqs.edofs[:eqs.elements]
    energy = lin.energy - p.inertia.energy(edofs, u) + inertia.energy(edofs, u)
    g = lin.g + (inertia.force(edofs, u) - p.inertia.force(edofs, u))[eqs.free]
    kel = lin.kel._replace(elements=lin.kel.elements + (inertia.blocks - p.inertia.blocks))
    if eqs.solid.contact:  # the last tangent's contact blocks may be of the normal stiffness only (_contact_normal)
        mu = eqs.solid.material.moduli(p.mat)[0]
        kel = kel._replace(**dict(zip(("contact", "which", "near"), contact.force_and_blocks(
            eqs.solid.contact, p.quad.walls, p.quad.X + u.reshape(-1, 2), mu, eqs.contact_slots)[2:])))
    finite = jnp.all(jnp.isfinite(d)) & jnp.all(jnp.isfinite(inertia.b))
    zero = jnp.asarray(0.0, u.dtype)
    status = jnp.where(finite, Status.RUNNING, Status.NONFINITE_INPUT)
    return q, _initial(opts, lin.state.u, status, zero, zero + 1.0, zero), (energy, g, kel)


def _scales(eqs: Equations, opts: NewtonOptions, p: Problem, kel):
    """The tolerance, the stiffness scale k_ref and the force scale f_ref, from the element tangents at
    rest: f_ref the norm of the linearised out-of-balance force of the full load, k_ref the largest
    diagonal entry."""
    f_ref = norm(eqs.coupling(kel, p.u_D) - eqs.f_free) + norm(eqs.f_free)
    return _tolerance(eqs, opts, p, kel, f_ref)


def _step_scales(eqs: Equations, opts: NewtonOptions, p: Problem, kel, g0):
    """A time step's scales, from its first linearisation (residual g0, tangent kel with the inertia's
    blocks): f_ref the norm of its linearised out-of-balance force at its start (the previous state's
    residual under this step's inertia, and the boundary's move), plus the static solve's force scale of
    the actuation at its end: a step meets at least the test a static solve of that actuation meets."""
    static = norm(eqs.coupling(kel, p.u_D) - eqs.f_free) + norm(eqs.f_free)
    return _tolerance(eqs, opts, p, kel, norm(g0 + eqs.coupling(kel, p.u_D - p.u_D0)) + static)


def _tolerance(eqs: Equations, opts: NewtonOptions, p: Problem, kel, f_ref):
    """rtol f_ref + atol k_ref size, never below tolerance_floor: a solve converges against a scale
    that cannot vanish."""
    kdiag = jnp.max(jnp.stack([jnp.max(jnp.abs(jnp.diagonal(K, axis1=1, axis2=2)), initial=0.0)
                               for _, K in eqs.blocks(kel)]))
    tol = opts.rtol * f_ref + opts.atol * kdiag * p.size
    return jnp.maximum(tol, tolerance_floor(tol.dtype)), kdiag, f_ref


def tolerance_floor(dtype) -> float:
    """The smallest tolerance: a residual below it has round-off (eps of it) under float's smallest
    normal number, so that it cannot be told from 0 (about 1e-292 in float64; every material in its
    ranges has a tolerance far above it)."""
    info = jnp.finfo(dtype)
    return float(info.tiny) / float(info.eps)


EXPONENT_BITS = 0x7FF0000000000000  # a float64's exponent field


def norm(v):
    """||v||_2 without underflow or overflow: v divided by the power of two at or below its largest
    entry, the norm of that times it.  A power of two scales exactly, so wherever jnp.linalg.norm(v)
    neither underflows nor overflows this is the same number, bit for bit; where its squares would
    underflow (forces of a very soft material) it is not 0."""
    if v.dtype != jnp.float64:
        return jnp.linalg.norm(v)
    m = jnp.max(jnp.abs(v), initial=0.0)
    bits = jax.lax.bitcast_convert_type(m, jnp.uint64) & jnp.uint64(EXPONENT_BITS)
    scale = jax.lax.bitcast_convert_type(bits, jnp.float64)
    scale = jnp.where(scale > 0, scale, jnp.finfo(jnp.float64).tiny)  # m subnormal: least normal
    ok = jnp.isfinite(m) & (m > 0)
    return jnp.where(ok, scale * jnp.linalg.norm(jnp.where(ok, v / scale, v)), jnp.linalg.norm(v))


def linearise(eqs: Equations, opts: NewtonOptions, p: Problem, s: State, at=None) -> Linearised:
    """First half of an iteration: linearise at the state (or take `at`, its potential, free residual and
    element tangents, already computed); a corrector that meets the tolerance closes its load step (and
    the solve, at full load); the right-hand side of the next step."""
    E0, g, kel = (eqs.linearise(p.quad, s.u, p.boundary(s.lam), p.load(s.lam), p.mat, _contact_normal(eqs, opts, s),
                                  p.inertia)
                  if at is None else at)
    rnorm = norm(g)
    first = (s.it == 0) & (s.tol == 0)  # a cold start, at rest, or a time step: the scales come from this tangent
    scales = (lambda _: _scales(eqs, opts, p, kel)) if p.inertia is None else (lambda _: _step_scales(eqs, opts, p, kel, g))
    tol, k_ref, f_ref = jax.lax.cond(first, scales,
                                     lambda _: (s.tol, s.k_ref, s.f_ref), None)
    closed = loading.close_step(opts, s, rnorm, tol)
    rhs = loading.step_rhs(eqs, p, closed, g, kel)
    return Linearised(closed._replace(tol=tol, k_ref=k_ref, f_ref=f_ref, rnorm=rnorm), E0, g, kel, rhs)


def _contact_normal(eqs: Equations, opts: NewtonOptions, s: State):
    """Whether this iteration's tangent takes contact's normal stiffness only (positive semi-definite):
    in a load step's first corrector (the predictor has just pressed the walls together along a line
    that ignored how the barrier stiffens) and in every corrector whose last residual was above
    contact_exact_below times the force scale.  The exact Hessian's indefinite part swings the walls in
    and out of the barrier there (shape matching's trained design at 14 x 5: 4 evaluation targets that
    took 200 iterations and more now take 98-119).  Near equilibrium the exact one, so that Newton
    converges quadratically and a converged state's factor is of the exact Hessian (its inertia, the
    adjoint).  False (a static branch) without contact or with contact_exact_below = 0."""
    if not (eqs.solid.contact and opts.contact_exact_below > 0):
        return False
    return (s.it > 0) & ~s.predictor & ((s.step_it == 0) | (s.rnorm > opts.contact_exact_below * s.f_ref))


def _tick(s: State, opts: NewtonOptions) -> State:
    it = s.it + 1
    status = jnp.where((s.status == Status.RUNNING) & (it >= opts.max_iters), Status.ITERATION_LIMIT, s.status)
    return s._replace(it=it, status=status, history=s.history.at[s.it].set(s.rnorm))


def hold(opts: NewtonOptions, lin: Linearised) -> State:
    """Second half of an iteration that takes no step (the solve has ended)."""
    return _tick(lin.state._replace(predictor=jnp.asarray(False)), opts)


def advance(eqs: Equations, opts: NewtonOptions, p: Problem, lin: Linearised, du) -> State:
    """Second half of an iteration: take the step du (the solution of K_ff du = rhs), a predictor's as
    far as the bounds allow, a corrector's as solver.corrector finds (nma.solver.correctors)."""
    s, E0, g = lin.state, lin.energy, lin.g
    predictor, dlam = s.predictor, s.dlam
    corrector = CORRECTORS.get(opts.corrector)()
    finite = jnp.all(jnp.isfinite(du))
    du = jnp.where(finite, du, jnp.zeros_like(du))
    slope = jnp.dot(g, du)
    # a corrector direction that climbs (g.du > 0) has negative curvature, du^T K du < -shift |du|^2:
    # its reverse descends with negative curvature too, so the iteration steps along -du (and the
    # next one is shifted) instead of being spent on a retry
    flipped = ~predictor & finite & (slope > 0)
    step = jnp.where(flipped, -du, du)
    # the step may go a fraction of the way to J = 0 or to the walls' impact (predictor: load moves along)
    gauss, checks, walls = loading.bounds(eqs, p, s.u, s.lam, step, jnp.where(predictor, dlam, 0.0),
                                          1.0 / opts.step_fraction)
    material = jnp.minimum(gauss, checks)
    a0 = jnp.minimum(1.0, opts.step_fraction * jnp.minimum(material, walls))
    # the step stopped where the material would invert between Gauss points (the element bound's doing)
    inverting = s.inverting | ((checks < jnp.minimum(gauss, walls)) & (a0 < 1.0))

    def predict(_):
        return a0, finite & (a0 * dlam >= opts.min_increment), jnp.asarray(True), jnp.ones_like(slope), jnp.zeros_like(slope)

    def correct(_):
        descent = finite & (slope < 0)
        energy = lambda u: eqs.potential(p.quad, u, p.boundary(s.lam), p.load(s.lam), p.mat, p.inertia)  # noqa: E731
        noise = _energy_noise(eqs, p)  # a time step's only: a corrector serves static solves without it
        a, ok, agreement, curvature = corrector.search(eqs, opts, lin.kel, energy, s.u, step, E0, -jnp.abs(slope), a0,
                                                       *(() if noise is None else (noise,)))
        return a, (descent | flipped) & ok, descent, agreement, curvature

    a, ok, descent, agreement, curvature = jax.lax.cond(predictor, predict, correct, None)
    trial = Trial(du, step, slope, finite, flipped, descent, a, ok, agreement, curvature)
    step_it, damped, cut = corrector.cut(s, opts, trial)
    moved = ok & ~cut
    # the fraction of the increment the load goes (the free dofs go a of the predictor)
    reach = loading.past_the_walls(eqs, opts, p, s.u + a * step, s.lam + a * dlam, (1.0 - a) * dlam,
                                   predictor & (walls < material) & (p.mat[-1] < NEARLY_INCOMPRESSIBLE)) \
        if eqs.solid.contact else 0.0
    a_load = a + reach * (1.0 - a)
    u_new, lam_new, dlam_new, dlam_cut = loading.after_step(s, s.u + a * step, moved, cut, a_load)
    shift_new, shift_memory = corrector.next_shift(s, trial, cut)
    why = jnp.where(inverting, Status.INVERTS, Status.INCREMENT_TOO_SMALL) if opts.element_bound \
        else Status.INCREMENT_TOO_SMALL
    status = jnp.where(cut & (dlam_cut < opts.min_increment), why, s.status)
    return _tick(s._replace(u=u_new, lam=lam_new, dlam=dlam_new, predictor=cut, shift=shift_new,
                            step_it=jnp.where(cut, 0, step_it), cuts=s.cuts + cut, status=status,
                            damped=jnp.where(cut, 0, damped), shift_memory=shift_memory, inverting=inverting), opts)


ENERGY_NOISE = 1e-13  # a time step's energy round-off, relative to mu0 x area (see _energy_noise)


def _energy_noise(eqs: Equations, p: Problem):
    """A time step's energy round-off: its strain energy sums terms of order mu0 at every Gauss point
    that cancel to O(strain^2), so at small strains (a small vibration) its round-off, ~1e-16 mu0 x area,
    exceeds 1e-12 |E0| and would stall the line search; ENERGY_NOISE mu0 x area bounds it.  None for a
    static solve (its tests as they were)."""
    if p.inertia is None:
        return None
    return ENERGY_NOISE * eqs.solid.material.moduli(p.mat)[0] * jnp.sum(p.quad.weights)


def leave_saddle(eqs: Equations, opts: NewtonOptions, p: Problem, lin: Linearised, v, curvature):
    """Move a converged state off a saddle along an unstable mode v (unit length, v^T K v = curvature
    < 0), as far as the energy keeps falling at least half as fast as its quadratic model says (from at
    most a tenth of the structure's size, within the J > 0 bound), and linearise there.  Newton goes
    on from there: with the next load step, or with correctors at full load, towards the equilibrium
    the buckled structure settles in.  Returns (linearised state, whether the energy fell)."""
    s, E0 = lin.state, lin.energy
    v = jnp.where(jnp.dot(lin.g, v) > 0, -v, v)  # downhill (at a saddle g ~ 0: either sign)
    slope = jnp.dot(lin.g, v)
    reach = 0.1 * p.size / jnp.max(jnp.abs(v))
    a0 = jnp.minimum(reach, opts.step_fraction * loading.bound(eqs, p, s.u, s.lam, v, 0.0, reach / opts.step_fraction))

    def falls(a, Ea):
        return Ea <= E0 + 0.5 * (slope * a + 0.5 * curvature * a * a)

    def body(c):
        a, _, k = c
        a = 0.5 * a
        return a, eqs.potential(p.quad, s.u + a * v, p.boundary(s.lam), p.load(s.lam), p.mat, p.inertia), k + 1

    a, Ea, _ = jax.lax.while_loop(lambda c: ~falls(c[0], c[1]) & (c[2] < opts.max_backtracks), body,
                                  (2.0 * a0, jnp.inf, 0))
    ok = falls(a, Ea) & (a0 > 0)
    # at full load the state continues as a corrector; below it, as the predictor it was
    state = s._replace(u=jnp.where(ok, s.u + a * v, s.u), status=jnp.asarray(Status.RUNNING), step_it=jnp.asarray(0),
                       damped=jnp.asarray(0), shift=jnp.zeros_like(s.shift),
                       predictor=s.predictor & (s.lam < 1.0))
    return linearise(eqs, opts, p, state), ok


def result(s: State) -> tuple[jnp.ndarray, NewtonInfo]:
    # a solve that did not converge returns the last state it did converge to (at info.load), not the
    # iterate it stopped at: an equilibrium, if not the one asked for
    u = jnp.where(s.status == Status.CONVERGED, s.u, s.u_conv)
    return u, NewtonInfo(s.status, s.it, s.steps, s.cuts, s.lam_conv, s.rnorm, s.tol, s.history)


def newton_solve(eqs: Equations, backend, opts: NewtonOptions, X, d, mat):
    """Solve for the free displacements at full load as one traced loop (a traceable linear backend,
    e.g. dense on a GPU). Returns (u_free, NewtonInfo). Host backends drive the same two halves of an
    iteration from Python instead (HostNewton), so that no compiled program holds a host callback."""
    p, init = setup(eqs, opts, X, d, mat)

    def body(s: State) -> State:
        lin = linearise(eqs, opts, p, s)
        return jax.lax.cond(lin.state.status == Status.RUNNING,
                            lambda _: advance(eqs, opts, p, lin, backend.solve(lin.kel, lin.rhs, lin.state.shift)),
                            lambda _: hold(opts, lin), None)

    return result(jax.lax.while_loop(lambda s: s.status == Status.RUNNING, body, init))
