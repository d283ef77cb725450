"""The concealed-effect benchmark of flightgp diagnose (validation.diagnose.bench)."""
import json
import math

import numpy as np
import pytest

from tests.validation.diagnose.test_diagnose import CASE_STEP
from validation.cli import main
from validation.core.errors import BadInputError
from validation.diagnose import diagnose
from validation.diagnose.bench import (
    DURATION,
    REQUIRED_CUT,
    ConcealedCase,
    _polynomial_term_states,
    case_recordings,
    concealed_cases,
    format_seed_summary,
    score_case,
    summarise_seeds,
)
from validation.vehicles.bo105 import STATE_NAMES, Bo105Reference
from validation.vehicles.bo105_effects import identification_manoeuvre
from validation.vehicles.bo105_flight import SENSOR_NOISE_STD
from validation.vehicles.effect_vehicle import EffectVehicle


def test_every_named_effect_kind_is_in_the_suite_at_realistic_magnitude():
    """Realistic magnitudes (docs/diagnose.md, "The concealed-effect benchmark: `flightgp
    diagnose-bench`"): delay >= 40 ms, lag >= 50 ms, derivative changes >= 25 %, biases >= 3x
    noise, a quadratic damping that changes the peak rate by >= 20 %; plus pairs, a no-effect case
    and effects outside the named list."""
    reference = Bo105Reference(80)
    cases = concealed_cases(reference="bo105-80kt")
    kinds = {effect["effect"] for case in cases for effect in case.effects}
    assert kinds == {"time_delay", "input_lag", "control_derivative", "stability_derivative", "sensor_bias",
                     "nonlinear_damping", "dead_band", "backlash", "saturation", "rate_limit", "search_term",
                     "nonlinear_stiffness", "quadratic_stiffness", "sensor_lag", "output_scale", "sensor_drift",
                     "sensor_cross_axis"}
    assert {case.kind for case in cases} == {"single", "pair", "none", "ambiguous", "changing", "turbulence"}
    # Turbulence of each intensity the bench flies, with nothing missing and with an effect.
    assert {c.turbulence for c in cases if c.kind == "turbulence"} == {"light", "moderate"}
    assert {c.turbulence for c in cases if c.kind == "single" and c.turbulence} == {"light", "moderate"}
    assert len({case.name for case in cases}) == len(cases)
    for case in cases:
        for effect in case.effects:
            kind, value = effect["effect"], effect["value"]
            if kind == "time_delay":
                assert value >= 0.04
            elif kind == "input_lag":
                assert value >= 0.05
            elif kind == "sensor_bias":
                assert abs(value) >= 3 * SENSOR_NOISE_STD[effect["output"]] - 1e-15
            elif kind == "sensor_lag":
                assert value >= 0.05
            elif kind == "output_scale":  # a 10 % scale factor error or more
                assert abs(value - 1.0) >= 0.1 - 1e-12
            elif kind == "sensor_drift":  # 3x noise or more by the end of the recording
                assert abs(value) * DURATION >= 3 * SENSOR_NOISE_STD[effect["output"]] - 1e-15
            elif kind == "sensor_cross_axis":  # a misalignment of 1 deg or more
                assert abs(value) >= 0.017
            elif kind == "dead_band":  # 10-30 % of the manoeuvre's 1 deg steps
                assert math.radians(0.1) <= value <= math.radians(0.3) + 1e-15
            elif kind == "backlash":  # 10-40 % of the manoeuvre's 1 deg steps
                assert math.radians(0.1) <= value <= math.radians(0.4) + 1e-15
            elif kind == "saturation":  # 60-80 % of the larger (2 deg) steps of variant 2
                assert case.fit_variant == 2 and math.radians(1.2) <= value <= math.radians(1.6)
            elif kind == "rate_limit":  # bites on the steps: a 1 deg step ramps over at least 5 samples
                assert math.radians(1.0) / value >= 5 * 0.01
            elif kind in ("search_term", "nonlinear_stiffness", "quadratic_stiffness"):
                # moves the held-out flight by >= 3x noise
                time, inputs = identification_manoeuvre(duration=20.0, sample_time=0.01, variant=1)
                moved = (_polynomial_term_states("bo105-80kt", effect["term"], value, time, inputs)
                         - reference.simulate_states(time, inputs))
                noise = np.array([SENSOR_NOISE_STD[name] for name in STATE_NAMES])
                assert np.sqrt(np.mean((moved / noise) ** 2, axis=0)).max() >= 3.0
            elif kind == "nonlinear_damping":  # the peak pitch rate of the manoeuvre changes by >= 20 %
                time, inputs = identification_manoeuvre(duration=20.0, sample_time=0.01)
                q = STATE_NAMES.index("q")
                peaks = [np.abs(states[:, q]).max() for states in (
                    reference.simulate_states(time, inputs),
                    _polynomial_term_states("bo105-80kt", "M_q|q|", value, time, inputs))]
                assert peaks[1] <= 0.8 * peaks[0], peaks
            elif case.kind == "changing":  # the derivative moves by >= 25 % over the flight
                _, _, start, end = case.outside
                assert abs(end - start) >= 0.25 * abs(start) and value == pytest.approx((start + end) / 2)
            else:
                old = reference.derivative(effect["term"])
                assert abs(value - old) >= 0.25 * abs(old) - 1e-12, (effect, old)
    # Each measurement-chain kind at two values.
    for kind in ("sensor_lag", "output_scale", "sensor_drift", "sensor_cross_axis"):
        assert len({e["value"] for c in cases for e in c.effects if e["effect"] == kind}) >= 2, kind
    # Several channels per single-effect kind.
    for kind, key in (("time_delay", "input"), ("input_lag", "input"), ("control_derivative", "term"),
                      ("stability_derivative", "term"), ("sensor_bias", "output")):
        targets = {e[key] for c in cases if c.kind == "single" for e in c.effects if e["effect"] == kind}
        assert len(targets) >= 2, kind


