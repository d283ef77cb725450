"""State-space references (validation/vehicles/state_space.py, linear_effects.py): the JSON format
round trip, its one-line errors, diagnose through a JSON file naming what it names through the
built-in Bo105, a user's own small model diagnosed, and the corrected model carrying its
reference."""
import json

import numpy as np
import pytest

from tests.validation.diagnose.test_diagnose import CASE_STEP, CASES, _concealed
from validation.cli import main
from validation.core.errors import BadInputError
from validation.core.recordings import Recording, write_recording
from validation.diagnose import diagnose
from validation.diagnose.data import prepare
from validation.vehicles.bo105 import Bo105Reference
from validation.vehicles.effect_vehicle import EffectVehicle, effect_model
from validation.vehicles.linear_effects import LinearEffects
from validation.vehicles.registry import get_vehicle
from validation.vehicles.state_space import read_state_space, state_space_from_dict

#: A user's short-period model (heave velocity and pitch rate, one elevator): made-up but
#: stable numbers of a light aircraft's order (Z_w -2 1/s, M_q -3 1/s).
SHORT_PERIOD = {"name": "short-period", "states": ["w", "q"], "inputs": ["elevator"],
                "A": [[-2.0, 50.0], [-0.2, -3.0]], "B": [[-5.0], [-20.0]],
                "derivative_rows": {"w": "Z", "q": "M"}, "units": {"w": "m/s", "q": "rad/s", "elevator": "1"}}


@pytest.fixture(scope="module")
def bo105_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("state_space") / "bo105_80kt.json"
    assert main(["state-space", "bo105-80kt", "--out", str(path)]) == 0
    return path


def test_the_bo105_written_and_read_back_is_the_same_model(bo105_file):
    bo105, model = Bo105Reference(80), read_state_space(bo105_file)
    np.testing.assert_array_equal(model.A, bo105.A)
    np.testing.assert_array_equal(model.B, bo105.B)
    assert (model.state_names, model.input_names, model.row_letters) == (bo105.state_names, bo105.input_names,
                                                                         bo105.row_letters)
    assert model.derivative("M_theta_1s") == bo105.derivative("M_theta_1s")
    time = np.arange(300) * 0.01
    inputs = np.zeros((300, 4))
    inputs[50:100, 1] = 0.01
    np.testing.assert_array_equal(model.simulate_states(time, inputs), bo105.simulate_states(time, inputs))
    assert get_vehicle(str(bo105_file)).name == "bo105-80kt"


@pytest.mark.slow
@pytest.mark.parametrize("case", ["delay"])
def test_diagnose_through_the_json_file_names_what_the_built_in_bo105_names(bo105_file, case):
    # 10 s flights at the concealed cases' 33 Hz (the 40 ms delay between samples): the delay is
    # still named, and the file's reference replays what the built-in one replays.
    fit, held = _concealed(CASES[case], duration=10.0, sample_time=CASE_STEP)
    built_in = diagnose([fit], reference="bo105-80kt", holdout=[held]).as_dict()["findings"]
    through_file = diagnose([fit], reference=str(bo105_file), holdout=[held]).as_dict()["findings"]
    assert built_in and built_in[0]["effect"] == "time_delay"
    assert [(f["effect"], f["value"], f["interval"]) for f in through_file] == \
        [(f["effect"], f["value"], f["interval"]) for f in built_in]


