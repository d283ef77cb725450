"""Dryden turbulence (validation.vehicles.turbulence) and gusts in the linear replay."""
import math

import numpy as np
import pytest

from validation.core.manoeuvres import time_grid
from validation.vehicles.bo105 import Bo105Reference
from validation.vehicles.linear_discretisation import zero_order_hold
from validation.vehicles.linear_effects import simulate_linear_with_effects
from validation.vehicles.turbulence import dryden_gusts, low_altitude_turbulence


def test_low_altitude_intensities_are_the_specifications():
    """MIL-F-8785C, low altitude, at 500 ft, worked by hand: 0.177 + 0.000823 * 500 = 0.5885,
    0.5885^0.4 = 0.8089, 0.5885^1.2 = 0.5293; W_20 = 30 kt = 15.433 m/s for moderate."""
    sigma, length = low_altitude_turbulence("moderate", altitude_m=152.4)
    assert sigma[2] == pytest.approx(1.5433, rel=1e-4)  # 0.1 W_20
    assert sigma[0] == sigma[1] == pytest.approx(1.5433 / 0.8089, rel=1e-4)  # 1.908 m/s
    assert length[2] == pytest.approx(152.4)  # L_w = h
    assert length[0] == length[1] == pytest.approx(500 / 0.5293 * 0.3048, rel=1e-4)  # 287.9 m
    light, _ = low_altitude_turbulence("light", altitude_m=152.4)
    np.testing.assert_allclose(light, np.array(sigma) / 2)  # W_20 = 15 kt
    with pytest.raises(ValueError, match="low-altitude"):
        low_altitude_turbulence("light", altitude_m=400.0)
    with pytest.raises(ValueError, match="intensity"):
        low_altitude_turbulence("gale", altitude_m=100.0)


def test_gusts_have_the_dryden_spread_and_correlation():
    """Against the Dryden autocorrelations, the inverse Fourier transforms of the MIL-F-8785C
    spectra (sec. 3.7.2): ``R_u(tau) = sigma^2 exp(-tau / T)`` and ``R_w(tau) = sigma^2 (1 -
    tau / (2T)) exp(-tau / T)``, on one record of 20 000 s (about 5000 time constants of w:
    sample variance and autocorrelation scatter by ~2-3 %)."""
    sigma, length, speed, step = (1.9, 1.9, 1.5), (288.0, 288.0, 152.4), 41.2, 0.05
    gusts = dryden_gusts(sigma, length, speed, step, 400_000, np.random.default_rng(3))
    np.testing.assert_allclose(gusts.std(axis=0), sigma, rtol=0.08)
    for column, shape in ((0, lambda r: math.exp(-r)), (2, lambda r: (1 - r / 2) * math.exp(-r))):
        T = length[column] / speed
        for ratio in (0.5, 1.0, 2.0):
            lag = round(ratio * T / step)
            x = gusts[:, column]
            correlation = np.mean(x[lag:] * x[:-lag]) / np.mean(x * x)
            assert correlation == pytest.approx(shape(lag * step / T), abs=0.06)
    # Stationary from the first sample: the first gusts of many records have the full spread.
    starts = np.array([dryden_gusts(sigma, length, speed, step, 1, np.random.default_rng(s))[0] for s in range(2000)])
    np.testing.assert_allclose(starts.std(axis=0), sigma, rtol=0.08)


def test_gusts_enter_the_linear_replay_on_the_air_relative_velocity():
    """One interval from trim with a gust held over it: ``x[1] = Gamma g`` with ``Gamma`` the
    exact zero-order hold of ``(A, -A[:, (u, v, w)])``, for any effects on the inputs (a delay
    and a lag leave it), and a changed derivative changes ``A`` there too."""
    reference = Bo105Reference(80)
    time = time_grid(duration=0.01, sample_time=0.01)
    gusts = np.array([[0.5, -0.3, 0.8], [0.0, 0.0, 0.0]])
    columns = [reference.state_names.index(n) for n in ("u", "v", "w")]
    inputs = np.zeros((2, 4))
    for effects, model in (([], reference),
                           ([{"effect": "time_delay", "input": "theta_1s", "value": 0.06},
                             {"effect": "input_lag", "input": "theta_0", "value": 0.1}], reference),
                           ([{"effect": "stability_derivative", "term": "Z_w", "value": -1.2}],
                            reference.with_derivatives({"Z_w": -1.2}))):
        states = simulate_linear_with_effects(reference, effects, time, inputs, gusts=gusts)
        Gamma = zero_order_hold(model.A, -model.A[:, columns], 0.01)[1]
        np.testing.assert_allclose(states[1], Gamma @ gusts[0], rtol=1e-9, atol=1e-15)
    with pytest.raises(ValueError, match="gusts"):
        simulate_linear_with_effects(reference, [], time, inputs, gusts=gusts[:, :2])
