"""How a Newton solve ended: the status enumeration with its words, the solve's statistics
(NewtonInfo), what a solve returns (Equilibrium) and the error of a failed one."""

from __future__ import annotations

import enum
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SolverError
from ..mechanics.options import NEARLY_INCOMPRESSIBLE


class Status(enum.IntEnum):
    """A solve's status; an int inside traced code (jnp.where takes the members as they are).

    `CONVERGED` is the only success.  `INCREMENT_TOO_SMALL`, `ITERATION_LIMIT`, `NONFINITE_INPUT`
    and `INVERTS` end a failed solve; `WALLS_CROSS` marks a warm start that is redone from rest, and
    `RUNNING` a solve not yet ended.  Each member's `message` says it in words.

    Examples:
        >>> Status.CONVERGED.message
        'converged'
        >>> Status.describe(3)
        'the iteration limit solver.max_iters was reached'
        >>> Status.describe(99)
        'status 99'
    """

    RUNNING = 0
    CONVERGED = 1
    INCREMENT_TOO_SMALL = 2
    ITERATION_LIMIT = 3
    NONFINITE_INPUT = 4
    INVERTS = 5
    WALLS_CROSS = 6

    @property
    def message(self) -> str:
        return _MESSAGES[self]

    @classmethod
    def describe(cls, status) -> str:
        """The words of a status given as a number (an unknown one by its number)."""
        return (
            cls(int(status)).message
            if int(status) in cls._value2member_map_
            else f"status {int(status)}"
        )


_MESSAGES = {
    Status.RUNNING: "still running",
    Status.CONVERGED: "converged",
    Status.INCREMENT_TOO_SMALL: "the load increment fell below solver.min_increment",
    Status.ITERATION_LIMIT: "the iteration limit solver.max_iters was reached",
    Status.NONFINITE_INPUT: "its input (geometry, actuation or material) is not finite; nothing "
    "was solved",
    Status.INVERTS: (
        "the load increment fell below solver.min_increment where the material would invert "
        "between "
        "Gauss points (det F at an element's 4 x 4 check points, which solver.element_bound keeps "
        "positive; without the bound the solve may go on to a state inverted there, not a physical "
        "object)"
    ),
    Status.WALLS_CROSS: (
        "a warm start whose pores' walls cross each other under this design (it moved since that "
        "equilibrium was kept); such a start is redone from rest"
    ),
}


class NewtonInfo(NamedTuple):
    """How a Newton solve went (arrays: under vmap each gains the batch axis).

    Attributes:
        status: How it ended, a `Status` as an integer.
        iterations: Newton iterations, predictors and correctors together.
        load_steps: Load steps that converged.
        cuts: Load steps that failed and were halved.
        load: The load factor of the last converged state (1: full load).
        residual: The norm of the out-of-balance force at the last iterate.
        tolerance: The residual the solve had to reach.
        residual_history: The residual of every iteration, NaN past the last.
    """

    status: jnp.ndarray
    iterations: jnp.ndarray
    load_steps: jnp.ndarray
    cuts: jnp.ndarray
    load: jnp.ndarray  # load factor of the last converged state
    residual: jnp.ndarray  # ||g_f|| at the last iterate
    tolerance: jnp.ndarray
    residual_history: jnp.ndarray  # (max_iters,), nan past the last iteration


