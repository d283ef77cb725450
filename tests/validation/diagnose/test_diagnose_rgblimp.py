"""flightgp diagnose on the RGBlimp and the replication of findings across folds.

- Effects concealed in flights replayed from real recorded starts and inputs (the excerpt's
  flights of two configurations) are named with their values, from the first recorded states,
  one of them a term on no list, which the residual search finds;
- the replication (validation/diagnose/replicate.py) on the Bo105, whose replays take
  milliseconds: a concealed effect is named in every fold; a finding named with opposite
  changes in the folds is not replicated;
- headings that cross +-pi in the source's files are unwrapped before comparing;
- bad input exits 2 with one line.
"""
import numpy as np
import pytest

from tests.validation.diagnose.test_diagnose import CASE_STEP, _concealed
from validation.cli import main
from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.diagnose import diagnose
from validation.diagnose.data import prepare
from validation.diagnose.replicate import Replication
from validation.vehicles.bo105_effects import identification_manoeuvre
from validation.vehicles.bo105_flight import SENSOR_NOISE_STD
from validation.vehicles.effect_vehicle import EffectVehicle, effect_model
from validation.vehicles.rgblimp_data import EXCERPT_FOLDER, read_rgblimp_flight

#: A buoyancy imbalance and a draught, well above the floors the RGBlimp weighs residuals by, and
#: a roll acceleration proportional to pitch, which no named effect is (the residual search's).
TRUTH = [{"effect": "force_offset", "term": "Z_0", "value": 0.12},
         {"effect": "steady_wind", "term": "wind_x", "value": 0.1},
         {"effect": "search_term", "term": "L_theta", "value": 0.3}]
#: Samples of each concealed flight (1 s at 60 Hz).
SAMPLES = 60


def _excerpt(number: int, samples: int = SAMPLES) -> Recording:
    r = read_rgblimp_flight(EXCERPT_FOLDER / f"data_{number}.csv").recording
    return Recording(r.time[:samples], r.inputs[:samples], r.input_names, r.outputs[:samples], r.output_names,
                     {"name": f"data_{number}"})


def _concealed_flight(number: int) -> Recording:
    """The excerpt flight's first state and inputs, flown by the model with :data:`TRUTH`."""
    recording = _excerpt(number)
    states = EffectVehicle("rgblimp", TRUTH).replay_states(recording)
    return Recording(recording.time, recording.inputs, recording.input_names, states, recording.output_names,
                     recording.metadata)


@pytest.mark.slow
def test_concealed_effects_on_real_starts_are_named_with_their_values():
    fit = [_concealed_flight(n) for n in (117, 121, 118)]
    result = diagnose(fit, reference="rgblimp", holdout=[_concealed_flight(122)]).as_dict()
    named = {f["term"]: f for f in result["findings"] if f["effect"] != "unexplained"}
    assert set(named) == {"Z_0", "wind_x", "L_theta"}, [f["statement"] for f in result["findings"]]
    for effect in TRUTH:
        assert named[effect["term"]]["value"] == pytest.approx(effect["value"], rel=1e-3)
        assert named[effect["term"]]["carries_over"]
    assert "buoyancy imbalance" in named["Z_0"]["statement"]
    assert named["L_theta"]["effect"] == "search_term" and result["search"]["residual_search"]["ran"]
    assert "roll acceleration proportional to theta" in named["L_theta"]["statement"]
    assert result["fit"]["rmse_corrected"]["z"] < 0.01 * result["fit"]["rmse_reference"]["z"]
    pose = result["fidelity"]["pose"]  # the source's score on the held-out flight
    assert pose["corrected"]["score"] < 0.01 * pose["reference"]["score"]
    assert pose["corrected"]["position_rmse_m"] < 0.1 * pose["reference"]["position_rmse_m"]