def test_case_recordings_are_the_concealed_vehicle_with_independent_noise():
    case = next(c for c in concealed_cases() if c.name == "delay-theta_1s-60ms")
    recordings = case_recordings(case, seed=3)
    fit, holdout, truth = recordings.fit, recordings.holdout, recordings.truth_states
    time, inputs = identification_manoeuvre(duration=20.0, sample_time=0.01, variant=1)
    np.testing.assert_array_equal(holdout.inputs, inputs)
    expected = EffectVehicle("bo105-80kt", case.effects).simulate_states(time, inputs)
    np.testing.assert_array_equal(truth, expected)
    noise = (holdout.outputs - truth) / np.array([SENSOR_NOISE_STD[n] for n in STATE_NAMES])
    assert abs(noise.std() - 1) < 0.02 and abs(noise.mean()) < 0.02
    fit_noise = fit.outputs - EffectVehicle("bo105-80kt", case.effects).simulate_states(fit.time, fit.inputs)
    assert abs(np.corrcoef(fit_noise[:, 2], noise[:, 2])[0, 1]) < 0.05  # streams differ
    assert fit.metadata["vehicle"] == "bo105-80kt" and "effects" not in fit.metadata  # concealed


def test_outside_effects_change_the_flight_and_the_quadratic_integrator_is_accurate():
    time, inputs = identification_manoeuvre(duration=10.0, sample_time=0.01)
    reference = Bo105Reference(80).simulate_states(time, inputs)
    # With no quadratic term, RK4 at 100 Hz reproduces the exact zero-order-hold solution:
    # local error O(h^5) per step with |lambda| h <= 0.14 for the fastest (roll) mode.
    rk4 = _polynomial_term_states("bo105-80kt", "M_q|q|", 0.0, time, inputs)
    scale = np.abs(reference).max(axis=0)
    assert np.all(np.abs(rk4 - reference).max(axis=0) <= 1e-4 * scale)
    damped = _polynomial_term_states("bo105-80kt", "M_q|q|", -40.0, time, inputs)
    q = STATE_NAMES.index("q")
    assert np.abs(damped[:, q]).max() < 0.9 * np.abs(reference[:, q]).max()
    flown_apart = [case for case in concealed_cases() if case.outside is not None]
    assert len(flown_apart) == 5  # the quadratic damping, both stiffnesses, the control power, the drift: by RK4
    noise = np.array([SENSOR_NOISE_STD[name] for name in STATE_NAMES])
    for case in flown_apart:
        recordings = case_recordings(case)
        replay = Bo105Reference(80).simulate_states(recordings.holdout.time, recordings.holdout.inputs)
        assert (np.abs(recordings.truth_states - replay) / noise).max() > 10, case.name


