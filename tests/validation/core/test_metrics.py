"""validation.core.metrics: RMSE and Theil's inequality coefficient."""
import numpy as np
import pytest

from validation.core.metrics import rmse, theil_inequality


def test_rmse_of_a_constant_error_is_its_size_and_is_symmetric():
    measured = np.sin(np.linspace(0.0, 3.0, 50))
    assert rmse(measured, measured) == 0.0
    assert rmse(measured, measured + 0.2) == pytest.approx(0.2, rel=1e-12)  # rounding only
    assert rmse(measured, measured - 0.2) == rmse(measured - 0.2, measured)
    assert isinstance(rmse(measured, measured + 0.2), float)


def test_rmse_along_axis_0_is_one_value_per_column():
    measured = np.zeros((4, 3))
    predicted = np.column_stack([np.full(4, 1.0), [3.0, -3.0, 3.0, -3.0], [0.0, 0.0, 0.0, 2.0]])
    per_column = rmse(measured, predicted, axis=0)
    assert per_column.shape == (3,)
    np.testing.assert_allclose(per_column, [1.0, 3.0, 1.0], rtol=1e-15)  # sqrt(4 / 4) = 1 exactly
    # Without an axis the mean runs over every element: sqrt((4 + 36 + 4) / 12).
    assert rmse(measured, predicted) == pytest.approx(np.sqrt(44 / 12), rel=1e-15)


def test_theil_coefficient_bounds():
    y = np.sin(np.linspace(0, 10, 200))
    assert theil_inequality(y, y) == 0.0
    # The worst cases, 1 up to rounding: opposite signals, and a prediction of nothing.
    assert theil_inequality(y, -y) == pytest.approx(1.0)
    assert theil_inequality(y, np.zeros_like(y)) == pytest.approx(1.0)


def test_theil_coefficient_is_zero_for_two_zero_signals_and_ignores_a_common_scale():
    assert theil_inequality(np.zeros(5), np.zeros(5)) == 0.0
    y = np.sin(np.linspace(0, 6, 100))
    # Dimensionless: the same agreement in other units gives the same coefficient (up to rounding).
    assert theil_inequality(1000 * y, 1100 * y) == pytest.approx(theil_inequality(y, 1.1 * y), rel=1e-12)
    assert 0 < theil_inequality(y, 1.1 * y) < 1
