"""Implicit time integration by members of the generalised-alpha family, one file each, registered
in nma.dynamics.options.SCHEMES (`newmark`, `generalised_alpha`): a scheme is its four constants.

With the free and prescribed dofs together in u, v, a, a step from t_n to t_{n+1} = t_n + dt solves
    M a_{n+1-am} + C v_{n+1-af} + (1 - af) f(u_{n+1}) + af f(u_n) = 0   (free rows)
with x_{n+1-a} = (1 - a) x_{n+1} + a x_n and Newmark's
    u_{n+1} = u_n + dt v_n + dt^2 ((1/2 - beta) a_n + beta a_{n+1}),
    v_{n+1} = v_n + dt ((1 - gamma) a_n + gamma a_{n+1}).
The internal force is interpolated between the two states (the form of Kuhl & Crisfield, IJNME 45,
569, 1999), so dividing by (1 - af) the step is the stationary point of
    W(u) + 1/2 u.B u - b.u,   B = (1 - am) / ((1 - af) beta dt^2) M + gamma / (beta dt) C
and the static Newton solves it unchanged (nma.solver.equations.Inertia).

A new scheme is a file here whose factory f(rho_inf) -> Scheme is declared in SCHEMES.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp

from ... import checks
from ...solver.equations import Inertia


@dataclass(frozen=True)
class Scheme:
    """The four constants of a generalised-alpha family member."""

    alpha_m: float
    alpha_f: float
    beta: float
    gamma: float

    @classmethod
    def of(cls, name: str, rho_inf: float = 0.8) -> "Scheme":
        """The scheme registered as `name` (nma.dynamics.options.SCHEMES); rho_inf in [0, 1], the
        spectral radius at infinite frequency of the schemes that damp (generalised_alpha's)."""
        from ..options import SCHEMES

        rho_inf = checks.number("Scheme.of", "rho_inf", rho_inf, "[0, 1]")
        return SCHEMES.get(name)(rho_inf)

    def predictor(self, u, v, a, dt):
        """u*: where u_{n+1} would be with a_{n+1} = 0 in the beta term,
        a_{n+1} = (u_{n+1} - u*) / (beta dt^2)."""
        return u + dt * v + dt * dt * (0.5 - self.beta) * a

    def blocks(self, M, C, dt):
        """B, the step's inertia and damping blocks:
        (1 - am) / ((1 - af) beta dt^2) M + gamma / (beta dt) C."""
        return (1.0 - self.alpha_m) / (
            (1.0 - self.alpha_f) * self.beta * dt * dt
        ) * M + self.gamma / (self.beta * dt) * C

    def inertia(self, u, v, a, f_n, M, C, edofs, dt) -> Inertia:
        """The step's quadratic term from the state (u, v, a) at t_n (flat, every dof), its
        internal force f_n (flat) and the mass and damping blocks."""
        am, af, gamma = self.alpha_m, self.alpha_f, self.gamma
        B = self.blocks(M, C, dt)
        # h: the residual's affine part at u = u*, besides the internal force at u_{n+1}
        h = (
            (am / (1.0 - af)) * _apply(M, edofs, a)
            + _apply(C, edofs, v / (1.0 - af) + dt * (1.0 - gamma) * a)
            + (af / (1.0 - af)) * f_n
        )
        return Inertia(B, _apply(B, edofs, self.predictor(u, v, a, dt)) - h)

    def update(self, u_next, u, v, a, dt):
        """(v_{n+1}, a_{n+1}) from the step's solution."""
        a_next = (u_next - self.predictor(u, v, a, dt)) / (self.beta * dt * dt)
        return v + dt * ((1.0 - self.gamma) * a + self.gamma * a_next), a_next

    def local_error(self, a, a_next, dt):
        """The step's local error in u, estimated as dt^2 (beta - 1/6) (a_{n+1} - a_n)
        (Zienkiewicz & Xie, Earthquake Eng. Struct. Dyn. 20, 871, 1991): the difference between
        its u_{n+1} and a third-order Taylor step's with the same linear change of acceleration."""
        return dt * dt * (self.beta - 1.0 / 6.0) * (a_next - a)


def _apply(blocks, edofs, x):
    """The assembled matrix of element blocks times x (flat, every dof)."""
    return jnp.zeros_like(x).at[edofs].add(jnp.einsum("eab,eb->ea", blocks, x[edofs]))
