"""Local polynomial smoothing and differentiation of sampled signals.

A least-squares polynomial of ``order`` through ``window`` consecutive samples, evaluated at the
middle one, gives the smoothed value (its constant term) and the slope (its linear term): the
Savitzky-Golay filter (Savitzky & Golay, Analytical Chemistry 36(8), 1964), here on the actual,
possibly unevenly spaced sample times. The window is centred where it fits and shifted inward at
the ends (where the one-sided fits are noisier). On an even grid with step ``h`` a quadratic
through 5 samples has slope weights ``[-2, -1, 0, 1, 2] / (10 h)``: white noise of sd ``s`` gives
slope noise ``s / (sqrt(10) h)``, and a wider window trades that noise for the bias of curvature
it cannot follow (Schafer, IEEE Signal Processing Magazine 28(4), 2011).
"""
from __future__ import annotations

import numpy as np


def local_polynomial(time: np.ndarray, signal: np.ndarray, *, window: int, order: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed value and slope at every sample (module docstring).

    Parameters
    ----------
    time : ndarray, shape (n,)
        Strictly increasing sample times, s; n >= ``window``.
    signal : ndarray, shape (n, c)
        Samples of c signals.
    window : int
        Samples in each fit, odd, greater than ``order``.
    order : int
        Degree of the polynomial, >= 1.

    Returns
    -------
    value, slope : ndarray, shape (n, c)
        The fit and its derivative at each sample time (slope in signal units per s).
    """
    n = len(time)
    if not (order >= 1 and window > order and window % 2 == 1 and n >= window):
        raise ValueError(f"need an odd window > order >= 1 and at least window samples; got window "
                         f"{window}, order {order}, {n} samples")
    start = np.clip(np.arange(n) - window // 2, 0, n - window)
    rows = start[:, None] + np.arange(window)  # (n, window)
    offset = time[rows] - time[:, None]
    design = offset[..., None] ** np.arange(order + 1)  # (n, window, order + 1)
    weights = np.linalg.pinv(design)[:, :2, :]  # value and slope rows of the least-squares solution
    fitted = np.einsum("nkw,nwc->nkc", weights, signal[rows])
    return fitted[:, 0], fitted[:, 1]
