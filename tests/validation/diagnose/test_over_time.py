"""Whether a finding holds over the flights (validation.diagnose.over_time)."""
import numpy as np
import pytest

from validation.diagnose.bench import _drifting_derivative_states
from validation.diagnose.fitting import FitData, FittedModel, akaike_weights
from validation.diagnose.over_time import WINDOWS, time_check, window_masks
from validation.vehicles.bo105 import STATE_NAMES, Bo105Reference
from validation.vehicles.bo105_effects import identification_manoeuvre
from validation.vehicles.effects import Hypothesis

M_Q = Hypothesis("stability_derivative", "M_q", -1.0, -np.inf, np.inf, 0.1)


def _windows(values, sds):
    """FittedModels of one effect (M_q) with these window values and standard deviations."""
    return [None if v is None else FittedModel([M_Q], np.array([v]), 0.0, np.array([[s**2]]), np.array([[s**2]]))
            for v, s in zip(values, sds)]


def _model(value=-1.0):
    return FittedModel([M_Q], np.array([value]), 0.0, np.eye(1) * 1e-4, np.eye(1) * 1e-4)


def test_windows_cut_each_recordings_fitted_span_into_consecutive_parts():
    time = [np.arange(0, 10, 0.5), np.arange(0, 4, 0.5)]
    fit_mask = [time[0] < 7.0, np.ones(8, bool)]  # the first recording's tail is held out
    data = FitData(time=time, inputs=[], measured=[], output_names=("q",), noise_sd=[], fit_mask=fit_mask,
                   starts=[None, None])
    masks = window_masks(data)
    assert len(masks) == WINDOWS
    for r in range(2):
        parts = np.stack([masks[w][r] for w in range(WINDOWS)])
        np.testing.assert_array_equal(parts.sum(axis=0), fit_mask[r])  # disjoint, and every fitted sample
        first = [time[r][part].min() for part in parts]
        assert first == sorted(first) and all(part.sum() >= 2 for part in parts)
    assert time[0][masks[-1][0]].max() == 6.5  # the held-out tail is in no window


def test_a_steady_value_is_not_called_changing():
    check = time_check(_model(), 0, _windows([-1.00, -1.02, -0.99], [0.02] * 3))
    assert not check["changes"] and not check["drifts"] and check["p_value"] > 0.1
    assert check["values"] == [-1.00, -1.02, -0.99]
    assert check["weights"]["constant"] == max(check["weights"].values())


def test_a_value_moving_steadily_is_a_drift_with_its_line():
    # Windows centred at 1/6, 1/2, 5/6 of the flight: the line -0.9 - 0.6 tau.
    check = time_check(_model(), 0, _windows([-1.0, -1.2, -1.4], [0.01] * 3))
    assert check["changes"] and check["drifts"] and check["p_value"] < 1e-6
    assert check["drift_start"] == pytest.approx(-0.9) and check["drift_end"] == pytest.approx(-1.5)
    assert check["weight_constant"] < 1e-6  # the cap on the finding's confidence
    # A value that comes and goes is a change but no drift.
    back = time_check(_model(), 0, _windows([-1.0, -1.4, -1.0], [0.01] * 3))
    assert back["changes"] and not back["drifts"]
    # Wide windows cannot tell: the same values with standard deviations of 0.3.
    assert not time_check(_model(), 0, _windows([-1.0, -1.2, -1.4], [0.3] * 3))["changes"]


def test_windows_that_cannot_fit_the_value_leave_it_untold():
    assert time_check(_model(), 0, _windows([-1.0, None, -1.4], [0.01] * 3)) is None
    assert time_check(_model(), 0, _windows([-1.0, -1.2, -1.4], [0.01, 0.0, 0.01])) is None  # pinv's null


def test_the_drifting_flight_follows_an_independent_integration():
    """RK4 at the recording interval with M_q moving linearly in time, against scipy's RK45 at
    rtol 1e-10 over each held interval; with nothing drifting, the exact linear replay."""
    from scipy.integrate import solve_ivp

    time, inputs = identification_manoeuvre(duration=3.0, sample_time=0.01)
    reference = Bo105Reference(80)
    q = STATE_NAMES.index("q")
    m_q = float(reference.A[q, q])
    exact = reference.simulate_states(time, inputs)
    steady = _drifting_derivative_states("bo105-80kt", "M_q", m_q, m_q, time, inputs)
    assert np.all(np.abs(steady - exact).max(axis=0) <= 1e-4 * np.abs(exact).max(axis=0))
    drifting = _drifting_derivative_states("bo105-80kt", "M_q", m_q, 0.4 * m_q, time, inputs)
    B = reference.B

    def derivative(t, x, u):
        A = reference.A.copy()
        A[q, q] = m_q + (0.4 * m_q - m_q) * (t - time[0]) / (time[-1] - time[0])
        return A @ x + B @ u

    state, independent = np.zeros(len(STATE_NAMES)), [np.zeros(len(STATE_NAMES))]
    for k in range(len(time) - 1):
        state = solve_ivp(derivative, (time[k], time[k + 1]), state, args=(inputs[k],), rtol=1e-10,
                          atol=1e-12).y[:, -1]
        independent.append(state)
    independent = np.array(independent)
    scale = np.abs(independent).max(axis=0)
    # RK4's own error at 100 Hz (measured up to 1.1e-6 of a state's excursion, on r).
    assert np.all(np.abs(drifting - independent).max(axis=0) <= 1e-5 * scale)
    assert np.abs(drifting[:, q] - exact[:, q]).max() > 0.05 * scale[q]  # and the drift moves it


def test_the_statement_of_a_changing_finding_gives_its_parts_and_its_drift():
    from validation.diagnose.report import statement
    from validation.vehicles.effect_vehicle import effect_model

    reference = effect_model("bo105-80kt", purpose="test")
    check = time_check(_model(), 0, _windows([-3.6, -3.2, -2.8], [0.01] * 3))
    finding = {"effect": "stability_derivative", "term": "M_q", "value": -3.2, "model_value": -4.0,
               "interval": [-3.21, -3.19], "unit": "1/s", "main_output": "q", "alternatives": [], "time_check": check}
    text = statement(finding, {"rmse_reference": {}}, reference)
    assert ("But it changes during the flights: fitted on each of 3 consecutive parts of the diagnosed flights it is "
            "-3.6, -3.2, -2.8 1/s") in text
    assert "M_q shrinks from -3.8 to -2.6 1/s over the flights" in text
    steady = {**finding, "time_check": time_check(_model(), 0, _windows([-3.2, -3.21, -3.19], [0.01] * 3))}
    assert "changes during" not in statement(steady, {"rmse_reference": {}}, reference)


def test_akaike_weights_sum_to_one_favour_the_smaller_criterion_and_do_not_overflow():
    # Two models two AIC units apart: weights 1 / (1 + e^-1) and e^-1 / (1 + e^-1).
    assert np.allclose(akaike_weights([10.0, 12.0]), [1 / (1 + np.exp(-1)), np.exp(-1) / (1 + np.exp(-1))])
    weights = akaike_weights([3.0, 1.0, 2.0])
    assert weights.sum() == pytest.approx(1.0) and np.argmax(weights) == 1
    assert np.array_equal(akaike_weights([1e6, 0.0]), [0.0, 1.0])  # criteria far apart: no inf or NaN
