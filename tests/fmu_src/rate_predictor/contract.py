"""The rate predictor's own contract, which the pythonfmu and the native rate predictor FMUs both
pass (:class:`RatePredictorContract`), and the factory of their ``case``."""
from __future__ import annotations

from statistics import NormalDist

import numpy as np
import pytest
from fmpy import extract

from tests.fmu_src.contract import FmuCase, Host, run_in_fmpy
from validation.models.narx import one_step


def assert_fast_free_run_within_tolerance(path, theta_1s, *, parallel: bool = False) -> None:
    """The free run of the rate predictor FMU at ``path`` under ``theta_1s`` (at the 0.1 s NARX
    step) on its fast path (``exact_moments = false``: the pair terms of eq. 6 in single
    precision), on two threads if ``parallel``, against its exact path on one: the means and the
    bound half-widths (z sd) within 2 % of the exact run's predicted standard deviation (the fast
    path's tolerance, docs/fmus.md), and different at all, or it would not be the fast path."""
    outputs = [f"{axis}{suffix}" for axis in "pqr" for suffix in ("", "_lower", "_upper")]
    exact, fast = (run_in_fmpy(path, {"theta_1s": theta_1s}, step=0.1, outputs=outputs,
                               start_values={"free_run": True, "exact_moments": e, "parallel": parallel and not e})
                   for e in (True, False))
    means, uppers = [outputs.index(a) for a in "pqr"], [outputs.index(f"{a}_upper") for a in "pqr"]
    half_width = exact[1:, uppers] - exact[1:, means]  # z sd of the exact run
    assert np.max(np.abs(fast[1:, means] - exact[1:, means]) / half_width) <= 0.02
    assert np.max(np.abs((fast[1:, uppers] - fast[1:, means]) - half_width) / half_width) <= 0.02
    assert np.max(np.abs(fast - exact)) > 0.0


def rate_predictor_case(path, trained, recording) -> FmuCase:
    """The rate predictor FMU at ``path`` of the model ``trained`` (a
    :class:`validation.models.narx.TrainedNarx`), driven by the controls and measured rates of
    ``recording`` (the training flight: inside the envelope), against ``one_step``'s predictions
    with 95 % bounds."""
    rows = slice(None, None, trained.config.decimation)
    controls = {n: recording.input(n)[rows] for n in trained.config.inputs}
    rates = {n: recording.output(n)[rows] for n in trained.config.outputs}
    n = len(recording.time[rows])

    def inputs(k):
        return {**{n: v[k] for n, v in controls.items()}, **{f"{n}_prev": v[k] for n, v in rates.items()}}

    def reference():
        prediction = one_step(trained, recording)
        z = NormalDist().inv_cdf(0.975)  # confidence_level 0.95
        columns = []
        for j in range(len(trained.config.outputs)):
            mean, sd = prediction.mean[:, j], np.sqrt(prediction.var[:, j])
            columns += [mean, mean - z * sd, mean + z * sd]
        return np.column_stack(columns), prediction.first

    # tolerance 1e-9 rad/s: the FMU evaluates the same formulas as GaussianProcess.predict in a
    # different order (rounding of order 1e-16 relative; the native FMU's C too, measured 1e-13),
    # far below any physical meaning.
    return FmuCase(path=path, step=trained.step, n_steps=n - 1, inputs=inputs, reference=reference,
                   far_inputs={"theta_1s": 0.3},  # 17 deg of cyclic; trained on +/-1 deg
                   bands=[(f"{a}_lower", f"{a}_upper") for a in trained.config.outputs],
                   bad_inputs=[("theta_1s", float("nan")), ("q_prev", float("inf")),
                               ("theta_1s", 0.6)])  # beyond the declared 0.5 rad


class RatePredictorContract:
    """What every rate predictor FMU does besides the FMU contract: start at the given rates,
    free-run mode (moment matching, belief in the state) and the confidence level; run on the
    ``case`` fixture of the test module."""

    def test_rate_predictor_starts_at_the_given_rates(self, case, tmp_path):
        unzipped = extract(str(case.path), unzipdir=str(tmp_path / "u"))
        host = Host(unzipped)
        try:
            start = {**case.inputs(0), "p_prev": 0.01, "q_prev": -0.02, "r_prev": 0.03}
            outputs = dict(zip(host.outputs, host.start(case, start)))
        finally:
            host.close()
        for axis, value in (("p", 0.01), ("q", -0.02), ("r", 0.03)):
            assert outputs[axis] == outputs[f"{axis}_lower"] == outputs[f"{axis}_upper"] == value

    def test_free_run_mode_equals_the_python_moment_matching_free_run(self, case, bo105_trained, bo105_flights,
                                                                      tmp_path):
        u = bo105_flights["unseen"].input("theta_1s")[::10, None]  # partly outside the envelope
        assert len(u) == case.n_steps + 1
        unzipped = extract(str(case.path), unzipdir=str(tmp_path / "u"))
        host = Host(unzipped)
        free = lambda k: {"theta_1s": u[k, 0]}  # noqa: E731 - the rates are not driven
        half = case.n_steps // 2
        try:
            host.set({"free_run": True, "exact_moments": True})  # the exact path of either FMU
            outputs = np.vstack([host.start(case, free(0)), host.run(case, inputs=free)])
            # The propagated belief is state: saved mid-run and restored, the run repeats exactly.
            host.fmu.reset()
            host.set({"free_run": True, "exact_moments": True})  # the exact path of either FMU
            host.start(case, free(0))
            host.run(case, 0, half, inputs=free)
            state = host.fmu.getFMUstate()
            host.run(case, half, inputs=free)
            host.fmu.setFMUstate(state)
            np.testing.assert_array_equal(host.run(case, half, inputs=free), outputs[half + 1:])
            host.fmu.freeFMUstate(state)
        finally:
            host.close()
        columns = lambda suffix: [host.outputs.index(f"{a}{suffix}") for a in "pqr"]  # noqa: E731
        means, upper = outputs[:, columns("")], outputs[:, columns("_upper")]
        # The FMU starts from rest: every lag before t0 holds the t0 values. GPNarx's moment-matching
        # free run from the same rest (inputs held at u(t0) over the first max_lag - 1 samples) predicts
        # the same rows from its sample max_lag on.
        lag = bo105_trained.model.structure.max_lag
        padded = np.vstack([np.repeat(u[:1], lag - 1, axis=0), u])
        python = bo105_trained.model.free_run(padded, np.tile(means[0], (lag, 1)), method="moment_matching")
        np.testing.assert_allclose(means[1:], python.mean[lag:], rtol=0, atol=1e-9)
        sd = (upper - means) / NormalDist().inv_cdf(0.975)
        np.testing.assert_allclose(sd[1:], np.sqrt(python.var[lag:]), rtol=0, atol=1e-9)
        # Propagated, not one-step: the band at the end of the run is wider than one step ahead.
        assert np.all(sd[-1] > 1.5 * sd[1])

    def test_confidence_level_sets_the_band(self, case, tmp_path):
        unzipped = extract(str(case.path), unzipdir=str(tmp_path / "u"))
        widths = {}
        for level in (0.6827, 0.95):
            host = Host(unzipped, name=f"level{level}")
            try:
                host.set({"confidence_level": level})
                host.start(case)
                row = dict(zip(host.outputs, host.run(case, 0, 5)[-1]))
            finally:
                host.close()
            widths[level] = row["q_upper"] - row["q_lower"]
        z = NormalDist().inv_cdf
        assert widths[0.95] / widths[0.6827] == pytest.approx(z(0.975) / z(0.5 + 0.6827 / 2), rel=1e-12)
