"""Static equilibrium by Newton's method with adaptive incremental loading, as one jitted loop.

Each iteration assembles the force and element tangents at the current state and does one of:
  predictor  (start of a load step): solve K_ff du = -(g + K_fD dU_D - dlam f_ext), the consistent
             linearised response to the next load increment, and move the load as far as the
             exact J > 0 step bound allows (the increment is cut to what keeps every point valid);
             with contact, one that the walls' time of impact stops short moves the load on, the
             prescribed displacements alone, as far as that keeps every point valid (_past_the_walls);
  corrector  (at fixed load): Newton step with backtracking Armijo line search on the energy, the
             step first bounded so that J > 0 at every Gauss point (det F is quadratic in the step),
             and with element_bound (or the inversion barrier) at each element's 4 x 4 check points too;
             with contact, far from equilibrium the tangent takes contact's normal stiffness only
             (_contact_normal).  With corrector="trust_region" the step of K + shift I instead, taken
             or rejected by how well the energy's quadratic model predicted its fall, the shift adapted
             (_trust_region, _next_trust_shift; the predictor is then solved with the kept shift).
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
given max_step_iters (100) iterations: cutting it earlier (25, 60) threw away snap-throughs that were
about to converge and the slow descent along the soft valley of a nearly-mechanism design; one whose
residual is, or just was, within FINISHING_RESIDUAL (1000) times the tolerance gets up to
FINISHING_ITERS more.  Convergence: ||g_f|| <= rtol * f_ref + atol * k_ref * L, where f_ref is the
norm of the linearised out-of-balance force of the full load and k_ref * L a force scale of the
structure.  The load steps before the last may close at a looser path_rtol instead (0, the default:
rtol): the next predictor's right-hand side carries the residual left, but where several equilibria
lie near one actuation (walls in contact) the looser path can end on another (docs/validity.md).  A
warm solve (setup's `start`) walks the same way from another sample's equilibrium: the prescribed
displacements from that sample's to this one's.  The converged state is a stationary point of the
energy, usually a minimum; where a symmetric path has passed a buckling point it can be a saddle
(Simulator.negative_eigenvalues counts its unstable modes).
"""
from __future__ import annotations

import copy
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SolverError
from ..geometry.discretise import Discretisation
from ..mechanics import contact
from ..mechanics.options import NEARLY_INCOMPRESSIBLE
from ..mechanics.energy import (Quadrature, Tangents, check_point_dets, energy_force_tangents, quadrature,
                                step_bounds, strain_energy)
from .assembly import element_dofs
from .options import NewtonOptions

RUNNING, CONVERGED, INCREMENT_TOO_SMALL, ITERATION_LIMIT, NONFINITE_INPUT, INVERTS, WALLS_CROSS = 0, 1, 2, 3, 4, 5, 6
FINISHING_ITERS = 5  # corrector iterations past max_step_iters for a step nearly converged...
FINISHING_RESIDUAL = 1e3  # ...one whose residual is, or just was, within this factor of the tolerance
TRUST_ACCEPT, TRUST_POOR, TRUST_GOOD = 0.1, 0.25, 0.75  # actual over predicted fall: taken, shift raised, lowered
TRUST_REJECTIONS = 10  # rejected trust-region steps in a row that cut the load step (the shift grew 4^10-fold)
STATUS_TEXT = {RUNNING: "still running", CONVERGED: "converged",
               INCREMENT_TOO_SMALL: "the load increment fell below solver.min_increment",
               ITERATION_LIMIT: "the iteration limit solver.max_iters was reached",
               NONFINITE_INPUT: "its input (geometry, actuation or material) is not finite; nothing was solved",
               INVERTS: ("the load increment fell below solver.min_increment where the material would invert "
                         "between Gauss points (det F at an element's 4 x 4 check points, which solver.element_bound "
                         "keeps positive; without the bound the solve may go on to a state inverted there, not a "
                         "physical object)"),
               WALLS_CROSS: ("a warm start whose pores' walls cross each other under this design (it moved since "
                             "that equilibrium was kept); such a start is redone from rest")}


class NewtonInfo(NamedTuple):
    status: jnp.ndarray
    iterations: jnp.ndarray
    load_steps: jnp.ndarray
    cuts: jnp.ndarray
    load: jnp.ndarray             # load factor of the last converged state
    residual: jnp.ndarray         # ||g_f|| at the last iterate
    tolerance: jnp.ndarray
    residual_history: jnp.ndarray  # (max_iters,), nan past the last iteration


