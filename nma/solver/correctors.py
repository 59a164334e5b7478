"""Correctors: how a Newton step at fixed load is globalised.  Each is an object with three parts:
`search` (how far along the step to go, and whether to take it), `cut` (whether the load step has
failed) and `next_shift` (the diagonal shift of the next step's matrix, K + shift I).  The loop
(nma.solver.newton.advance) calls them by name, solver.corrector; a new one registers in
nma.registry.CORRECTORS and needs no edit of the loop.  In a time step (nma.dynamics) `search` is
also given `noise`, the energy's round-off, to widen its acceptance test by.  A `search` that takes
`first`, (known, E), is given the energy E at the full step a0 along `step`, valid where `known`
(the loop linearised there: nma.solver.newton.advance), and need not evaluate it again.

line_search: the Newton step, shortened as a whole until the energy falls enough (backtracking
Armijo), a non-descent direction retried with a larger shift.  trust_region: the step of K + shift
I, taken or rejected by how well the energy's quadratic model predicted its fall, the shift adapted
(Levenberg-Marquardt): a soft mode's part of the step is damped while the stiff part keeps Newton's.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .equations import State
from .loading import finishing
from .options import NewtonOptions

# actual over predicted fall: taken, shift raised, lowered
TRUST_ACCEPT, TRUST_POOR, TRUST_GOOD = 0.1, 0.25, 0.75
# rejected trust-region steps in a row that cut the load step (the shift grew 4^10-fold)
TRUST_REJECTIONS = 10


class Trial(NamedTuple):
    """One step as the loop tried it: du the solution of (K + shift I) du = rhs, `step` the
    direction taken (-du where du climbs), its slope g.step and how far it went (a), whether it was
    taken (ok), and what the search found: the energy's fall against its model's (agreement) and the
    curvature step^T K step (the model's; 0 where the corrector has none)."""

    du: jnp.ndarray
    step: jnp.ndarray
    slope: jnp.ndarray
    finite: jnp.ndarray
    flipped: jnp.ndarray
    descent: jnp.ndarray
    a: jnp.ndarray
    ok: jnp.ndarray
    agreement: jnp.ndarray
    curvature: jnp.ndarray


class LineSearch:
    """The Newton step, shortened as a whole until the energy falls enough."""

    def search(
        self, eqs, opts: NewtonOptions, kel, energy, u, step, E0, slope, a0, noise=None, first=None
    ):
        """How far along `step` (slope < 0, at most a0) and whether to take it: (a, ok, agreement,
        curvature). `noise`: the energy's round-off where it is known to exceed 1e-12 |E0| (a time
        step's); `first`: (known, the energy at a0), where the caller may have it."""
        curvature = jnp.zeros_like(slope)
        a, ok = _line_search(energy, opts, u, step, E0, slope, a0, noise, first)
        return a, ok, jnp.ones_like(slope), curvature

    def cut(self, s: State, opts: NewtonOptions, t: Trial):
        """(the load step's corrector iterations, its run of damped steps, whether it fails now)."""
        return _cut(s, opts, t.a, t.ok, t.flipped, t.descent)

    def next_shift(self, s: State, t: Trial, cut):
        """(the next step's shift, the last shift that gave descent)."""
        return _next_shift(s, t.du, t.slope, t.finite, t.descent, cut)


class TrustRegion:
    """The step of K + shift I, taken where the energy's quadratic model predicted its fall."""

    def search(
        self, eqs, opts: NewtonOptions, kel, energy, u, step, E0, slope, a0, noise=None, first=None
    ):
        curvature = eqs.curvature(kel, step)
        a, ok, agreement = _trust_region(energy, u, step, E0, slope, curvature, a0, noise, first)
        return a, ok, agreement, curvature

    def cut(self, s: State, opts: NewtonOptions, t: Trial):
        return _cut_trust_region(s, opts, t.ok)

    def next_shift(self, s: State, t: Trial, cut):
        return _next_trust_shift(
            s,
            _retry_shift(s, t.du, t.slope, t.finite),
            t.step,
            t.curvature,
            t.a,
            t.ok,
            t.descent,
            t.agreement,
            cut,
        )


def _slack(E0, noise):
    """The energy's round-off: 1e-12 |E0|, or `noise` more where the caller knows it larger."""
    slack = 1e-12 * jnp.abs(E0) + 1e-300
    return slack if noise is None else slack + noise


def _line_search(energy, opts: NewtonOptions, u, du, E0, slope, alpha0, noise=None, first=None):
    """Backtracking (halving) from alpha0 until Armijo holds (to round-off of the energy): the step
    and whether it was found.  `first`: (known, the energy at alpha0), where the caller may have
    it."""
    slack = _slack(E0, noise)

    def ok(a, Ea):
        return Ea <= E0 + opts.armijo * a * slope + slack

    def cond(c):
        a, Ea, k = c
        return (~ok(a, Ea)) & (k < opts.max_backtracks)

    def body(c):
        a, _, k = c
        a = 0.5 * a
        return a, energy(u + a * du), k + 1

    start = (2.0 * alpha0, jnp.inf, 0)
    if first is not None:  # the loop's state after its first pass (at alpha0) where that is known
        start = tuple(jnp.where(first[0], a, b) for a, b in zip((alpha0, first[1], 1), start))
    a, Ea, _ = jax.lax.while_loop(cond, body, start)
    return a, ok(a, Ea) & (alpha0 > 0)


def _trust_region(energy, u, step, E0, slope, curvature, a, noise=None, first=None):
    """The trust-region test of a corrector step a * step (its slope and curvature along `step`):
    the energy's actual fall against the fall its quadratic model predicts.  Returns (a, accepted,
    ratio). Near equilibrium both are round-off, and a step that does not raise the energy beyond it
    is taken.  `first`: (known, the energy at a), where the caller may have it."""
    slack = _slack(E0, noise)
    predicted = -(a * slope + 0.5 * a * a * curvature)
    Ea = (
        energy(u + a * step)
        if first is None
        else jax.lax.cond(first[0], lambda: first[1], lambda: energy(u + a * step))
    )
    ratio = (E0 - Ea) / jnp.maximum(predicted, slack)
    roundoff = jnp.abs(predicted) <= slack
    ok = jnp.isfinite(Ea) & (a > 0) & ((ratio >= TRUST_ACCEPT) | (roundoff & (Ea <= E0 + slack)))
    # a step taken on the round-off test agreed with the model as far as the energy can tell: its
    # ratio is noise, and read as poor it would raise the shift just before convergence
    return a, ok, jnp.where(roundoff & ok, 1.0, jnp.where(jnp.isfinite(ratio), ratio, -jnp.inf))


def _cut_trust_region(s: State, opts: NewtonOptions, ok):
    """As _cut, for the trust-region corrector: a rejected step is not a failure (the shift grows
    and the step is solved again), but TRUST_REJECTIONS of them in a row cut the load step.  Poor
    steps that are taken do not count: cutting after a few of them (as the line search's damped
    steps do) throws away the slow descent a nearly incompressible material needs."""
    step_it = jnp.where(s.predictor, 0, s.step_it + 1)
    rejected = jnp.where(s.predictor | ok, 0, s.damped + 1)
    # a predictor that a bound (J > 0, the walls) cut below min_increment: the load step is cut, as
    # the line search's is, else the next corrector closes it at once and the same predictor is
    # tried again
    cut = (
        (s.predictor & ~ok)
        | ((step_it >= opts.max_step_iters) & ~finishing(s, opts, step_it))
        | (rejected >= TRUST_REJECTIONS)
    )
    return step_it, rejected, cut


def _next_trust_shift(s: State, retry, step, curvature, a, ok, descent, agreement, cut):
    """The trust region's diagonal shift (the inverse of its radius, as in Levenberg-Marquardt):
    raised where the model predicted the step badly, the J > 0 bound cut it short or it was
    rejected, lowered fourfold where the full step agreed with the model; kept through a predictor
    (the soft mode that called for it is still there in the next load step), and after a cut the
    last one that was taken. A raise goes to at least the stiffness along the step (its Rayleigh
    quotient): where one soft mode dominates the step, that halves its part and leaves the stiff
    part.  After a direction that did not descend (K + shift I is indefinite) the shift is at least
    _retry_shift's, sized from the curvature it revealed."""
    dd = jnp.dot(step, step)
    along = jnp.where(dd > 0, jnp.abs(curvature) / jnp.where(dd > 0, dd, 1.0), 0.0)
    raised = jnp.maximum(jnp.maximum(4.0 * s.shift, along), 1e-8 * s.k_ref)
    lowered = jnp.where(s.shift > 4e-12 * s.k_ref, 0.25 * s.shift, 0.0)
    poor = ~ok | (agreement < TRUST_POOR) | (a < 1.0)
    shift = jnp.where(poor, raised, jnp.where(agreement > TRUST_GOOD, lowered, s.shift))
    shift = jnp.where(s.predictor, s.shift, jnp.maximum(shift, jnp.where(descent, 0.0, retry)))
    memory = jnp.where(~s.predictor & ok, s.shift, s.shift_memory)
    return jnp.where(cut, memory, shift), memory


def _cut(s: State, opts: NewtonOptions, a, ok, flipped, descent):
    """Whether the load step fails at this iteration (it returns to the last converged state with
    half the increment), with the step's iteration count and its run of damped corrector steps."""
    predictor = s.predictor
    step_it = jnp.where(predictor, 0, s.step_it + 1)
    # corrector steps that the line search or the J > 0 bound keep cutting short, several in a row,
    # mean the increment is too large for Newton's model: cut it now rather than after
    # max_step_iters
    damped = jnp.where(
        predictor | ~ok,
        0,
        jnp.where(flipped, s.damped, jnp.where(a < opts.damped_step, s.damped + 1, 0)),
    )
    # a non-descent direction is retried with a larger diagonal shift first (no cut)
    # ...and a step whose residual is, or just was, within FINISHING_RESIDUAL x the tolerance is a
    # few iterations from converging (the residual need not fall monotonically there): it gets them
    cut = (
        (descent & ~ok)
        | ((step_it >= opts.max_step_iters) & ~finishing(s, opts, step_it))
        | (damped >= opts.max_damped_steps)
    )
    return step_it, damped, cut


def _retry_shift(s: State, du, slope, finite):
    """The shift after a direction du that did not descend (slope = g.du >= 0)."""
    # (K + shift) du = -g with slope = g.du >= 0: du^T K du / du^T du = -slope / |du|^2 - shift < 0
    # bounds the lowest eigenvalue of K from above; the retry's shift must at least exceed it
    dd = jnp.dot(du, du)
    rayleigh = jnp.where(finite & (dd > 0), -slope / jnp.where(dd > 0, dd, 1.0) - s.shift, 0.0)
    return jnp.maximum(
        jnp.maximum(10.0 * s.shift, -2.0 * rayleigh), jnp.maximum(s.shift_memory, 1e-8 * s.k_ref)
    )


def _next_shift(s: State, du, slope, finite, descent, cut):
    """The diagonal shift of the next iteration, and the last one that gave a descent direction."""
    retry = _retry_shift(s, du, slope, finite)
    shift_new = jnp.where(
        cut,
        0.0,
        jnp.where(~descent, retry, jnp.where(s.shift > 1e-12 * s.k_ref, 0.1 * s.shift, 0.0)),
    )
    shift_memory = jnp.where(descent & ~s.predictor & (s.shift > 0), s.shift, s.shift_memory)
    return shift_new, shift_memory
