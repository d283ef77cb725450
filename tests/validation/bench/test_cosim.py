"""validation.bench.cosim: the GP rate-predictor co-simulation against real time."""
import pytest

from validation.bench import cosim


@pytest.mark.slow
def test_reports_real_time_factors_of_both_models_and_both_fmu_kinds():
    report = cosim.run(progress=False)
    assert report["simulated_s"] == pytest.approx(8.0)
    assert {(r["model"].split(":")[0], r["fmu"]) for r in report["rows"]} == {
        ("paper", "pythonfmu"), ("paper", "native"),
        ("32 points, 1 sample (max. likelihood)", "pythonfmu"),
        ("32 points, 1 sample (max. likelihood)", "native")}
    for row in report["rows"]:
        assert row["real_time_factor"] == pytest.approx(8.0 / row["seconds"])
        assert row["goal_met"] == (row["real_time_factor"] >= cosim.COSIM_GOAL_REAL_TIME)
        assert row["over_reference_alone"] > 0
    assert [met for *_, met in cosim.summary_rows(report)] == [r["goal_met"] for r in report["rows"]]
