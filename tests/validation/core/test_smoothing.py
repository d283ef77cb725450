"""Local polynomial smoothing (validation.core.smoothing)."""
import numpy as np
import pytest

from validation.core.smoothing import local_polynomial


@pytest.mark.parametrize("window, order", [(5, 2), (13, 2), (9, 3)])
def test_reproduces_a_polynomial_of_its_order_on_uneven_times(window, order):
    time = np.cumsum(np.random.default_rng(0).uniform(0.04, 0.06, 40))
    coefficients = np.array([0.3, -1.2, 0.7, 0.25])[:order + 1]
    signal = np.polynomial.polynomial.polyval(time, coefficients)[:, None]
    value, slope = local_polynomial(time, signal, window=window, order=order)
    derivative = np.polynomial.polynomial.polyval(time, np.polynomial.polynomial.polyder(coefficients))
    # A polynomial the fit can represent is reproduced exactly, up to rounding of the
    # least-squares solve on times of order 1.
    np.testing.assert_allclose(value[:, 0], signal[:, 0], atol=1e-10)
    np.testing.assert_allclose(slope[:, 0], derivative, atol=1e-8)


def test_slope_noise_of_the_five_point_quadratic_is_the_textbook_value():
    """On an even grid the centred weights are [-2, -1, 0, 1, 2] / (10 h): slope noise s / (sqrt(10) h)."""
    h, n, s = 0.05, 20000, 0.001
    time = np.arange(n) * h
    noise = np.random.default_rng(1).normal(0.0, s, (n, 1))
    _, slope = local_polynomial(time, noise, window=5, order=2)
    # Interior samples; the standard deviation of 20 000 correlated-in-pairs draws is good to ~2 %.
    assert np.std(slope[2:-2]) == pytest.approx(s / (np.sqrt(10) * h), rel=0.03)


def test_refuses_a_window_it_cannot_fit():
    with pytest.raises(ValueError, match="odd window"):
        local_polynomial(np.arange(10.0), np.zeros((10, 1)), window=4, order=2)
    with pytest.raises(ValueError, match="odd window"):
        local_polynomial(np.arange(3.0), np.zeros((3, 1)), window=5, order=2)
