"""validation.bench.fmu: the step cost of the rate-predictor FMUs (pythonfmu and native) and the
blimp RKGP FMUs against bare FMUs."""
import math

import pytest

from validation.bench import fmu
from validation.models import narx


def test_times_the_gp_fmu_against_a_bare_one_and_the_native_fmus(monkeypatch, bo105_trained, train_narx_once):
    # Of the other native models only the single-sample one (the 500-point ones train and build
    # two FMUs each for rows whose arithmetic the single one's already checks). Its models are
    # trained once per test process: the paper's is bo105_trained, on the same flight.
    monkeypatch.setattr(fmu, "NATIVE_MODELS", fmu.NATIVE_MODELS[:1])
    monkeypatch.setattr(narx, "train_narx", train_narx_once)
    report = fmu.run(n_steps=50, progress=False)
    assert report["steps"] == 50 and report["training_points"] == 32  # the paper's model
    assert 0 < report["bare_us_per_step"] < report["gp_us_per_step"]
    assert report["gp_over_bare"] == pytest.approx(report["gp_us_per_step"] / report["bare_us_per_step"])
    assert report["goal_met"] == (report["gp_over_bare"] <= report["goal_ratio"])
    blimp = report["blimp"]
    assert blimp["steps"] > 0
    times = [value for key, value in blimp.items() if key.endswith("us_per_step")]
    assert len(times) >= 3 and all(math.isfinite(t) and t > 0 for t in times)
    assert "bare us/step" in fmu.format_table(report)
    # Headline rows: the pythonfmu FMU against the bare one, the paper's native FMU free run
    # (fast on two threads and on one, exact; against 200x real time) and one step, each other
    # native rate predictor run (here the single-sample one), the blimp.
    rows = {row.id: row for row in fmu.summary_rows(report)}
    assert list(rows) == ["fmu.pythonfmu.gp_over_bare", "fmu.paper.native.step_us",
                          "fmu.paper.native.one_thread_step_us", "fmu.paper.native.exact_step_us",
                          "fmu.paper.native.one_step_us", "fmu.single.native.speedup", "fmu.blimp_rkgp.native.speedup"]
    free_run = report["paper_free_run"]
    for path, (key, *_) in fmu.FREE_RUN_PATHS.items():
        paper = rows[key]
        assert paper.value == free_run[path]["median_us"] and len(free_run[path]["us_per_step"]) == 3
        assert paper.goal == pytest.approx(report["narx_step_s"] * 1e6 / 200) and not paper.at_least
        assert paper.met == (paper.value <= paper.goal)
        # The share of the peak is the time the counted FLOPs would take at the peak over the
        # measured time (its size is the benchmark's to report, not a test's to time).
        count, peak = free_run["flops"]["exact" if "exact" in path else "fast"], free_run["peak"]
        at_peak_s = (count["double"] / peak["double"] + count["single"] / peak["single"]) / free_run[path]["threads"]
        assert free_run[path]["share_of_peak"] == pytest.approx(at_peak_s / (free_run[path]["median_us"] * 1e-6))
    # The fast path takes its exponents and exponentials in single precision: fewer double FLOPs,
    # some single.
    flops = free_run["flops"]
    assert flops["fast"]["double"] < flops["exact"]["double"]
    assert flops["fast"]["single"] > 0 == flops["exact"]["single"]
    assert flops["terms"] > 0 and free_run["peak"]["double"] > 0
    assert rows["fmu.paper.native.one_step_us"].value == report["native"][0]["native_c_host_us_per_step"]