def test_replication_names_a_concealed_effect_in_every_fold():
    """8 s recordings at the concealed cases' 33 Hz (test_diagnose.py's CASE_STEP; the 60 ms
    delay is two samples): the delay named in each fold within 5 ms."""
    effect = {"effect": "time_delay", "input": "theta_1s", "value": 0.06}
    first, held = _concealed([effect], duration=8.0, sample_time=CASE_STEP)
    vehicle = EffectVehicle("bo105-80kt", [effect], noise_sd=SENSOR_NOISE_STD)
    second = vehicle.simulate(*identification_manoeuvre(duration=8.0, sample_time=CASE_STEP, variant=0),
                              seed=3)  # other noise
    result = diagnose([first, second], reference="bo105-80kt", holdout=[held], folds=2).as_dict()
    finding = next(f for f in result["findings"] if f["effect"] == "time_delay")
    replication = finding["replication"]
    assert replication["folds"] == 2 and replication["named_in"] == 2 and replication["replicated"]
    assert all(v == pytest.approx(0.06, abs=0.005) for v in replication["values"])
    # Each fold fitted its own recording alone: its value is not the full diagnosis' of both.
    assert len(set(replication["values"])) == 2 and finding["value"] not in replication["values"]
    assert "Replicated: each of the 2 folds" in finding["statement"]
    assert [len(fold["recordings"]) for fold in result["replication"]["folds"]] == [1, 1]


def test_a_finding_moved_opposite_ways_by_the_folds_is_not_replicated():
    finding = {"effect": "stability_derivative", "term": "N_R", "value": -0.02, "model_value": -0.0137}
    folds = [{"recordings": ["a"], "effects": []}, {"recordings": ["b"], "effects": []}]
    same = Replication(folds, {("stability_derivative", "N_R"): [-0.019, -0.025]}).of(finding)
    opposite = Replication(folds, {("stability_derivative", "N_R"): [-0.019, -0.010]}).of(finding)
    missing = Replication(folds, {("stability_derivative", "N_R"): [-0.019, None]}).of(finding)
    assert same["replicated"] and not opposite["replicated"] and not missing["replicated"]
    assert (opposite["named_in"], missing["named_in"]) == (2, 1)


def test_headings_across_the_wrap_are_compared_unwrapped():
    """A flight whose recorded heading jumps from +pi to -pi is the same flight unwrapped: the
    reference's misfit does not change when the recorded heading is shifted by whole turns at
    the wrap."""
    recording = _excerpt(117, samples=200)
    shifted = recording.outputs.copy()
    shifted[100:, 5] += 2 * np.pi  # as if the source had wrapped there
    twin = Recording(recording.time, recording.inputs, recording.input_names, shifted, recording.output_names)
    model = effect_model("rgblimp", purpose="test")
    a, b = (prepare([r], model) for r in (recording, twin))
    np.testing.assert_allclose(a.measured[0], b.measured[0], atol=1e-12)


def test_impossible_folds_and_partial_states_are_refused(tmp_path, capsys):
    flights = [str(EXCERPT_FOLDER / f"data_{n}.csv") for n in (117, 121)]
    out = tmp_path / "out"
    for folds, message in (("3", "3 folds need at least 3 diagnosed recordings"), ("1", "folds must be 2 or more")):
        code = main(["diagnose", *flights, "--reference", "rgblimp", "--folds", folds, "--out", str(out),
                     "--no-progress"])
        err = capsys.readouterr().err
        assert code == 2 and message in err and err.count("\n") == 1, err
    recording = _excerpt(117, samples=300)
    partial = Recording(recording.time, recording.inputs, recording.input_names, recording.outputs[:, :6],
                        recording.output_names[:6])
    with pytest.raises(BadInputError, match="needs all 12 states"):
        diagnose([partial], reference="rgblimp")
    spun = recording.outputs[:120].copy()
    spun[0, recording.output_names.index("R")] = 400.0  # a start the model cannot fly: no verdict on NaN
    diverging = Recording(recording.time[:120], recording.inputs[:120], recording.input_names, spun,
                          recording.output_names, {"name": "spun"})
    with pytest.raises(BadInputError, match="could not replay spun: its outputs are not finite"):
        diagnose([diverging, diverging], reference="rgblimp")
    assert not out.exists()
