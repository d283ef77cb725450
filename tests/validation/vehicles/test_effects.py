"""validation.vehicles.effects and effect_vehicle: each named effect on a Bo105 does what its
docstring says, against independent constructions; model files round-trip; bad effects are
refused with one clear line; every diagnosable reference implements the EffectModel protocol."""
import re

import numpy as np
import pytest

from validation.core.errors import BadInputError
from validation.vehicles.bo105 import INPUT_NAMES, Bo105Reference
from validation.vehicles.bo105_effects import Bo105Effects, identification_manoeuvre
from validation.vehicles.bo105_flight import SENSOR_NOISE_STD
from validation.vehicles.effect_vehicle import EffectVehicle, effect_model
from validation.vehicles.effects import TARGET_KEYS, check_effects
from validation.vehicles.registry import get_vehicle

Q, P = 2, 5  # columns of q and p in the Bo105 state vector


@pytest.fixture(scope="module")
def manoeuvre():
    return identification_manoeuvre(duration=8.0)


def _states(effects, time, inputs):
    return EffectVehicle("bo105-80kt", effects).simulate_states(time, inputs)


def test_no_effect_is_the_reference(manoeuvre):
    time, inputs = manoeuvre
    assert np.array_equal(_states([], time, inputs), Bo105Reference(80).simulate_states(time, inputs))


def test_whole_sample_delay_equals_shifted_input(manoeuvre):
    time, inputs = manoeuvre
    shifted = inputs.copy()
    shifted[:, 1] = np.concatenate([np.zeros(7), inputs[:-7, 1]])
    expected = Bo105Reference(80).simulate_states(time, shifted)
    got = _states([{"effect": "time_delay", "input": "theta_1s", "value": 0.07}], time, inputs)
    np.testing.assert_allclose(got, expected, atol=1e-12)  # exact: same discrete system


def test_fractional_delay_matches_fine_grid(manoeuvre):
    """0.043 s on a 1 ms grid is a whole number of steps: the 10 ms result must agree with it
    at the common samples (exact ZOH on both grids, so only rounding differs)."""
    time, inputs = manoeuvre
    fine_time = np.arange(len(time) * 10 - 9) * 0.001
    fine_inputs = np.repeat(inputs, 10, axis=0)[:len(fine_time)]
    effect = [{"effect": "time_delay", "input": "theta_1c", "value": 0.043}]
    fine = _states(effect, fine_time, fine_inputs)[::10]
    np.testing.assert_allclose(_states(effect, time, inputs), fine, atol=1e-9)


def test_lag_matches_fine_grid(manoeuvre):
    time, inputs = manoeuvre
    fine_time = np.arange(len(time) * 10 - 9) * 0.001
    fine_inputs = np.repeat(inputs, 10, axis=0)[:len(fine_time)]
    effect = [{"effect": "input_lag", "input": "theta_1s", "value": 0.07}]
    fine = _states(effect, fine_time, fine_inputs)[::10]
    np.testing.assert_allclose(_states(effect, time, inputs), fine, atol=1e-9)


def test_lag_steady_state_gain_is_one():
    """A first-order lag delays a step but keeps its final value (DC gain 1)."""
    time = np.arange(0, 3.0, 0.01)
    inputs = np.zeros((len(time), 4))
    inputs[10:, 3] = 0.01  # pedal step; yaw rate settles in about 1 s at 80 kt
    plain = _states([], time, inputs)
    lagged = _states([{"effect": "input_lag", "input": "theta_0T", "value": 0.05}], time, inputs)
    assert abs(lagged[15, 7]) < abs(plain[15, 7])  # lags early on
    assert lagged[-1, 7] == pytest.approx(plain[-1, 7], rel=0.02)  # 0.05 s lag, 3 s horizon


def test_derivatives_and_bias(manoeuvre):
    time, inputs = manoeuvre
    effects = [{"effect": "stability_derivative", "term": "L_q", "value": -3.0},
               {"effect": "sensor_bias", "output": "q", "value": 0.01}]
    expected = Bo105Reference(80).with_derivatives({"L_q": -3.0}).simulate_states(time, inputs)
    expected[:, Q] += 0.01
    np.testing.assert_allclose(_states(effects, time, inputs), expected, atol=1e-12)