def test_the_nonlinear_damping_replay_follows_rk4_of_the_continuous_model():
    """bo105-80kt's nonlinear_damping M_q|q| (Heun's mean of the term over each interval, through
    the exact discretisation) against RK4 of x_dot = A x + B u + e_q c q|q| at the same step:
    within 1e-3 of each state's largest excursion (measured 5e-4 on q; holding the term at the
    interval's start instead was 1.5 %). At c = 0 it is the linear replay, bit for bit."""
    from validation.vehicles.effect_vehicle import effect_model

    model = effect_model("bo105-80kt", purpose="test")
    time, inputs = identification_manoeuvre(duration=10.0, sample_time=0.01)
    damped, zero, linear = model.simulate_many([[{"effect": "nonlinear_damping", "term": "M_q|q|", "value": -40.0}],
                                                [{"effect": "nonlinear_damping", "term": "M_q|q|", "value": 0.0}],
                                                []], time, inputs)
    rk4 = _polynomial_term_states("bo105-80kt", "M_q|q|", -40.0, time, inputs)
    assert np.all(np.abs(damped - rk4).max(axis=0) <= 1e-3 * np.abs(rk4).max(axis=0))
    np.testing.assert_array_equal(zero, linear)
    assert "M_q|q|" in model.terms["nonlinear_damping"] and model.model_value("M_q|q|") == 0.0
    assert model.term_unit("M_q|q|") == "(rad/s^2)/(rad/s)^2"
    assert model.term_description("M_q|q|").startswith("pitch moment proportional to q|q|")


def test_a_dead_band_is_a_gain_on_one_amplitude_and_not_on_two():
    """bo105-80kt takes dead bands, input gains and saturations. On the identification manoeuvre
    (theta_1s between trim and 1 deg only) a dead band of w is a gain of 1 - w/A and a limit L a
    gain of L/A, to rounding; on variant 2 (the same 3-2-1-1 again at 2 deg) they differ: the data
    can then tell them apart."""
    from validation.vehicles.effect_vehicle import effect_model

    model = effect_model("bo105-80kt", purpose="test")
    assert {"dead_band", "input_gain", "saturation"} <= set(model.kinds)
    width, amplitude = math.radians(0.3), math.radians(1.0)
    band = {"effect": "dead_band", "input": "theta_1s", "value": width}
    gain = {"effect": "input_gain", "input": "theta_1s", "value": 1 - width / amplitude}
    limit = {"effect": "saturation", "input": "theta_1s", "value": amplitude - width}  # also a gain of 0.7
    one = model.simulate_many([[band], [gain], [limit], []],
                              *identification_manoeuvre(duration=20.0, sample_time=0.01))
    scale = np.abs(one[3]).max(axis=0)
    assert np.all(np.abs(one[0] - one[1]).max(axis=0) <= 1e-12 * scale)
    assert np.all(np.abs(one[2] - one[1]).max(axis=0) <= 1e-12 * scale)
    assert np.abs(one[0] - one[3]).max() > 100 * np.abs(one[0] - one[1]).max()  # the dead band acts
    two = model.simulate_many([[band], [gain], [limit]], *identification_manoeuvre(duration=20.0, sample_time=0.01,
                                                                                     variant=2))
    q = STATE_NAMES.index("q")
    assert np.abs(two[0] - two[1])[:, q].max() > 5 * SENSOR_NOISE_STD["q"]
    assert np.abs(two[2] - two[1])[:, q].max() > 5 * SENSOR_NOISE_STD["q"]
    from validation.vehicles.effects import check_effects

    with pytest.raises(BadInputError, match="a limit cannot be negative"):
        check_effects([{**limit, "value": -0.01}], model)


