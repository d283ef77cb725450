"""The fidelity scorecard (validation/diagnose/fidelity.py): a concealed pitch-axis delay fails
the pitch-rate band of 14 CFR Part 60 before correction and passes after, its frequency-domain
cost falls from above Tischler's acceptable 100 to below 50; a tolerance file overrides the
bands (given in SI, shown in SI); the report shows Table C2A's bands in its units; bad
tolerance files exit 2."""
import json
import math

import numpy as np
import pytest

from tests.validation.diagnose.test_diagnose import CASE_STEP, _concealed
from validation.cli import main
from validation.core.errors import BadInputError
from validation.core.recordings import write_recording
from validation.diagnose import diagnose
from validation.diagnose.fidelity import DEFAULT_TOLERANCES, POSE_OUTPUTS, pose_scores, read_tolerances
from validation.vehicles.rgblimp_data import SOURCE_STATE_WIDTH


@pytest.fixture(scope="module")
def delayed():
    """A 40 ms delay on longitudinal cyclic (the Bo105 at 80 kt, 12 s at 33 Hz: the pitch rate
    still fails its band before correction and passes after)."""
    return _concealed([{"effect": "time_delay", "input": "theta_1s", "value": 0.04}], duration=12.0,
                      sample_time=CASE_STEP)


def test_the_delay_fails_the_pitch_rate_band_before_correction_and_passes_after(delayed):
    fit, held = delayed
    fidelity = diagnose([fit], reference="bo105-80kt", holdout=[held]).as_dict()["fidelity"]
    q = fidelity["outputs"]["q"]
    assert q["tolerance"] == pytest.approx(math.radians(2.0))
    assert q["tolerance_source"] == "2.c.3.b: +-2 deg/s pitch rate"
    assert q["tolerance_as_stated"] == "2 deg/s" and fidelity["outputs"]["u"]["tolerance_as_stated"] == "5 kt"
    assert not q["reference"]["passes"] and q["corrected"]["passes"]
    assert q["reference"]["max_error"] > q["tolerance"] >= q["corrected"]["max_error"]
    assert q["reference"]["inside_share"] < 1.0 == q["corrected"]["inside_share"]
    assert q["frequency_input"] == "theta_1s"
    assert q["reference"]["frequency_cost"] > 100 > 50 > q["corrected"]["frequency_cost"]
    assert fidelity["outputs"]["v"]["tolerance"] is None and fidelity["outputs"]["v"]["corrected"]["passes"] is None


def test_a_tolerance_file_overrides_the_bands_and_the_report_leads_with_them(delayed, tmp_path, capsys):
    fit, held = delayed
    write_recording(tmp_path / "fit.csv", fit)
    write_recording(tmp_path / "held.csv", held)
    bands = tmp_path / "bands.json"
    bands.write_text(json.dumps({"q": 1.0, "w": 0.001}))
    out = tmp_path / "out"
    assert main(["diagnose", str(tmp_path / "fit.csv"), "--holdout", str(tmp_path / "held.csv"), "--reference",
                 "bo105-80kt", "--tolerances", str(bands), "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "inside the tolerance bands before correction: " in printed.splitlines()[1]
    fidelity = json.loads((out / "diagnosis.json").read_text())["fidelity"]
    assert fidelity["outputs"]["q"]["tolerance"] == 1.0 and fidelity["outputs"]["q"]["reference"]["passes"]
    assert fidelity["outputs"]["w"]["tolerance"] == 0.001 and not fidelity["outputs"]["w"]["corrected"]["passes"]
    assert fidelity["outputs"]["theta"]["tolerance"] == DEFAULT_TOLERANCES["theta"].half_width
    assert fidelity["outputs"]["q"]["tolerance_as_stated"] is None
    assert fidelity["outputs"]["theta"]["tolerance_as_stated"] == "1.5 deg"
    report = (out / "report.md").read_text()
    assert report.split("\n\n")[2].startswith("**Fidelity** (tolerance file and 14 CFR Part 60")
    # The file's bands in SI, as the file gives them; the table's in its units, with SI beside.
    assert "| q | +-1 rad/s |" in report and "| w | +-0.001 m/s |" in report
    assert "| theta | +-1.5 deg (0.0262 rad) |" in report


def test_a_tolerance_for_an_output_not_recorded_is_refused_before_the_diagnosis(tmp_path, capsys):
    """A band the scorecard would drop (a misspelt output) is refused at once, naming the nearest
    recorded output, and nothing is written."""
    recording = tmp_path / "run.csv"
    recording.write_text("time,theta_0,theta_1s,theta_1c,theta_0T,q\n"
                         + "".join(f"{k / 100},0,{0.01 * (k // 50 % 2)},0,0,0\n" for k in range(300)))
    bands = tmp_path / "bands.json"
    bands.write_text(json.dumps({"qq": 0.03}))
    code = main(["diagnose", str(recording), "--reference", "bo105-80kt", "--tolerances", str(bands),
                 "--out", str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "bands.json: unknown output 'qq' (did you mean 'q'?); known: q" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("content, message", [
    ("{not json", "not a JSON tolerance file"),
    ('{"q": -1}', "the band of 'q' must be a positive number in rad/s"),
    ('[0.1]', "a tolerance file maps outputs to band half-widths"),
])
def test_bad_tolerance_files_are_refused(tmp_path, content, message):
    path = tmp_path / "bands.json"
    path.write_text(content)
    with pytest.raises(BadInputError, match=message):
        read_tolerances(path)
    with pytest.raises(BadInputError, match="no such tolerance file"):
        read_tolerances(tmp_path / "missing.json")


def test_the_rgblimp_pose_score_is_the_sources_over_the_held_out_ranges():
    """The flight score of each model: the source's score with each pose column's held-out range,
    and the RMS 3-D position error; none without the six pose outputs."""
    time = np.linspace(0.0, 1.0, 5)
    measured = {name: np.linspace(0.0, width, 5) for name, width in zip(POSE_OUTPUTS, (2.0, 1.0, 0.5, 0.2, 0.1, 1.0))}
    traces = {name: {"measured": values, "time": time, "reference": values + (0.1 if name == "x" else 0.0),
                     "corrected": values, "corrected_gp": values + (0.05 if name == "theta" else 0.0)}
              for name, values in measured.items()}
    pose = pose_scores(traces)
    assert pose["ranges"]["x"] == 2.0 and pose["ranges"]["theta"] == 0.1
    assert math.isclose(pose["reference"]["score"], (0.1 / 2.0) ** 2 / SOURCE_STATE_WIDTH, rel_tol=1e-12)
    assert math.isclose(pose["corrected_gp"]["score"], (0.05 / 0.1) ** 2 / SOURCE_STATE_WIDTH, rel_tol=1e-12)
    assert pose["corrected"]["score"] == 0.0 and pose["corrected_gp"]["position_rmse_m"] == 0.0
    assert math.isclose(pose["reference"]["position_rmse_m"], 0.1, rel_tol=1e-12)
    assert pose_scores({name: traces[name] for name in POSE_OUTPUTS[:5]}) is None
