"""validation.bench.cosim: the GP rate-predictor co-simulation against real time."""
import pytest

from validation.bench import cosim
from validation.models import narx


@pytest.mark.slow
def test_reports_real_time_factors_of_both_models_and_both_fmu_kinds(monkeypatch, bo105_trained, train_narx_once):
    # Each time from one run instead of the best of 3 (a third of the co-simulations): what is
    # checked here is the report, not the timings' noise. Its models are trained once per test
    # process (the paper's is bo105_trained, on the same flight; bench fmu trains the other too).
    monkeypatch.setattr(narx, "train_narx", train_narx_once)
    report = cosim.run(repeats=1, progress=False)
    assert report["simulated_s"] == pytest.approx(8.0) and report["repeats"] == 1
    assert {(r["model"].split(":")[0], r["fmu"]) for r in report["rows"]} == {
        (model, kind) for model in ("paper", "32 points, 1 sample (max. likelihood)") for kind in cosim.STEPPED}
    for row in report["rows"]:
        assert len(row["loop_s"]) == 1 and row["load_s"] > 0
        assert row["real_time_factor"] == pytest.approx(8.0 / row["loop_s"][0])
        assert row["cosim_real_time_factor"] == pytest.approx(8.0 / row["cosim_s"])
        goal = cosim.COSIM_GOAL_REAL_TIME_PYTHONFMU if row["fmu"] == "pythonfmu" else cosim.COSIM_GOAL_REAL_TIME
        assert row["goal_met"] == (row["real_time_factor"] >= goal)
        # Single timings, so only their arithmetic is checked (the reference FMU alone, timed first,
        # measured slower than a whole co-simulation once: its first run loads what the others reuse).
        assert row["over_reference_alone"] == pytest.approx(row["cosim_s"] / report["reference_alone_s"])
    rows = cosim.summary_rows(report)
    assert [row.met for row in rows] == [r["goal_met"] for r in report["rows"]]
    assert {row.id for row in rows} == {f"cosim.{model}.{kind}.realtime" for model in ("paper", "single")
                                        for kind in ("native", "native_one_thread", "pythonfmu")}
    assert "1 runs" in cosim.format_table(report) and "best of 1;" in cosim.format_table(report)
