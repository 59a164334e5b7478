"""Implicit time integration: Newmark's average acceleration and the generalised-alpha method.

With the free and prescribed dofs together in u, v, a, a step from t_n to t_{n+1} = t_n + dt solves
    M a_{n+1-am} + C v_{n+1-af} + (1 - af) f(u_{n+1}) + af f(u_n) = 0   (free rows)
with x_{n+1-a} = (1 - a) x_{n+1} + a x_n and Newmark's
    u_{n+1} = u_n + dt v_n + dt^2 ((1/2 - beta) a_n + beta a_{n+1}),  v_{n+1} = v_n + dt ((1 - gamma) a_n + gamma a_{n+1}).
Generalised-alpha (Chung & Hulbert, J. Appl. Mech. 60, 371, 1993) sets, from the spectral radius at
infinite frequency rho_inf in [0, 1],
    am = (2 rho_inf - 1) / (rho_inf + 1),  af = rho_inf / (rho_inf + 1),
    gamma = 1/2 - am + af,  beta = (1 - am + af)^2 / 4:
second order, unconditionally stable for linear problems, high frequencies damped to rho_inf.  Average
acceleration is am = af = 0, beta = 1/4, gamma = 1/2 (rho_inf = 1, no numerical damping; it conserves
a linear system's energy exactly).  The internal force is interpolated between the two states (the
form of Kuhl & Crisfield, IJNME 45, 569, 1999), so dividing by (1 - af) the step is the stationary
point of
    W(u) + 1/2 u.B u - b.u,   B = (1 - am) / ((1 - af) beta dt^2) M + gamma / (beta dt) C
and the static Newton solves it unchanged (nma.solver.equations.Inertia).
"""
from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp

from .. import checks
from ..solver.equations import Inertia
from .options import SCHEMES


@dataclass(frozen=True)
class Scheme:
    """The four constants of a generalised-alpha family member."""
    alpha_m: float
    alpha_f: float
    beta: float
    gamma: float

    @classmethod
    def of(cls, name: str, rho_inf: float = 1.0) -> "Scheme":
        """The scheme `name` (one of SCHEMES); rho_inf in [0, 1] (generalised_alpha's)."""
        rho_inf = checks.number("Scheme.of", "rho_inf", rho_inf, "[0, 1]")
        if name == "newmark":
            return cls(0.0, 0.0, 0.25, 0.5)
        if name == "generalised_alpha":
            am, af = (2.0 * rho_inf - 1.0) / (rho_inf + 1.0), rho_inf / (rho_inf + 1.0)
            return cls(am, af, 0.25 * (1.0 - am + af) ** 2, 0.5 - am + af)
        raise ValueError(f"dynamics.scheme must be one of {SCHEMES}, got {name!r}")

    def predictor(self, u, v, a, dt):
        """u*: where u_{n+1} would be with a_{n+1} = 0 in the beta term, a_{n+1} = (u_{n+1} - u*) / (beta dt^2)."""
        return u + dt * v + dt * dt * (0.5 - self.beta) * a

    def blocks(self, M, C, dt):
        """B, the step's inertia and damping blocks: (1 - am) / ((1 - af) beta dt^2) M + gamma / (beta dt) C."""
        return ((1.0 - self.alpha_m) / ((1.0 - self.alpha_f) * self.beta * dt * dt) * M
                + self.gamma / (self.beta * dt) * C)

    def inertia(self, u, v, a, f_n, M, C, edofs, dt) -> Inertia:
        """The step's quadratic term from the state (u, v, a) at t_n (flat, every dof), its internal force
        f_n (flat) and the mass and damping blocks."""
        am, af, gamma = self.alpha_m, self.alpha_f, self.gamma
        B = self.blocks(M, C, dt)
        # h: the residual's affine part at u = u*, besides the internal force at u_{n+1}
        h = (am / (1.0 - af)) * _apply(M, edofs, a) \
            + _apply(C, edofs, v / (1.0 - af) + dt * (1.0 - gamma) * a) + (af / (1.0 - af)) * f_n
        return Inertia(B, _apply(B, edofs, self.predictor(u, v, a, dt)) - h)

    def update(self, u_next, u, v, a, dt):
        """(v_{n+1}, a_{n+1}) from the step's solution."""
        a_next = (u_next - self.predictor(u, v, a, dt)) / (self.beta * dt * dt)
        return v + dt * ((1.0 - self.gamma) * a + self.gamma * a_next), a_next


def _apply(blocks, edofs, x):
    """The assembled matrix of element blocks times x (flat, every dof)."""
    return jnp.zeros_like(x).at[edofs].add(jnp.einsum("eab,eb->ea", blocks, x[edofs]))