def test_noise_is_seeded_and_sized(manoeuvre):
    time, inputs = manoeuvre
    vehicle = EffectVehicle("bo105-80kt", [], noise_sd=SENSOR_NOISE_STD)
    first, again = vehicle.simulate(time, inputs, seed=3), vehicle.simulate(time, inputs, seed=3)
    assert np.array_equal(first.outputs, again.outputs)
    noise = first.outputs - _states([], time, inputs)
    # 801 samples: the sample sd is within 10 % of the true one (5 sigma is 12.5 %).
    assert np.std(noise[:, P]) == pytest.approx(SENSOR_NOISE_STD["p"], rel=0.1)
    assert first.metadata["vehicle"] == "bo105-80kt" and first.input_names == INPUT_NAMES


def test_model_file_round_trip(tmp_path, manoeuvre):
    time, inputs = manoeuvre
    vehicle = EffectVehicle("bo105-40kt", [{"effect": "input_lag", "input": "theta_0", "value": 0.1},
                                           {"effect": "control_derivative", "term": "Z_theta_0", "value": -90.0}])
    loaded = EffectVehicle.load(vehicle.save(tmp_path / "model.json"))
    assert loaded.effects == vehicle.effects
    assert np.array_equal(loaded.simulate_states(time, inputs), vehicle.simulate_states(time, inputs))


@pytest.mark.parametrize("effect, message", [
    ({"effect": "gremlin", "input": "theta_0", "value": 1}, "unknown effect"),
    ({"effect": "time_delay", "input": "stick", "value": 0.1}, "is not one of"),
    ({"effect": "stability_derivative", "term": "M_theta_1s", "value": 1}, "M_theta_1s is a control_derivative of"),
    ({"effect": "stability_derivative", "term": "M_x", "value": 1}, "is not one of"),
    ({"effect": "control_derivative", "term": "M_q", "value": 1}, "M_q is a stability_derivative of"),
    ({"effect": "search_term", "term": "N_v^3", "value": 1}, re.escape('give it as {"effect": "nonlinear_stiffness"')),
    ({"effect": "search_term", "term": "N_v|v|", "value": 1}, re.escape('give it as {"effect": "quadratic_stiffness"')),
    ({"effect": "input_lag", "input": "theta_0", "value": -0.1}, "outside"),
    ({"effect": "sensor_bias", "output": "q", "value": float("nan")}, "finite"),
])
def test_bad_effects_are_refused(effect, message):
    with pytest.raises(BadInputError, match=message):
        check_effects([effect], Bo105Effects(Bo105Reference(80)))


def test_other_references_and_bo105_effects_on_the_blimp_are_refused():
    with pytest.raises(BadInputError, match="bo105-<V>kt, blimp, rgblimp, state-space FILE.json and FILE.fmu"):
        EffectVehicle("blimp-flight", [])
    with pytest.raises(BadInputError, match="is not one of"):
        EffectVehicle("blimp", [{"effect": "stability_derivative", "term": "M_q", "value": -1.0}])
    with pytest.raises(BadInputError, match="unknown effect 'quadratic_drag'"):
        EffectVehicle("bo105-80kt", [{"effect": "quadratic_drag", "term": "X_UU", "value": -1.0}])


def test_thrust_per_unit_command_must_be_positive_on_the_blimp():
    with pytest.raises(BadInputError, match="thrust per unit command must be positive, got 0.0 N"):
        EffectVehicle("blimp", [{"effect": "control_derivative", "term": "tail_thrust_positive", "value": 0.0}])


