"""``flightgp reproduce rgblimp-diagnose`` (validation/reproduce/rgblimp_diagnose.py) end to end on
the first two seconds of the excerpt's flights (configurations 29 and 30, each diagnosed on its own,
in this process): the bookkeeping (diagnosed, validation and test flights), the corrected
models and the test scores, checked against independent free runs; not the numbers."""
import json

import numpy as np
import pytest

from validation.cli import main
from validation.reproduce.rgblimp import flight_metrics, read_score_ranges
from validation.reproduce.rgblimp_diagnose import SCORED, reproduce_rgblimp_diagnose
from validation.vehicles.effect_vehicle import EffectVehicle
from validation.vehicles.effects import TARGET_KEYS
from validation.vehicles.rgblimp import RGBlimpReference
from validation.vehicles.rgblimp_data import EXCERPT_FOLDER, read_rgblimp_flight

#: Rows of each truncated flight (2.07 s at 60 Hz; the header besides): the 2 s a diagnosis needs.
ROWS = 125


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    data = tmp_path_factory.mktemp("rgblimp_short")
    for number in (117, 118, 119, 121, 122, 123):
        lines = (EXCERPT_FOLDER / f"data_{number}.csv").read_text().splitlines()[:ROWS + 1]
        (data / f"data_{number}.csv").write_text("\n".join(lines) + "\n")
    (data / "data_info").mkdir()
    for path in (EXCERPT_FOLDER / "data_info").iterdir():
        (data / "data_info" / path.name).write_bytes(path.read_bytes())
    out = tmp_path_factory.mktemp("rgblimp_diagnose_out")
    # No PNGs (a fifth of the run; diagnose's own tests draw them): the bookkeeping, not the plots.
    return data, out, reproduce_rgblimp_diagnose(data, out, configurations=(29, 30), workers=1, progress=False,
                                                 figures=False)


@pytest.mark.slow
def test_results_diagnosis_and_report_are_written(run):
    data, out, results = run
    assert json.loads((out / "results.json").read_text()) == json.loads(json.dumps(results))
    assert [(c["diagnosed"], c["validation"], c["test"]) for c in results["configurations"]] == [
        ("data_117.csv", "data_118.csv", "data_119.csv"), ("data_121.csv", "data_122.csv", "data_123.csv")]
    assert [(d["configurations"], d["folder"]) for d in results["diagnoses"]] == [
        ([29], "diagnosis/configuration_29"), ([30], "diagnosis/configuration_30")]
    for configuration, validation, test in ((29, "data_118.csv", "data_119.csv"), (30, "data_122.csv", "data_123.csv")):
        folder = out / "diagnosis" / f"configuration_{configuration}"
        diagnosis = json.loads((folder / "diagnosis.json").read_text())
        assert validation in diagnosis["fit"]["holdout"] and test not in json.dumps(diagnosis)
        corrected = EffectVehicle.load(folder / "corrected_model.json")
        for finding in (f for f in diagnosis["findings"] if f["effect"] != "unexplained"):
            assert finding["in_corrected_model"] == any(
                e["effect"] == finding["effect"] and e["value"] == finding["value"] for e in corrected.effects)
    assert (out / "report.md").read_text().startswith("# RGBlimp diagnosis on real flights")
    assert not list(out.rglob("*.png"))  # figures=False


@pytest.mark.slow
def test_test_scores_are_the_free_runs_of_the_published_named_and_corrected_models(run):
    data, out, results = run
    models = {}
    for diagnosis in results["diagnoses"]:
        named = [{key: f[key] for key in ("effect", TARGET_KEYS[f["effect"]], "value")}
                 for f in diagnosis["findings"] if f["effect"] != "unexplained"]
        models[diagnosis["configurations"][0]] = (
            EffectVehicle("rgblimp", named), EffectVehicle.load(out / diagnosis["folder"] / "corrected_model.json"))
    ranges = read_score_ranges(data)
    for flight in results["flights"]:
        recording = read_rgblimp_flight(data / flight["test"]).recording
        kind = "straight" if flight["configuration"] >= 30 else "spiral"
        physics = RGBlimpReference().simulate_states(recording.time, recording.inputs,
                                                     initial_state=recording.outputs[0])
        named, corrected = models[flight["configuration"]]
        for name, states in (("physics", physics), ("all_named", named.replay_states(recording)),
                             ("corrected", corrected.replay_states(recording))):
            expected = flight_metrics(states, recording.outputs, ranges[kind])
            assert flight["score"][name] == pytest.approx(expected["score"], rel=1e-12)
            assert flight["position_rmse_m"][name] == pytest.approx(expected["position_rmse_m"], rel=1e-12)
    summary = results["summary"]
    for name in SCORED:
        assert summary["mean_score"][name] == pytest.approx(np.mean([f["score"][name] for f in results["flights"]]))
    factor = sum(1.5 * f["score"]["corrected"] <= f["score"]["physics"] for f in results["flights"])
    assert summary["corrected_factor_flights"] == factor
    assert results["goal"]["met"] == (factor >= 6 and summary["mean_position_rmse_m"]["corrected"]
                                      < summary["mean_position_rmse_m"]["physics"])


def test_too_few_configurations_and_bad_folders_exit_2(tmp_path, capsys):
    data = tmp_path / "data"
    data.mkdir()
    (data / "data_117.csv").write_text("")
    code = main(["reproduce", "rgblimp-diagnose", "--data", str(data), "--out", str(tmp_path / "out"),
                 "--configurations", "29"])
    err = capsys.readouterr().err
    assert code == 2 and "configuration 29 has 1 flight" in err and err.count("\n") == 1
    (data / "data_118.csv").write_text("")
    code = main(["reproduce", "rgblimp-diagnose", "--data", str(data), "--out", str(tmp_path / "out"),
                 "--configurations", "29"])
    err = capsys.readouterr().err
    assert code == 2 and "fewer than three flights" in err and err.count("\n") == 1
