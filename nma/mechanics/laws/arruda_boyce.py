"""Arruda-Boyce, the eight-chain model, with the inverse Langevin function as its five-term series
(Arruda and Boyce, J. Mech. Phys. Solids 41(2), 1993, 389-412; the form of the Abaqus
Theory Manual, hyperelastic material behaviour):

    psi = mu sum_{i=1..5} C_i / lambda_m^(2i - 2) (I1^i - 3^i),
    C = 1/2, 1/20, 11/1050, 19/7000, 519/673750,

the Taylor series of (mu / 6) (lambda_m / lambda_ch) L^-1(lambda_ch / lambda_m) = dpsi/dI1 in
lambda_ch^2 = I1 / 3, truncated after x^8 (x = lambda_ch / lambda_m: relative error ~1e-3 at
x = 0.5).  The series has no pole at the locking stretch: it stiffens like x^8, not without bound.
Its initial shear modulus is mu (1 + 3/(5 lambda_m^2) + 99/(175 lambda_m^4) + 513/(875 lambda_m^6)
+ 42039/(67375 lambda_m^8)), mu as lambda_m grows.
"""

from __future__ import annotations

from .base import InvariantLaw, Parameter, register

SERIES = (1 / 2, 1 / 20, 11 / 1050, 19 / 7000, 519 / 673750)  # C_1 .. C_5


@register
class ArrudaBoyce(InvariantLaw):
    """psi = mu sum_i C_i / lambda_m^(2i - 2) (I1^i - 3^i), i = 1..5 (the eight-chain model's
    five-term series); mu0 = 2 dpsi/dI1 at rest, mu (1 + 3 / (5 lambda_m^2) + ...)."""

    name = "arruda_boyce"
    parameters = (
        Parameter("mu", 0.02659, "(0, 1e30]", "the chains' shear modulus (mu0 as lambda_m grows)"),
        Parameter("lambda_m", 7.0, "(1, 1e6]", "the locking stretch of a chain", stress=False),
    )

    def shear_modulus(self, q):
        return (
            2.0
            * q["mu"]
            * sum((i + 1) * c * 3.0**i / q["lambda_m"] ** (2 * i) for i, c in enumerate(SERIES))
        )

    def stress_free(self, q):
        return self.shear_modulus(q)

    def psi(self, q, I1, I2):
        return q["mu"] * sum(
            c / q["lambda_m"] ** (2 * i) * (I1 ** (i + 1) - 3.0 ** (i + 1))
            for i, c in enumerate(SERIES)
        )
