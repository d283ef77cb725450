"""validation.bench.rgblimp: the RGBlimp JAX free run and diagnose's compiled replay against numpy,
and the hybrid's fit time."""
import pytest

from validation.bench import rgblimp
from validation.models.rgblimp_rollout import RolloutSetup


@pytest.mark.slow
def test_times_the_free_runs_and_the_fit_against_the_goal(monkeypatch):
    # Two timed runs, replays of two effect lists, a 1-iteration identification and a 2-iteration
    # fit: the report's rows and their arithmetic are what is checked here, not the speed.
    monkeypatch.setattr(rgblimp, "FREE_RUN_REPEATS", 2)
    monkeypatch.setattr(rgblimp, "REPLAY_REPEATS", 1)
    monkeypatch.setattr(rgblimp, "REPLAY_MEMBERS", 2)
    report = rgblimp.run(progress=False, identification_iterations=1,
                         setup=RolloutSetup(inducing_points=8, segment_duration=2.0, max_segments=8, max_iterations=2))
    free, fit = report["free_run"], report["fit"]
    assert len(free["numpy_s"]) == len(free["jax_s"]) == 2
    ratios = sorted(n / j for n, j in zip(free["numpy_s"], free["jax_s"]))
    assert free["speedup"] == pytest.approx(sum(ratios) / 2)  # the median of two
    assert free["speedup_range"] == pytest.approx([ratios[0], ratios[-1]])
    assert fit["goal_met"] == (fit["hybrid_s"] <= rgblimp.FIT_GOAL_S) and 1 <= fit["iterations"] <= 2
    rows = {row.id: row for row in rgblimp.summary_rows(report)}
    assert rows["rgblimp.hybrid.fit_s"].met == fit["goal_met"]
    assert rows["rgblimp.free_run.jax_over_numpy"].value == free["speedup"]
    replay = report["replay"]
    assert replay["members"] == report["blimp_replay"]["members"] == 2
    assert len(replay["jax_s"]) == 1 and replay["speedup"] == pytest.approx(replay["numpy_s"][0] / replay["jax_s"][0])
    assert rows["rgblimp.diagnose_replay.compiled_over_numpy"].value == replay["speedup"]
    blimp = report["blimp_replay"]
    assert len(blimp["jax_s"]) == 1 and blimp["speedup"] == pytest.approx(blimp["numpy_s"][0] / blimp["jax_s"][0])
    assert rows["blimp.diagnose_replay.compiled_over_numpy"].value == blimp["speedup"]
    assert "speed-up" in rgblimp.format_table(report)