class Equilibrium(NamedTuple):
    """What a solve returns: the displacement of every control point and how Newton got there (its
    status, statistics and residual history).  A pytree, so traced, batched (vmap: every field gains
    the batch axis) and differentiated solves return it too; `u, info = equilibrium` unpacks it.
    The host-side properties read a solved one; a failed solve's error says how far it got and why.

    Attributes:
        u: The displacement of every control point (n_points, 2); of a failed solve, its last
            converged state (at load factor `info.load`).
        info: Newton's statistics (`NewtonInfo`).

    Examples:
        >>> import numpy as np
        >>> info = NewtonInfo(*(np.array(v) for v in (Status.ITERATION_LIMIT, 200, 3, 1, 0.5,
        ...                                            1e-3, 1e-10, [np.nan])))
        >>> eq = Equilibrium(np.zeros((4, 2)), info)
        >>> bool(eq.converged), eq.message
        (False, 'the iteration limit solver.max_iters was reached')
        >>> print(eq.error("demo: "))
        demo: Newton solve failed: the iteration limit solver.max_iters was reached; converged up to
        load factor 0.5 of 1 after 200 iterations, 3 load steps and 1 cuts; last residual 1.000e-03
        (tolerance 1.000e-10)
    """

    # (n_points, 2); of a failed solve, its last converged state (at load info.load)
    u: jnp.ndarray
    info: NewtonInfo

    @property
    def converged(self) -> np.ndarray:
        """Whether the solve reached full load (per sample of a batch)."""
        return np.asarray(self.info.status) == Status.CONVERGED

    @property
    def message(self) -> str:
        """The status in words (one solve)."""
        return Status.describe(self.info.status)

    def error(self, context: str = "", nu: float | None = None) -> SolverError | None:
        """None where converged, else the error of the failed solve (of the first failed sample of a
        batch), `context` saying which solve it was."""
        status = np.asarray(self.info.status)
        if status.ndim == 0:
            return None if int(status) == Status.CONVERGED else failure(self.info, context, nu)
        failed = np.flatnonzero(status != Status.CONVERGED)
        if not failed.size:
            return None
        i = int(failed[0])
        return failure(
            jax.tree_util.tree_map(lambda a: np.asarray(a)[i], self.info),
            f"{context}sample {i}: ",
            nu,
        )


def failure(info: NewtonInfo, context: str = "", nu: float | None = None) -> SolverError:
    """The error of one failed solve: how far it got and why (a trajectory's, nma.dynamics: at which
    time)."""
    status = int(info.status)
    if hasattr(info, "time"):  # a TrajectoryInfo: its time steps solve as static solves do
        return SolverError(
            f"{context}time stepping failed: the step at time "
            f"{float(info.time):.6g} (time step {int(info.intervals) + 1}) did not "
            f"converge, even cut into smaller steps (dynamics.max_cuts): "
            f"{Status.describe(status)}; "
            f"{int(info.steps)} steps had converged ({int(info.cuts)} intervals cut), "
            f"{int(info.iterations)} Newton iterations in all",
            info,
        )
    msg = (
        f"{context}Newton solve failed: {Status.describe(status)}; converged up to load factor "
        f"{float(info.load):.4g} of 1 after {int(info.iterations)} iterations, "
        f"{int(info.load_steps)} "
        f"load steps and {int(info.cuts)} cuts; "
    )
    if status == Status.NONFINITE_INPUT:
        msg = f"{context}Newton solve failed: {Status.NONFINITE_INPUT.message}"
    # no corrector iterate was measured: say what happened instead
    elif float(info.residual) == 0.0:
        msg += (
            "no load increment beyond it could be taken (each was cut down to solver.min_increment)"
        )
    else:
        msg += f"last residual {float(info.residual):.3e} (tolerance {float(info.tolerance):.3e})"
    if nu is not None and nu >= NEARLY_INCOMPRESSIBLE and status == Status.ITERATION_LIMIT:
        msg += (
            f". material.nu = {nu:g} is nearly incompressible (bulk/shear modulus "
            f"{2 * (1 + nu) / (3 * (1 - 2 * nu)):.0f}): Newton needs several times the usual "
            "iterations there; the commands' auto settings model it locking-free "
            "(material.formulation=mixed, "
            f"solver.corrector=trust_region, solver.max_step_iters=300, solver.max_iters=1000, "
            "fidelity.inversion_barrier=0.5, contact on): leave those to auto, raise "
            f"solver.max_iters, or lower nu"
        )
    return SolverError(msg, info)
