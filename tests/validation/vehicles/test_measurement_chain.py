"""validation.vehicles.effects.apply_measurement_chain: each sensor effect replays against an
independent computation (scipy's lsim for the lag), the linear and the blimp references apply it
alike, check_effects refuses what no sensor does, and diagnose names a sensor lag on q as a sensor
lag, not as an input effect, and says where the data cannot tell the two apart."""
import numpy as np
import pytest
from scipy import signal

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.diagnose.data import prepare
from validation.diagnose.explain import _excursions, hypotheses_for, select_effects
from validation.diagnose.fitting import fit_many, null_model, weigh_step
from validation.diagnose.report import statement
from validation.vehicles.blimp import BlimpReference
from validation.vehicles.blimp_effects import STATE_NAMES as BLIMP_STATES
from validation.vehicles.blimp_effects import simulate_batch
from validation.vehicles.bo105_effects import identification_manoeuvre
from validation.vehicles.bo105_flight import SENSOR_NOISE_STD
from validation.vehicles.effect_vehicle import EffectVehicle, effect_model
from validation.vehicles.effects import (
    Hypothesis,
    apply_measurement_chain,
    check_effects,
    lagged_samples,
    true_first_values,
)

STATES = ("u", "w", "q", "theta", "v", "p", "phi", "r")
Q, P, THETA = STATES.index("q"), STATES.index("p"), STATES.index("theta")


@pytest.fixture(scope="module")
def bo105():
    """The Bo105's effect model and its replay without effects over the pitch 3-2-1-1 (5 s)."""
    model = effect_model("bo105-80kt", purpose="test")
    time, inputs = identification_manoeuvre(duration=5.0)
    inputs[:, 2] = 0.1 * np.sin(2.0 * time)  # some lateral cyclic, so that p moves
    return model, time, inputs, model.simulate_many([[]], time, inputs)[0]


def _lsim_lag(values, time_constant, time, *, fine=20):
    """Independent: scipy's lsim of T z' = -z + x on a grid ``fine`` times finer, ``x`` linear
    between the samples, starting at rest on ``x[0]``, read back at the samples."""
    grid = np.linspace(time[0], time[-1], fine * (len(time) - 1) + 1)
    lag = signal.StateSpace([[-1.0 / time_constant]], [[1.0 / time_constant]], [[1.0]], [[0.0]])
    _, out, _ = signal.lsim(lag, np.interp(grid, time, values), grid, X0=[values[0]], interp=True)
    return out[::fine]


@pytest.mark.parametrize("effect", [
    {"effect": "output_scale", "output": "q", "value": 1.08},
    {"effect": "sensor_cross_axis", "output": "q_from_p", "value": 0.05},
    {"effect": "sensor_lag", "output": "q", "value": 0.05},
    {"effect": "sensor_bias", "output": "q", "value": 0.01},
    {"effect": "sensor_drift", "output": "q", "value": 2e-3},
])
def test_each_sensor_effect_on_a_linear_replay_matches_an_independent_computation(bo105, effect):
    """Only the named output moves, by what the effect's definition says; the lag against lsim
    of the replay taken linear between samples (the chain's assumption), to 1e-6 of the output."""
    model, time, inputs, plain = bo105
    replay = model.simulate_many([check_effects([effect], model)], time, inputs)[0]
    q, p = plain[:, Q], plain[:, P]
    expected = {"output_scale": 1.08 * q, "sensor_cross_axis": q + 0.05 * p, "sensor_bias": q + 0.01,
                "sensor_drift": q + 2e-3 * (time - time[0])}.get(effect["effect"])
    if expected is None:
        expected = _lsim_lag(q, 0.05, time)
    assert np.abs(replay[:, Q] - expected).max() < 1e-6 * np.abs(q).max()
    others = [i for i in range(len(STATES)) if i != Q]
    assert np.array_equal(replay[:, others], plain[:, others])  # a sensor effect touches its own output only


def test_the_chain_applies_scale_and_cross_axis_then_lag_then_bias_and_drift_on_uneven_samples():
    """The order of the docstring, on unevenly sampled outputs (the lag's per-interval recursion):
    lsim of (s y + c x) on a fine grid, then the bias and the drift from the first sample."""
    rng = np.random.default_rng(0)
    time = np.sort(np.concatenate([[0.0, 3.0], rng.uniform(0.0, 3.0, 100)]))
    outputs = np.column_stack([np.sin(2.0 * time), np.cos(3.0 * time)])
    effects = [{"effect": "sensor_drift", "output": "a", "value": 0.3},
               {"effect": "sensor_bias", "output": "a", "value": -0.2},
               {"effect": "sensor_lag", "output": "a", "value": 0.2},
               {"effect": "sensor_cross_axis", "output": "a_from_b", "value": 0.1},
               {"effect": "output_scale", "output": "a", "value": 0.9}]
    recorded = apply_measurement_chain(outputs, time, effects, ("a", "b"))
    mixed = 0.9 * outputs[:, 0] + 0.1 * outputs[:, 1]
    grid = np.linspace(0.0, 3.0, 30001)
    lag = signal.StateSpace([[-5.0]], [[5.0]], [[1.0]], [[0.0]])
    _, fine, _ = signal.lsim(lag, np.interp(grid, time, mixed), grid, X0=[mixed[0]], interp=True)
    expected = np.interp(time, grid, fine) - 0.2 + 0.3 * time
    np.testing.assert_allclose(recorded[:, 0], expected, rtol=0, atol=1e-6)
    assert np.array_equal(recorded[:, 1], outputs[:, 1])
    assert np.abs(lagged_samples(mixed, 1e-9, time) - mixed).max() < 1e-6  # continuous at T = 0
    # The first sample inverted: what the vehicle's outputs were, from the recorded ones.
    first = true_first_values(recorded[0], effects, ("a", "b"))
    np.testing.assert_allclose(first, outputs[0], rtol=0, atol=1e-12)


