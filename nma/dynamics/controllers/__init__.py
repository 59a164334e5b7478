"""Step control: how each output interval [k dt, (k + 1) dt] is covered by time steps, one file per
controller, registered in nma.dynamics.options.CONTROLLERS (`fixed`, `cuts`, `adaptive`).

The states are reported at k dt, k = 0 .. steps (as diffrax's SaveAt(ts)): a controller steps
through one interval at a time and ends each at its end exactly, known by its index k, never by
comparing times.  What a controller carries from one interval to the next (adaptive: the step it
proposes) is one number, kept for every interval, so that the backward pass can take an interval's
steps again as the forward pass took them (Controller.replay): the accepted steps are fixed there,
and no gradient flows through their choice.

A new controller is a file here whose class, built from the settings (DynamicsOptions), is declared
in CONTROLLERS.
"""

from __future__ import annotations

from typing import NamedTuple

from ...errors import SolverError


class Interval(NamedTuple):
    """How an interval went."""

    steps: list | None  # its accepted steps (nma.dynamics.stepper.Step), in order; None: failed
    z: tuple  # the state at its end (at its start where it failed)
    end: object  # the last step's linearisation at its end, for the next (None: failed)
    iterations: int  # Newton's, over every step tried
    rejected: int  # steps tried and not accepted (not converged, or not accurate enough)
    failed: tuple | None  # (NewtonInfo, the start of the step that failed) where it failed
    state: float  # what the controller carries to the next interval


class Controller:
    """How an interval is stepped: `interval` forward, `replay` in the backward pass."""

    def start(self, dt: float) -> float:
        """What the controller carries into the first interval."""
        return 0.0

    def interval(self, stepper, z, k: int, state: float, previous) -> Interval:
        """Interval k from the state z, `previous` the last step's linearisation at z (None: start
        afresh), `state` what the last interval left."""
        raise NotImplementedError

    def replay(self, stepper, z, k: int, state: float, count: int, previous) -> Interval:
        """Interval k's `count` accepted steps again from z, as `interval` took them (the backward
        pass: from a kept state, `previous` as the forward pass had it where that was not None)."""
        out = self.interval(stepper, z, k, state, previous)
        return checked(out, k, count)


def checked(out: Interval, k: int, count: int) -> Interval:
    """`out`, refused where the interval was not stepped as the forward pass stepped it."""
    if out.failed is not None or len(out.steps) != count:
        took = "failed" if out.failed is not None else f"took {len(out.steps)} steps"
        raise SolverError(
            f"dynamics: the backward pass could not take interval {k}'s {count} "
            f"steps again ({took}): the linear solver does not repeat itself"
        )
    return out
