"""validation.bench.qtg: a QTG with one FMU instance against an instance per test, and its reports
(on two short tests instead of the example's twenty)."""
import pytest

from validation.bench import qtg

TWO_TESTS = """title = "bench"

[[test]]
id = "pitch rate, longitudinal cyclic doublet"
recording = "ref_theta_1s_doublet.csv"
outputs = ["q"]

[[test]]
id = "pitch rate, longitudinal cyclic 3-2-1-1"
recording = "flight_theta_1s_3211.csv"
outputs = ["q"]
"""


def test_times_one_instance_against_one_per_test_and_the_reports(qtg_flights, monkeypatch):
    spec = qtg_flights / "bench.toml"
    spec.write_text(TWO_TESTS)
    monkeypatch.setattr(qtg, "EXAMPLE", spec)
    report = qtg.run(repeats=2, progress=False)
    assert report["tests"] == 2 and report["instantiations"] == 1 and len(report["runs"]) == 2
    for key in ("one_instance_s", "instance_per_test_s", "reports_s"):
        assert all(run[key] > 0 for run in report["runs"])
        assert report[f"median_{key}"] == pytest.approx(sum(run[key] for run in report["runs"]) / 2)
    assert report["median_total_s"] == pytest.approx(report["median_one_instance_s"] + report["median_reports_s"])
    assert report["reuse_speedup"] == pytest.approx(report["median_instance_per_test_s"]
                                                    / report["median_one_instance_s"])
    total, reuse = qtg.summary_rows(report)
    assert (total.id, total.value, total.goal, total.at_least) == ("qtg.example.seconds", report["median_total_s"],
                                                                   60.0, False)
    assert total.met == (report["median_total_s"] <= 60.0) and (reuse.id, reuse.goal) == (
        "qtg.instance_reuse.speedup", None)
    assert "an instance per test (peer)" in qtg.format_table(report)
