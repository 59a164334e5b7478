"""From the `dynamics` settings (nma.schema.physics.DynamicsConfig) to what a Dynamics takes: the
one rule for the time step, and Rayleigh damping from a damping ratio, each from the lowest natural
frequency at rest where the settings leave them open (nma.dynamics.modes: one modal solve)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import ConfigError

PERIOD_FRACTION = 20  # dt null: the lowest natural period at rest over this


def time_step(dt: float | None, omega_1: float | None) -> float:
    """The time step: dt where given, else a PERIOD_FRACTION-th of the lowest natural period
    2 pi / omega_1."""
    return float(dt) if dt is not None else 2.0 * np.pi / omega_1 / PERIOD_FRACTION


def needs_frequency(s) -> bool:
    """Whether settings `s` take the lowest natural frequency: dt null, or a damping ratio
    without its frequency."""
    return s.dt is None or (s.damping_ratio is not None and s.damping_frequency is None)


def resolve(sim, s, density: float, X=None, mat=None, omega_1: float | None = None):
    """The settings `s` (a DynamicsConfig, nma.schema.physics) with dt and alpha, beta filled in
    (its damping ratio spent): from `omega_1` where given, else the lowest natural frequency at
    rest of the design X under the material mat (the scene's initial design and material where
    None)."""
    if not dataclasses.is_dataclass(s) or not hasattr(s, "damping_ratio"):
        raise TypeError(
            f"dynamics settings must be a DynamicsConfig (nma.schema.physics) or a "
            f"mapping of its fields, got {type(s).__name__}"
        )
    if s.scheme == "off":
        raise ConfigError(
            "dynamics.scheme is off: choose a scheme (newmark, generalised_alpha) to step in time"
        )
    if omega_1 is None and needs_frequency(s):
        X = sim.reference_points(sim.init_params()) if X is None else X
        omega_1 = lowest_frequency(sim, X, sim.material_params if mat is None else mat, density)
    alpha, beta = s.alpha, s.beta
    if s.damping_ratio is not None:
        omega = s.damping_frequency or omega_1
        alpha, beta = s.damping_ratio * omega, s.damping_ratio / omega
    return dataclasses.replace(
        s,
        dt=time_step(s.dt, omega_1),
        alpha=alpha,
        beta=beta,
        damping_ratio=None,
        damping_frequency=None,
    )


def lowest_frequency(sim, X, mat, density: float) -> float:
    """The lowest natural frequency at rest (rad per unit time); SolverError, saying why, where the
    modal solve fails or finds none above 0 (a mechanism)."""
    from .modes import lowest_at_rest

    return lowest_at_rest(sim, X, mat, density)
