"""The flightgp command line: exit codes, bench gp, demo."""
import json
import subprocess
import sys

import numpy as np
import pytest

from validation.cli import main


def test_bench_gp_writes_report_with_ratios(tmp_path, capsys):
    assert main(["bench", "gp", "--sizes", "30", "60", "--restarts", "0", "--out-dir", str(tmp_path),
                 "--summary", str(tmp_path / "bench.json")]) == 0
    report = json.loads((tmp_path / "gp.json").read_text())
    combined = json.loads((tmp_path / "bench.json").read_text())
    assert combined["reports"]["gp"] == report
    # The summary: one headline row per size, the fit speedup against the >= 3x goal.
    assert [row["measure"] for row in combined["summary"]] == [
        "GP fit vs scikit-learn, n = 30", "GP fit vs scikit-learn, n = 60"]
    for row, size in zip(combined["summary"], report["rows"]):
        assert row["met"] == (size["fit_speedup"] >= 3.0) and row["goal"] == ">= 3x"
    assert [row["n"] for row in report["rows"]] == [30, 60]
    for row in report["rows"]:
        for key in ("fit_s", "fit_s_sklearn", "lml", "lml_sklearn", "predict_s", "predict_s_sklearn"):
            assert row[key] == row[key] and row[key] != float("inf"), key  # finite
        assert row["fit_s"] > 0 and row["fit_s_sklearn"] > 0
        # Both optimisers start from the same hyperparameters on the same function; flightgp's
        # optimum must be at least as good (1e-3 covers L-BFGS-B stopping tolerances).
        assert row["lml"] >= row["lml_sklearn"] - 1e-3
    assert "speedup" in capsys.readouterr().out


def test_bench_unknown_name_exits_2(tmp_path, capsys):
    assert main(["bench", "nope", "--out-dir", str(tmp_path), "--summary", str(tmp_path / "b.json")]) == 2
    err = capsys.readouterr().err
    assert "unknown benchmark nope" in err and "Traceback" not in err
    assert not any(tmp_path.iterdir())


def test_usage_error_exits_2_without_traceback():
    result = subprocess.run([sys.executable, "-m", "validation.cli", "no-such-command"],
                            capture_output=True, text=True)
    assert result.returncode == 2
    assert "invalid choice" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.slow
def test_demo_runs_the_bo105_case_end_to_end(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    names = {p.name for p in tmp_path.iterdir()}
    assert {"flight_test_training.csv", "bo105_gp_narx.npz", "fmp.png", "osap.png", "results.json",
            "bo105_gp_rate_predictor.fmu", "bo105_80kt_reference.fmu", "report.md"} <= names
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["config"]["training_points"] == 32
    cosim = json.loads((tmp_path / "cosim_training" / "cosim.json").read_text())
    assert set(cosim["rmse"]) == {"gp", "reference"}
    assert (tmp_path / "cosim_unseen" / "bo105_gp_rate_predictor" / "bo105_gp_rate_predictor_ref.csv").is_file()
    assert "GP FMU (free run)" in (tmp_path / "report.md").read_text()
    assert "FMP   GP" in capsys.readouterr().out


def test_demo_onto_a_file_exits_2(tmp_path, capsys):
    target = tmp_path / "taken"
    target.write_text("keep me")
    assert main(["demo", "--out", str(target)]) == 2
    assert "is not a folder" in capsys.readouterr().err
    assert target.read_text() == "keep me"


def test_bench_narx_checks_agreement_and_beats_the_loop(tmp_path, capsys):
    assert main(["bench", "narx", "--runs", "50", "--steps", "40", "--out-dir", str(tmp_path),
                 "--summary", str(tmp_path / "bench.json")]) == 0
    report = json.loads((tmp_path / "narx.json").read_text())
    assert {"runs", "steps", "vectorised_s", "loop_s_estimated", "loop_runs_timed", "speedup",
            "goal_speedup", "goal_seconds"} <= set(report)
    assert (report["runs"], report["steps"], report["loop_runs_timed"]) == (50, 40, 10)
    assert 0 < report["vectorised_s"] < float("inf") and 0 < report["loop_s_estimated"] < float("inf")
    # Fed the same random numbers, the loop reproduces the vectorised runs up to rounding.
    assert report["max_abs_difference"] <= 1e-8
    # Even this small, set-up (factorising 3 x 400 hyperparameter samples) is a like cost on
    # both sides and the loop's 6000 single-point predictions still make it 3-7x slower
    # (measured with three copies running at once on the 2-core machine): margin for noise.
    assert report["speedup"] > 1
    assert "peer timed on 10 runs, scaled to R" in capsys.readouterr().out


def test_bench_summary_or_out_dir_that_cannot_be_written_exits_2_before_running(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    assert main(["bench", "gp", "--out-dir", str(tmp_path / "file"), "--summary", str(tmp_path / "b.json")]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err
    assert main(["bench", "gp", "--out-dir", str(tmp_path / "o"), "--summary", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_bench_option_of_a_benchmark_not_run_exits_2(tmp_path, capsys):
    assert main(["bench", "gp", "--runs", "50", "--out-dir", str(tmp_path), "--summary",
                 str(tmp_path / "b.json")]) == 2
    assert "--runs applies to `bench narx` only" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_bench_fmu_times_both_fmus(tmp_path, capsys):
    assert main(["bench", "fmu", "--fmu-steps", "50", "--out-dir", str(tmp_path), "--summary",
                 str(tmp_path / "bench.json")]) == 0
    report = json.loads((tmp_path / "fmu.json").read_text())
    assert report["steps"] == 50 and report["training_points"] == 32
    assert 0 < report["bare_us_per_step"] < report["gp_us_per_step"]
    assert report["gp_over_bare"] == pytest.approx(report["gp_us_per_step"] / report["bare_us_per_step"])
    blimp = report["blimp"]
    assert blimp["steps"] > 0
    times = [value for key, value in blimp.items() if key.endswith("us_per_step")]
    assert len(times) >= 3 and all(np.isfinite(t) and t > 0 for t in times)
    assert "bare us/step" in capsys.readouterr().out


@pytest.mark.slow
def test_bench_cosim_and_diagnose_report_real_time_factors_and_goals(tmp_path, capsys):
    assert main(["bench", "cosim", "diagnose", "--out-dir", str(tmp_path), "--summary",
                 str(tmp_path / "bench.json")]) == 0
    cosim = json.loads((tmp_path / "cosim.json").read_text())
    assert cosim["simulated_s"] == pytest.approx(8.0)
    assert {(r["model"].split(":")[0], r["fmu"]) for r in cosim["rows"]} == {
        ("paper", "pythonfmu"), ("paper", "native"),
        ("32 points, 1 sample (max. likelihood)", "pythonfmu"),
        ("32 points, 1 sample (max. likelihood)", "native")}
    for row in cosim["rows"]:
        assert row["real_time_factor"] == pytest.approx(8.0 / row["seconds"])
        assert row["goal_met"] == (row["real_time_factor"] >= 200)
        assert row["over_reference_alone"] > 0
    diagnose = json.loads((tmp_path / "diagnose.json").read_text())
    assert [r["case"] for r in diagnose["cases"]] == [
        "delay-theta_1s-60ms", "M_q-40%", "pair-delay+bias", "none", "outside-quadratic-damping"]
    assert diagnose["max_seconds"] == max(r["seconds"] for r in diagnose["cases"])
    summary = json.loads((tmp_path / "bench.json").read_text())["summary"]
    assert {row["benchmark"] for row in summary} == {"cosim", "diagnose"}
    assert "met" in capsys.readouterr().out
