"""`adaptive`: steps sized by a local error estimate, clipped so that every interval ends at its
end exactly.

A step's local error in u is estimated as dt^2 (beta - 1/6) (a_{n+1} - a_n) (Zienkiewicz & Xie,
Earthquake Eng. Struct. Dyn. 20, 871, 1991; nma.dynamics.schemes.Scheme.local_error), measured as
its largest entry over the free dofs relative to atol + rtol x the largest displacement at either
end of the step (nma.dynamics.stepper.Stepper.error).  A step at err <= 1 is accepted, else
redone shorter; either way the next is err^(-1/3) times as long (the error is of third order in
the step), times a safety factor 0.9, within 0.2 to 5 times, and never longer than dt nor shorter
than dt / 2^max_cuts.  A step that does not converge is redone at half its length.  At the
shortest length a step is accepted whatever its error, and one that does not converge ends the
trajectory.

Within an interval the steps left are equal: the time still to go split into as many steps of at
most the proposed length as it takes, the last ending at the interval's end, found by that count.
The proposed length is carried into the next interval; the first is the shortest, since a step
cannot see an actuation that starts and ends within it.  Each interval's steps start afresh at its
start (nma.dynamics.stepper), so that the backward pass can take them again from that state and
the proposal alone.
"""

from __future__ import annotations

import math

from . import Controller, Interval


class Adaptive(Controller):
    def __init__(self, options, safety: float = 0.9, shrink: float = 0.2, grow: float = 5.0):
        self.rtol, self.atol, self.max_cuts = (
            float(options.rtol),
            float(options.atol),
            int(options.max_cuts),
        )
        self.safety, self.shrink, self.grow = safety, shrink, grow

    def start(self, dt: float) -> float:
        """The shortest step: from rest, the actuation's first change may be short."""
        return dt / 2**self.max_cuts

    def interval(self, stepper, z, k, state, previous) -> Interval:
        dt, t, z0 = stepper.dt, float(stepper.times[k]), z
        shortest = dt / 2**self.max_cuts
        done, end, iterations, rejected, s, proposal = [], None, 0, 0, 0.0, state
        while True:
            rest = dt - s
            n = max(1, math.ceil(rest / proposal - 1e-9))  # steps left, each at most the proposal
            n = min(n, max(1, math.floor(rest / shortest + 1e-9)))  # and none below the shortest
            h = rest / n if n > 1 else rest
            step, info, end1, z1 = stepper.step(z, t + s, h, k, len(done), end)
            iterations += int(info.iterations)
            floor = h <= shortest * (1.0 + 1e-9)
            if step is None:
                rejected += 1
                if floor:
                    return Interval(None, z0, None, iterations, rejected, (info, t + s), state)
                proposal = max(0.5 * h, shortest)
                continue
            err = stepper.error(z, z1, h, self.rtol, self.atol)
            factor = self.grow if err == 0.0 else self.safety * err ** (-1.0 / 3.0)
            if err > 1.0 and not floor:
                rejected += 1
                proposal = max(h * max(self.shrink, factor), shortest)
                continue
            done.append(step)
            z, end, s = z1, end1, s + h
            proposal = min(dt, max(shortest, h * min(self.grow, factor)))
            if n == 1:
                return Interval(done, z, end, iterations, rejected, None, proposal)