class Equilibrium(NamedTuple):
    """What a solve returns: the displacement of every control point and how Newton got there (its
    status, statistics and residual history).  A pytree, so traced, batched (vmap: every field gains
    the batch axis) and differentiated solves return it too; `u, info = equilibrium` unpacks it.  The
    host-side properties read a solved one; a failed solve's error says how far it got and why."""
    u: jnp.ndarray     # (n_points, 2); of a failed solve, its last converged state (at load info.load)
    info: NewtonInfo

    @property
    def converged(self) -> np.ndarray:
        """Whether the solve reached full load (per sample of a batch)."""
        return np.asarray(self.info.status) == CONVERGED

    @property
    def message(self) -> str:
        """The status in words (one solve)."""
        return STATUS_TEXT.get(int(self.info.status), f"status {int(self.info.status)}")

    def error(self, context: str = "", nu: float | None = None) -> SolverError | None:
        """None where converged, else the error of the failed solve (of the first failed sample of a
        batch), `context` saying which solve it was."""
        status = np.asarray(self.info.status)
        if status.ndim == 0:
            return None if int(status) == CONVERGED else failure(self.info, context, nu)
        failed = np.flatnonzero(status != CONVERGED)
        if not failed.size:
            return None
        i = int(failed[0])
        return failure(jax.tree_util.tree_map(lambda a: np.asarray(a)[i], self.info), f"{context}sample {i}: ", nu)


class _State(NamedTuple):
    u: jnp.ndarray
    lam: jnp.ndarray
    u_conv: jnp.ndarray
    lam_conv: jnp.ndarray
    dlam: jnp.ndarray
    predictor: jnp.ndarray
    shift: jnp.ndarray
    it: jnp.ndarray
    step_it: jnp.ndarray
    steps: jnp.ndarray
    cuts: jnp.ndarray
    status: jnp.ndarray
    tol: jnp.ndarray
    k_ref: jnp.ndarray
    rnorm: jnp.ndarray
    history: jnp.ndarray
    damped: jnp.ndarray   # heavily damped corrector steps (trust region: rejected steps) in a row in this load step
    shift_memory: jnp.ndarray  # the last diagonal shift that gave a descent direction in this solve
    f_ref: jnp.ndarray    # the force scale of the full load (the tolerance is rtol times it, plus atol's)
    inverting: jnp.ndarray  # since the last converged load step, a step was stopped short by the check points


class Equations:
    """The discrete equilibrium equations of one scene: everything Newton and the adjoint need.
    `contact_slots`: the contact blocks a linearisation's Tangents has room for (all where None)."""

    def __init__(self, disc: Discretisation, contact_slots: int | None = None):
        self.disc = disc
        self.contact_slots = contact_slots
        self.free = jnp.asarray(disc.free_dofs)
        self.dirichlet = jnp.asarray(disc.dirichlet_dofs)
        self.A = jnp.asarray(disc.actuation_matrix)
        self.f_ext = jnp.asarray(disc.external_force)
        self.f_free = self.f_ext[self.free]
        self.edofs = jnp.asarray(element_dofs(disc))
        self.elements = disc.elem_points.reshape(-1, 9).shape[0]

    def with_contact_slots(self, slots: int | None) -> "Equations":
        """The same equations, their linearisations with room for `slots` contact blocks."""
        other = copy.copy(self)
        other.contact_slots = slots
        return other

    def full(self, u_free, u_dir):
        """Every control point's displacement from the free DOFs and the prescribed ones."""
        u = jnp.zeros(2 * self.disc.n_points, u_free.dtype)
        return u.at[self.free].set(u_free).at[self.dirichlet].set(u_dir).reshape(-1, 2)

    def potential(self, quad, u_free, u_dir, load, mat):
        """Strain energy less the work of the dead load at load factor `load`."""
        u = self.full(u_free, u_dir)
        return strain_energy(self.disc, quad, u, mat) - load * jnp.dot(self.f_ext, u.reshape(-1))

    def residual(self, quad, u_free, u_dir, load, mat):
        return jax.grad(self.potential, argnums=1)(quad, u_free, u_dir, load, mat)

    def linearise(self, quad, u_free, u_dir, load, mat, contact_normal=False):
        """Potential, free residual g_f and Tangents at a state (`contact_normal`: contact's blocks of
        its normal stiffness only, nma.mechanics.contact.force_and_blocks)."""
        u = self.full(u_free, u_dir)
        energy, force, kel = energy_force_tangents(self.disc, quad, u, mat, contact_normal, self.contact_slots)
        potential = energy - load * jnp.dot(self.f_ext, u.reshape(-1))
        return potential, force.reshape(-1)[self.free] - load * self.f_free, kel

    def blocks(self, kel: Tangents):
        """(dofs (B, 18), blocks (B, 18, 18)) of the elements, then of the contact slots (an empty slot's
        block is zero)."""
        contact = self.edofs[self.elements + jnp.maximum(kel.which, 0)]
        return (self.edofs[:self.elements], kel.elements), (contact, kel.contact)

    def curvature(self, kel: Tangents, v_free):
        """v^T K_ff v: the energy's second derivative along the free-dof direction v."""
        v = jnp.zeros(2 * self.disc.n_points, kel.elements.dtype).at[self.free].set(v_free)
        return sum(jnp.einsum("ea,eab,eb->", v[dofs], K, v[dofs]) for dofs, K in self.blocks(kel))

    def coupling(self, kel: Tangents, u_D):
        """K_fD u_D: the free force produced by moving the Dirichlet dofs by u_D, at fixed free dofs."""
        v = jnp.zeros(2 * self.disc.n_points, kel.elements.dtype).at[self.dirichlet].set(u_D)
        f = jnp.zeros_like(v)
        for dofs, K in self.blocks(kel):
            f = f.at[dofs].add(jnp.einsum("eab,eb->ea", K, v[dofs]))
        return f[self.free]