def test_an_ambiguous_case_passes_when_the_truth_is_offered_and_nothing_false_is_certain(delay_case):
    """A dead band flown on one amplitude: naming it, or naming the gain it cannot be told from
    with the dead band as the alternative and a confidence of at most 0.9, passes; the gain stated
    with confidence 0.95, or without the dead band offered, fails."""
    _, holdout, truth = delay_case
    case = ConcealedCase("a", "ambiguous", ({"effect": "dead_band", "input": "theta_1s", "value": 0.005},))
    band = {"effect": "dead_band", "input": "theta_1s", "value": 0.005, "interval": [0.004, 0.006],
            "confidence": 0.5, "alternatives": [{"effect": "input_gain", "input": "theta_1s", "value": 0.7,
                                                 "evidence_ratio": 1.0}]}
    gain = {"effect": "input_gain", "input": "theta_1s", "value": 0.7, "interval": [0.69, 0.71], "confidence": 0.5,
            "alternatives": [{"effect": "dead_band", "input": "theta_1s", "value": 0.005, "evidence_ratio": 1.0}]}

    def passes(findings):
        return score_case(case, _diagnosis(findings), truth_states=truth, holdout=holdout, reference="bo105-80kt",
                          seconds=0.0).passed

    assert passes([band]) and passes([gain])
    assert not passes([{**gain, "confidence": 0.95}])
    assert not passes([{**gain, "alternatives": []}])


def _input_finding(kind: str, value: float, alternative: str, alternative_value: float, ratio: float) -> dict:
    """A finding on theta_1s (rad) whose first alternative is ``alternative`` at evidence ratio ``ratio``."""
    return {"effect": kind, "input": "theta_1s", "value": value, "interval": [0.98 * value, 1.02 * value],
            "unit": "rad", "confidence": 0.5,
            "alternatives": [{"effect": alternative, "input": "theta_1s", "value": alternative_value,
                              "evidence_ratio": ratio}]}


def _words(finding: dict) -> str:
    from validation.diagnose.report import statement
    from validation.vehicles.effect_vehicle import effect_model

    return statement(finding, {"rmse_reference": {}}, effect_model("bo105-80kt", purpose="test"))


def test_the_statement_says_what_one_amplitude_cannot_tell_and_what_would():
    finding = _input_finding("dead_band", 0.0052, "input_gain", 0.7, 1.0)
    text = _words(finding)
    assert "cannot tell a dead band on theta_1s from a lower gain" in text
    assert "at twice the amplitude" in text
    far = {**finding, "alternatives": [{**finding["alternatives"][0], "evidence_ratio": 50.0}]}
    assert "cannot tell" not in _words(far)
    limit = {**finding, "effect": "saturation", "value": 0.0122}
    assert "cannot tell a saturation on theta_1s from a lower gain" in _words(limit)
    assert "stops at 0.0122 rad" in _words(limit)


def test_free_play_is_said_in_words_and_what_cannot_tell_it_from_a_dead_band():
    finding = _input_finding("backlash", 0.0044, "dead_band", 0.0044, 1.5)
    text = _words(finding)
    assert "Free play (backlash)" in text and "0.0088 rad back across the play" in text
    assert "cannot tell free play on theta_1s from a dead band" in text and "back to where it started" in text
    told = {**finding, "alternatives": [{**finding["alternatives"][0], "evidence_ratio": 50.0}]}
    assert "cannot tell" not in _words(told)
    other_input = {**finding, "alternatives": [{**finding["alternatives"][0], "input": "theta_1c"}]}
    assert "cannot tell" not in _words(other_input)


def test_the_statements_of_a_rate_limit_and_of_an_amplitude_dependent_derivative():
    from validation.diagnose.report import statement
    from validation.vehicles.effect_vehicle import effect_model

    reference = effect_model("bo105-80kt", purpose="test")
    fit = {"rmse_reference": {}}
    rate = {"effect": "rate_limit", "input": "theta_1c", "value": 0.1746, "interval": [0.1741, 0.1751],
            "unit": "rad/s", "alternatives": []}
    assert statement(rate, fit, reference).startswith(
        "A rate limit on theta_1c, the lateral cyclic pitch: it moves no faster than 0.175 rad/s (0.174 to 0.175)")
    check = {"value_small": 0.1416, "value_large": 0.1433, "likelihood_ratio": 41.3, "amplitude_dependent": True,
             "weight_linear": 3e-9}
    derivative = {"effect": "stability_derivative", "term": "N_v", "value": 0.1426, "model_value": 0.128,
                  "interval": [0.1423, 0.1429], "unit": "(rad/s^2)/(m/s)", "main_output": "r", "alternatives": [],
                  "amplitude_check": check}
    text = statement(derivative, fit, reference)
    assert ("the data want 0.143 on the larger yaw rate excursions and 0.142 on the smaller (likelihood ratio 41.3): "
            "the response depends on amplitude, so this is not a linear error for certain") in text
    steady = {**derivative, "amplitude_check": {**check, "amplitude_dependent": False}}
    assert "depends on amplitude" not in statement(steady, fit, reference)


