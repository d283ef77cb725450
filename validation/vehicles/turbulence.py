"""Dryden turbulence: gust velocities ``u_g, v_g, w_g`` along the body axes, for the stand-ins and
the concealed-effect benchmark.

Transfer functions of the Dryden form (MIL-F-8785C, 1980, sec. 3.7.2; MIL-HDBK-1797, 1997,
appendix A, sec. 4.9.2), driven by unit-intensity white noise, so that each gust has standard
deviation ``sigma_i``::

    H_u(s) = sigma_u sqrt(2 T_u) / (T_u s + 1)
    H_v(s) = sigma_v sqrt(T_v) (sqrt(3) T_v s + 1) / (T_v s + 1)^2     (the same for w)

with ``T_i = L_i / V``, the scale length over the speed the aircraft flies through the frozen
field. (The specification writes them for white noise of two-sided power spectral density 1/pi,
``H_u = sigma_u sqrt(2 L_u / (pi V)) / (1 + L_u s / V)``; with unit-intensity noise the ``pi``
goes and the variance is the same.)

Intensities and scale lengths below 1000 ft above ground (MIL-F-8785C, sec. 3.7.2.3, "low
altitude"): ``sigma_w = 0.1 W_20`` with ``W_20`` the wind speed at 20 ft, ``sigma_u = sigma_v =
sigma_w / (0.177 + 0.000823 h)^0.4``, ``L_w = h`` and ``L_u = L_v = h / (0.177 + 0.000823
h)^1.2``, ``h`` in ft. ``W_20`` is 15 kt for light, 30 kt for moderate and 45 kt for severe
turbulence (MIL-F-8785C, fig. 10; MIL-HDBK-1797, fig. 264): :data:`W20_KT`.

The filters are discretised exactly (Van Loan, IEEE TAC 23(3), 1978), start from their
stationary distribution (the air is turbulent from the first sample), and each gust is held over
one step.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import linalg

from validation.vehicles.linear_discretisation import expm
from validation.vehicles.state_space import propagate

#: ``W_20``, the wind speed 20 ft above ground, kt, of each turbulence intensity of MIL-F-8785C
#: (fig. 10) below 1000 ft: light, moderate, severe.
W20_KT = {"light": 15.0, "moderate": 30.0, "severe": 45.0}
_FT = 0.3048  # m
_KT = 1852.0 / 3600.0  # m/s


def low_altitude_turbulence(intensity: str, *, altitude_m: float) -> tuple[tuple, tuple]:
    """Gust standard deviations and scale lengths below 1000 ft (module docstring).

    Parameters
    ----------
    intensity : {"light", "moderate", "severe"}
    altitude_m : float
        Height above ground, m, above 0 and at most 1000 ft (304.8 m).

    Returns
    -------
    sigma : tuple of float, (3,)
        ``sigma_u, sigma_v, sigma_w``, m/s.
    length : tuple of float, (3,)
        ``L_u, L_v, L_w``, m.
    """
    if intensity not in W20_KT:
        raise ValueError(f"turbulence intensity {intensity!r} is none of {', '.join(W20_KT)}")
    height = altitude_m / _FT
    if not 0 < height <= 1000.0:
        raise ValueError(f"altitude {altitude_m:g} m is outside the low-altitude model's (0, 304.8] m")
    sigma_w = 0.1 * W20_KT[intensity] * _KT
    factor = 0.177 + 0.000823 * height
    sigma_uv = sigma_w / factor ** 0.4
    length_uv = height / factor ** 1.2 * _FT
    return (sigma_uv, sigma_uv, sigma_w), (length_uv, length_uv, altitude_m)


def dryden_filter(sigma, length, airspeed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous Dryden filters for (u_g, v_g, w_g): ``xi_dot = F xi + G n``, ``gust = C xi``.

    Parameters
    ----------
    sigma, length : sequence of 3 float
        Standard deviations (m/s) and scale lengths (m) of ``u_g, v_g, w_g``.
    airspeed : float
        Speed through the frozen field, m/s, positive.

    Returns
    -------
    F : ndarray, shape (5, 5)
    G : ndarray, shape (5, 3)
        ``n`` is unit-intensity white noise (3,).
    C : ndarray, shape (3, 5)
    """
    if not airspeed > 0:
        raise ValueError(f"the advection speed must be positive, got {airspeed!r} m/s")
    T = [float(L) / airspeed for L in length]
    F, G, C = np.zeros((5, 5)), np.zeros((5, 3)), np.zeros((3, 5))
    F[0, 0], G[0, 0], C[0, 0] = -1 / T[0], 1.0, sigma[0] * math.sqrt(2 * T[0]) / T[0]
    for gust, first in ((1, 1), (2, 3)):  # v_g, w_g: controllable canonical form of 1/(s + 1/T)^2
        t = T[gust]
        F[first, first + 1] = 1.0
        F[first + 1, first:first + 2] = [-1 / t**2, -2 / t]
        G[first + 1, gust] = 1.0
        C[gust, first:first + 2] = sigma[gust] * math.sqrt(t) / t**2 * np.array([1.0, math.sqrt(3) * t])
    return F, G, C


@lru_cache(maxsize=64)
def dryden_discretisation(sigma: tuple, length: tuple, airspeed: float, step: float):
    """Exact discrete Dryden filters at ``step`` s (Van Loan, IEEE TAC 23(3), 1978).

    ``expm([[-F, G G^T], [0, F^T]] h)`` gives ``Phi = E22^T`` and ``Q = Phi E12``. Returns
    ``Phi`` (5, 5), a square root of ``Q`` (5, 5), a square root of the stationary covariance
    ``P`` (``F P + P F^T + G G^T = 0``) (5, 5), and ``C`` (3, 5). ``sigma`` and ``length`` are
    tuples (hashable) as :func:`dryden_filter` takes them.
    """
    F, G, C = dryden_filter(sigma, length, airspeed)
    n = len(F)
    E = expm(np.block([[-F, G @ G.T], [np.zeros((n, n)), F.T]]) * step)
    transition = E[n:, n:].T
    process_noise = linalg.cholesky(transition @ E[:n, n:], lower=True)
    stationary = linalg.cholesky(linalg.solve_continuous_lyapunov(F, -G @ G.T), lower=True)
    return transition, process_noise, stationary, C


def dryden_gusts(sigma, length, airspeed: float, step: float, n_steps: int, rng) -> np.ndarray:
    """Gust velocities (u_g, v_g, w_g), shape (n_steps, 3), m/s, one per step of ``step`` s,
    from the stationary distribution on (module docstring); ``rng`` a numpy Generator."""
    transition, process_noise, stationary, C = dryden_discretisation(
        tuple(float(s) for s in sigma), tuple(float(L) for L in length), float(airspeed), float(step))
    xi = stationary @ rng.standard_normal(len(transition))
    increments = rng.standard_normal((n_steps, len(transition))) @ process_noise.T
    return propagate(transition, increments, xi)[:-1] @ C.T
