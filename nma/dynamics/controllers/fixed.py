"""`fixed`: one step of dt per interval; a step that does not converge ends the trajectory."""

from __future__ import annotations

from . import Controller, Interval


class Fixed(Controller):
    def __init__(self, options=None):
        pass

    def interval(self, stepper, z, k, state, previous) -> Interval:
        step, info, end, z1 = stepper.whole(z, k, previous)
        its = int(info.iterations)
        if step is None:
            return Interval(None, z, None, its, 1, (info, float(stepper.times[k])), state)
        return Interval([step], z1, end, its, 0, None, state)
