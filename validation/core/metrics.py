"""Agreement between a measured and a predicted signal: RMSE and Theil's inequality coefficient."""
from __future__ import annotations

import math

import numpy as np


def rmse(measured: np.ndarray, predicted: np.ndarray, *, axis: int | None = None):
    """Root-mean-square error ``sqrt(mean((y - y_hat)^2))``.

    Parameters
    ----------
    measured, predicted : ndarray, same shape
        In one unit (the signal's, or one per column).
    axis : int, optional
        The axis to average over (``0``: one RMSE per column of an (n, k) array); default all.

    Returns
    -------
    float, or ndarray with ``axis`` removed
        In the signal's unit.
    """
    error = np.sqrt(np.mean((np.asarray(measured) - np.asarray(predicted)) ** 2, axis=axis))
    return float(error) if axis is None else error


def theil_inequality(measured: np.ndarray, predicted: np.ndarray) -> float:
    """Theil's inequality coefficient ``U = RMSE / (RMS(y) + RMS(y_hat))``, 0 (perfect) to 1
    (Theil, *Economic Forecasts and Policy*, 1961; Jategaonkar, *Flight Vehicle System
    Identification*, 2006, sec. 11.4, where ``U < 0.25-0.3`` counts as good agreement).

    Parameters
    ----------
    measured, predicted : ndarray, same shape
        In one unit (the signal's).

    Returns
    -------
    float
        Dimensionless, in [0, 1]; 0 when both signals are zero.
    """
    denominator = math.sqrt(np.mean(measured**2)) + math.sqrt(np.mean(predicted**2))
    return float(rmse(measured, predicted) / denominator) if denominator > 0 else 0.0


def robust_sd(values: np.ndarray, *, axis: int | None = None) -> np.ndarray | float:
    """A standard deviation robust to outliers: 1.4826 times the median absolute deviation from
    the median (Hampel, JASA 69(346), 1974; the factor makes it the standard deviation of a
    normal sample).

    Parameters
    ----------
    values : ndarray
    axis : int, optional
        Along this axis (default: over every value).

    Returns
    -------
    float or ndarray
        In the unit of ``values``.
    """
    values = np.asarray(values, dtype=float)
    centre = np.median(values, axis=axis, keepdims=True)
    spread = 1.4826 * np.median(np.abs(values - centre), axis=axis)
    return float(spread) if axis is None else spread
