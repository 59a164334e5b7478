"""`cuts`: one step of dt per interval; an interval whose step does not converge (a load-step cut
below solver.min_increment, the element bound, the iteration limit) is redone in 2, 4, ... equal
steps, up to 2^max_cuts: the static solver's load-step cuts become time-step cuts.  Where even the
finest fails, the trajectory ends.

The whole step continues from the last step's linearisation; a redone interval's steps start
afresh at the interval's start (nma.dynamics.stepper), so that the backward pass can take them
again from that state alone.
"""

from __future__ import annotations

from . import Controller, Interval, checked


class Cuts(Controller):
    def __init__(self, options):
        self.max_cuts = int(options.max_cuts)

    def interval(self, stepper, z, k, state, previous) -> Interval:
        iterations, rejected, failed = 0, 0, None
        for level in range(self.max_cuts + 1):
            out = self._equal(stepper, z, k, 2**level, previous if level == 0 else None)
            iterations += out.iterations
            if out.failed is None:
                return out._replace(iterations=iterations, rejected=rejected, state=state)
            rejected, failed = rejected + 1, out.failed
        return Interval(None, z, None, iterations, rejected, failed, state)

    def replay(self, stepper, z, k, state, count, previous) -> Interval:
        out = self._equal(stepper, z, k, count, previous if count == 1 else None)
        return checked(out._replace(state=state), k, count)

    @staticmethod
    def _equal(stepper, z, k, n: int, previous) -> Interval:
        """Interval k in n equal steps from z."""
        t, h, done, iterations, zz = float(stepper.times[k]), stepper.dt / n, [], 0, z
        for j in range(n):
            t0 = t + j * h
            step, info, previous, z1 = stepper.step(zz, t0, h, k, j, previous)
            iterations += int(info.iterations)
            if step is None:
                return Interval(None, z, None, iterations, 0, (info, t0), 0.0)
            done.append(step)
            zz = z1
        return Interval(done, zz, previous, iterations, 0, None, 0.0)