class Problem(NamedTuple):
    """What one solve needs besides the state: the design's quadrature, the boundary data, the material.
    The load path runs from the start (load factor 0) to the target (1): the prescribed displacements
    from u_D0 to u_D and the dead load's factor from load0 to 1.  A cold solve starts at rest (u_D0 = 0,
    load0 = 0); a warm one at another sample's equilibrium (its u_D0, the full dead load)."""
    quad: Quadrature
    u_D: jnp.ndarray
    mat: jnp.ndarray
    size: jnp.ndarray
    u_D0: jnp.ndarray
    load0: jnp.ndarray

    def boundary(self, lam):
        return self.u_D0 + lam * (self.u_D - self.u_D0)

    def load(self, lam):
        return self.load0 + lam * (1.0 - self.load0)


class Linearised(NamedTuple):
    """A state linearised, its load step closed if it converged, and the right-hand side of its step."""
    state: _State
    energy: jnp.ndarray
    g: jnp.ndarray
    kel: Tangents
    rhs: jnp.ndarray


def setup(eqs: Equations, opts: NewtonOptions, X, d, mat, start=None) -> tuple[Problem, _State]:
    """The problem data and the initial state (NONFINITE_INPUT at once for non-finite input, INVERTS for
    a warm start inverted at the check points under this design, with element_bound, WALLS_CROSS for one
    whose pores' walls cross under it, with contact).  Cold (start None): at rest.  Warm (start =
    (u_free0, u_D0, kel_rest, X0): another sample's equilibrium, under the full dead load, this design's
    element tangents at rest, and the reference points X0 it was solved on): the load walks from u_D0 to this
    sample's u_D.  Either way the first iteration is a
    predictor, whose right-hand side -(g + K_fD (u_D - u_D0)) also carries the start's own residual g
    where the design moved since: the first-order response to the change of design and actuation
    together.  The tolerance is the cold solve's either way (the force scale of the full load, from
    the tangent at rest), so a warm answer meets the same test as a cold one."""
    quad = quadrature(eqs.disc, X, check_points=opts.element_bound)
    u_D = eqs.A @ d
    finite = jnp.all(jnp.isfinite(X)) & jnp.all(jnp.isfinite(d)) & jnp.all(jnp.isfinite(mat))
    scalar = lambda v: jnp.asarray(v, X.dtype)
    zero = jnp.zeros(eqs.disc.n_dofs, X.dtype)
    size = jnp.max(jnp.ptp(X, axis=0))
    if start is None:
        p = Problem(quad, u_D, mat, size, jnp.zeros_like(u_D), scalar(0.0))
        u0, tol, k_ref, f_ref = zero, scalar(0.0), scalar(1.0), scalar(0.0)
    else:
        u0, u_D0, kel_rest, X0 = start
        finite = finite & jnp.all(jnp.isfinite(u0)) & jnp.all(jnp.isfinite(u_D0)) & jnp.all(jnp.isfinite(X0))
        p = Problem(quad, u_D, mat, size, u_D0, scalar(1.0))
        tol, k_ref, f_ref = _scales(eqs, opts, p, kel_rest)
    status = jnp.where(finite, RUNNING, NONFINITE_INPUT)
    if start is not None and opts.element_bound:
        # a start inverted between Gauss points under this design (it moved since): no bound holds from
        # there, so the warm solve ends at once (INVERTS) and is redone cold
        J, defined = check_point_dets(eqs.disc, X, eqs.full(u0, u_D0))
        status = jnp.where(finite & jnp.any((J <= 0) & defined), INVERTS, status)
    if start is not None and eqs.disc.contact:
        # the start's displacements carried from the design it was solved on to this one: where a wall
        # vertex meets a chord on the way, the start is interpenetrated here (the barrier sees distances,
        # not sides, and would keep it so), so the warm solve ends at once and is redone cold
        x0 = X0 + eqs.full(u0, u_D0)
        crossed = contact.time_of_impact(eqs.disc.contact, quad.walls, x0, X - X0, horizon=1.0) <= 1.0
        status = jnp.where(finite & crossed, WALLS_CROSS, status)
    init = _State(u0, scalar(0.0), u0, scalar(0.0), scalar(opts.initial_increment), jnp.asarray(True),
                  scalar(0.0), jnp.asarray(0), jnp.asarray(0), jnp.asarray(0), jnp.asarray(0),
                  status, tol, k_ref, scalar(jnp.inf),
                  jnp.full(opts.max_iters, jnp.nan, X.dtype), jnp.asarray(0), scalar(0.0), f_ref, jnp.asarray(False))
    return p, init


