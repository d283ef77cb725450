"""flightgp diagnose on the blimp: its named effects do what validation.blimp_effects says
(against the reference ODE with changed parameters), concealed effects are named with their
values, and blimp recordings with bad columns exit 2."""
import dataclasses
import json

import numpy as np
import pytest
from test_diagnose import _check_named, _write_table  # shared with the Bo105 tests

from validation.blimp import BlimpParameters, BlimpReference
from validation.blimp_effects import SAMPLE_TIME, SENSOR_NOISE_STD, identification_manoeuvre
from validation.cli import main
from validation.diagnose import diagnose
from validation.diagnose_bench import concealed_cases
from validation.effects import EffectVehicle
from validation.recordings import write_recording

DEFAULT = BlimpParameters()


@pytest.fixture(scope="module")
def manoeuvre():
    return identification_manoeuvre(duration=12.0)


def _states(effects, time, inputs):
    return EffectVehicle("blimp", effects).simulate_states(time, inputs)


def _reference(time, inputs, **changes):
    """The reference ODE with changed parameters, RK4 at the recording interval (as the effects)."""
    params = dataclasses.replace(DEFAULT, **changes)
    return BlimpReference(params=params, max_step=SAMPLE_TIME).simulate_states(time, inputs)


def test_no_effect_is_the_reference_at_the_recording_interval(manoeuvre):
    time, inputs = manoeuvre
    np.testing.assert_allclose(_states([], time, inputs), _reference(time, inputs), rtol=0, atol=1e-12)


@pytest.mark.parametrize("effect, changes", [
    ({"effect": "quadratic_drag", "term": "X_UU", "value": -0.2},
     {"quadratic_drag": (0.2, *DEFAULT.quadratic_drag[1:])}),
    ({"effect": "stability_derivative", "term": "N_R", "value": -0.03},
     {"rotational_damping": (*DEFAULT.rotational_damping[:2], 0.03)}),
    ({"effect": "force_offset", "term": "Z_0", "value": 0.004}, {"net_lift": -0.004}),
    ({"effect": "control_derivative", "term": "gondola_thrust_backward", "value": 0.05},
     {"gondola_thrust_backward": 0.05}),
    ({"effect": "control_derivative", "term": "tail_thrust_negative", "value": 0.02},
     {"tail_thrust_negative": 0.02}),
])
def test_term_effects_equal_the_changed_parameter(manoeuvre, effect, changes):
    """Each term is the BlimpParameters entry it documents (same ODE, same RK4: rounding only)."""
    time, inputs = manoeuvre
    expected = _reference(time, inputs, **changes)
    got = _states([effect], time, inputs)
    assert np.abs(expected - _states([], time, inputs)).max() > 1e-3  # the change is visible
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10)


def test_whole_sample_delay_equals_shifted_input_and_small_lags_vanish(manoeuvre):
    time, inputs = manoeuvre
    shifted = inputs.copy()
    shifted[:, 2] = np.concatenate([np.zeros(3), inputs[:-3, 2]])
    expected = _states([], time, shifted)
    delayed = _states([{"effect": "time_delay", "input": "u_tail", "value": 3 * SAMPLE_TIME}], time, inputs)
    np.testing.assert_allclose(delayed, expected, rtol=0, atol=1e-12)
    # A lag is continuous at T = 0: interval means differ from the input by O(T/h) of each
    # command step (2e-5 here), so states by about as much times the step's effect.
    plain, tiny = _states([], time, inputs), _states([{"effect": "input_lag", "input": "u_gondola",
                                                        "value": 1e-6}], time, inputs)
    np.testing.assert_allclose(tiny, plain, rtol=0, atol=1e-5)


def test_lag_keeps_the_final_value():
    time = np.arange(0, 30.0, SAMPLE_TIME)
    inputs = np.zeros((len(time), 3))
    inputs[20:, 0] = 0.5  # gondola step; surge speed settles against quadratic drag in ~15 s
    plain = _states([], time, inputs)
    lagged = _states([{"effect": "input_lag", "input": "u_gondola", "value": 0.3}], time, inputs)
    assert lagged[30, 6] < plain[30, 6]
    assert lagged[-1, 6] == pytest.approx(plain[-1, 6], rel=0.01)