@pytest.mark.parametrize("name", ["bo105-80kt", "bo105-40kt", "blimp", "rgblimp"])
def test_every_diagnosable_reference_keeps_the_effect_model_contract(name):
    """The EffectModel protocol, checked as diagnose and its bench use it: kinds and terms agree
    with the shared contract, term hypotheses start at the model's values inside their bounds,
    the manoeuvre excites every input (the RGBlimp's two variants differ in the thrusts and the
    gondola's x, as its flights do: they hold their inputs), and a replay without effects is the reference's own."""
    vehicle = get_vehicle(name)
    model = effect_model(name, purpose="test")
    assert (model.name, model.input_names, model.state_names) == (name, vehicle.input_names, vehicle.state_names)
    assert model.family == name.split("-")[0]  # every bo105-<V>kt shares one family
    assert set(model.kinds) <= set(TARGET_KEYS)
    assert ({"time_delay", "input_lag", "sensor_bias"} <= set(model.kinds)) == (name != "rgblimp")
    assert {kind for kind in model.kinds if TARGET_KEYS[kind] == "term"} == set(model.terms)
    for terms in model.terms.values():
        assert all(np.isfinite(model.model_value(term)) and model.term_unit(term) for term in terms)
        assert all(model.term_description(term) not in ("", term) for term in terms)  # words for every term
    assert model.term_description("no_such_term") == "no_such_term"
    hypotheses = model.term_hypotheses(model.input_names)
    assert {h.key for h in hypotheses} <= {(kind, term) for kind, terms in model.terms.items() for term in terms}
    for h in hypotheses:
        assert h.null == model.model_value(h.target) and h.lower <= h.null <= h.upper and h.step > 0, h
    assert set(model.sensor_noise_sd) == set(model.state_names) and model.sample_time == vehicle.sample_time
    time, inputs = model.identification_manoeuvre(duration=20.0, sample_time=model.sample_time, variant=1)
    assert inputs.shape == (len(time), len(model.input_names))
    if name == "rgblimp":
        other = model.identification_manoeuvre(duration=20.0, sample_time=model.sample_time, variant=0)[1]
        assert np.all(inputs[0, :3] != other[0, :3]) and np.all(np.ptp(inputs, axis=0) == 0)
    else:
        assert np.all(np.ptp(inputs, axis=0) > 0)
    replay = model.simulate_many([[], []], time, inputs)
    assert replay.shape == (2, len(time), len(model.state_names)) and np.array_equal(replay[0], replay[1])
    if model.needs_even_sampling:  # the blimp's RK4 at the recording interval: test_diagnose_blimp
        expected = vehicle.simulate_states(time, inputs)
        if name == "rgblimp":  # the replay carries heading on, the reference wraps it; the replay is
            expected[:, 5] = np.unwrap(expected[:, 5])  # compiled (rgblimp_jax): equal to rounding
            np.testing.assert_allclose(replay[0], expected, rtol=0, atol=1e-12)
        else:
            np.testing.assert_array_equal(replay[0], expected)


@pytest.mark.parametrize("name, message", [
    ("bo105-80kt-flight", "'bo105-80kt-flight' is a flight-test stand-in: use its physics reference bo105-80kt"),
    ("blimp-flight", "'blimp-flight' is a flight-test stand-in: use its physics reference blimp"),
    ("jsbsim:c172x", "named effects are not implemented for 'jsbsim:c172x' yet"),
])
def test_only_the_effect_references_take_effects(name, message):
    """One lookup and one message for every caller: what it is for, the references that take
    effects, and why this one does not."""
    needs = "^doing X needs one of the bo105-<V>kt, blimp, rgblimp, state-space FILE.json and FILE.fmu references; "
    with pytest.raises(BadInputError, match=needs) as error:
        effect_model(name, purpose="doing X")
    assert str(error.value).endswith(message)


def test_effect_models_are_found_by_registry_name():
    """Every tabulated Bo105 speed takes the Bo105 effects; an unknown name gets the registry's message."""
    assert effect_model("bo105-140kt", purpose="test").name == "bo105-140kt"
    with pytest.raises(BadInputError, match="no Bo105 model at 85 kt"):
        effect_model("bo105-85kt", purpose="test")