def _scales(eqs: Equations, opts: NewtonOptions, p: Problem, kel):
    """The tolerance, the stiffness scale k_ref and the force scale f_ref, from the element tangents at
    rest: f_ref the norm of the linearised out-of-balance force of the full load, k_ref the largest
    diagonal entry."""
    kdiag = jnp.max(jnp.stack([jnp.max(jnp.abs(jnp.diagonal(K, axis1=1, axis2=2)), initial=0.0)
                               for _, K in eqs.blocks(kel)]))
    f_ref = jnp.linalg.norm(eqs.coupling(kel, p.u_D) - eqs.f_free) + jnp.linalg.norm(eqs.f_free)
    return opts.rtol * f_ref + opts.atol * kdiag * p.size, kdiag, f_ref


def linearise(eqs: Equations, opts: NewtonOptions, p: Problem, s: _State, at=None) -> Linearised:
    """First half of an iteration: linearise at the state (or take `at`, its potential, free residual and
    element tangents, already computed); a corrector that meets the tolerance closes its load step (and
    the solve, at full load); the right-hand side of the next step."""
    E0, g, kel = (eqs.linearise(p.quad, s.u, p.boundary(s.lam), p.load(s.lam), p.mat, _contact_normal(eqs, opts, s))
                  if at is None else at)
    rnorm = jnp.linalg.norm(g)
    first = (s.it == 0) & (s.tol == 0)  # a cold start, at rest: the scales come from this tangent
    tol, k_ref, f_ref = jax.lax.cond(first, lambda _: _scales(eqs, opts, p, kel),
                                     lambda _: (s.tol, s.k_ref, s.f_ref), None)
    step_done = (~s.predictor) & (rnorm <= _step_tolerance(opts, s.lam, tol))
    finished = step_done & (s.lam >= 1.0)
    lam_conv = jnp.where(step_done, s.lam, s.lam_conv)
    u_conv = jnp.where(step_done, s.u, s.u_conv)
    quick = s.step_it <= opts.max_step_iters // 3  # a slow step: the next one no larger
    dlam = jnp.where(step_done, jnp.minimum(s.dlam * jnp.where(quick, opts.grow, 1.0), 1.0 - s.lam), s.dlam)
    predictor = s.predictor | step_done
    status = jnp.where(finished, CONVERGED, s.status)
    rhs = jnp.where(predictor, -(g + eqs.coupling(kel, dlam * (p.u_D - p.u_D0)) - dlam * (1.0 - p.load0) * eqs.f_free),
                    -g)
    state = s._replace(u_conv=u_conv, lam_conv=lam_conv, dlam=dlam, predictor=predictor,
                       steps=s.steps + step_done, status=status, tol=tol, k_ref=k_ref, f_ref=f_ref, rnorm=rnorm,
                       inverting=s.inverting & ~step_done)
    return Linearised(state, E0, g, kel, rhs)


def _contact_normal(eqs: Equations, opts: NewtonOptions, s: _State):
    """Whether this iteration's tangent takes contact's normal stiffness only (positive semi-definite):
    in a load step's first corrector (the predictor has just pressed the walls together along a line
    that ignored how the barrier stiffens) and in every corrector whose last residual was above
    contact_exact_below times the force scale.  The exact Hessian's indefinite part swings the walls in
    and out of the barrier there (shape matching's trained design at 14 x 5: 4 evaluation targets that
    took 200 iterations and more now take 98-119).  Near equilibrium the exact one, so that Newton
    converges quadratically and a converged state's factor is of the exact Hessian (its inertia, the
    adjoint).  False (a static branch) without contact or with contact_exact_below = 0."""
    if not (eqs.disc.contact and opts.contact_exact_below > 0):
        return False
    return (s.it > 0) & ~s.predictor & ((s.step_it == 0) | (s.rnorm > opts.contact_exact_below * s.f_ref))


