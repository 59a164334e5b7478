"""`checkpointed`: the state at every K-th output time is kept, K = ceil(sqrt(steps)) (or, with
`checkpoints` = b, K = ceil(steps / b): at most b states); the backward pass solves each run of K
intervals again from its kept state, the last run first (as diffrax's checkpointed adjoint, at a
fixed spacing).

Memory: u, v and a at ceil(steps / K) output times, 3 x 2 n_points floats each, and two numbers an
interval; in the backward pass, one run's steps at a time, 4 x 2 n_points floats a step (its start
state and its solution) for its K intervals' steps: O(sqrt(steps)) states in all at the default K.
Cost: the backward pass solves every interval's steps once more (a forward pass again).  Each run
starts afresh at its kept state in the forward pass, so the steps solved again are the forward
pass's to the bit; the gradient equals store_all's to round-off (its forward pass continues from
the last linearisation there instead).
"""

from __future__ import annotations

import math

import numpy as np

from . import Adjoint


class Checkpointed(Adjoint):
    def __init__(self, options):
        self.budget = None if options.checkpoints is None else int(options.checkpoints)

    def spacing(self, steps: int) -> int:
        """K: the intervals between kept states."""
        if self.budget is None:
            return max(1, math.ceil(math.sqrt(steps)))
        return max(1, math.ceil(steps / self.budget))

    def kept(self, steps: int):
        return np.arange(0, steps, self.spacing(steps))

    def restarts(self, k: int, steps: int) -> bool:
        return k % self.spacing(steps) == 0
