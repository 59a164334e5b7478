"""Incremental loading: when a load step closes and how the next increment grows, the predictor's
right-hand side, how far a step may go (the J > 0 and walls' bounds) and how far the load goes past
a predictor the walls stopped.  The corrector at fixed load is apart (nma.solver.correctors)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..mechanics.energy import step_bounds as material_and_wall_bounds
from .equations import Equations, Problem, State
from .options import NewtonOptions
from .status import Status

FINISHING_ITERS = 5  # corrector iterations past max_step_iters for a step nearly converged...
# ...one whose residual is, or just was, within this factor of the tolerance
FINISHING_RESIDUAL = 1e3


def close_step(opts: NewtonOptions, s: State, rnorm, tol) -> State:
    """The state with its load step closed where a corrector's residual rnorm meets the step's
    tolerance (converged at full load; the next increment grown after a quick step, never past full
    load)."""
    # a state that is not finite never closes a step, whatever its residual's norm says
    step_done = (
        (~s.predictor) & (rnorm <= step_tolerance(opts, s.lam, tol)) & jnp.all(jnp.isfinite(s.u))
    )
    finished = step_done & (s.lam >= 1.0)
    lam_conv = jnp.where(step_done, s.lam, s.lam_conv)
    u_conv = jnp.where(step_done, s.u, s.u_conv)
    quick = s.step_it <= opts.max_step_iters // 3  # a slow step: the next one no larger
    dlam = jnp.where(
        step_done, jnp.minimum(s.dlam * jnp.where(quick, opts.grow, 1.0), 1.0 - s.lam), s.dlam
    )
    status = jnp.where(finished, Status.CONVERGED, s.status)
    return s._replace(
        u_conv=u_conv,
        lam_conv=lam_conv,
        dlam=dlam,
        predictor=s.predictor | step_done,
        steps=s.steps + step_done,
        status=status,
        inverting=s.inverting & ~step_done,
    )


def step_rhs(eqs: Equations, p: Problem, s: State, g, kel):
    """The right-hand side of the next step: a predictor's -(g + K_fD dU_D - dlam f_ext), the
    consistent linearised response to the next load increment; a corrector's -g."""
    return jnp.where(
        s.predictor,
        -(
            g
            + eqs.coupling(kel, s.dlam * (p.u_D - p.u_D0))
            - s.dlam * (1.0 - p.load0) * eqs.external_free(p.quad)
        ),
        -g,
    )


def after_step(s: State, u_step, moved, cut, a_load):
    """The displacement, load and increment after a step to u_step that moved (a predictor taking
    the load a_load of its increment along) or cut its load step (back to the last converged state,
    half the increment), and the increment a cut leaves."""
    predictor, dlam = s.predictor, s.dlam
    u_new = jnp.where(moved, u_step, jnp.where(cut, s.u_conv, s.u))
    lam_new = jnp.where(moved & predictor, s.lam + a_load * dlam, jnp.where(cut, s.lam_conv, s.lam))
    dlam_cut = 0.5 * jnp.where(predictor, dlam, s.lam - s.lam_conv)
    dlam_new = jnp.where(cut, dlam_cut, jnp.where(predictor, a_load * dlam, dlam))
    return u_new, lam_new, dlam_new, dlam_cut


def step_tolerance(opts: NewtonOptions, lam, tol):
    """The residual that closes a load step: the solve's tolerance at full load, the looser
    path_rtol before it (the next predictor's right-hand side carries the residual left, so it is
    not lost)."""
    return jnp.where(lam >= 1.0, tol, tol * max(1.0, opts.path_rtol / opts.rtol))


def finishing(s: State, opts: NewtonOptions, step_it):
    """Whether a load step past max_step_iters is a few iterations from converging: its residual is,
    or just was, within FINISHING_RESIDUAL x the tolerance (it need not fall monotonically
    there)."""
    recent = jnp.minimum(s.rnorm, s.history[jnp.maximum(s.it - 1, 0)])
    return (recent <= FINISHING_RESIDUAL * step_tolerance(opts, s.lam, s.tol)) & (
        step_it < opts.max_step_iters + FINISHING_ITERS
    )


def bounds(eqs: Equations, p: Problem, u, lam, du, dlam, horizon):
    """The largest steps along (du, dlam) that keep J > 0 at every Gauss point, at every check point
    (inf without them: element_bound, the inversion barrier), and with contact no pore's walls
    meeting (exact up to `horizon`, the longest step the caller takes; inf without); 0 where
    undefined."""
    found = material_and_wall_bounds(
        eqs.solid,
        p.quad,
        eqs.full(u, p.boundary(lam)),
        eqs.full(du, dlam * (p.u_D - p.u_D0)),
        horizon,
    )
    return tuple(jnp.where(jnp.isnan(b), 0.0, b) for b in found)


def bound(eqs: Equations, p: Problem, u, lam, du, dlam, horizon):
    """The largest step along (du, dlam) that keeps J > 0 and the walls apart (the smallest
    bound)."""
    return jnp.min(jnp.stack(bounds(eqs, p, u, lam, du, dlam, horizon)))


def past_the_walls(eqs: Equations, opts: NewtonOptions, p: Problem, u, lam, rest, stopped):
    """How far (a fraction of `rest`) the load goes beyond a predictor that the walls stopped: the
    prescribed displacements move on, the free dofs staying, as far as that keeps J > 0 and the
    walls apart (0 where not `stopped`).  The linearised response does not see the barrier until the
    walls are within d_hat, so it closes them too fast: stopped at its time of impact, the predictor
    would hold the contact force to about twice its last value per load step, and the load would
    crawl.  The correctors then press the walls into contact at the larger load.  Not for a nearly
    incompressible material (the caller's `stopped`): there the boundary's move alone compresses the
    elements next to it at a bulk modulus hundreds of times the shear modulus, and undoing that
    costs the correctors more than the load gains."""

    def reach(_):
        reachable = bound(eqs, p, u, lam, jnp.zeros_like(u), rest, 1.0 / opts.step_fraction)
        return jnp.minimum(1.0, opts.step_fraction * reachable)

    return jax.lax.cond(stopped, reach, lambda _: jnp.zeros_like(lam), None)
