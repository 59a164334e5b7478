"""Neo-Hookean, the paper's law: psi = mu/2 (I1 - 3), mu = E / (2 (1 + nu)), parametrised by Young's
modulus E with every law's nu.  Its bulk modulus is E / (3 (1 - 2 nu)), Neo-Hookean's own, which
the other laws take at their initial shear modulus; nma.mechanics.material writes W, its stress and
its tangent in closed form (`closed_form`)."""

from __future__ import annotations

from .base import InvariantLaw, Parameter, register


@register
class NeoHookean(InvariantLaw):
    """psi = mu/2 (I1 - 3); mu0 = mu = E / (2 (1 + nu)), the incompressible E / 3."""

    name = "neo_hookean"
    # E from 1e-30 to 1e30 (any unit system's softest and stiffest solid), beyond which the
    # energy, its residual and their round-off leave float64's normal numbers and a solve could
    # not tell equilibrium from underflow or overflow
    parameters = (
        Parameter(
            "E", 0.07, "[1e-30, 1e30]", "Young's modulus, in the unit of every force and stress"
        ),
    )
    closed_form = True
    stable = True  # psi is convex in I1 with mu > 0

    def shear_modulus(self, q):
        return q["E"] / (2.0 * (1.0 + q["nu"]))

    def bulk_modulus(self, q, mu0):
        return q["E"] / (3.0 * (1.0 - 2.0 * q["nu"]))

    def psi_lambda(self, q):
        return 0.0 * q["E"]  # psi = mu/2 (a^2 + b^2 + c^2 - 3) has no cross term

    def stress_free(self, q):
        return self.shear_modulus(q)

    def psi(self, q, I1, I2):
        return 0.5 * self.shear_modulus(q) * (I1 - 3.0)
