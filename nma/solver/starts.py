"""How a Newton solve starts: cold at rest, warm from another sample's equilibrium (the load walking
from its prescribed displacements to this sample's), or a time step from the end of the last; each
start's first state and whether its input lets it begin at all."""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax.numpy as jnp

from ..mechanics import contact
from ..mechanics.energy import check_point_dets, quadrature
from .equations import Equations, Problem, State
from .options import NewtonOptions
from .scales import _scales
from .status import Status

if TYPE_CHECKING:  # the type of continue_in_time's argument, for the reader
    from .newton import Linearised


def setup(
    eqs: Equations, opts: NewtonOptions, X, d, mat, start=None, inertia=None
) -> tuple[Problem, State]:
    """The problem data and the initial state (NONFINITE_INPUT at once for non-finite input, INVERTS
    for a warm start inverted at the check points under this design, with element_bound, WALLS_CROSS
    for one whose pores' walls cross under it, with contact).  Cold (start None): at rest.  Warm
    (start = (u_free0, u_D0, kel_rest, X0): another sample's equilibrium, under the full dead load,
    this design's element tangents at rest, and the reference points X0 it was solved on): the load
    walks from u_D0 to this sample's u_D.  Either way the first iteration is a
    predictor, whose right-hand side -(g + K_fD (u_D - u_D0)) also carries the start's own residual
    g where the design moved since: the first-order response to the change of design and actuation
    together.  The tolerance is the cold solve's either way (the force scale of the full load, from
    the tangent at rest), so a warm answer meets the same test as a cold one.  A time step
    (`inertia`, nma.dynamics) starts warm at the previous state (kel_rest unused); its scales come
    from its first linearisation (_step_scales)."""
    quad = quadrature(eqs.solid, X, check_points=opts.element_bound)
    u_D = eqs.A @ d
    finite = jnp.all(jnp.isfinite(X)) & jnp.all(jnp.isfinite(d)) & jnp.all(jnp.isfinite(mat))
    scalar = lambda v: jnp.asarray(v, X.dtype)
    zero = jnp.zeros(eqs.boundary.n_dofs, X.dtype)
    size = jnp.max(jnp.ptp(X, axis=0))
    if start is None:
        p = Problem(quad, u_D, mat, size, jnp.zeros_like(u_D), scalar(0.0))
        u0, tol, k_ref, f_ref = zero, scalar(0.0), scalar(1.0), scalar(0.0)
    else:
        u0, u_D0, kel_rest, X0 = start
        finite = (
            finite
            & jnp.all(jnp.isfinite(u0))
            & jnp.all(jnp.isfinite(u_D0))
            & jnp.all(jnp.isfinite(X0))
        )
        p = Problem(quad, u_D, mat, size, u_D0, scalar(1.0), inertia)
        # a time step's scales come from its first linearisation (_step_scales), as a cold solve's
        # do
        tol, k_ref, f_ref = (
            _scales(eqs, opts, p, kel_rest)
            if inertia is None
            else (scalar(0.0), scalar(1.0), scalar(0.0))
        )
    status = jnp.where(finite, Status.RUNNING, Status.NONFINITE_INPUT)
    if start is not None and opts.element_bound:
        # a start inverted between Gauss points under this design (it moved since): no bound holds
        # from there, so the warm solve ends at once (INVERTS) and is redone cold
        J, defined = check_point_dets(eqs.solid.mesh, X, eqs.full(u0, u_D0))
        status = jnp.where(finite & jnp.any((J <= 0) & defined), Status.INVERTS, status)
    if start is not None and eqs.solid.contact:
        # the start's displacements carried from the design it was solved on to this one: where a
        # wall vertex meets a chord on the way, the start is interpenetrated here (the barrier sees
        # distances, not sides, and would keep it so), so the warm solve ends at once and is redone
        # cold
        x0 = X0 + eqs.full(u0, u_D0)
        crossed = (
            contact.time_of_impact(eqs.solid.contact, quad.walls, x0, X - X0, horizon=1.0) <= 1.0
        )
        status = jnp.where(finite & crossed, Status.WALLS_CROSS, status)
    return p, _initial(opts, u0, status, tol, k_ref, f_ref)


def _initial(opts: NewtonOptions, u0, status, tol, k_ref, f_ref) -> State:
    """A solve's first state: at u0, load factor 0, its first step a predictor."""
    scalar = lambda v: jnp.asarray(v, u0.dtype)
    return State(
        u=u0,
        lam=scalar(0.0),
        u_conv=u0,
        lam_conv=scalar(0.0),
        dlam=scalar(opts.initial_increment),
        predictor=jnp.asarray(True),
        shift=scalar(0.0),
        it=jnp.asarray(0),
        step_it=jnp.asarray(0),
        steps=jnp.asarray(0),
        cuts=jnp.asarray(0),
        status=status,
        tol=tol,
        k_ref=k_ref,
        rnorm=scalar(jnp.inf),
        history=jnp.full(opts.max_iters, jnp.nan, u0.dtype),
        damped=jnp.asarray(0),
        shift_memory=scalar(0.0),
        f_ref=f_ref,
        inverting=jnp.asarray(False),
    )


def continue_in_time(eqs: Equations, opts: NewtonOptions, p: Problem, lin: Linearised, d, inertia):
    """The next time step from the converged end (p, lin) of the last: its Problem (the same design
    and material, the boundary from its end to eqs.A d, this step's `inertia`), its first State (at
    that end, as setup starts a time step) and its first linearisation without another pass over the
    elements: the strain energy, force and element tangents at that state are the last step's, only
    the Inertia's terms change (returned as linearise's `at`; contact's blocks are taken again,
    exact)."""
    q = Problem(p.quad, eqs.A @ d, p.mat, p.size, p.u_D, jnp.asarray(1.0, p.size.dtype), inertia)
    u = eqs.full(lin.state.u, p.u_D).reshape(-1)
    edofs = eqs.edofs[: eqs.elements]
    energy = lin.energy - p.inertia.energy(edofs, u) + inertia.energy(edofs, u)
    g = lin.g + (inertia.force(edofs, u) - p.inertia.force(edofs, u))[eqs.free]
    kel = lin.kel._replace(elements=lin.kel.elements + (inertia.blocks - p.inertia.blocks))
    # the last tangent's contact blocks may be of the normal stiffness only (newton._contact_normal)
    if eqs.solid.contact:
        mu = eqs.solid.material.moduli(p.mat)[0]
        kel = kel._replace(
            **dict(
                zip(
                    ("contact", "which", "near"),
                    contact.force_and_blocks(
                        eqs.solid.contact,
                        p.quad.walls,
                        p.quad.X + u.reshape(-1, 2),
                        mu,
                        eqs.contact_slots,
                    )[2:],
                )
            )
        )
    finite = jnp.all(jnp.isfinite(d)) & jnp.all(jnp.isfinite(inertia.b))
    zero = jnp.asarray(0.0, u.dtype)
    status = jnp.where(finite, Status.RUNNING, Status.NONFINITE_INPUT)
    return q, _initial(opts, lin.state.u, status, zero, zero + 1.0, zero), (energy, g, kel)