def _step_tolerance(opts: NewtonOptions, lam, tol):
    """The residual that closes a load step: the solve's tolerance at full load, the looser path_rtol
    before it (the next predictor's right-hand side carries the residual left, so it is not lost)."""
    return jnp.where(lam >= 1.0, tol, tol * max(1.0, opts.path_rtol / opts.rtol))


def _tick(s: _State, opts: NewtonOptions) -> _State:
    it = s.it + 1
    status = jnp.where((s.status == RUNNING) & (it >= opts.max_iters), ITERATION_LIMIT, s.status)
    return s._replace(it=it, status=status, history=s.history.at[s.it].set(s.rnorm))


def hold(opts: NewtonOptions, lin: Linearised) -> _State:
    """Second half of an iteration that takes no step (the solve has ended)."""
    return _tick(lin.state._replace(predictor=jnp.asarray(False)), opts)


def advance(eqs: Equations, opts: NewtonOptions, p: Problem, lin: Linearised, du) -> _State:
    """Second half of an iteration: take the step du (the solution of K_ff du = rhs)."""
    s, E0, g = lin.state, lin.energy, lin.g
    predictor, dlam = s.predictor, s.dlam
    finite = jnp.all(jnp.isfinite(du))
    du = jnp.where(finite, du, jnp.zeros_like(du))
    slope = jnp.dot(g, du)
    # a corrector direction that climbs (g.du > 0) has negative curvature, du^T K du < -shift |du|^2:
    # its reverse descends with negative curvature too, so the iteration steps along -du (and the
    # next one is shifted) instead of being spent on a retry
    flipped = ~predictor & finite & (slope > 0)
    step = jnp.where(flipped, -du, du)
    # the step may go a fraction of the way to J = 0 or to the walls' impact (predictor: load moves along)
    gauss, checks, walls = _step_bounds(eqs, p, s.u, s.lam, step, jnp.where(predictor, dlam, 0.0), 1.0 / opts.step_fraction)
    material = jnp.minimum(gauss, checks)
    a0 = jnp.minimum(1.0, opts.step_fraction * jnp.minimum(material, walls))
    # the step stopped where the material would invert between Gauss points (the element bound's doing)
    inverting = s.inverting | ((checks < jnp.minimum(gauss, walls)) & (a0 < 1.0))

    trust = opts.corrector == "trust_region"

    def predict(_):
        return a0, finite & (a0 * dlam >= opts.min_increment), jnp.asarray(True), jnp.ones_like(slope), jnp.zeros_like(slope)

    def correct(_):
        descent = finite & (slope < 0)
        energy = lambda u: eqs.potential(p.quad, u, p.boundary(s.lam), p.load(s.lam), p.mat)  # noqa: E731
        curvature = eqs.curvature(lin.kel, step) if trust else jnp.zeros_like(slope)  # the model's, correctors only
        if trust:  # the bounded step, taken where the energy's quadratic model predicted its fall
            a, ok, agreement = _trust_region(energy, s.u, step, E0, -jnp.abs(slope), curvature, a0)
        else:  # bounded line search on the energy at fixed load
            (a, ok), agreement = _line_search(energy, opts, s.u, step, E0, -jnp.abs(slope), a0), jnp.ones_like(slope)
        return a, (descent | flipped) & ok, descent, agreement, curvature

    a, ok, descent, agreement, curvature = jax.lax.cond(predictor, predict, correct, None)
    if trust:
        step_it, damped, cut = _cut_trust_region(s, opts, ok)
    else:
        step_it, damped, cut = _cut(s, opts, a, ok, flipped, descent)
    moved = ok & ~cut
    # the fraction of the increment the load goes (the free dofs go a of the predictor)
    reach = _past_the_walls(eqs, opts, p, s.u + a * step, s.lam + a * dlam, (1.0 - a) * dlam,
                            predictor & (walls < material) & (p.mat[1] < NEARLY_INCOMPRESSIBLE)) if eqs.disc.contact else 0.0
    a_load = a + reach * (1.0 - a)
    u_new = jnp.where(moved, s.u + a * step, jnp.where(cut, s.u_conv, s.u))
    lam_new = jnp.where(moved & predictor, s.lam + a_load * dlam, jnp.where(cut, s.lam_conv, s.lam))
    dlam_cut = 0.5 * jnp.where(predictor, dlam, s.lam - s.lam_conv)
    dlam_new = jnp.where(cut, dlam_cut, jnp.where(predictor, a_load * dlam, dlam))
    if trust:
        shift_new, shift_memory = _next_trust_shift(s, _retry_shift(s, du, slope, finite), step, curvature, a, ok,
                                                    descent, agreement, cut)
    else:
        shift_new, shift_memory = _next_shift(s, du, slope, finite, descent, cut)
    why = jnp.where(inverting, INVERTS, INCREMENT_TOO_SMALL) if opts.element_bound else INCREMENT_TOO_SMALL
    status = jnp.where(cut & (dlam_cut < opts.min_increment), why, s.status)
    return _tick(s._replace(u=u_new, lam=lam_new, dlam=dlam_new, predictor=cut, shift=shift_new,
                            step_it=jnp.where(cut, 0, step_it), cuts=s.cuts + cut, status=status,
                            damped=jnp.where(cut, 0, damped), shift_memory=shift_memory, inverting=inverting), opts)


