"""validation.bench.diagnose: seconds of flightgp diagnose per concealed-effect case."""
import pytest

from validation.bench import diagnose


@pytest.mark.slow
def test_times_every_chosen_case_against_the_goal():
    report = diagnose.run(progress=False)
    # One row per chosen case, in the order of validation.diagnose.bench's case list.
    assert [r["case"] for r in report["cases"]] == [
        "delay-theta_1s-60ms", "M_q-40%", "pair-delay+bias", "none", "outside-quadratic-damping"]
    assert report["max_seconds"] == max(r["seconds"] for r in report["cases"])
    assert report["goal_met"] == (report["max_seconds"] <= diagnose.DIAGNOSE_GOAL_S)
    for row in report["cases"]:
        assert row["over_recording"] == pytest.approx(row["seconds"] / report["recording_s"])
