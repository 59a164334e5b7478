"""Mooney-Rivlin: linear in both invariants of C."""

from __future__ import annotations

from .base import InvariantLaw, Parameter, register


@register
class MooneyRivlin(InvariantLaw):
    """psi = C10 (I1 - 3) + C01 (I2 - 3); mu0 = 2 (C10 + C01).  C01 = 0 is Neo-Hookean."""

    name = "mooney_rivlin"
    parameters = (
        Parameter("C10", 0.0108, "(-inf, inf)", "the coefficient of I1 - 3"),
        Parameter("C01", 0.0027, "(-inf, inf)", "the coefficient of I2 - 3"),
    )

    def shear_modulus(self, q):
        return 2.0 * (q["C10"] + q["C01"])

    def stress_free(self, q):
        return 2.0 * q["C10"] + 4.0 * q["C01"]

    def psi_lambda(self, q):
        return 4.0 * q["C01"]  # I2 = a^2 b^2 + b^2 + a^2 at c = 1: d2/da db (a^2 b^2) = 4

    def psi(self, q, I1, I2):
        return q["C10"] * (I1 - 3.0) + q["C01"] * (I2 - 3.0)

    def fit_start(self, mu0, stretches, i1_max):
        inf = float("inf")
        return [0.4 * mu0, 0.1 * mu0], [-inf, -inf], [inf, inf]