def _line_search(energy, opts: NewtonOptions, u, du, E0, slope, alpha0):
    """Backtracking (halving) from alpha0 until Armijo holds (to round-off of the energy): the step and
    whether it was found."""
    slack = 1e-12 * jnp.abs(E0) + 1e-300

    def ok(a, Ea):
        return Ea <= E0 + opts.armijo * a * slope + slack

    def cond(c):
        a, Ea, k = c
        return (~ok(a, Ea)) & (k < opts.max_backtracks)

    def body(c):
        a, _, k = c
        a = 0.5 * a
        return a, energy(u + a * du), k + 1

    a, Ea, _ = jax.lax.while_loop(cond, body, (2.0 * alpha0, jnp.inf, 0))
    return a, ok(a, Ea) & (alpha0 > 0)


def _trust_region(energy, u, step, E0, slope, curvature, a):
    """The trust-region test of a corrector step a * step (its slope and curvature along `step`): the
    energy's actual fall against the fall its quadratic model predicts.  Returns (a, accepted, ratio).
    Near equilibrium both are round-off, and a step that does not raise the energy beyond it is taken."""
    slack = 1e-12 * jnp.abs(E0) + 1e-300
    predicted = -(a * slope + 0.5 * a * a * curvature)
    Ea = energy(u + a * step)
    ratio = (E0 - Ea) / jnp.maximum(predicted, slack)
    roundoff = jnp.abs(predicted) <= slack
    ok = jnp.isfinite(Ea) & (a > 0) & ((ratio >= TRUST_ACCEPT) | (roundoff & (Ea <= E0 + slack)))
    # a step taken on the round-off test agreed with the model as far as the energy can tell: its ratio
    # is noise, and read as poor it would raise the shift just before convergence
    return a, ok, jnp.where(roundoff & ok, 1.0, jnp.where(jnp.isfinite(ratio), ratio, -jnp.inf))


def _cut_trust_region(s: _State, opts: NewtonOptions, ok):
    """As _cut, for the trust-region corrector: a rejected step is not a failure (the shift grows and
    the step is solved again), but TRUST_REJECTIONS of them in a row cut the load step.  Poor steps
    that are taken do not count: cutting after a few of them (as the line search's damped steps do)
    doubled the iterations of the stability map's nu = 0.499 translation cells (1,843 against 824)."""
    step_it = jnp.where(s.predictor, 0, s.step_it + 1)
    rejected = jnp.where(s.predictor | ok, 0, s.damped + 1)
    # a predictor that a bound (J > 0, the walls) cut below min_increment: the load step is cut, as the
    # line search's is, else the next corrector closes it at once and the same predictor is tried again
    cut = ((s.predictor & ~ok) | ((step_it >= opts.max_step_iters) & ~_finishing(s, opts, step_it))
           | (rejected >= TRUST_REJECTIONS))
    return step_it, rejected, cut


def _next_trust_shift(s: _State, retry, step, curvature, a, ok, descent, agreement, cut):
    """The trust region's diagonal shift (the inverse of its radius, as in Levenberg-Marquardt): raised
    where the model predicted the step badly, the J > 0 bound cut it short or it was rejected, lowered
    fourfold where the full step agreed with the model; kept through a predictor (the soft mode that
    called for it is still there in the next load step), and after a cut the last one that was taken.
    A raise goes to at least the stiffness along the step (its Rayleigh quotient): where one soft mode
    dominates the step, that halves its part and leaves the stiff part.  After a direction that did not
    descend (K + shift I is indefinite) the shift is at least _retry_shift's, sized from the curvature
    it revealed."""
    dd = jnp.dot(step, step)
    along = jnp.where(dd > 0, jnp.abs(curvature) / jnp.where(dd > 0, dd, 1.0), 0.0)
    raised = jnp.maximum(jnp.maximum(4.0 * s.shift, along), 1e-8 * s.k_ref)
    lowered = jnp.where(s.shift > 4e-12 * s.k_ref, 0.25 * s.shift, 0.0)
    poor = ~ok | (agreement < TRUST_POOR) | (a < 1.0)
    shift = jnp.where(poor, raised, jnp.where(agreement > TRUST_GOOD, lowered, s.shift))
    shift = jnp.where(s.predictor, s.shift, jnp.maximum(shift, jnp.where(descent, 0.0, retry)))
    memory = jnp.where(~s.predictor & ok, s.shift, s.shift_memory)
    return jnp.where(cut, memory, shift), memory