def _diagnosis(findings, rmse=(0.02, 0.004, 0.004)):
    fit = {"outputs": list(STATE_NAMES),
           "rmse_reference": dict.fromkeys(STATE_NAMES, rmse[0]),
           "rmse_corrected": dict.fromkeys(STATE_NAMES, rmse[1]),
           "rmse_corrected_gp": dict.fromkeys(STATE_NAMES, rmse[2])}
    return {"findings": findings, "fit": fit}


@pytest.fixture(scope="module")
def delay_case():
    case = ConcealedCase("d", "single", ({"effect": "time_delay", "input": "theta_1s", "value": 0.06},))
    recordings = case_recordings(case)
    return case, recordings.holdout, recordings.truth_states


def test_score_requires_the_right_target_the_value_in_the_interval_and_the_cut(delay_case):
    case, holdout, truth = delay_case
    score = lambda findings, rmse=(0.02, 0.004, 0.004): score_case(  # noqa: E731
        case, _diagnosis(findings, rmse), truth_states=truth, holdout=holdout,
        reference="bo105-80kt", seconds=1.0)
    right = {"effect": "time_delay", "input": "theta_1s", "value": 0.061, "interval": [0.055, 0.065]}
    good = score([right])
    assert good.named and good.in_interval and good.affected_output == "q" and good.passed
    assert good.cut == pytest.approx(0.8)
    assert not score([{**right, "interval": [0.062, 0.065]}]).passed  # truth outside the interval
    assert not score([{**right, "input": "theta_1c"}]).passed  # wrong channel
    assert not score([{**right, "effect": "input_lag"}]).passed  # wrong kind
    assert not score([right], rmse=(0.02, 0.02 * (1 - REQUIRED_CUT) + 1e-4, 0.0)).passed  # cut too small
    extra = score([right, {"effect": "sensor_bias", "output": "r", "value": 0.01, "interval": [0, 1]}])
    assert extra.false_findings == ["sensor_bias r"] and not extra.passed


def test_score_of_the_no_effect_and_outside_cases(delay_case):
    _, holdout, truth = delay_case
    none = ConcealedCase("none", "none")
    replay = Bo105Reference(80).simulate_states(holdout.time, holdout.inputs)
    assert score_case(none, _diagnosis([]), truth_states=replay, holdout=holdout,
                      reference="bo105-80kt", seconds=0.0).passed
    bias = {"effect": "sensor_bias", "output": "q", "value": 0.01, "interval": [0.0, 0.02]}
    assert not score_case(none, _diagnosis([bias]), truth_states=replay, holdout=holdout,
                          reference="bo105-80kt", seconds=0.0).passed
    outside = ConcealedCase("o", "outside", outside=("dead_band", "theta_1s", math.radians(0.3)))
    unexplained = {"effect": "unexplained", "output": "q", "value": 0.01}
    assert score_case(outside, _diagnosis([unexplained]), truth_states=truth, holdout=holdout,
                      reference="bo105-80kt", seconds=0.0).passed
    assert not score_case(outside, _diagnosis([bias]), truth_states=truth, holdout=holdout,
                          reference="bo105-80kt", seconds=0.0).passed


@pytest.mark.slow
def test_cli_runs_chosen_cases_and_writes_the_scorecard(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["diagnose-bench", "--cases", "none", "delay-theta_1s-60ms", "--duration", "5", "--out", str(out),
                 "--no-progress"]) == 0
    printed = capsys.readouterr().out
    report = json.loads((out / "scorecard.json").read_text())
    assert [row["case"] for row in report["cases"]] == ["delay-theta_1s-60ms", "none"]
    assert (out / "scorecard.txt").read_text().strip() in printed
    # Measured (seed 0): both pass; the delay is named with 60 ms inside its interval.
    delay = report["cases"][0]
    assert delay["named"] and delay["in_interval"] and delay["cut"] >= REQUIRED_CUT
    assert report["cases"][1]["found"] == []


