"""The numpy-only matrix exponential and zero-order hold that the Bo105 reference and its FMU share."""
import numpy as np
import pytest
from scipy.linalg import expm as scipy_expm

from validation.vehicles.linear_discretisation import expm, zero_order_hold


@pytest.mark.parametrize("scale", [1e-3, 1.0, 30.0])  # no scaling, a little, several squarings
def test_expm_equals_scipys_on_a_random_matrix(scale):
    M = scale * np.random.default_rng(0).normal(size=(9, 9))
    expected = scipy_expm(M)
    # The same algorithm (Higham 2005, [13/13] Pade with scaling and squaring) in another order:
    # rounding only, relative to the largest entry, growing with the squarings.
    np.testing.assert_allclose(expm(M), expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_expm_of_a_diagonal_and_of_minus_itself():
    np.testing.assert_allclose(expm(np.diag([-2.0, 0.0, 1.5])), np.diag(np.exp([-2.0, 0.0, 1.5])), rtol=1e-14)
    M = np.random.default_rng(1).normal(size=(6, 6))
    np.testing.assert_allclose(expm(M) @ expm(-M), np.eye(6), atol=1e-12)


def test_zero_order_hold_of_a_first_order_lag():
    """``x_dot = -a x + a u``: ``Phi = exp(-a h)``, ``Gamma = 1 - exp(-a h)`` exactly."""
    a, h = 7.0, 0.05
    phi, gamma = zero_order_hold(np.array([[-a]]), np.array([[a]]), h)
    np.testing.assert_allclose([phi[0, 0], gamma[0, 0]], [np.exp(-a * h), -np.expm1(-a * h)], rtol=1e-14)
