"""State estimation from noisy measurements of part of the state: the extended Kalman filter.

A one-step model ``x(k+1) = g(x(k), u(k)) + w(k)``, ``w ~ N(0, Q(x, u))``, measured as
``z(k) = x(k)[measured] + v(k)``, ``v ~ N(0, R)`` with R diagonal. The filter's estimate at frame
k uses the measurements up to and including frame k only (causal): a prediction through ``g``
linearised at the estimate (``F = dg/dx`` by central differences), then the measurement update
with the Joseph-form covariance (Simon, *Optimal State Estimation*, Wiley, 2006, sec. 13.2 for
the extended filter and eq. 5.19 for the Joseph form, which keeps the covariance symmetric and
positive semi-definite under rounding).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: Central-difference step of the filter's linearisation, in state units.
DIFFERENCE_STEP = 1e-5


@dataclass(frozen=True)
class FilteredStates:
    """Output of :func:`extended_kalman_filter`.

    Attributes
    ----------
    mean : ndarray, shape (n, n_states)
        Estimate at each frame from the measurements up to that frame.
    covariance : ndarray, shape (n, n_states, n_states)
    """

    mean: np.ndarray
    covariance: np.ndarray


def extended_kalman_filter(step: Callable, measurements: np.ndarray, inputs: np.ndarray, *,
                           measured_columns, measurement_variance, process_variance,
                           initial_mean, initial_covariance,
                           difference_step: float = DIFFERENCE_STEP) -> FilteredStates:
    """Filter a recording's measurements through a one-step model (module docstring).

    Parameters
    ----------
    step : callable
        ``step(states (m, n_states), inputs (m, n_inputs)) -> next states (m, n_states)``,
        vectorised over rows.
    measurements : ndarray, shape (n, n_measured)
        ``z(k)``, the measured state columns at each frame.
    inputs : ndarray, shape (n, n_inputs)
        ``u(k)``, acting from frame k to k + 1 (the last row is not used).
    measured_columns : sequence of int
        The state column each measurement column measures.
    measurement_variance : array_like, shape (n_measured,)
        Diagonal of R, in squared measurement units.
    process_variance : array_like of shape (n_states,), or callable
        Diagonal of Q: constant, or ``process_variance(states (1, n_states), inputs (1,
        n_inputs)) -> (1, n_states)`` at the estimate (e.g. a residual GP's predictive variance).
    initial_mean : array_like, shape (n_states,)
        Prior mean at frame 0, before its measurement.
    initial_covariance : array_like, shape (n_states, n_states)
    difference_step : float
        Central-difference step of the linearisation, state units.

    Returns
    -------
    FilteredStates
    """
    x = np.asarray(initial_mean, dtype=float).copy()
    P = np.asarray(initial_covariance, dtype=float).copy()
    n_frames, n_states = len(measurements), len(x)
    H = np.zeros((len(measured_columns), n_states))
    H[np.arange(len(measured_columns)), list(measured_columns)] = 1.0
    R = np.diag(np.asarray(measurement_variance, dtype=float))
    offsets = difference_step * np.concatenate([np.zeros((1, n_states)), np.eye(n_states), -np.eye(n_states)])
    identity = np.eye(n_states)
    means, covariances = np.empty((n_frames, n_states)), np.empty((n_frames, n_states, n_states))
    for k in range(n_frames):
        if k:
            u = np.repeat(inputs[k - 1][None], len(offsets), axis=0)
            moved = step(x + offsets, u)
            F = (moved[1:n_states + 1] - moved[n_states + 1:]).T / (2 * difference_step)
            Q = (process_variance(x[None], inputs[k - 1][None])[0] if callable(process_variance)
                 else np.asarray(process_variance, dtype=float))
            x, P = moved[0], F @ P @ F.T + np.diag(Q)
        innovation = measurements[k] - H @ x
        gain = np.linalg.solve(H @ P @ H.T + R, H @ P).T  # P H^T S^-1, S symmetric
        x = x + gain @ innovation
        correction = identity - gain @ H
        P = correction @ P @ correction.T + gain @ R @ gain.T
        means[k], covariances[k] = x, P
    return FilteredStates(means, covariances)