@pytest.mark.slow
def test_a_quadratic_pitch_damping_flown_by_rk4_is_named_first_and_its_correction_cuts_pitch_rate():
    """The case that linear derivatives once absorbed with certainty (M_theta_1s and M_q off by
    30 %): M = -40 q|q| flown by RK4 of the continuous model, diagnosed with the replay's own
    discretisation. The first finding is the nonlinear damping, its value within the interval,
    nothing else is found, and the corrected model cuts held-out pitch-rate RMSE by at least
    60 % (10 s recordings at 33 Hz, which hold the longitudinal 3-2-1-1: measured 94 %, 0.054 ->
    0.0031 rad/s, the sensor noise; interval -40.3 to -39.7; at the bench's 100 Hz the same
    finding, interval -40.1 to -39.8)."""
    case = next(c for c in concealed_cases() if c.name == "quadratic-damping-M_q|q|")
    recordings = case_recordings(case, seed=0, duration=10.0, sample_time=CASE_STEP)
    diagnosis = diagnose([recordings.fit], reference="bo105-80kt", holdout=[recordings.holdout], seed=0).as_dict()
    first = diagnosis["findings"][0]
    assert (first["effect"], first["term"]) == ("nonlinear_damping", "M_q|q|")
    assert first["interval"][0] <= -40.0 <= first["interval"][1]
    assert len(diagnosis["findings"]) == 1
    fit = diagnosis["fit"]
    assert fit["rmse_corrected"]["q"] <= 0.4 * fit["rmse_reference"]["q"]
    assert "proportional to q|q|" in first["statement"]


def test_blimp_fan_thrust_quadratic_in_its_command_is_unexplained():
    """Outside the named list on the blimp: per-direction thrust gains fit the tail fan's u|u|
    thrust at the diagnosed manoeuvre's one amplitude (0.8), not at the held-out one's (0.6)."""
    case = next(c for c in concealed_cases(reference="blimp") if c.name == "outside-quadratic-thrust-u_tail")
    recordings = case_recordings(case, reference="blimp", seed=0)
    result = diagnose([recordings.fit], reference="blimp", holdout=[recordings.holdout], seed=0).as_dict()
    assert score_case(case, result, truth_states=recordings.truth_states, holdout=recordings.holdout,
                      reference="blimp", seconds=0.0).passed
    assert any(f["effect"] == "unexplained" and f["output"] in ("y", "psi", "R") for f in result["findings"])


def _report(seed, rows):
    return {"reference": "bo105-80kt", "seed": seed, "cases": [
        {"case": name, "kind": kind, "passed": passed, "named": named, "in_interval": in_ci,
         "false_findings": false, "says_unexplained": False, "cut": cut, "seconds": 1.0 + seed}
        for name, kind, passed, named, in_ci, false, cut in rows]}


def test_seed_summary_counts_rates_over_runs():
    reports = [_report(0, [("d", "single", True, True, True, [], 0.9), ("none", "none", True, False, False, [], None)]),
               _report(1, [("d", "single", False, True, False, [], 0.8),
                           ("none", "none", False, False, False, ["sensor_bias q"], None)])]
    summary = summarise_seeds(reports)
    d, none = summary["cases"]
    assert (d["runs"], d["passed"], d["named"], d["in_interval"]) == (2, 1, 2, 1)
    assert d["median_cut"] == pytest.approx(0.85) and d["max_seconds"] == 2.0
    assert none["with_false_findings"] == 1 and none["median_cut"] is None
    assert (summary["passed"], summary["total"], summary["seeds"]) == (2, 4, [0, 1])
    assert summary["interval_coverage"] == 0.5
    table = format_seed_summary(summary)
    assert "2 of 4 runs pass" in table and "50%" in table


