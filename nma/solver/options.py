"""Newton's own settings (nma.solver.newton), a plain value the solver takes; no config machinery.

The config's `solver` group (nma.schema.SolverConfig) declares each of these with its allowed range
and hands them down through `SolverConfig.newton()`; library code builds them directly:

    Simulator(disc, "pardiso", NewtonOptions(rtol=1e-12))
"""
from __future__ import annotations

from dataclasses import dataclass

from ..registry import CORRECTORS


CORRECTORS.declare("line_search", "nma.solver.correctors:LineSearch")  # how a corrector step at fixed load
CORRECTORS.declare("trust_region", "nma.solver.correctors:TrustRegion")  # is globalised (nma.solver.correctors)
WARM_START_NEEDS_HOST = ("needs a host linear solver (pardiso, superlu): solver.linear=dense solves a batch in "
                         "lockstep from rest")


@dataclass(frozen=True)
class NewtonOptions:
    rtol: float = 1e-10             # residual tolerance relative to the full-load force scale
    path_rtol: float = 0.0          # rtol of the load steps before the last (0: rtol); may change the branch
    atol: float = 1e-13             # noise floor relative to (max element stiffness x size)
    max_iters: int = 200
    max_step_iters: int = 100       # corrector iterations before a load step fails (a few more near convergence)
    initial_increment: float = 1.0  # first load increment, a fraction of the full load
    min_increment: float = 1e-4     # an increment cut below this fails the solve
    grow: float = 2.0               # increment growth after a quick load step
    step_fraction: float = 0.9      # a step may go this fraction of the way to J = 0
    armijo: float = 1e-4            # sufficient decrease of the line search
    max_backtracks: int = 40
    damped_step: float = 0.1        # a corrector step shorter than this fraction of the Newton step is heavily damped
    max_damped_steps: int = 3       # heavily damped steps in a row that cut the load step at once
    corrector: str = "line_search"  # a name in nma.registry.CORRECTORS (nma/solver/correctors.py)
    # contact's tangent in the corrector iterations whose last residual exceeded this fraction of the full
    # load's force scale (and in each load step's first): each barrier term's normal stiffness only, a
    # positive semi-definite matrix; below it, the exact Hessian (quadratic convergence, and the adjoint's)
    contact_exact_below: float = 1e-3
    # leave saddles: a converged state whose Hessian has negative eigenvalues (PARDISO's inertia; a
    # symmetric path past a buckling point) is perturbed along its unstable mode and Newton goes on to
    # the stable (buckled) equilibrium.  Off by default: the paper's solver, and every reproduction
    # measured so far, takes the first stationary point Newton reaches.
    escape_saddles: bool = False
    # the step bound at each element's 4 x 4 check points too (corners included, where nma.geometry.validity
    # evaluates det F), not only at its Gauss points: Newton never steps to det F <= 0 at those points, so
    # an equilibrium the model reaches only by inverting there is a failed solve (INVERTS), not a
    # converged state that is not a physical object.  Always on with fidelity.inversion_barrier.
    element_bound: bool = True
    # warm starts (host backends): a solve starts from the kept equilibrium nearest in actuation (of
    # the last warm_pool solves) where that is nearer than rest, and walks the load from there; one
    # that has not converged within warm_iters iterations is redone cold.  Every warm_audit-th warm
    # solve is also solved cold, and the cold answer taken where the two differ (a branch jump).
    warm_start: bool = False
    warm_pool: int = 64
    warm_iters: int = 30
    warm_audit: int = 16

    def __post_init__(self):
        if self.corrector not in CORRECTORS.names():  # the config checks it too; library callers get the same words
            raise ValueError(f"corrector must be one of {CORRECTORS.names()}, got {self.corrector!r}")