def test_rate_limited_means_are_the_exact_means_of_a_continuous_ramp():
    """The interval means against a ramp integrated at 1000 points per interval: a step of 1 unit
    at rate 4 ramps over 0.25 s (2.5 intervals of 0.1 s), then a reversal of 2 units over 0.5 s;
    a rate so large that no ramp lasts a microsecond changes nothing beyond 1e-5 of a step."""
    from validation.vehicles.effects import rate_limited_interval_means

    held = np.array([0.0, 1.0, 1.0, 1.0, 1.0, -1.0, -1.0, -1.0, -1.0, -1.0, -1.0, 0.0])
    steps = np.full(len(held), 0.1)
    rate = 4.0
    fine = np.empty(len(held))
    position = 0.0
    for k, command in enumerate(held):  # the actuator at 1000 sub-steps per interval
        dt = steps[k] / 1000
        values = []
        for _ in range(1000):
            start = position
            position += np.clip(command - position, -rate * dt, rate * dt)
            values.append(0.5 * (start + position))
        fine[k] = np.mean(values)
    got = rate_limited_interval_means(held, rate, steps)
    np.testing.assert_allclose(got, fine, atol=1e-9)
    assert got[1] == pytest.approx(0.2) and got[3] == pytest.approx(1.0 - 0.2 * 0.05 / (2 * 0.1))  # 0.2 left, 50 ms
    fast = rate_limited_interval_means(held, 2.0 / 1e-6, steps)
    np.testing.assert_allclose(fast, held, atol=1e-5)
    np.testing.assert_array_equal(rate_limited_interval_means(held, np.inf, steps), held)


def test_a_rate_limit_ramps_the_steps_of_every_linear_reference_and_is_refused_when_not_positive(manoeuvre):
    """On the Bo105 a rate limit is the reference flown with the rate-limited interval means
    (built independently here), and it is no delay: its ramp is twice as long on the 2 deg
    reversals of the 3-2-1-1 as on the 1 deg steps."""
    from validation.vehicles.effects import rate_limited_interval_means

    time, inputs = manoeuvre
    rate = np.radians(10.0)
    got = _states([{"effect": "rate_limit", "input": "theta_1s", "value": rate}], time, inputs)
    flown = inputs.copy()
    flown[:-1, 1] = rate_limited_interval_means(inputs[:-1, 1], rate, np.diff(time))
    np.testing.assert_allclose(got, Bo105Reference(80).simulate_states(time, flown), atol=1e-12)
    ramping = np.abs(flown[:-1, 1] - inputs[:-1, 1]) > 1e-12
    runs = np.split(np.flatnonzero(ramping), np.flatnonzero(np.diff(np.flatnonzero(ramping)) > 1) + 1)
    lengths = sorted({len(run) for run in runs})
    assert lengths[0] >= 9 and lengths[-1] >= 2 * lengths[0] - 1, lengths  # 0.1 s and 0.2 s ramps
    for bad in (0.0, -1.0):
        with pytest.raises(BadInputError, match="largest rate must be positive"):
            check_effects([{"effect": "rate_limit", "input": "theta_1s", "value": bad}],
                          Bo105Effects(Bo105Reference(80)))


def test_a_reciprocal_hypothesis_reports_the_rate_and_its_interval_in_order():
    """A rate limit is searched as the ramp time per unit (s/rad): the effect and both ends of
    its interval are reciprocals, the ends in increasing order."""
    from validation.diagnose.fitting import FittedModel
    from validation.vehicles.effects import Hypothesis

    h = Hypothesis("rate_limit", "theta_1s", 1e-4, 1e-4, 100.0, 0.5, reciprocal=True)
    assert h.as_effect(0.25) == {"effect": "rate_limit", "input": "theta_1s", "value": 4.0}
    variance = np.array([[(0.05 / 1.959963984540054) ** 2]])
    fitted = FittedModel([h], np.array([0.25]), 1.0, variance, variance)
    low, high = fitted.interval(0)
    assert low == pytest.approx(1 / 0.3) and high == pytest.approx(1 / 0.2)


