"""Yeoh: a cubic in I1 - 3, stiffening at large strain."""

from __future__ import annotations

from .base import InvariantLaw, Parameter, register


@register
class Yeoh(InvariantLaw):
    """psi = C10 (I1 - 3) + C20 (I1 - 3)^2 + C30 (I1 - 3)^3; mu0 = 2 C10.  C20 = C30 = 0 is
    Neo-Hookean."""

    name = "yeoh"
    parameters = (
        Parameter("C10", 0.01346, "(-inf, inf)", "the coefficient of I1 - 3"),
        Parameter("C20", 0.0005, "(-inf, inf)", "the coefficient of (I1 - 3)^2"),
        Parameter("C30", 0.00002, "(-inf, inf)", "the coefficient of (I1 - 3)^3"),
    )

    def shear_modulus(self, q):
        return 2.0 * q["C10"]

    def stress_free(self, q):
        return 2.0 * q["C10"]

    def psi(self, q, I1, I2):
        a = I1 - 3.0
        return q["C10"] * a + q["C20"] * a**2 + q["C30"] * a**3

    def fit_start(self, mu0, stretches, i1_max):
        inf = float("inf")
        return [0.5 * mu0, 0.0, 0.0], [0.0, -inf, -inf], [inf, inf, inf]
