"""Cook's membrane, plane strain, nearly incompressible Neo-Hookean (de Souza Neto et al., 1996).

Reference tip displacement 6.93 +- 0.015 mm (measured for this project with an independent
finite-element code under refinement; mixed u-p-J converges from above to 6.947, degree-4
displacement from below to 6.918). Pure-displacement quadratic B-splines lock on coarse meshes, so
they approach from below; the mixed formulation (volume term at each element's mean dilatation,
nma.mechanics.energy) does not lock and approaches from above, as mixed u-p fields do."""

import numpy as np
import pytest

from experiments.verification.common import richardson
from experiments.verification.cooks_membrane import (
    OGS_FBAR,
    OGS_STANDARD,
    OGS_TOLERANCE,
    REFERENCE_TIP,
    tip_displacement,
)


def check_convergence(spans, tolerance, formulation="displacement"):
    tips = np.array([tip_displacement(s + 2, formulation) for s in spans])
    side = 1.0 if formulation == "displacement" else -1.0  # from below (locking), or from above
    # monotone
    assert np.all(side * np.diff(tips) > 0) and np.all(side * tips < side * REFERENCE_TIP)
    limit, p = richardson(spans, tips)
    assert 0.8 < p < 3.0
    assert abs(limit - REFERENCE_TIP) < tolerance * REFERENCE_TIP


# the patch test and the mixed model's Cook's membrane cover the discretisation in the fast suite
@pytest.mark.slow
def test_cooks_membrane_converges_to_reference():
    check_convergence([24, 36, 48], 0.01)  # coarser meshes are not yet in the asymptotic range


@pytest.mark.slow
def test_cooks_membrane_fine_meshes_extrapolate_within_half_percent():
    # tips 6.740, 6.814, 6.847 mm: still 1.2% low at 96 spans
    check_convergence([48, 72, 96], 0.005)


def test_mixed_formulation_does_not_lock():
    """At 24 spans the mixed formulation's tip is within 1% of the converged value (measured: 6.947
    mm, +0.25%), where the displacement model is still more than 1% low (it is 1.2% low even at 96
    spans)."""
    mixed, displacement = tip_displacement(26, "mixed"), tip_displacement(26)
    assert abs(mixed - REFERENCE_TIP) < 0.01 * REFERENCE_TIP
    assert displacement < 0.99 * REFERENCE_TIP
    # OpenGeoSys's published F-bar quadrilaterals (experiments/verification/cooks_membrane.py)
    # approach from below and reach 6.891 mm at 30 elements per side: nma's mixed tip at 24 spans
    # lies within 1% above it; its locking quadrilaterals without F-bar are at 4.70 mm there, far
    # under the quadratic B-splines' displacement model at 24 spans
    assert OGS_FBAR[-1] < mixed < (1.0 + OGS_TOLERANCE) * OGS_FBAR[-1]
    assert np.all(np.diff(OGS_FBAR) > 0) and OGS_STANDARD[-1] < 0.75 * displacement


@pytest.mark.slow
def test_mixed_formulation_converges_from_above():
    # tips 6.947, 6.943, 6.940 mm: order ~1, limit 6.934
    check_convergence([24, 36, 48], 0.005, "mixed")
