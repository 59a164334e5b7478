"""Gent: the chains' limiting extensibility in one parameter, Jm, the largest I1 - 3."""

from __future__ import annotations

import numpy as np

from .base import InvariantLaw, Parameter, jnp, register

JM_OVER_I1 = 1e3  # a fit's bound on Jm over its data's largest I1 - 3 (Gent.fit_start)


@register
class Gent(InvariantLaw):
    """psi = -mu Jm / 2 log(1 - (I1 - 3) / Jm); mu0 = mu.  It stiffens without bound as I1 - 3
    nears Jm, where the energy is infinite."""

    name = "gent"
    parameters = (
        Parameter("mu", 0.02692, "(0, 1e30]", "the initial shear modulus"),
        Parameter("Jm", 50.0, "(0, 1e12]", "the limit of I1 - 3", stress=False),
    )

    def shear_modulus(self, q):
        return q["mu"]

    def stress_free(self, q):
        return q["mu"]

    def psi(self, q, I1, I2):
        arg = 1.0 - (I1 - 3.0) / q["Jm"]
        return jnp.where(
            arg > 0, -0.5 * q["mu"] * q["Jm"] * jnp.log(jnp.where(arg > 0, arg, 1.0)), jnp.inf
        )

    def fit_start(self, mu0, stretches, i1_max):
        """Jm from just above the data's largest I1 - 3 (uniaxial's; any mode's is of its order) to
        JM_OVER_I1 times it, beyond which Gent's stress is Neo-Hookean's within 1 / JM_OVER_I1 over
        the data and its energy loses digits as Jm grows (a solve's line search then cannot tell its
        steps apart)."""
        I1 = np.max(stretches**2 + 2.0 / stretches)
        top = JM_OVER_I1 * max(float(i1_max) - 3.0, 1.0)
        return [mu0, 10.0 * (I1 - 3.0) + 1.0], [0.0, 1.0001 * (I1 - 3.0)], [np.inf, top]

    def fit_notes(self, values, upper, nu):
        if values["Jm"] < 0.99 * upper[1]:
            return []
        return [
            f"law=gent: Jm is at its bound {upper[1]:.4g} ({JM_OVER_I1:g} times the data's "
            "largest I1 - 3): the data show no limiting stretch, and over them this Gent is "
            f"Neo-Hookean's within {100 / JM_OVER_I1:g}%; material.law=neo_hookean with "
            f"E = 2 mu (1 + nu) = {2 * values['mu'] * (1 + nu):.6g} is the same material"
        ]