def _cut(s: _State, opts: NewtonOptions, a, ok, flipped, descent):
    """Whether the load step fails at this iteration (it returns to the last converged state with half
    the increment), with the step's iteration count and its run of damped corrector steps."""
    predictor = s.predictor
    step_it = jnp.where(predictor, 0, s.step_it + 1)
    # corrector steps that the line search or the J > 0 bound keep cutting short, several in a row,
    # mean the increment is too large for Newton's model: cut it now rather than after max_step_iters
    damped = jnp.where(predictor | ~ok, 0, jnp.where(flipped, s.damped, jnp.where(a < opts.damped_step, s.damped + 1, 0)))
    # a non-descent direction is retried with a larger diagonal shift first (no cut)
    # ...and a step whose residual is, or just was, within FINISHING_RESIDUAL x the tolerance is a few iterations
    # from converging (the residual need not fall monotonically there): it gets them
    cut = (descent & ~ok) | ((step_it >= opts.max_step_iters) & ~_finishing(s, opts, step_it)) | (damped >= opts.max_damped_steps)
    return step_it, damped, cut


def _finishing(s: _State, opts: NewtonOptions, step_it):
    """Whether a load step past max_step_iters is a few iterations from converging: its residual is, or
    just was, within FINISHING_RESIDUAL x the tolerance (it need not fall monotonically there)."""
    recent = jnp.minimum(s.rnorm, s.history[jnp.maximum(s.it - 1, 0)])
    return ((recent <= FINISHING_RESIDUAL * _step_tolerance(opts, s.lam, s.tol))
            & (step_it < opts.max_step_iters + FINISHING_ITERS))


def _retry_shift(s: _State, du, slope, finite):
    """The shift after a direction du that did not descend (slope = g.du >= 0)."""
    # (K + shift) du = -g with slope = g.du >= 0: du^T K du / du^T du = -slope / |du|^2 - shift < 0 bounds
    # the lowest eigenvalue of K from above; the retry's shift must at least exceed it
    dd = jnp.dot(du, du)
    rayleigh = jnp.where(finite & (dd > 0), -slope / jnp.where(dd > 0, dd, 1.0) - s.shift, 0.0)
    return jnp.maximum(jnp.maximum(10.0 * s.shift, -2.0 * rayleigh), jnp.maximum(s.shift_memory, 1e-8 * s.k_ref))


def _next_shift(s: _State, du, slope, finite, descent, cut):
    """The diagonal shift of the next iteration, and the last one that gave a descent direction."""
    retry = _retry_shift(s, du, slope, finite)
    shift_new = jnp.where(cut, 0.0, jnp.where(
        ~descent, retry, jnp.where(s.shift > 1e-12 * s.k_ref, 0.1 * s.shift, 0.0)))
    shift_memory = jnp.where(descent & ~s.predictor & (s.shift > 0), s.shift, s.shift_memory)
    return shift_new, shift_memory


def _step_bounds(eqs: Equations, p: Problem, u, lam, du, dlam, horizon):
    """The largest steps along (du, dlam) that keep J > 0 at every Gauss point, at every check point (inf
    without them: element_bound, the inversion barrier), and with contact no pore's walls meeting (exact
    up to `horizon`, the longest step the caller takes; inf without); 0 where undefined."""
    bounds = step_bounds(eqs.disc, p.quad, eqs.full(u, p.boundary(lam)), eqs.full(du, dlam * (p.u_D - p.u_D0)), horizon)
    return tuple(jnp.where(jnp.isnan(b), 0.0, b) for b in bounds)


def _step_bound(eqs: Equations, p: Problem, u, lam, du, dlam, horizon):
    """The largest step along (du, dlam) that keeps J > 0 and the walls apart (the smallest bound)."""
    return jnp.min(jnp.stack(_step_bounds(eqs, p, u, lam, du, dlam, horizon)))


