"""validation.bench.narx: the vectorised GP-NARX Monte Carlo free run against a run-by-run loop."""
import math

import pytest

from validation.bench import narx


def test_the_loop_reproduces_the_vectorised_runs_and_the_speedup_is_their_time_ratio():
    report = narx.run(n_runs=50, n_steps=40, progress=False)
    assert {"runs", "steps", "vectorised_s", "loop_s_estimated", "loop_runs_timed", "speedup",
            "goal_speedup", "goal_seconds"} <= set(report)
    assert (report["runs"], report["steps"], report["loop_runs_timed"]) == (50, 40, 10)
    assert 0 < report["vectorised_s"] < math.inf and 0 < report["loop_s_estimated"] < math.inf
    # Fed the same random numbers, the loop reproduces the vectorised runs up to rounding.
    assert report["max_abs_difference"] <= narx.NARX_AGREEMENT_TOLERANCE
    # The loop's time is its set-up and its timed runs scaled to all runs; the speed-up is the
    # ratio (how large it is is the benchmark's to report, not a test's to time).
    assert report["loop_s_estimated"] == pytest.approx(report["loop_setup_s"] + 50 * report["loop_s_per_run"])
    assert report["speedup"] == pytest.approx(report["loop_s_estimated"] / report["vectorised_s"])
    assert report["goal_met"] is None  # the goal applies at the goal's size only
    assert "peer timed on 10 runs, scaled to R" in narx.format_table(report)
