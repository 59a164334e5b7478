"""Newmark's average acceleration (beta 1/4, gamma 1/2, alpha_m = alpha_f = 0): second order, no
numerical damping; a linear system's energy is kept exactly (the trapezoidal rule)."""

from __future__ import annotations

from . import Scheme


def newmark(rho_inf: float) -> Scheme:
    """Average acceleration (rho_inf 1 whatever is asked: it damps no frequency)."""
    return Scheme(0.0, 0.0, 0.25, 0.5)
