"""What the benchmarks share: relative errors, Richardson extrapolation through three meshes, and
the report's number formats."""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq


def relative_error(value, reference) -> float:
    return float(value / reference - 1.0)


def richardson(spans, values):
    """Limit L and rate p of v(h) = L - C h^p through three meshes of h = 1 / spans."""
    h = 1.0 / np.asarray(spans, float)
    ratio = (values[1] - values[0]) / (values[2] - values[1])
    p = brentq(lambda p: (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p) - ratio, 0.2, 10.0)
    return values[0] + (values[1] - values[0]) / (h[0] ** p - h[1] ** p) * h[0] ** p, p


def richardson_or_none(spans, values):
    """richardson's (limit, order), or (None, None) where the ladder is not monotone or its rate
    lies outside [0.2, 10]."""
    try:
        return tuple(float(x) for x in richardson(spans, values))
    except ValueError:
        return None, None


def order(p) -> str:
    return "" if p is None else f"{p:.2f}"
