"""What the forward pass keeps for the gradient, and how the backward pass gets every step back:
one file per adjoint, registered in nma.dynamics.options.ADJOINTS (`store_all`, `checkpointed`).

The forward pass keeps the states (u, v, a) at some of the output times k dt, with, for every
interval, how many steps it took and what its controller carried into it (two numbers).  All of it
travels in the gradient's residuals, as arrays: the records live exactly as long as JAX keeps the
residuals, and the gradient can be asked any number of times.

The backward pass then walks the trajectory's steps from the last to the first (the discrete
adjoint, nma.dynamics.backward) and gets each back from the nearest kept state before it: a step
over a whole interval whose end is kept is known without a solve; any other is solved again by the
interval's controller (Controller.replay), each run of intervals from its kept state onwards, one
run at a time.  A run of intervals starts afresh at its kept state in the forward pass too
(Adjoint.restarts), so that what the backward pass solves again is what the forward pass solved,
to the bit, on a linear solver that repeats itself.

A new adjoint is a file here whose class, built from the settings (DynamicsOptions), is declared in
ADJOINTS; it says which states it keeps (kept) and where the forward pass starts afresh
(restarts), or walks the steps its own way (steps_back).
"""

from __future__ import annotations

import numpy as np

from ...errors import SolverError


class Adjoint:
    """Which states the forward pass keeps, and the steps back from them."""

    def kept(self, steps: int) -> np.ndarray | None:
        """The output indices k (of the states at k dt, 0 .. steps) whose states are kept; None:
        all of them."""
        raise NotImplementedError

    def restarts(self, k: int, steps: int) -> bool:
        """Whether interval k's first step starts afresh in the forward pass (not from the last
        step's linearisation)."""
        return False

    def steps_back(self, dyn, stepper, states: dict, counts, control, intervals: int):
        """Every accepted step of the trajectory (nma.dynamics.stepper.Step), the last first, from
        the kept states {k: (u, v, a)} and each interval's step count and controller state; the
        trajectory reached state `intervals`."""
        starts = sorted(k for k in states if k < intervals)
        for a, b in reversed(list(zip(starts, starts[1:] + [intervals]))):
            yield from reversed(self._run(dyn, stepper, states, counts, control, a, b))

    @staticmethod
    def _run(dyn, stepper, states, counts, control, a: int, b: int) -> list:
        """The steps of intervals a .. b - 1, from the kept state at a."""
        z, previous, done = states[a], None, []
        for k in range(a, b):
            known = states.get(k + 1)
            if counts[k] == 1 and known is not None:  # its end is kept: nothing to solve
                done.append(stepper.known(z, k, known))
                z, previous = known, None
                continue
            out = dyn.controller.replay(stepper, z, k, float(control[k]), int(counts[k]), previous)
            done.extend(out.steps)
            z, previous = out.z, out.end
            if known is not None:
                _same(z, known, k + 1)
        return done


def _same(z, kept, k: int) -> None:
    """The state solved again at k against the one kept there: refused where they differ beyond
    round-off (a linear solver that does not repeat itself, taking other steps)."""
    u, ref = np.asarray(z[0]), np.asarray(kept[0])
    if not np.allclose(u, ref, rtol=1e-8, atol=1e-12 * max(np.max(np.abs(ref)), 1e-300)):
        raise SolverError(
            f"dynamics: the backward pass solved the state at step {k} again to "
            f"another one (off by {np.max(np.abs(u - ref)):.3g}): the linear solver "
            "does not repeat itself"
        )