def _past_the_walls(eqs: Equations, opts: NewtonOptions, p: Problem, u, lam, rest, stopped):
    """How far (a fraction of `rest`) the load goes beyond a predictor that the walls stopped: the
    prescribed displacements move on, the free dofs staying, as far as that keeps J > 0 and the walls
    apart (0 where not `stopped`).  The linearised response does not see the barrier until the walls are
    within d_hat, so it closes them too fast: stopped at its time of impact, the predictor would hold the
    contact force to about twice its last value per load step, and the load would crawl (shape matching's
    evaluation targets: 8 load steps where the pores touch against 2 without contact).  The correctors
    then press the walls into contact at the larger load (4 load steps, 29% fewer iterations; docs/validity.md).
    Not for a nearly incompressible material: there the boundary's move alone compresses the elements
    next to it at a bulk modulus hundreds of times the shear modulus, and undoing that costs the
    correctors more than the load gains (the stability map at nu 0.499: 6 of 49 solves that converged
    before failed)."""
    def reach(_):
        bound = _step_bound(eqs, p, u, lam, jnp.zeros_like(u), rest, 1.0 / opts.step_fraction)
        return jnp.minimum(1.0, opts.step_fraction * bound)

    return jax.lax.cond(stopped, reach, lambda _: jnp.zeros_like(lam), None)


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
    a0 = jnp.minimum(reach, opts.step_fraction * _step_bound(eqs, p, s.u, s.lam, v, 0.0, reach / opts.step_fraction))

    def falls(a, Ea):
        return Ea <= E0 + 0.5 * (slope * a + 0.5 * curvature * a * a)

    def body(c):
        a, _, k = c
        a = 0.5 * a
        return a, eqs.potential(p.quad, s.u + a * v, p.boundary(s.lam), p.load(s.lam), p.mat), k + 1

    a, Ea, _ = jax.lax.while_loop(lambda c: ~falls(c[0], c[1]) & (c[2] < opts.max_backtracks), body,
                                  (2.0 * a0, jnp.inf, 0))
    ok = falls(a, Ea) & (a0 > 0)
    # at full load the state continues as a corrector; below it, as the predictor it was
    state = s._replace(u=jnp.where(ok, s.u + a * v, s.u), status=jnp.asarray(RUNNING), step_it=jnp.asarray(0),
                       damped=jnp.asarray(0), shift=jnp.zeros_like(s.shift),
                       predictor=s.predictor & (s.lam < 1.0))
    return linearise(eqs, opts, p, state), ok


def result(s: _State) -> tuple[jnp.ndarray, NewtonInfo]:
    # a solve that did not converge returns the last state it did converge to (at info.load), not the
    # iterate it stopped at: an equilibrium, if not the one asked for
    u = jnp.where(s.status == CONVERGED, s.u, s.u_conv)
    return u, NewtonInfo(s.status, s.it, s.steps, s.cuts, s.lam_conv, s.rnorm, s.tol, s.history)


def newton_solve(eqs: Equations, backend, opts: NewtonOptions, X, d, mat):
    """Solve for the free displacements at full load as one traced loop (a traceable linear backend,
    e.g. dense on a GPU). Returns (u_free, NewtonInfo). Host backends drive the same two halves of an
    iteration from Python instead (HostNewton), so that no compiled program holds a host callback."""
    p, init = setup(eqs, opts, X, d, mat)

    def body(s: _State) -> _State:
        lin = linearise(eqs, opts, p, s)
        return jax.lax.cond(lin.state.status == RUNNING,
                            lambda _: advance(eqs, opts, p, lin, backend.solve(lin.kel, lin.rhs, lin.state.shift)),
                            lambda _: hold(opts, lin), None)

    return result(jax.lax.while_loop(lambda s: s.status == RUNNING, body, init))


def failure(info: NewtonInfo, context: str = "", nu: float | None = None) -> SolverError:
    """The error of one failed solve: how far it got and why."""
    status = int(info.status)
    msg = (f"{context}Newton solve failed: {STATUS_TEXT.get(status, status)}; converged up to load factor "
           f"{float(info.load):.4g} of 1 after {int(info.iterations)} iterations, {int(info.load_steps)} "
           f"load steps and {int(info.cuts)} cuts; ")
    if status == NONFINITE_INPUT:
        msg = f"{context}Newton solve failed: {STATUS_TEXT[status]}"
    elif float(info.residual) == 0.0:  # no corrector iterate was measured: say what happened instead
        msg += "no load increment beyond it could be taken (each was cut down to solver.min_increment)"
    else:
        msg += f"last residual {float(info.residual):.3e} (tolerance {float(info.tolerance):.3e})"
    if nu is not None and nu >= NEARLY_INCOMPRESSIBLE and status == ITERATION_LIMIT:
        msg += (f". material.nu = {nu:g} is nearly incompressible (bulk/shear modulus "
                f"{2 * (1 + nu) / (3 * (1 - 2 * nu)):.0f}): Newton needs several times the usual iterations "
                f"there; the commands' auto settings model it locking-free (material.formulation=mixed, "
                f"solver.corrector=trust_region, solver.max_step_iters=300, solver.max_iters=1000, "
                f"fidelity.inversion_barrier=0.5, contact on): leave those to auto, raise solver.max_iters, "
                f"or lower nu")
    return SolverError(msg, info)

