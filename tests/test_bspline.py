import numpy as np
import pytest

from nma.geometry.bspline import (
    basis_matrix,
    element_tables,
    refinement_operator,
    span_breaks,
    span_points,
)

GRADINGS = [1.0, 2.5]  # uniform knots, and graded towards the patch corners (fidelity.grading)


@pytest.mark.parametrize("n_ctrl", [5, 8, 11])
@pytest.mark.parametrize("quad", [2, 3, 5])
@pytest.mark.parametrize("grading", GRADINGS)
def test_partition_of_unity(n_ctrl, quad, grading):
    _, values, grads, weights = element_tables(n_ctrl, quad, grading)
    np.testing.assert_allclose(values.sum(-1), 1.0, atol=1e-13)
    np.testing.assert_allclose(grads.sum(-2), 0.0, atol=1e-11)
    np.testing.assert_allclose(weights.sum(), 1.0, atol=1e-13)  # area of the parameter square


@pytest.mark.parametrize("n_ctrl", [5, 8])
@pytest.mark.parametrize("grading", GRADINGS)
def test_derivatives_match_finite_differences(n_ctrl, grading):
    # sample inside spans: at a knot the second derivative jumps and FD is O(h)
    x = span_points(n_ctrl, np.linspace(0.1, 0.9, 7), grading).ravel()
    h = 1e-6
    fd = (
        basis_matrix(x + h, n_ctrl, grading=grading) - basis_matrix(x - h, n_ctrl, grading=grading)
    ) / (2 * h)
    np.testing.assert_allclose(basis_matrix(x, n_ctrl, 1, grading), fd, atol=1e-7)


@pytest.mark.parametrize("grading", GRADINGS)
def test_refinement_is_exact_knot_insertion(grading):
    rng = np.random.default_rng(0)
    coarse = rng.normal(size=(5, 2))
    x = rng.uniform(0, 1, 50)
    for n in (8, 11, 14):
        fine = refinement_operator(n, grading) @ coarse
        np.testing.assert_allclose(
            basis_matrix(x, n, grading=grading) @ fine, basis_matrix(x, 5) @ coarse, atol=1e-12
        )


@pytest.mark.parametrize("grading", [1.5, 2.5, 4.0])
def test_graded_knots_shrink_towards_both_ends_and_keep_the_design_knots(grading):
    """span_breaks: 1/3 and 2/3 stay knots (the design nests), the middle third stays uniform, the
    spans grow from each end as (i/k)^g over the outer thirds, mirror-symmetric (patches of either
    orientation meet knot to knot)."""
    b = span_breaks(14, grading)  # k = 4 spans per design span
    np.testing.assert_allclose(b[[0, 4, 8, 12]], [0, 1 / 3, 2 / 3, 1], atol=1e-15)
    np.testing.assert_allclose(b, 1.0 - b[::-1], atol=1e-15)
    widths = np.diff(b)
    np.testing.assert_allclose(widths[4:8], 1 / 12, atol=1e-15)
    assert np.all(np.diff(widths[:4]) > 0)  # finest at the end
    np.testing.assert_allclose(widths[0], (1 / 4) ** grading / 3)
    np.testing.assert_array_equal(span_breaks(14, 1.0), np.linspace(0, 1, 13))


@pytest.mark.parametrize("count", [4, 6, 7, 9])
def test_fidelity_rejects_non_nested_counts(count):
    """Only 3k + 2 control points nest the design knots (knot insertion is then exact)."""
    from nma.errors import ConfigError
    from nma.schema import Fidelity

    with pytest.raises(ConfigError, match="fidelity.ctrl_per_patch"):
        Fidelity(count, 3)
