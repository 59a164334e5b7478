"""Generalised-alpha (Chung & Hulbert, J. Appl. Mech. 60, 371, 1993): from the spectral radius at
infinite frequency rho_inf in [0, 1],
    am = (2 rho_inf - 1) / (rho_inf + 1),  af = rho_inf / (rho_inf + 1),
    gamma = 1/2 - am + af,  beta = (1 - am + af)^2 / 4:
second order, unconditionally stable for linear problems, the highest frequencies damped to
rho_inf."""

from __future__ import annotations

from . import Scheme


def generalised_alpha(rho_inf: float) -> Scheme:
    am, af = (2.0 * rho_inf - 1.0) / (rho_inf + 1.0), rho_inf / (rho_inf + 1.0)
    return Scheme(am, af, 0.25 * (1.0 - am + af) ** 2, 0.5 - am + af)
