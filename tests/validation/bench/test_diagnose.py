"""validation.bench.diagnose: seconds of flightgp diagnose per concealed-effect case."""
import pytest

from validation.bench import diagnose
from validation.diagnose import bench


@pytest.mark.slow
def test_times_every_chosen_case_against_the_goal(monkeypatch):
    # 3 s recordings instead of the bench's 20 s (both chosen cases still pass, through the FMU
    # too): the report's rows and their arithmetic are what is checked here, and over_recording is
    # per the recording's length. Two cases, chosen out of the suite's order; through the FMU the
    # no-effect one (a diagnosis that accepts no step replays the fewest candidates), its
    # candidates replayed in this process (workers=1).
    monkeypatch.setattr(bench, "DURATION", 3.0)
    chosen = ("none", "delay-theta_1s-60ms")
    report = diagnose.run(cases=chosen, fmu_cases=("none",), workers=1, progress=False)
    assert report["recording_s"] == 3.0
    # One row per chosen case, in the order of validation.diagnose.bench's case list.
    assert [r["case"] for r in report["cases"]] == ["delay-theta_1s-60ms", "none"]
    assert report["max_seconds"] == max(r["seconds"] for r in report["cases"])
    assert report["goal_met"] == (report["max_seconds"] <= diagnose.DIAGNOSE_GOAL_S)
    for row in report["cases"]:
        assert row["over_recording"] == pytest.approx(row["seconds"] / report["recording_s"])
    # Through the Bo105 reference FMU: the same case, scored the same, timed against its own goal
    # and as a ratio to the built-in run of it.
    fmu = report["fmu"]
    assert [r["case"] for r in fmu["cases"]] == ["none"] and fmu["cases"][0]["passed"]
    assert fmu["cases"][0]["over_built_in"] == pytest.approx(fmu["cases"][0]["seconds"] / report["cases"][1]["seconds"])
    assert fmu["goal_met"] == (fmu["max_seconds"] <= diagnose.FMU_GOAL_S) and fmu["workers"] == 1
    rows = {row.id: row for row in diagnose.summary_rows(report)}
    with pytest.raises(ValueError, match="no case outside-quadratic-damping"):  # a name not in the suite
        diagnose.run(cases=("outside-quadratic-damping",), progress=False)
    assert rows["diagnose.worst_case.seconds"].value == report["max_seconds"]
    assert rows["diagnose.fmu.worst_case.seconds"].met == fmu["goal_met"]
