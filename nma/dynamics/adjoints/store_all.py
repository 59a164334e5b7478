"""`store_all`: the state at every output time is kept.

Memory: u, v and a at every k dt, 3 x 2 n_points floats an interval (u and v are the trajectory's
own output), and two numbers an interval.  A whole-interval step is then known without a solve;
an interval the controller stepped in several steps (a cut, or adaptive steps) is solved again from
its start, one interval at a time.
"""

from __future__ import annotations

from . import Adjoint


class StoreAll(Adjoint):
    def __init__(self, options=None):
        pass

    def kept(self, steps: int):
        return None