def test_free_play_is_a_spring_linkage_held_by_friction_and_remembers_its_last_push():
    """Free play against a surface on a spring linkage held by Coulomb friction (breakout force
    equal to the sliding force, a negligible mass), integrated independently: the surface moves
    only while the spring's pull ``k (u - y)`` exceeds the friction ``F``, relaxing quickly toward
    ``|u - y| = F / k``; the play operator with ``w = F / k`` gives the same positions. A step
    away from trim loses ``w`` as a dead band does; back at trim free play stays ``w`` off."""
    from validation.vehicles.effects import backlash_inputs, dead_band_inputs

    held = np.array([0.0, 1.0, 1.0, -1.0, -1.0, 0.3, 0.25, 0.0, 0.0, -0.05, 0.6, 0.0])
    stiffness, friction = 50.0, 10.0  # N/unit, N: w = 0.2
    width = friction / stiffness
    position, fine = 0.0, np.empty(len(held))
    for k, command in enumerate(held):  # 2000 sub-steps per interval of a stiff relaxation
        for _ in range(2000):
            pull = stiffness * (command - position)
            excess = np.sign(pull) * max(abs(pull) - friction, 0.0)
            position += 1e-3 * excess / stiffness * 20.0
        fine[k] = position
    got = backlash_inputs(held, width)
    np.testing.assert_allclose(got, fine, atol=1e-6)
    np.testing.assert_allclose(got[:3], dead_band_inputs(held[:3], width))  # away from trim: a dead band
    # Back at trim after a push up to 0.6, free play rests w above it; a dead band returns.
    assert got[11] == pytest.approx(width) and dead_band_inputs(held, width)[11] == 0.0
    np.testing.assert_allclose(got[5:10], 0.1)  # pushed to 0.3 - w, then held still inside the play
    np.testing.assert_array_equal(backlash_inputs(held, 0.0), held)


def test_free_play_on_the_bo105_leaves_the_cyclic_off_trim_after_the_manoeuvre(manoeuvre):
    """On the Bo105 free play is the reference flown with the play operator's commands (built
    here from the definition), and it differs from a dead band of the same width only after the
    input has come back: the 3-2-1-1's last step is down, so the rotor stays w below trim."""
    time, inputs = manoeuvre
    width = np.radians(0.3)
    got = _states([{"effect": "backlash", "input": "theta_1s", "value": width}], time, inputs)
    flown, position = inputs.copy(), 0.0
    for k, command in enumerate(inputs[:, 1]):
        position = min(max(position, command - width), command + width)
        flown[k, 1] = position
    np.testing.assert_allclose(got, Bo105Reference(80).simulate_states(time, flown), atol=1e-12)
    band = _states([{"effect": "dead_band", "input": "theta_1s", "value": width}], time, inputs)
    moved = np.flatnonzero(inputs[:, 1] != 0.0)
    before_return = slice(0, moved[-1] + 1)
    np.testing.assert_allclose(got[before_return], band[before_return], atol=1e-12)
    assert flown[-1, 1] == pytest.approx(-width) and np.abs(got[-1] - band[-1]).max() > 1e-3
    with pytest.raises(BadInputError, match="half-width cannot be negative"):
        check_effects([{"effect": "backlash", "input": "theta_1s", "value": -0.01}], Bo105Effects(Bo105Reference(80)))


def test_inputs_are_shaped_in_one_order_whatever_the_order_of_the_effects():
    """Free play then a limit, about the first command, however the list orders them (listed the
    other way, a limit first would give 0.3 where free play first gives 0.5)."""
    from validation.vehicles.effects import shaped_inputs

    time = np.arange(5) * 0.1
    inputs = np.array([[0.0, 2.0], [1.0, 2.0], [1.0, 2.0], [0.0, 2.0], [0.0, 2.0]])
    effects = [{"effect": "saturation", "input": "a", "value": 0.5},
               {"effect": "backlash", "input": "a", "value": 0.2}]
    forward = shaped_inputs(effects, time, inputs, ("a", "b"), centre=inputs[0])
    np.testing.assert_array_equal(shaped_inputs(effects[::-1], time, inputs, ("a", "b"), centre=inputs[0]), forward)
    np.testing.assert_allclose(forward[:, 0], [0.0, 0.5, 0.5, 0.2, 0.2])
    np.testing.assert_array_equal(forward[:, 1], inputs[:, 1])
    assert shaped_inputs([], time, inputs, ("a", "b")) is inputs
