"""The time stepping's settings and parts, without JAX (the settings' schemas import them).

Time stepping has three parts, each chosen by name from its registry (nma.registry.Registry), each a
file of its own package, declared here by its import path and imported when first asked for:

- SCHEMES: the integrator of one step (nma/dynamics/schemes/): `newmark`, `generalised_alpha`;
- CONTROLLERS: how each output interval [k dt, (k + 1) dt] is covered by steps
  (nma/dynamics/controllers/): `fixed`, `cuts`, `adaptive`;
- ADJOINTS: what the forward pass keeps for the backward one (nma/dynamics/adjoints/): `store_all`,
  `checkpointed`.

A part from outside nma registers itself in its own module (`@CONTROLLERS.register("name")`).
DynamicsOptions declares every setting the parts take, once, with its default, range and meaning:
the library's defaults (nma.dynamics.trajectory.Dynamics) and the config's (DynamicsConfig,
nma.schema.physics) are these.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Optional

from ..registry import Registry
from ..settings import bounded, choice, option

SCHEMES: Registry = Registry("dynamics.scheme")
SCHEMES.declare("newmark", "nma.dynamics.schemes.newmark:newmark")
SCHEMES.declare("generalised_alpha", "nma.dynamics.schemes.generalised_alpha:generalised_alpha")

CONTROLLERS: Registry = Registry("dynamics.controller")
CONTROLLERS.declare("cuts", "nma.dynamics.controllers.cuts:Cuts")
CONTROLLERS.declare("fixed", "nma.dynamics.controllers.fixed:Fixed")
CONTROLLERS.declare("adaptive", "nma.dynamics.controllers.adaptive:Adaptive")

STARTS = ("rest", "static")  # dynamics.start: where a trajectory starts (nma.dynamics.initial)

ADJOINTS: Registry = Registry("dynamics.adjoint")
ADJOINTS.declare("store_all", "nma.dynamics.adjoints.store_all:StoreAll")
ADJOINTS.declare("checkpointed", "nma.dynamics.adjoints.checkpointed:Checkpointed")


@dataclass(frozen=True)
class DynamicsOptions:
    """The time stepping's settings, each declared once here (the config's `dynamics` group takes
    them all, nma.schema.physics.DynamicsConfig; Dynamics' arguments default to them)."""

    scheme: str = option(
        "newmark",
        "newmark: average acceleration (no numerical damping); "
        "generalised_alpha: second order, high frequencies damped to rho_inf; a "
        "name in nma.dynamics.options.SCHEMES (nma/dynamics/schemes/)",
    )
    rho_inf: float = bounded(
        0.8,
        "[0, 1]",
        doc="generalised_alpha's spectral radius at infinite "
        "frequency (1: none damped, 0: damped at once)",
    )
    dt: Optional[float] = bounded(
        None,
        "(0, inf)",
        doc="the time step, and the interval between "
        "the states reported (adaptive: its longest step); null: a 20th "
        "of the lowest natural period at rest",
    )
    steps: int = bounded(
        100, "[1, 1000000]", doc="time steps of dt: the states reported are at k dt, k = 0 .. steps"
    )
    alpha: float = bounded(
        0.0, "[0, inf)", doc="Rayleigh damping's mass-proportional part, C = alpha M + beta K_0"
    )
    beta: float = bounded(
        0.0,
        "[0, inf)",
        doc="Rayleigh damping's stiffness-proportional part (K_0: the tangent at rest)",
    )
    max_cuts: int = bounded(
        4,
        "[0, 20]",
        doc="the shortest step is dt / 2^max_cuts: cuts redoes "
        "a failed interval in 2, 4, ... 2^max_cuts steps; adaptive steps no "
        "shorter",
    )
    controller: str = option(
        "cuts",
        "how each interval dt is stepped: fixed (one step; a failed "
        "one ends the run), cuts (one step, redone in 2, 4, ... equal steps "
        "where it fails), adaptive (steps sized by a local error estimate, "
        "clipped to hit every k dt); a name in "
        "nma.dynamics.options.CONTROLLERS (nma/dynamics/controllers/)",
    )
    rtol: float = bounded(
        1e-3,
        "(0, 1]",
        doc="adaptive: the local error allowed per step, relative to the largest displacement",
    )
    atol: float = bounded(
        1e-6,
        "(0, inf)",
        doc="adaptive: the local error allowed per step, in length units, added to rtol's",
    )
    adjoint: str = option(
        "store_all",
        "what the forward pass keeps for the gradient: store_all "
        "(every interval's state), checkpointed (every k-th; the rest solved "
        "again in the backward pass); a name in nma.dynamics.options.ADJOINTS "
        "(nma/dynamics/adjoints/)",
    )
    checkpoints: Optional[int] = bounded(
        None,
        "[1, 1000000]",
        doc="checkpointed: the states kept; null: ceil(sqrt(steps)) intervals apart",
    )
    start: str = choice(
        "rest",
        STARTS,
        doc="where the trajectory starts: rest (u = 0 but the actuation's value at t = 0, v = 0; "
        "a dead load, scene.gravity or a traction, applied at once at t = 0: the body falls and "
        "oscillates about its sagged state), static (the static equilibrium under the dead load "
        "and the actuation's value at t = 0, v = 0: nothing moves unless the actuation does)",
    )


DEFAULTS = DynamicsOptions()
# the ranges of the settings that have one, by name (nma.dynamics.checks, nma.schema.physics)
RANGES = {f.name: f.metadata["range"] for f in fields(DynamicsOptions) if "range" in f.metadata}
