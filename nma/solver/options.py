"""Newton's own settings (nma.solver.newton), a plain value the solver takes, each declared once
here with its default, range and meaning.  The config's `solver` group (nma.schema.SolverConfig)
takes them all and the commands hand them down (nma.resolve.newton_options); library code builds
them directly:

    Simulator(disc, "pardiso", NewtonOptions(rtol=1e-12))
"""

from __future__ import annotations

from dataclasses import dataclass

from ..registry import CORRECTORS
from ..settings import bounded, option


# how a corrector step at fixed load is globalised (nma.solver.correctors)
CORRECTORS.declare("line_search", "nma.solver.correctors:LineSearch")
CORRECTORS.declare("trust_region", "nma.solver.correctors:TrustRegion")
WARM_START_NEEDS_HOST = (
    "needs a host linear solver (pardiso, superlu): solver.linear=dense solves a batch in "
    "lockstep from rest"
)


@dataclass(frozen=True)
class NewtonOptions:
    """Newton's settings, each declared once here with its range and meaning (the config's `solver`
    group, nma.schema.SolverConfig, takes them all)."""

    rtol: float = bounded(
        1e-10, "(0, 1]", doc="residual tolerance relative to the full-load force scale"
    )
    path_rtol: float = bounded(
        0.0,
        "[0, 1]",
        doc="residual tolerance of the load steps before the last, relative "
        "as rtol (0: rtol; the last always meets rtol): fewer iterations, but where several "
        "equilibria are near, another may be reached",
    )
    atol: float = bounded(
        1e-13, "(0, 1]", doc="noise floor relative to (max element stiffness x size)"
    )
    max_iters: int = bounded(
        200, "[1, 100000]", doc="Newton iterations of a whole solve, every load step's"
    )
    max_step_iters: int = bounded(
        100,
        "[1, 100000]",
        doc="corrector iterations before a load step fails (up to 5 "
        "more while its residual is within 1000x the tolerance)",
    )
    initial_increment: float = bounded(
        1.0, "(0, 1]", doc="the first load step, a fraction of the full load"
    )
    min_increment: float = bounded(
        1e-4, "(0, 1]", doc="a load step halved below this fails the solve"
    )
    grow: float = bounded(2.0, "[1, 100]", doc="the next load step's growth after a quick one")
    step_fraction: float = bounded(
        0.9, "(0, 1]", doc="a step may go this fraction of the way to J = 0"
    )
    armijo: float = bounded(1e-4, "(0, 0.5]", doc="the line search's sufficient decrease")
    max_backtracks: int = bounded(
        40, "[1, 1000]", doc="halvings of a step before the line search gives up"
    )
    damped_step: float = bounded(
        0.1,
        "(0, 1]",
        doc="a corrector step shorter than this fraction of the Newton step is heavily damped",
    )
    max_damped_steps: int = bounded(
        3,
        "[1, 100000]",
        doc="heavily damped corrector steps in a row that cut the "
        "load step at once (Newton's model does not hold there)",
    )
    corrector: str = option(
        "line_search",
        "a corrector step at fixed load: the Newton step shortened by a line "
        "search, or a trust region on the energy's quadratic model (its diagonal shift "
        "adapted), which damps a soft mode's part of the step only; a name in "
        "nma.registry.CORRECTORS (nma/solver/correctors.py)",
    )
    contact_exact_below: float = bounded(
        1e-3,
        "[0, 1]",
        doc="with contact, Newton's correctors use contact's "
        "normal stiffness only (positive semi-definite) until the residual falls "
        "below this fraction of the full load's force scale, then the exact "
        "tangent (0: exact throughout)",
    )
    # off by default: the paper's solver takes the first stationary point Newton reaches
    escape_saddles: bool = option(
        False,
        "a converged saddle (PARDISO's inertia) is left along its unstable mode "
        "for a stable equilibrium",
    )
    element_bound: bool = option(
        True,
        "Newton's step keeps det F > 0 at each element's 4 x 4 check points "
        "(corners included), not only at its Gauss points: a state that inverts between "
        "them fails (INVERTS) instead of converging; always on with "
        "fidelity.inversion_barrier",
    )
    warm_start: bool = option(
        False,
        "start a solve from the kept equilibrium nearest in actuation, where nearer "
        "than rest (host backends); one not converged within warm_iters is redone cold",
    )
    warm_pool: int = bounded(64, "[1, 100000]", doc="equilibria kept as warm starts")
    warm_iters: int = bounded(
        30, "[1, 100000]", doc="iterations a warm solve may take before it is redone cold"
    )
    warm_audit: int = bounded(
        16,
        "[0, 100000]",
        doc="every this many warm solves one is also solved cold and "
        "the cold answer taken where the two differ; 0: none",
    )

    def __post_init__(self):
        # the config checks it too; library callers get the same words
        if self.corrector not in CORRECTORS.names():
            raise ValueError(
                f"corrector must be one of {CORRECTORS.names()}, got {self.corrector!r}"
            )