def test_blimp_model_file_round_trip(tmp_path, manoeuvre):
    time, inputs = manoeuvre
    vehicle = EffectVehicle("blimp", [{"effect": "force_offset", "term": "N_0", "value": 0.001},
                                      {"effect": "input_lag", "input": "mu", "value": 0.2}])
    loaded = EffectVehicle.load(vehicle.save(tmp_path / "model.json"))
    assert loaded.effects == vehicle.effects
    np.testing.assert_array_equal(loaded.simulate_states(time, inputs), vehicle.simulate_states(time, inputs))


def _concealed(effects):
    vehicle = EffectVehicle("blimp", effects, noise_sd=SENSOR_NOISE_STD)
    fit = vehicle.simulate(*identification_manoeuvre(variant=0), seed=1)
    held = vehicle.simulate(*identification_manoeuvre(variant=1), seed=2)
    return fit, held


def test_no_effect_on_the_blimp_is_consistent():
    fit, held = _concealed([])
    result = diagnose([fit], reference="blimp", holdout=[held]).as_dict()
    assert result["verdict"] == "consistent" and result["findings"] == []
    for name in result["fit"]["outputs"]:  # held-out error is the sensor noise (20 % margin)
        assert result["fit"]["rmse_reference"][name] < 1.2 * SENSOR_NOISE_STD[name]


BLIMP_CASES = {
    "quadratic_drag": [{"effect": "quadratic_drag", "term": "X_UU", "value": 1.5 * -DEFAULT.quadratic_drag[0]}],
    "buoyancy": [{"effect": "force_offset", "term": "Z_0", "value": 0.003}],
    "tail_lag": [{"effect": "input_lag", "input": "u_tail", "value": 0.3}],
}


@pytest.mark.slow
@pytest.mark.parametrize("case", BLIMP_CASES)
def test_concealed_blimp_effect_is_named_with_its_value(case):
    fit, held = _concealed(BLIMP_CASES[case])
    _check_named(diagnose([fit], reference="blimp", holdout=[held]).as_dict(), BLIMP_CASES[case])


@pytest.mark.slow
def test_cli_names_a_gondola_delay_and_writes_a_loadable_blimp_model(tmp_path, capsys):
    truth = [{"effect": "time_delay", "input": "u_gondola", "value": 0.15}]
    fit, held = _concealed(truth)
    write_recording(tmp_path / "fit.csv", fit)
    write_recording(tmp_path / "held.csv", held)
    out = tmp_path / "out"
    assert main(["diagnose", str(tmp_path / "fit.csv"), "--holdout", str(tmp_path / "held.csv"),
                 "--reference", "blimp", "--out", str(out), "--no-progress"]) == 0
    result = json.loads((out / "diagnosis.json").read_text())
    _check_named(result, truth)
    corrected = EffectVehicle.load(out / "corrected_model.json")
    assert corrected.reference_name == "blimp" and corrected.effects[0]["input"] == "u_gondola"
    assert (out / "holdout_x.png").read_bytes()[:4] == b"\x89PNG"
    assert "gondola thrust command" in capsys.readouterr().out


@pytest.mark.parametrize("problem, expected", [
    ("missing_input", "missing input column(s) 'u_tail'"),
    ("bo105_columns", "another vehicle"),
])
def test_bad_blimp_recordings_exit_2_with_one_line(tmp_path, capsys, problem, expected):
    time = np.arange(0, 4.0, SAMPLE_TIME)
    if problem == "missing_input":
        header = ["time", "u_gondola", "mu", "x", "U"]
        rows = [[t, 0.5 * (t > 1), 0.0, 0.0, 0.0] for t in time]
    else:
        header = ["time", "theta_0", "theta_1s", "theta_1c", "theta_0T", "q"]
        rows = [[t, 0.0, 0.01 * (t > 0.5), 0.0, 0.0, 0.0] for t in time]
    path = _write_table(tmp_path / "bad.csv", header, rows)
    out = tmp_path / "out"
    assert main(["diagnose", str(path), "--reference", "blimp", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert expected in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_blimp_bench_suite_covers_every_blimp_effect_kind():
    cases = concealed_cases("blimp")
    kinds = {effect["effect"] for case in cases for effect in case.effects}
    assert kinds == {"time_delay", "input_lag", "control_derivative", "stability_derivative",
                     "quadratic_drag", "force_offset", "sensor_bias"}
    assert {case.kind for case in cases} == {"single", "pair", "none"}
    assert len({case.name for case in cases}) == len(cases)
