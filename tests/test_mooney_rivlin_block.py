"""A nearly incompressible Mooney-Rivlin block in plane-strain compression against the
incompressible closed form P = 2 (l - l^-3)(C10 + C01), lateral stretch 1/l (Ogden, Non-linear
Elastic Deformations, sec. 7.2): the mixed formulation, sliding supports and a dead traction, so the
deformation is homogeneous (experiments/verification/mooney_rivlin_block.py)."""

import numpy as np
import pytest

from experiments.verification import mooney_rivlin_block as mr


def test_closed_form_is_the_derivative_of_the_plane_strain_energy():
    """W(l) = (C10 + C01)(l^2 + l^-2 - 2) on F = diag(1/l, l, 1): P = dW/dl, by central
    differences (step 1e-6: truncation ~1e-12)."""
    W = lambda l: (mr.C10 + mr.C01) * (l**2 + l**-2 - 2.0)
    lam = np.array([0.6, 0.75, 0.9, 1.3])
    numeric = (W(lam + 1e-6) - W(lam - 1e-6)) / 2e-6
    np.testing.assert_allclose(mr.closed_form_stress(lam), numeric, rtol=1e-8)


def test_compressed_block_is_homogeneous_and_within_its_compressibility():
    """At nu = 0.499 under the closed form's traction at stretches 0.8 and 0.6: the model is the
    compressible law's homogeneous state within 1e-8 (found 1e-12: a linear field is in the spline
    space and its mean dilatation is its own), and the closed form's stress at the reached stretch
    and the volume within 2 (mu0 + |P|) / kappa of it (found 0.4 to 0.46 of that: the volume
    change the mean stress leaves at kappa = 500 mu0)."""
    for ld in mr.compress(0.499, stretches=(0.8, 0.6)):
        assert ld["converged"]
        assert ld["exact_error"] < mr.EXACT_TOLERANCE and ld["homogeneous"] < mr.EXACT_TOLERANCE
        assert (
            abs(ld["stress_error"]) < ld["tolerance"] and abs(ld["lateral_error"]) < ld["tolerance"]
        )
        assert abs(ld["stress_error"]) > 0.2 * ld["tolerance"]  # compressibility, not zero


@pytest.mark.slow  # eight solves: about a minute
def test_the_gap_to_the_closed_form_shrinks_with_the_compressibility():
    """From nu = 0.499 to 0.4999 mu/kappa falls tenfold, and so does the gap to the
    incompressible closed form at every load (found a ratio of 10.0 within 1%)."""
    r = mr.run()
    assert r["failures"] == [], r["failures"]
    for coarse, fine in zip(r["0.499"]["loads"], r["0.4999"]["loads"]):
        assert coarse["stress_error"] / fine["stress_error"] == pytest.approx(10.0, rel=0.05)