def test_a_users_own_model_is_diagnosed_and_its_corrected_model_carries_it(tmp_path):
    model_file = tmp_path / "short_period.json"
    model_file.write_text(json.dumps(SHORT_PERIOD))
    truth = {"effect": "stability_derivative", "term": "M_q", "value": -2.0}
    concealed = EffectVehicle(str(model_file), [truth], noise_sd={"w": 0.01, "q": 0.001})
    reference = get_vehicle(str(model_file))
    fit = _with_other_columns(concealed.simulate(*_manoeuvre(reference, 0), seed=1))
    held = concealed.simulate(*_manoeuvre(reference, 1), seed=2)
    diagnosis = diagnose([fit], reference=str(model_file), holdout=[held])
    # The recording of the whole aircraft: the model's columns used, the others named and left out.
    assert diagnosis.as_dict()["ignored_columns"] == ["aileron", "theta"]
    finding = diagnosis.as_dict()["findings"][0]
    assert (finding["effect"], finding["term"]) == ("stability_derivative", "M_q")
    low, high = finding["interval"]  # within three half-widths of the 95 % interval (5.9 standard errors)
    assert abs(finding["value"] - -2.0) < 3 * (high - low) / 2 and finding["unit"] == "1/s"
    assert "pitch damping" in finding["statement"]
    saved = diagnosis.corrected.save(tmp_path / "corrected.json")
    model_file.unlink()  # the model file carries its reference
    loaded = EffectVehicle.load(saved)
    np.testing.assert_allclose(loaded.simulate_states(held.time, held.inputs),
                               diagnosis.corrected.simulate_states(held.time, held.inputs))


def _with_other_columns(recording):
    """``recording`` with a column the short-period model does not have among its inputs
    (``aileron``, moving) and one among its outputs (``theta``)."""
    aileron = 0.01 * np.sin(recording.time)
    return Recording(recording.time, np.column_stack([recording.inputs, aileron]), (*recording.input_names, "aileron"),
                     np.column_stack([recording.outputs, np.cumsum(recording.output("q")) * 0.01]),
                     (*recording.output_names, "theta"), dict(recording.metadata))


def test_a_reduced_model_reads_whole_recordings_and_says_what_it_left_out(tmp_path):
    """A recording file with columns the model does not have is read with the model's columns
    (the same numbers as without the others) and names the others; one sharing no output with
    the model, or missing one of its inputs, is refused."""
    model_file = tmp_path / "short_period.json"
    model_file.write_text(json.dumps(SHORT_PERIOD))
    reference = get_vehicle(str(model_file))
    flown = reference.simulate(*_manoeuvre(reference, 0))
    write_recording(tmp_path / "whole.csv", _with_other_columns(flown))
    model = effect_model(str(model_file), purpose="test")
    data = prepare([tmp_path / "whole.csv"], model)
    assert data.ignored_columns == ["aileron", "theta"] and data.output_names == ("w", "q")
    np.testing.assert_array_equal(data.measured[0], flown.outputs)
    np.testing.assert_array_equal(data.inputs[0], flown.inputs)
    assert prepare([flown], model).ignored_columns == []
    # The same with the model's input under another name, renamed by a column map.
    whole = _with_other_columns(flown)
    write_recording(tmp_path / "renamed.csv", Recording(whole.time, whole.inputs, ("elev", "aileron"), whole.outputs,
                                                        whole.output_names))
    mapped = prepare([tmp_path / "renamed.csv"], model, column_map={"elev": "elevator"})
    assert mapped.ignored_columns == ["aileron", "theta"]
    np.testing.assert_array_equal(mapped.inputs[0], flown.inputs)
    elsewhere = _with_other_columns(flown)
    only_theta = Recording(elsewhere.time, elsewhere.inputs, elsewhere.input_names, elsewhere.outputs[:, -1:],
                           ("theta",))
    with pytest.raises(BadInputError, match="none of its columns is an output of short-period"):
        prepare([only_theta], model)
    write_recording(tmp_path / "no_elevator.csv", Recording(flown.time, np.zeros((len(flown.time), 1)), ("aileron",),
                                                            flown.outputs, flown.output_names))
    with pytest.raises(BadInputError, match="missing input column"):
        prepare([tmp_path / "no_elevator.csv"], model)


def _manoeuvre(reference, variant):
    return LinearEffects(reference).identification_manoeuvre(duration=10.0, variant=variant)