def test_the_blimp_applies_the_same_chain_as_the_linear_references():
    """The blimp's batched replay through the shared chain: a lag on Q and a cross-axis term from
    P equal the chain applied to its plain replay, on uneven samples (numpy RK4, 2 s)."""
    time = np.sort(np.concatenate([[0.0, 2.0], np.random.default_rng(1).uniform(0.0, 2.0, 38)]))
    inputs = np.zeros((len(time), 3))
    inputs[time > 0.3, 2] = 0.8  # the tail fan yaws it
    inputs[time > 0.5, 0] = 0.5
    reference = BlimpReference()
    effects = check_effects([{"effect": "sensor_lag", "output": "R", "value": 0.3},
                             {"effect": "sensor_cross_axis", "output": "R_from_Q", "value": 0.1}],
                            effect_model("blimp", purpose="test"))
    plain, chained = simulate_batch(reference, [[], effects], time, inputs, compiled=False)
    assert np.ptp(plain[:, BLIMP_STATES.index("R")]) > 0
    np.testing.assert_array_equal(chained, apply_measurement_chain(plain, time, effects, BLIMP_STATES))


@pytest.mark.parametrize("effect, message", [
    ({"effect": "sensor_lag", "output": "zz", "value": 0.1}, "output 'zz' is not one of"),
    ({"effect": "sensor_lag", "output": "q", "value": -0.05}, "outside 0 .. 2.0 s"),
    ({"effect": "sensor_drift", "output": "q", "value": float("inf")}, "finite"),
    ({"effect": "sensor_cross_axis", "output": "q_from_u", "value": 0.1},
     r"the recorded q \(rad/s\) can only see another state of the same unit, not u \(m/s\)"),
    ({"effect": "sensor_cross_axis", "output": "q_from_q", "value": 0.1}, "another state"),
    ({"effect": "sensor_cross_axis", "output": "q", "value": 0.1}, 'as "q_from_p"'),
])
def test_sensor_effects_no_sensor_has_are_refused(bo105, effect, message):
    with pytest.raises(BadInputError, match=message):
        check_effects([effect], bo105[0])


@pytest.fixture(scope="module")
def concealed_sensor_lag():
    """4.5 s of the pitch 3-2-1-1 with a 100 ms lag of the q sensor, every state recorded with the
    flight-test noise, prepared for diagnose."""
    model = effect_model("bo105-80kt", purpose="diagnose")
    vehicle = EffectVehicle("bo105-80kt", [{"effect": "sensor_lag", "output": "q", "value": 0.1}],
                            noise_sd=SENSOR_NOISE_STD)
    recording = vehicle.simulate(*identification_manoeuvre(duration=4.5), seed=3)
    return model, recording


def _select(model, recording):
    data = prepare([recording], model)
    hypotheses = hypotheses_for(model, excited_inputs=data.excited, output_names=data.output_names,
                                noise_sd=data.typical_noise_sd, excursions=_excursions(data))
    return select_effects(data, model, hypotheses)


def test_a_concealed_sensor_lag_is_named_on_its_output_not_on_the_input(concealed_sensor_lag):
    """With the attitude and the velocities recorded beside q, which an input lag would slow too,
    the lag of the q sensor is named first and alone, with confidence, the truth in its interval."""
    model, recording = concealed_sensor_lag
    selection = _select(model, recording)
    first = selection.steps[0]
    assert first["key"] == ("sensor_lag", "q") and first["confidence"] > 0.9, first
    low, high = selection.model.interval(0)
    assert low <= 0.1 <= high
    assert not any(h.effect == "input_lag" for h in selection.model.hypotheses)


def test_a_sensor_lag_and_an_input_lag_on_the_only_recorded_output_cannot_be_told_apart(concealed_sensor_lag):
    """Recording q alone, a lag of its sensor and a lag on the input that drives it give the same
    recording (a linear response: the filters commute). Fitted and weighed as a step of the
    search weighs its competitors, neither has an Akaike weight above 0.5 and the other is the
    alternative; the statement says why and which recording would tell them apart."""
    model, recording = concealed_sensor_lag
    alone = Recording(recording.time, recording.inputs, recording.input_names,
                      recording.outputs[:, [Q]], ("q",), dict(recording.metadata))
    data = prepare([alone], model)
    null = null_model(data, model)
    competitors = [Hypothesis("sensor_lag", "q", 0.0, 0.0, 2.0, 0.01),
                   Hypothesis("input_lag", "theta_1s", 0.0, 0.0, 2.0, 0.01)]
    fits = fit_many(data, model, [([h], [0.05]) for h in competitors])
    _, step, _ = weigh_step(data, null, fits, n_tested=len(competitors))
    assert step is not None and step["confidence"] < 0.55, step
    kind, target = step["key"]
    alternative = step["alternatives"][0]
    assert {kind, alternative["effect"]} == {"sensor_lag", "input_lag"}
    assert all(abs(f.values[0] - 0.1) < 0.02 for f in fits), [f.values for f in fits]
    finding = {"effect": kind, {"sensor_lag": "output", "input_lag": "input"}[kind]: target, "value": 0.1,
               "unit": "s", "interval": [0.09, 0.11], "alternatives": [alternative], "main_output": "q"}
    words = statement(finding, {"rmse_reference": {}}, model)
    assert "These data cannot tell a lag of the q sensor from a lag on theta_1s" in words
