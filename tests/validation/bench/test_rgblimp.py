"""validation.bench.rgblimp: the RGBlimp JAX free run and diagnose's compiled replay against numpy,
the checkpointed gradient against the stored one, and the hybrid's fit time."""
import numpy as np
import pytest

from validation.bench import rgblimp
from validation.models.rgblimp_identification import RGBlimpModel
from validation.models.rgblimp_rollout import RolloutSetup, gradient_call, initial_correction
from validation.vehicles.rgblimp_data import EXCERPT_FOLDER, read_rgblimp_flight


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
    gradient = report["gradient"]
    assert len(gradient["checkpointed_s"]) == len(gradient["stored_s"]) == 1
    assert gradient["speedup"] == pytest.approx(gradient["stored_s"][0] / gradient["checkpointed_s"][0])
    assert rows["rgblimp.hybrid.gradient.checkpointed_over_stored"].value == gradient["speedup"]
    assert "speed-up" in rgblimp.format_table(report)


@pytest.mark.slow
def test_the_checkpointed_gradient_equals_the_stored_one():
    # The benchmark's two gradients (compiled already by the test above in this process, same
    # shapes) are one gradient computed two ways: equal to rounding in every parameter (a component
    # near zero to 1e-10 of its array's largest).
    fitting = [read_rgblimp_flight(EXCERPT_FOLDER / f"data_{n}.csv") for n in (117, 118)]
    small = RolloutSetup(inducing_points=8, segment_duration=2.0, max_segments=8, max_iterations=2)
    correction = initial_correction(fitting, small)
    correction["whitened"] = np.random.default_rng(0).normal(size=correction["whitened"].shape)
    loss, gradient = gradient_call(fitting, RGBlimpModel(), setup=small, correction=correction)()
    peer_loss, peer_gradient = gradient_call(fitting, RGBlimpModel(), setup=small, correction=correction,
                                             checkpoint_steps=False)()
    assert np.abs(gradient["correction"]["inducing"]).max() > 0  # the correction's path is exercised
    assert loss == pytest.approx(peer_loss, rel=1e-12)
    for part in ("physics", "correction"):
        for name, value in gradient[part].items():
            np.testing.assert_allclose(value, peer_gradient[part][name], rtol=1e-9, atol=1e-10 * np.abs(value).max())