def test_cli_with_several_seeds_writes_the_runs_and_their_summary(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["diagnose-bench", "--cases", "none", "--seed", "0", "1", "--duration", "5", "--out", str(out),
                 "--no-progress"]) == 0
    report = json.loads((out / "scorecard.json").read_text())
    assert [run["seed"] for run in report["runs"]] == [0, 1]
    assert report["summary"]["cases"][0]["runs"] == 2
    assert "over seeds 0, 1" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["--cases", "no-such-case"], "unknown case(s) no-such-case"),
    (["--reference", "blimp-flight"], "bo105-<V>kt, blimp, rgblimp, state-space FILE.json and FILE.fmu references"),
    (["--reference", "bo105-85kt"], "no Bo105 model at 85 kt"),
    (["--duration", "2"], "--duration must be at least 5 s"),
    (["--workers", "0"], "--workers must be at least 1"),
    (["--through", "missing.fmu", "--cases", "none"], "missing.fmu: no such FMU"),
    (["--input-terms", "--cases", "none"], "--input-terms is for a diagnosis --through an FMU"),
    (["--through", "bo105-80kt", "--input-terms", "--cases", "none"], "input terms are for an FMU reference"),
])
def test_cli_bad_input_exits_2(argv, message, tmp_path, capsys):
    assert main(["diagnose-bench", *argv, "--out", str(tmp_path / "o")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.fixture(scope="module")
def bo105_fmu(tmp_path_factory):
    from fmu_src import build_bo105_reference_fmu

    return str(build_bo105_reference_fmu(80, tmp_path_factory.mktemp("bench_fmu")))


def test_the_truth_as_a_diagnosis_through_another_reference_names_it(bo105_fmu, tmp_path):
    """Through the Bo105 reference FMU a derivative is the FMU parameter of the same name and a
    dead band stays a dead band; through a state-space JSON of the
    same model every case is unchanged; an effect the diagnosing reference cannot name is an
    outside case where the case is flown apart from its effects, else a BadInputError."""
    from validation.core.errors import BadInputError
    from validation.diagnose.bench import diagnosed_truth
    from validation.vehicles.effect_vehicle import effect_model

    cases = {case.name: case for case in concealed_cases(reference="bo105-80kt")}
    through_fmu = effect_model(bo105_fmu, purpose="test")
    pair = diagnosed_truth(cases["pair-lag+M_q"], through_fmu)
    assert pair.kind == "pair" and [e["effect"] for e in pair.effects] == ["input_lag", "fmu_parameter"]
    assert pair.effects[1]["term"] == "M_q" and pair.effects[1]["value"] == cases["pair-lag+M_q"].effects[1]["value"]
    # Every case of the suite has a truth through the FMU (the saturation too: the FMU takes it).
    assert all(diagnosed_truth(case, through_fmu).name == name for name, case in cases.items())
    assert diagnosed_truth(cases["saturation-theta_1s-1.4deg"], through_fmu) == cases["saturation-theta_1s-1.4deg"]
    dead_band = diagnosed_truth(cases["dead-band-theta_1s-one-amplitude"], through_fmu)
    assert dead_band == cases["dead-band-theta_1s-one-amplitude"]  # the FMU takes dead bands too
    # The quadratic damping is a named effect of bo105-80kt but not of the FMU; it is flown by
    # RK4 apart from its effects, so through the FMU it is an outside case.
    damping = diagnosed_truth(cases["quadratic-damping-M_q|q|"], through_fmu)
    assert damping.kind == "outside" and damping.effects == () and damping.outside[0] == "polynomial_term"
    # Flown on the linear reference, whose control derivatives map a term on the FMU's inputs
    # onto its rows, it is a case for the residual search through the inputs.
    flown_on = effect_model("bo105-80kt", purpose="test")
    assert diagnosed_truth(cases["quadratic-damping-M_q|q|"], through_fmu, flown_on=flown_on) == damping
    through_fmu.take_input_terms()  # asked for: polynomial terms are through_inputs cases
    through_inputs = diagnosed_truth(cases["quadratic-damping-M_q|q|"], through_fmu, flown_on=flown_on)
    assert through_inputs.kind == "through_inputs" and through_inputs.outside == damping.outside
    assert diagnosed_truth(cases["delay-theta_1s-60ms"], through_fmu, flown_on=flown_on) == cases["delay-theta_1s-60ms"]
    state_space = tmp_path / "bo105.json"
    assert main(["state-space", "bo105-80kt", "--out", str(state_space)]) == 0
    linear = effect_model(str(state_space), purpose="test")
    assert all(diagnosed_truth(case, linear) == case for case in cases.values())
    blimp_case = ConcealedCase("x", "single", ({"effect": "quadratic_drag", "term": "X_UU", "value": -1.0},))
    with pytest.raises(BadInputError, match="cannot name quadratic_drag X_UU"):
        diagnosed_truth(blimp_case, through_fmu)


def test_a_turbulence_case_diagnosed_through_an_fmu_flies_its_findings_on_the_fmu(bo105_fmu, delay_case):
    """In a turbulence case the corrected model's held-out RMSE flies the findings: through an
    FMU they are its own (an FMU parameter, which the flying reference does not take), so they
    are flown on the FMU, and a larger pitch damping moves the held-out pitch rate."""
    case, holdout, truth = delay_case
    windy = ConcealedCase("w", "single", case.effects, turbulence="light")
    finding = {"effect": "fmu_parameter", "term": "M_q", "value": -3.0, "interval": [-3.1, -2.9],
               "in_corrected_model": True}
    score = score_case(windy, _diagnosis([finding]), truth_states=truth, holdout=holdout, reference="bo105-80kt",
                       seconds=0.0, diagnosed_on=bo105_fmu)
    assert score.rmse_reference > 0 and score.rmse_corrected > 0 and score.rmse_corrected != score.rmse_reference


def test_a_term_found_through_the_inputs_is_mapped_onto_the_rows_by_the_control_derivatives():
    """M_q|q| = -40 through the cyclic inputs: search terms of the factor q|q| whose values, times
    the pitch row's control derivatives, sum to -40 within 10 % name it, with or without the
    truth inside their mapped interval; 20 % off, or none found, do not. Terms of another factor,
    or on an input that does not move the pitch row, are not counted."""
    from validation.diagnose.bench import _mapped_through_inputs
    from validation.vehicles.bo105 import Bo105Reference

    linear = Bo105Reference(80)
    pitch_1s, pitch_1c = linear.B[2, 1], linear.B[2, 2]  # q is state 2; theta_1s, theta_1c inputs 1, 2
    outside = ("polynomial_term", "M_q|q|", -40.0)
    lateral = {"effect": "search_term", "term": "theta1c_q|q|", "value": 0.25, "interval": [0.2499, 0.2501]}
    others = [{"effect": "search_term", "term": "theta1s_q^3", "value": 9.0, "interval": [8.0, 10.0]},
              {"effect": "fmu_parameter", "term": "L_v", "value": -0.27, "interval": [-0.28, -0.26]}]
    exact = -(40.0 + pitch_1c * 0.25) / pitch_1s
    for value, expected in ((exact, (True, True)), (1.05 * exact, (True, False)), (1.2 * exact, (False, False))):
        term = {"effect": "search_term", "term": "theta1s_q|q|", "value": value,
                "interval": [value - 0.01, value + 0.01]}
        assert _mapped_through_inputs([term, lateral, *others], outside, linear) == ([term, lateral], *expected)
    assert linear.B[2, 3] == 0  # the tail rotor does not pitch the model: its term is not counted
    tail = {"effect": "search_term", "term": "theta0T_q|q|", "value": 1.0, "interval": [0.9, 1.1]}
    assert _mapped_through_inputs([tail], outside, linear) == ([], False, False)
    assert _mapped_through_inputs(others, outside, linear) == ([], False, False)


def test_the_fmu_suite_acts_on_the_fmus_own_inputs_and_outputs(bo105_fmu):
    cases = concealed_cases(reference=bo105_fmu)
    assert [case.name for case in cases] == ["delay-theta_0-100ms", "lag-theta_1s-150ms", "bias-q-5sd", "none"]
    assert cases[2].effects[0]["value"] == pytest.approx(5 * 0.003)  # the stand-in's rate noise


def test_the_cli_scores_cases_through_another_reference(bo105_fmu, tmp_path, capsys):
    """``--through``: the no-effect case flown on bo105-80kt and diagnosed through the Bo105
    reference FMU (5 s recordings) is consistent, and the scorecard says what it went through."""
    out = tmp_path / "bench"
    assert main(["diagnose-bench", "--cases", "none", "--through", bo105_fmu, "--duration", "5",
                 "--workers", "1", "--out", str(out), "--no-progress"]) == 0
    report = json.loads((out / "scorecard.json").read_text())
    assert report["through"] == bo105_fmu and report["duration_s"] == 5.0 and report["cases"][0]["passed"]
    assert f"through {bo105_fmu}" in capsys.readouterr().out
