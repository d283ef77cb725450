"""Sensor noise: its level, estimated from each measured signal alone, and the test of whether
a residual exceeds it (used by every stage of ``flightgp diagnose``, docs/diagnose.md)."""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from validation.core.metrics import robust_sd

#: False-alarm probability of one test against the noise: one moving-RMS window, one frequency
#: bin, one coherence peak, one output's residual.
LOCATE_ALPHA = 1e-4
#: Residual RMS over noise above which an output counts as not explained (on top of a
#: chi-squared test), so a noise estimate a few per cent off never raises a finding.
UNEXPLAINED_RATIO = 1.2
#: Name of the estimator, as diagnosis.json reports it.
NOISE_ESTIMATOR = "Gasser et al. 1986 pseudo-residuals, MAD"


def estimate_noise_sd(measured: np.ndarray, *, time: np.ndarray | None = None) -> float:
    """White-noise standard deviation of a smooth signal sampled fast, from the signal alone.

    Pseudo-residuals of Gasser, Sroka & Jennen-Steinmetz (Biometrika 73(3), 1986), the
    deviation of each sample from the straight line through its two neighbours,
    ``e_k = (a_k y[k-1] + b_k y[k+1] - y[k]) / sqrt(a_k^2 + b_k^2 + 1)`` with
    ``a_k = (t[k+1] - t[k]) / (t[k+1] - t[k-1])`` and ``b_k = (t[k] - t[k-1]) / (t[k+1] - t[k-1])``,
    have the noise variance wherever the signal is locally linear over three samples, on any
    design, even or not (on an even grid ``a = b = 1/2`` and
    ``e_k = -(y[k-1] - 2 y[k] + y[k+1]) / sqrt(6)``). Their scale is taken robustly, as
    ``1.4826 * median |e - median e|`` (Hampel, JASA 69, 1974), so the few samples where a
    control step bends the signal do not count. At 100 Hz a rigid-body response changes its
    slope far less per sample than typical sensor noise (pitch rate: ``h^2 q_ddot ~ 1e-4``
    rad/s against 0.003 rad/s of noise).

    Parameters
    ----------
    measured : ndarray, shape (n,), n >= 3
    time : ndarray, shape (n,), optional
        Strictly increasing sample times, s; default evenly spaced.

    Returns
    -------
    float
        Noise standard deviation in the signal's units; at least ``1e-6`` of its RMS (plus
        1e-12), so noise-free data still get finite weights.
    """
    if time is None:
        before = after = np.full(len(measured) - 2, 0.5)
    else:
        gaps = np.diff(time)
        span = gaps[:-1] + gaps[1:]
        before, after = gaps[1:] / span, gaps[:-1] / span  # a_k, b_k
    e = (before * measured[:-2] + after * measured[2:] - measured[1:-1]) / np.sqrt(before**2 + after**2 + 1)
    sd = robust_sd(e)
    return max(sd, 1e-6 * float(np.sqrt(np.mean(measured**2))) + 1e-12)


def noise_excess(weighted_residual: np.ndarray) -> tuple[float, bool]:
    """Whether a noise-weighted residual exceeds the noise.

    Under white sensor noise the weighted residual has unit variance, so its ``RSS`` is
    chi-squared with ``n`` degrees of freedom (taken as ``N(n, 2n)``, the normal approximation).
    It exceeds the noise when ``RSS`` is above that law's ``1 - LOCATE_ALPHA`` quantile *and*
    its RMS above :data:`UNEXPLAINED_RATIO`.

    Parameters
    ----------
    weighted_residual : ndarray, shape (n,)
        Residual over noise standard deviation, dimensionless.

    Returns
    -------
    ratio : float
        RMS of ``weighted_residual`` (residual RMS over noise).
    exceeds : bool
    """
    n = len(weighted_residual)
    rss = float(weighted_residual @ weighted_residual)
    ratio = math.sqrt(rss / n)
    return ratio, (rss - n) / math.sqrt(2 * n) > stats.norm.isf(LOCATE_ALPHA) and ratio > UNEXPLAINED_RATIO
