"""St Venant-Kirchhoff: linear elasticity's energy of the Green-Lagrange strain E = (C - I)/2,

    W = lambda/2 (tr E)^2 + mu tr(E^2),
    mu = E / (2 (1 + nu)),  lambda = E nu / ((1 + nu) (1 - 2 nu)),

the simplest hyperelastic law of the benchmarks (Turek and Hron's CSM tests among them), with
Young's modulus E and every law's nu: its small-strain moduli are linear elasticity's.  W is the
whole energy (`volume_term` False: no -c0 log J, no kappa/2 (log J)^2, so the `mixed` formulation
does not apply), written in the invariants of the 3D C as psi = lambda/8 (I1 - 3)^2 + mu/4 (I1^2 -
2 I2 - 2 I1 + 3) and taken in plane strain like every law.

It is unstable in strong compression: in uniaxial plane-strain stress its nominal stress is
E'/2 (lambda^3 - lambda), E' = E / (1 - nu^2), which softens and turns back below the stretch
sqrt(1/3) = 0.577 (so does equibiaxial compression), and its energy stays finite as J -> 0.  The
config refuses stretch ranges (material.stretches) reaching below sqrt(1/3); its default is
[0.6, 2.0].  Its energy has no incompressible limit (lambda grows without bound as nu -> 0.5), so
the incompressible tests of a tensile fit (nma.mechanics.laws.homogeneous) do not apply.
"""

from __future__ import annotations

from .base import InvariantLaw, Parameter, register

TURNING_STRETCH = 3.0**-0.5  # where E'/2 (l^3 - l) has its minimum: d/dl (l^3 - l) = 0


@register
class StVenantKirchhoff(InvariantLaw):
    """W = lambda/2 (tr E)^2 + mu tr(E^2), E = (C - I)/2, the whole energy; mu0 = mu =
    E / (2 (1 + nu)).  Unstable in compression below the stretch sqrt(1/3) = 0.577."""

    name = "st_venant_kirchhoff"
    # E from 1e-30 to 1e30 as Neo-Hookean's: any unit system's softest and stiffest solid
    parameters = (
        Parameter(
            "E", 0.07, "[1e-30, 1e30]", "Young's modulus, in the unit of every force and stress"
        ),
    )
    volume_term = False
    stretch_range = (0.6, 2.0)

    def shear_modulus(self, q):
        return q["E"] / (2.0 * (1.0 + q["nu"]))

    def lame_lambda(self, q):
        return q["E"] * q["nu"] / ((1.0 + q["nu"]) * (1.0 - 2.0 * q["nu"]))

    def stress_free(self, q):
        return 0.0 * q["E"]  # psi's dpsi/dlambda at rest: 2 dpsi/dI1 + 4 dpsi/dI2 = 2 mu - 2 mu

    def psi(self, q, I1, I2):
        mu, lam = self.shear_modulus(q), self.lame_lambda(q)
        return 0.125 * lam * (I1 - 3.0) ** 2 + 0.25 * mu * (I1**2 - 2.0 * I2 - 2.0 * I1 + 3.0)

    def drucker(self, low: float, high: float) -> str:
        """'' for stretches [low, high] above sqrt(1/3); else where uniaxial compression softens
        (the nominal stress E'/2 (l^3 - l) of uniaxial plane-strain stress, whatever nu)."""
        if low > TURNING_STRETCH:
            return ""
        return (
            f"uniaxial compression at stretch {low:.3g} softens: St Venant-Kirchhoff's nominal "
            f"stress E'/2 (l^3 - l) turns back below the stretch sqrt(1/3) = {TURNING_STRETCH:.3f} "
            "(it is unstable in strong compression): keep material.stretches above it"
        )
