"""Intervals that hold when the model error is correlated in time: the fit's covariance widens
each variance to the Newey-West one (validation.diagnose.fitting), which for a constant regressor
and AR(1) errors is the long-run variance ``(1 + rho) / (1 - rho)`` times the white one."""
from types import SimpleNamespace

import numpy as np
import pytest

from validation.diagnose.fitting import _covariances


def _ar1(rho, n, rng):
    noise = rng.standard_normal(n)
    series = np.empty(n)
    series[0] = noise[0] / np.sqrt(1 - rho**2)
    for t in range(1, n):
        series[t] = rho * series[t - 1] + noise[t]
    return series * np.sqrt(1 - rho**2)  # unit variance


@pytest.mark.parametrize("rho", [0.0, 0.9])
def test_a_mean_of_ar1_errors_gets_its_long_run_variance(rho):
    """Two recordings of 4000 samples, one output, a constant regressor (the mean): the
    variance of the mean is (1 + rho) / (1 - rho) / N for AR(1) errors of unit variance (19x the
    white formula at rho = 0.9); white errors keep the classical one."""
    rng = np.random.default_rng(3)
    n = 4000
    residual = np.concatenate([_ar1(rho, n, rng), _ar1(rho, n, rng)])
    jacobian = np.ones((2 * n, 1))
    data = SimpleNamespace(fit_mask=[np.ones(n, bool), np.ones(n, bool)], output_names=("q",))
    variance = _covariances(jacobian, residual, data)[0][0, 0]
    expected = (1 + rho) / (1 - rho) / (2 * n)
    assert variance == pytest.approx(expected, rel=0.3)


def test_outputs_of_one_sample_are_one_score_and_the_classical_variance_is_a_floor():
    """Two outputs of the same samples: their residuals add into one score per sample. Anti-correlated
    errors of the two outputs cancel in the score; the variance never falls below s^2 (J^T J)^-1."""
    rng = np.random.default_rng(4)
    n = 3000
    first = 2.0 * rng.standard_normal(n)
    residual = np.column_stack([first, -first]).ravel()  # sample-major: output 0, output 1
    jacobian = np.ones((2 * n, 1))
    data = SimpleNamespace(fit_mask=[np.ones(n, bool)], output_names=("q", "p"))
    classical = float(residual @ residual) / (2 * n - 1) / (2 * n)  # s^2 (J^T J)^-1, s^2 about 4
    robust, white = _covariances(jacobian, residual, data)
    assert robust[0, 0] == pytest.approx(classical, rel=1e-12) and white[0, 0] == pytest.approx(classical, rel=1e-12)