@pytest.mark.parametrize("change, message", [
    ({"A": [[1.0, 2.0]]}, "'A' has shape (1, 2); its 2 states make it (2, 2)"),
    ({"B": [[1.0], [float("nan")]]}, "'B' holds a non-finite number"),
    ({"derivative_rows": {"x": "Z"}}, "derivative_rows names 'x', which is not a state"),
    ({"derivative_rows": {"w": "M", "q": "M"}}, "row letter 'M' names both 'w' and 'q'"),
    ({"derivative_rows": {"w": "zz"}}, "must be one capital letter"),
    ({"units": {"w": "m/s"}}, "units missing for q, elevator"),
    ({"states": ["w", "w"]}, "names ['w'] twice"),
    ({"inputs": []}, "'inputs' must be a non-empty list"),
    ({"sample_time": -1}, "'sample_time' must be a positive number"),
    ({"name": ""}, "'name' must be a non-empty string"),
    # Units that would be read as flightgp's: a known column in another unit, any column not SI.
    ({"units": {"w": "m/s", "q": "deg/s", "elevator": "1"}},
     "'q' is declared in 'deg/s', but flightgp's q is in rad/s"),
    ({"states": ["w", "alpha"], "derivative_rows": {"w": "Z"}, "units": {"w": "m/s", "alpha": "deg", "elevator": "1"}},
     "'alpha' is declared in 'deg'; flightgp reads SI units (rad)"),
    # Keys the format does not have are refused, with the nearest known one.
    ({"sample_rate": 100}, "unknown key 'sample_rate' (did you mean 'sample_time'?)"),
    ({"format": "matlab-ss"}, "format 'matlab-ss' is not a state-space model"),
])
def test_bad_state_space_files_are_refused_with_one_line(tmp_path, capsys, change, message):
    assert message in str(_refusal({**SHORT_PERIOD, **change}))
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**SHORT_PERIOD, **change}))
    recording = tmp_path / "run.csv"
    recording.write_text("time,elevator,q\n0,0,0\n0.01,0,0\n")
    code = main(["diagnose", str(recording), "--reference", str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and message in err and err.count("\n") == 1 and not (tmp_path / "out").exists()


def _refusal(content):
    with pytest.raises(BadInputError) as error:
        state_space_from_dict(content)
    return error.value


def test_missing_and_malformed_files_and_non_linear_exports_exit_2(tmp_path, capsys):
    assert main(["state-space", "blimp", "--out", str(tmp_path / "b.json")]) == 2
    assert "not a linear model" in capsys.readouterr().err
    (tmp_path / "broken.json").write_text("{not json")
    for path, message in ((tmp_path / "none.json", "no such state-space model file"),
                          (tmp_path / "broken.json", "not a JSON state-space model")):
        with pytest.raises(BadInputError, match=message):
            get_vehicle(str(path))


@pytest.mark.parametrize("steps", [0, 1, 31, 32, 33, 100, 2000])
@pytest.mark.parametrize("every", [1, 3])
def test_blocked_propagation_is_the_step_by_step_recursion(steps, every):
    """validation.vehicles.state_space.propagate works in blocks; it returns what
    x[j+1] = T x[j] + f[j] gives step by step, every ``every``-th state and the last, to rounding."""
    from validation.vehicles.state_space import propagate

    rng = np.random.default_rng(steps)
    transition = rng.standard_normal((9, 9))
    transition *= 0.99 / np.abs(np.linalg.eigvals(transition)).max()
    forcing, state = rng.standard_normal((steps, 9)), rng.standard_normal(9)
    expected = [state]
    for push in forcing:
        expected.append(transition @ expected[-1] + push)
    expected = np.array(expected)
    np.testing.assert_allclose(propagate(transition, forcing, state, every=every),
                               np.concatenate([expected[:steps:every][:steps // every], expected[-1:]]),
                               rtol=0, atol=1e-12)
