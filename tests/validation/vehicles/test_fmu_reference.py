"""FMU references (validation/vehicles/fmu_reference.py) on flightgp's Bo105 reference FMU: a
replay through the FMU is the built-in reference's, each effect acts as documented, a refused
replay ends only its candidate, diagnose names what it names through the built-in reference, and
bad FMUs exit 2 with one line."""
import numpy as np
import pytest

from fmu_src import build_bo105_reference_fmu
from validation.cli import main
from validation.core.errors import BadInputError
from validation.diagnose import diagnose
from validation.vehicles.bo105 import Bo105Reference
from validation.vehicles.bo105_effects import identification_manoeuvre
from validation.vehicles.bo105_flight import SENSOR_NOISE_STD
from validation.vehicles.effect_vehicle import EffectVehicle, effect_model

#: 6 s of the Bo105 manoeuvre at 50 Hz (its longitudinal 3-2-1-1 and lateral one): short
#: replays through a Python FMU.
DURATION, STEP = 6.0, 0.02


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    return str(build_bo105_reference_fmu(80, tmp_path_factory.mktemp("fmu_reference")))


@pytest.fixture(scope="module")
def manoeuvre():
    return identification_manoeuvre(duration=DURATION, sample_time=STEP)


def test_replays_through_the_fmu_are_the_built_in_references_with_each_effect(fmu, manoeuvre):
    """Delays of whole steps, gains, parameters, biases and scales: as the built-in Bo105 with the
    same physics (the FMU runs the same discretisation; 1e-9)."""
    time, inputs = manoeuvre
    through_fmu, built_in = effect_model(fmu, purpose="test"), Bo105Reference(80)
    assert through_fmu.input_names == built_in.input_names and through_fmu.state_names == built_in.state_names
    assert len(through_fmu.terms["fmu_parameter"]) == 72 and through_fmu.term_description("M_q").startswith("pitch")
    gain = 0.8
    lists = [[], [{"effect": "time_delay", "input": "theta_1s", "value": 2 * STEP}],
             [{"effect": "input_gain", "input": "theta_1c", "value": gain}],
             [{"effect": "fmu_parameter", "term": "M_q", "value": -3.0},
              {"effect": "sensor_bias", "output": "q", "value": 0.01},
              {"effect": "output_scale", "output": "p", "value": 1.1}]]
    replays = through_fmu.simulate_many(lists, time, inputs)
    delayed = np.vstack([np.zeros((2, 4)), inputs[:-2]])
    delayed[:, [0, 2, 3]] = inputs[:, [0, 2, 3]]
    scaled = inputs.copy()
    scaled[:, 2] *= gain
    corrected = built_in.with_derivatives({"M_q": -3.0}).simulate_states(time, inputs)
    corrected[:, 2] += 0.01
    corrected[:, 5] *= 1.1
    expected = [built_in.simulate_states(time, inputs), built_in.simulate_states(time, delayed),
                built_in.simulate_states(time, scaled), corrected]
    for replay, states in zip(replays, expected):
        np.testing.assert_allclose(replay, states, rtol=0, atol=1e-9)


def test_a_refused_replay_ends_only_its_candidate(fmu, manoeuvre, caplog):
    time, inputs = manoeuvre
    model = effect_model(fmu, purpose="test")
    blown_up, fine = model.simulate_many([[{"effect": "fmu_parameter", "term": "M_q", "value": 1e300}], []],
                                         time, inputs)
    assert np.isnan(blown_up).all() and np.isfinite(fine).all()
    np.testing.assert_allclose(fine, Bo105Reference(80).simulate_states(time, inputs), rtol=0, atol=1e-9)
    assert any("refused a replay" in record.message for record in caplog.records)


@pytest.mark.slow
def test_diagnose_through_the_fmu_names_what_the_built_in_reference_names(fmu):
    truth = [{"effect": "time_delay", "input": "theta_1s", "value": 0.06},
             {"effect": "stability_derivative", "term": "M_q", "value": -3.0}]
    aircraft = EffectVehicle("bo105-80kt", truth, noise_sd=SENSOR_NOISE_STD)
    fit = aircraft.simulate(*identification_manoeuvre(duration=DURATION, sample_time=STEP, variant=0), seed=1)
    held = aircraft.simulate(*identification_manoeuvre(duration=DURATION, sample_time=STEP, variant=1), seed=2)
    built_in = diagnose([fit], reference="bo105-80kt", holdout=[held]).as_dict()["findings"]
    through_fmu = diagnose([fit], reference=fmu, holdout=[held]).as_dict()["findings"]
    assert [f.get("input") or f.get("term") for f in through_fmu] == [f.get("input") or f.get("term") for f in built_in]
    assert [f["effect"] for f in through_fmu] == ["fmu_parameter", "time_delay"]
    for ours, theirs in zip(through_fmu, built_in):
        assert ours["interval"][0] <= theirs["value"] <= ours["interval"][1]
    assert "The parameter M_q (pitch damping, the derivative M_q) is -3" in through_fmu[0]["statement"]


def test_bad_fmus_exit_2_with_one_line(tmp_path, capsys):
    recording = tmp_path / "run.csv"
    recording.write_text("time,theta_0,theta_1s,theta_1c,theta_0T,q\n0,0,0,0,0,0\n0.01,0,0,0,0,0\n")
    (tmp_path / "text.fmu").write_text("not a zip")
    for reference, message in ((tmp_path / "text.fmu", "not an FMU"), (tmp_path / "none.fmu", "no such FMU")):
        code = main(["diagnose", str(recording), "--reference", str(reference), "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert code == 2 and message in err and err.count("\n") == 1, err
    with pytest.raises(BadInputError, match="no such FMU"):
        effect_model(str(tmp_path / "none.fmu"), purpose="test")
