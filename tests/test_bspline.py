import numpy as np
import pytest

from nma.geometry.bspline import basis_matrix, element_tables, refinement_operator


@pytest.mark.parametrize("n_ctrl", [5, 8, 11])
@pytest.mark.parametrize("quad", [2, 3, 5])
def test_partition_of_unity(n_ctrl, quad):
    _, values, grads, weights = element_tables(n_ctrl, quad)
    np.testing.assert_allclose(values.sum(-1), 1.0, atol=1e-13)
    np.testing.assert_allclose(grads.sum(-2), 0.0, atol=1e-11)
    np.testing.assert_allclose(weights.sum(), 1.0, atol=1e-13)  # area of the parameter square


@pytest.mark.parametrize("n_ctrl", [5, 8])
def test_derivatives_match_finite_differences(n_ctrl):
    spans = n_ctrl - 2  # sample inside spans: at a knot the second derivative jumps and FD is O(h)
    x = ((np.arange(spans)[:, None] + np.linspace(0.1, 0.9, 7)[None]) / spans).ravel()
    h = 1e-6
    fd = (basis_matrix(x + h, n_ctrl) - basis_matrix(x - h, n_ctrl)) / (2 * h)
    np.testing.assert_allclose(basis_matrix(x, n_ctrl, 1), fd, atol=1e-7)


def test_refinement_is_exact_knot_insertion():
    rng = np.random.default_rng(0)
    coarse = rng.normal(size=(5, 2))
    x = rng.uniform(0, 1, 50)
    for n in (8, 11, 14):
        fine = refinement_operator(n) @ coarse
        np.testing.assert_allclose(basis_matrix(x, n) @ fine, basis_matrix(x, 5) @ coarse, atol=1e-12)


@pytest.mark.parametrize("count", [4, 6, 7, 9])
def test_fidelity_rejects_non_nested_counts(count):
    """Only 3k + 2 control points nest the design knots (knot insertion is then exact)."""
    from nma.errors import ConfigError
    from nma.schema import Fidelity
    with pytest.raises(ConfigError, match="fidelity.ctrl_per_patch"):
        Fidelity(count, 3)
