"""The extended Kalman filter (validation.models.state_estimation)."""
import numpy as np
import pytest

from validation.models.state_estimation import extended_kalman_filter

DT = 0.1
A = np.array([[1.0, DT], [0.0, 0.95]])  # position and velocity of a damped cart
B = np.array([0.0, DT])


def linear_step(states, inputs):
    return states @ A.T + inputs[:, :1] * B


def kalman_filter(z, u, *, q, r, x0, p0):
    """The textbook linear Kalman filter (Simon 2006, sec. 5.1), position measured."""
    x, P, out = x0.copy(), p0.copy(), []
    H = np.array([[1.0, 0.0]])
    for k in range(len(z)):
        if k:
            x, P = A @ x + B * u[k - 1, 0], A @ P @ A.T + np.diag(q)
        S = H @ P @ H.T + r
        K = P @ H.T / S
        x = x + (K * (z[k] - H @ x)).ravel()
        P = (np.eye(2) - K @ H) @ P
        out.append((x.copy(), P.copy()))
    return out


def simulated(n=200, seed=0, q=(1e-6, 1e-4), r=1e-4):
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, (n, 1))
    x = np.zeros(2)
    states = []
    for k in range(n):
        states.append(x)
        x = A @ x + B * u[k, 0] + rng.normal(0, np.sqrt(q))
    states = np.array(states)
    return states, states[:, :1] + rng.normal(0, np.sqrt(r), (n, 1)), u


def test_on_a_linear_model_it_is_the_kalman_filter():
    q, r = np.array([1e-6, 1e-4]), 1e-4
    states, z, u = simulated(q=q, r=r)
    result = extended_kalman_filter(linear_step, z, u, measured_columns=[0], measurement_variance=[r],
                                    process_variance=q, initial_mean=np.zeros(2), initial_covariance=np.eye(2))
    for k, (x, P) in enumerate(kalman_filter(z, u, q=q, r=r, x0=np.zeros(2), p0=np.eye(2))):
        # Central differences of a linear map are exact up to rounding; Joseph and standard
        # covariance forms agree to rounding.
        np.testing.assert_allclose(result.mean[k], x, atol=1e-9)
        np.testing.assert_allclose(result.covariance[k], P, atol=1e-9)


def test_the_unmeasured_velocity_is_estimated_within_its_reported_spread():
    q, r = np.array([1e-6, 1e-4]), 1e-4
    states, z, u = simulated(n=2000, seed=3, q=q, r=r)
    result = extended_kalman_filter(linear_step, z, u, measured_columns=[0], measurement_variance=[r],
                                    process_variance=q, initial_mean=np.zeros(2), initial_covariance=np.eye(2))
    error = (result.mean - states)[100:, 1]
    sd = np.sqrt(result.covariance[100:, 1, 1])
    # A consistent filter's normalised errors have unit variance (2000 correlated samples: ~10 %).
    assert np.mean((error / sd) ** 2) == pytest.approx(1.0, rel=0.2)
    assert np.std(error) < 0.5 * np.std(np.diff(z[:, 0]) / 0.1)  # far better than differencing


def test_causal_the_estimate_at_k_ignores_later_measurements():
    states, z, u = simulated(n=60)
    kwargs = {"measured_columns": [0], "measurement_variance": [1e-4], "process_variance": [1e-6, 1e-4],
                  "initial_mean": np.zeros(2), "initial_covariance": np.eye(2)}
    full = extended_kalman_filter(linear_step, z, u, **kwargs)
    changed = z.copy()
    changed[40:] += 5.0
    partial = extended_kalman_filter(linear_step, changed, u, **kwargs)
    np.testing.assert_array_equal(full.mean[:40], partial.mean[:40])
