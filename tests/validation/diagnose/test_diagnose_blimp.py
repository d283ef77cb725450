"""flightgp diagnose on the blimp: its named effects do what validation.vehicles.blimp_effects says
(against the reference ODE with changed parameters, on even and on jittered frame times),
concealed effects are named with their values (also on unevenly sampled recordings), and blimp
recordings with bad columns exit 2."""
import dataclasses
import json
import math

import numpy as np
import pytest
from scipy import integrate, signal

from tests.validation.diagnose.test_diagnose import _check_named, _write_table  # shared with the Bo105 tests
from validation.cli import main
from validation.core.errors import BadInputError
from validation.core.recordings import write_recording
from validation.diagnose import diagnose
from validation.diagnose.bench import concealed_cases
from validation.diagnose.noise import estimate_noise_sd
from validation.vehicles.blimp import SAMPLE_TIME, BlimpParameters, BlimpReference, hanging_state
from validation.vehicles.blimp_effects import SENSOR_NOISE_STD, identification_manoeuvre, simulate_batch
from validation.vehicles.blimp_equations import blimp_dynamics, mass_matrix
from validation.vehicles.effect_vehicle import EffectVehicle

DEFAULT = BlimpParameters()


@pytest.fixture(scope="module")
def manoeuvre():
    return identification_manoeuvre(duration=12.0)


def _states(effects, time, inputs):
    return EffectVehicle("blimp", effects).simulate_states(time, inputs)


def _reference(time, inputs, **changes):
    """The reference ODE with changed parameters, RK4 at the recording interval (as the effects)."""
    params = dataclasses.replace(DEFAULT, **changes)
    return BlimpReference(params=params, max_step=SAMPLE_TIME).simulate_states(time, inputs)


def test_no_effect_is_the_reference_at_the_recording_interval(manoeuvre):
    time, inputs = manoeuvre
    np.testing.assert_allclose(_states([], time, inputs), _reference(time, inputs), rtol=0, atol=1e-12)


@pytest.mark.parametrize("effect, changes", [
    ({"effect": "quadratic_drag", "term": "X_UU", "value": -0.2},
     {"quadratic_drag": (0.2, *DEFAULT.quadratic_drag[1:])}),
    ({"effect": "stability_derivative", "term": "N_R", "value": -0.03},
     {"rotational_damping": (*DEFAULT.rotational_damping[:2], 0.03)}),
    ({"effect": "force_offset", "term": "Z_0", "value": 0.004}, {"net_lift": -0.004}),
    ({"effect": "control_derivative", "term": "gondola_thrust_backward", "value": 0.05},
     {"gondola_thrust_backward": 0.05}),
    ({"effect": "control_derivative", "term": "tail_thrust_negative", "value": 0.02},
     {"tail_thrust_negative": 0.02}),
])
def test_term_effects_equal_the_changed_parameter(manoeuvre, effect, changes):
    """Each term is the BlimpParameters entry it documents (same ODE, same RK4: rounding only)."""
    time, inputs = manoeuvre
    expected = _reference(time, inputs, **changes)
    got = _states([effect], time, inputs)
    assert np.abs(expected - _states([], time, inputs)).max() > 1e-3  # the change is visible
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10)


def test_compiled_replay_equals_the_numpy_step_for_every_effect_kind(manoeuvre):
    """validation.vehicles.blimp_jax against the numpy RK4 step, members changing every term and
    input effect, on jittered frame times (rounding only)."""
    time, inputs = manoeuvre
    time = _jittered(time, seed=5)
    lists = [[], [{"effect": "input_lag", "input": "u_gondola", "value": 0.3},
                  {"effect": "time_delay", "input": "u_tail", "value": 0.13}],
             [{"effect": "control_derivative", "term": "gondola_thrust_forward", "value": 0.05},
              {"effect": "stability_derivative", "term": "N_R", "value": -0.03},
              {"effect": "quadratic_drag", "term": "X_UU", "value": -0.2}],
             [{"effect": "force_offset", "term": "Z_0", "value": 0.004},
              {"effect": "force_offset", "term": "N_0", "value": 0.001},
              {"effect": "sensor_bias", "output": "Q", "value": 0.01}],
             [{"effect": "dead_band", "input": "u_gondola", "value": 0.2},
              {"effect": "rate_limit", "input": "u_tail", "value": 2.0},
              {"effect": "control_derivative", "term": "tail_thrust_negative", "value": 0.02}],
             [{"effect": "search_term", "term": "M_U*Q", "value": 0.05},
              {"effect": "search_term", "term": "N_V|V|", "value": 0.2},
              {"effect": "search_term", "term": "X_u_gondola^3", "value": 0.01},
              {"effect": "search_term", "term": "L_phi", "value": -0.002}]]
    compiled = simulate_batch(REFERENCE, lists, time, inputs)
    numpy_step = simulate_batch(REFERENCE, lists, time, inputs, compiled=False)
    assert np.abs(numpy_step[1:] - numpy_step[0]).max() > 1e-2  # every member changes the flight
    np.testing.assert_allclose(compiled, numpy_step, rtol=0, atol=1e-12)


def test_search_terms_are_the_generalised_forces_they_name(manoeuvre):
    """A search term adds ``value * factor`` to its row's force or moment: a linear one on a rate
    is the damping derivative, a signed square of a velocity the quadratic drag, and a product
    and a cube of a command equal an independent integration of the ODE with that force added
    (scipy's adaptive Runge-Kutta, the inputs held over each interval)."""
    time, inputs = manoeuvre
    for term, named, change in (("N_R", {"effect": "stability_derivative", "term": "N_R"}, -0.02),
                                ("Y_V|V|", {"effect": "quadratic_drag", "term": "Y_VV"}, -1.0)):
        model = -(DEFAULT.rotational_damping[2] if term == "N_R" else DEFAULT.quadratic_drag[1])
        searched = simulate_batch(REFERENCE, [[{"effect": "search_term", "term": term, "value": change}]], time, inputs)
        changed = simulate_batch(REFERENCE, [[{**named, "value": model + change}]], time, inputs)
        assert np.abs(searched - _states([], time, inputs)).max() > 1e-3
        np.testing.assert_allclose(searched, changed, rtol=0, atol=1e-12)
    terms = [{"effect": "search_term", "term": "M_U*Q", "value": 0.05},
             {"effect": "search_term", "term": "Y_u_gondola^3", "value": 0.004}]
    time, inputs = time[:121], inputs[:121]  # the gondola's steps (6 s)
    _, inverse = mass_matrix(DEFAULT.mass, DEFAULT.added_mass, DEFAULT.inertia, DEFAULT.added_inertia,
                             DEFAULT.cg_position)

    def exact(gain):
        def rates(_, state, command):
            force = np.zeros(6)
            force[4] = gain * 0.05 * state[6] * state[10]
            force[1] = gain * 0.004 * command[0] ** 3
            return blimp_dynamics(state[None], command[None], DEFAULT)[0] + np.concatenate([np.zeros(6),
                                                                                            inverse @ force])

        state, states = hanging_state(DEFAULT), [hanging_state(DEFAULT)]
        for k in range(len(time) - 1):
            state = integrate.solve_ivp(rates, (time[k], time[k + 1]), state, args=(inputs[k],), rtol=1e-11,
                                        atol=1e-13).y[:, -1]
            states.append(state)
        return np.array(states)

    # What the terms change, by RK4 at 20 Hz and exactly (the integrators' own errors, 3e-6, cancel).
    got = simulate_batch(REFERENCE, [terms], time, inputs)[0] - _states([], time, inputs)
    expected = exact(1.0) - exact(0.0)
    assert np.abs(expected).max() > 1e-2
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-3 * np.abs(expected).max())


def test_whole_sample_delay_equals_shifted_input_and_small_lags_vanish(manoeuvre):
    time, inputs = manoeuvre
    shifted = inputs.copy()
    shifted[:, 2] = np.concatenate([np.zeros(3), inputs[:-3, 2]])
    expected = _states([], time, shifted)
    delayed = _states([{"effect": "time_delay", "input": "u_tail", "value": 3 * SAMPLE_TIME}], time, inputs)
    np.testing.assert_allclose(delayed, expected, rtol=0, atol=1e-12)
    # A lag is continuous at T = 0: interval means differ from the input by O(T/h) of each
    # command step (2e-5 here), so states by about as much times the step's effect.
    plain, tiny = _states([], time, inputs), _states([{"effect": "input_lag", "input": "u_gondola",
                                                        "value": 1e-6}], time, inputs)
    np.testing.assert_allclose(tiny, plain, rtol=0, atol=1e-5)


def test_lag_keeps_the_final_value():
    time = np.arange(0, 30.0, SAMPLE_TIME)
    inputs = np.zeros((len(time), 3))
    inputs[20:, 0] = 0.5  # gondola step; surge speed settles against quadratic drag in ~15 s
    plain = _states([], time, inputs)
    lagged = _states([{"effect": "input_lag", "input": "u_gondola", "value": 0.3}], time, inputs)
    assert lagged[30, 6] < plain[30, 6]
    assert lagged[-1, 6] == pytest.approx(plain[-1, 6], rel=0.01)


def test_blimp_model_file_round_trip(tmp_path, manoeuvre):
    time, inputs = manoeuvre
    vehicle = EffectVehicle("blimp", [{"effect": "force_offset", "term": "N_0", "value": 0.001},
                                      {"effect": "input_lag", "input": "mu", "value": 0.2}])
    loaded = EffectVehicle.load(vehicle.save(tmp_path / "model.json"))
    assert loaded.effects == vehicle.effects
    np.testing.assert_array_equal(loaded.simulate_states(time, inputs), vehicle.simulate_states(time, inputs))


def _concealed(effects):
    vehicle = EffectVehicle("blimp", effects, noise_sd=SENSOR_NOISE_STD)
    fit = vehicle.simulate(*identification_manoeuvre(variant=0), seed=1)
    held = vehicle.simulate(*identification_manoeuvre(variant=1), seed=2)
    return fit, held


def test_no_effect_on_the_blimp_is_consistent():
    fit, held = _concealed([])
    result = diagnose([fit], reference="blimp", holdout=[held]).as_dict()
    assert result["verdict"] == "consistent" and result["findings"] == []
    for name in result["fit"]["outputs"]:  # held-out error is the sensor noise (20 % margin)
        assert result["fit"]["rmse_reference"][name] < 1.2 * SENSOR_NOISE_STD[name]


def test_command_limits_are_the_reference_flown_with_the_shaped_commands(manoeuvre):
    """A dead band, a limit and a rate limit on a blimp input are the reference flown with the
    command through them (built independently here; the rate limit as the exact interval means
    of the ramps), to rounding, and each changes the flight."""
    from validation.vehicles.effects import rate_limited_interval_means

    time, inputs = manoeuvre
    banded, limited, ramped = inputs.copy(), inputs.copy(), inputs.copy()
    banded[:, 0] = np.sign(inputs[:, 0]) * np.maximum(np.abs(inputs[:, 0]) - 0.2, 0.0)
    limited[:, 0] = np.clip(inputs[:, 0], -0.6, 0.6)
    ramped[:-1, 2] = rate_limited_interval_means(inputs[:-1, 2], 2.0, np.diff(time))
    plain = _states([], time, inputs)
    for effect, flown in (({"effect": "dead_band", "input": "u_gondola", "value": 0.2}, banded),
                          ({"effect": "saturation", "input": "u_gondola", "value": 0.6}, limited),
                          ({"effect": "rate_limit", "input": "u_tail", "value": 2.0}, ramped)):
        got = _states([effect], time, inputs)
        np.testing.assert_allclose(got, _states([], time, flown), rtol=0, atol=1e-12)
        assert np.abs(got - plain).max() > 1e-3, effect
    # One order whatever the list's: a limit then a rate limit on the same input.
    both = [{"effect": "rate_limit", "input": "u_gondola", "value": 1.0},
            {"effect": "saturation", "input": "u_gondola", "value": 0.6}]
    np.testing.assert_array_equal(_states(both, time, inputs), _states(both[::-1], time, inputs))


BLIMP_CASES = {
    "quadratic_drag": [{"effect": "quadratic_drag", "term": "X_UU", "value": 1.5 * -DEFAULT.quadratic_drag[0]}],
    "buoyancy": [{"effect": "force_offset", "term": "Z_0", "value": 0.003}],
    "tail_lag": [{"effect": "input_lag", "input": "u_tail", "value": 0.3}],
    # On no named list: the residual search finds it.
    "pitch_moment_in_U": [{"effect": "search_term", "term": "M_U", "value": 0.02}],
}


@pytest.mark.slow
@pytest.mark.parametrize("case", BLIMP_CASES)
def test_concealed_blimp_effect_is_named_with_its_value(case):
    fit, held = _concealed(BLIMP_CASES[case])
    _check_named(diagnose([fit], reference="blimp", holdout=[held]).as_dict(), BLIMP_CASES[case])


@pytest.mark.slow
def test_cli_names_a_gondola_delay_and_writes_a_loadable_blimp_model(tmp_path, capsys):
    truth = [{"effect": "time_delay", "input": "u_gondola", "value": 0.15}]
    fit, held = _concealed(truth)
    write_recording(tmp_path / "fit.csv", fit)
    write_recording(tmp_path / "held.csv", held)
    out = tmp_path / "out"
    assert main(["diagnose", str(tmp_path / "fit.csv"), "--holdout", str(tmp_path / "held.csv"),
                 "--reference", "blimp", "--out", str(out), "--no-progress"]) == 0
    result = json.loads((out / "diagnosis.json").read_text())
    _check_named(result, truth)
    corrected = EffectVehicle.load(out / "corrected_model.json")
    assert corrected.reference_name == "blimp" and corrected.effects[0]["input"] == "u_gondola"
    assert (out / "holdout_x.png").read_bytes()[:4] == b"\x89PNG"
    assert "u_gondola, the gondola fan command" in capsys.readouterr().out


@pytest.mark.parametrize("problem, expected", [
    ("missing_input", "missing input column(s) 'u_tail'"),
    ("bo105_columns", "another vehicle"),
])
def test_bad_blimp_recordings_exit_2_with_one_line(tmp_path, capsys, problem, expected):
    time = np.arange(0, 4.0, SAMPLE_TIME)
    if problem == "missing_input":
        header = ["time", "u_gondola", "mu", "x", "U"]
        rows = [[t, 0.5 * (t > 1), 0.0, 0.0, 0.0] for t in time]
    else:
        header = ["time", "theta_0", "theta_1s", "theta_1c", "theta_0T", "q"]
        rows = [[t, 0.0, 0.01 * (t > 0.5), 0.0, 0.0, 0.0] for t in time]
    path = _write_table(tmp_path / "bad.csv", header, rows)
    out = tmp_path / "out"
    assert main(["diagnose", str(path), "--reference", "blimp", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert expected in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_blimp_bench_suite_covers_every_blimp_effect_kind():
    cases = concealed_cases(reference="blimp")
    kinds = {effect["effect"] for case in cases for effect in case.effects}
    assert kinds == {"time_delay", "input_lag", "control_derivative", "stability_derivative",
                     "quadratic_drag", "force_offset", "sensor_bias", "saturation", "rate_limit", "search_term"}
    assert {case.kind for case in cases} == {"single", "pair", "none", "outside"}
    assert len({case.name for case in cases}) == len(cases)


# -- unevenly sampled recordings (motion capture with frame-timing jitter) ---------------------

def _jittered(time, *, seed, sd=0.004):
    """``time`` with the blimp-flight stand-in's frame jitter (4 ms, clipped to a quarter of the
    interval, first frame on time; validation.vehicles.blimp_flight.BlimpFlightTest)."""
    jitter = np.clip(np.random.default_rng(seed).normal(0.0, sd, len(time)), -SAMPLE_TIME / 4, SAMPLE_TIME / 4)
    jitter[0] = 0.0
    return time + jitter


REFERENCE = BlimpReference()


def _held_states(time, held_means):
    """The reference with the interval means ``held_means`` (n - 1, 3) as its inputs."""
    return simulate_batch(REFERENCE, [[]], time, np.vstack([held_means, held_means[-1]]))[0]


def test_even_steps_equal_the_fixed_step_formulas(manoeuvre):
    """On an even grid the per-interval integrator equals the fixed-step formulas: delay
    ``(1 - f) u[k-m] + f u[k-m-1]``, lag by a constant-coefficient filter with
    ``a = exp(-h/T)`` and mean ``u + (z - u) (T/h) (1 - a)``; states to rounding (1e-12 on
    states of order 1, against 1e-14 measured)."""
    time, inputs = manoeuvre
    h = SAMPLE_TIME
    delay, lag_gondola, delay_mu, lag_mu = 0.13, 0.3, 0.07, 0.2

    def fixed_step_delay(u, tau):
        whole = int(math.floor(tau / h + 1e-9))
        fraction = tau / h - whole
        padded = np.concatenate([np.zeros(whole + 1), u])
        return (1 - fraction) * padded[1:len(u) + 1] + fraction * padded[:len(u)]

    def fixed_step_lag(u, tau):
        a = math.exp(-h / tau)
        z = signal.lfilter([0.0, 1.0 - a], [1.0, -a], u)
        return u + (z - u) * tau / h * (1 - a)

    means = inputs.copy()
    means[:, 0] = fixed_step_lag(inputs[:, 0], lag_gondola)
    means[:, 1] = fixed_step_lag(fixed_step_delay(inputs[:, 1], delay_mu), lag_mu)
    means[:, 2] = fixed_step_delay(inputs[:, 2], delay)
    effects = [{"effect": "input_lag", "input": "u_gondola", "value": lag_gondola},
               {"effect": "time_delay", "input": "mu", "value": delay_mu},
               {"effect": "input_lag", "input": "mu", "value": lag_mu},
               {"effect": "time_delay", "input": "u_tail", "value": delay}]
    got = _states(effects, time, inputs)
    assert np.abs(got - _states([], time, inputs)).max() > 1e-3  # the effects are visible
    np.testing.assert_allclose(got, _held_states(time, means[:-1]), rtol=0, atol=1e-12)


def test_jittered_frames_are_one_rk4_step_per_interval(manoeuvre):
    """On jittered times the replay is the reference's RK4 with one step per actual interval,
    with and without a term effect (rounding only)."""
    time, inputs = manoeuvre
    time = _jittered(time, seed=3)
    single_step = BlimpReference(max_step=1.0)  # never splits an interval
    np.testing.assert_allclose(_states([], time, inputs), single_step.simulate_states(time, inputs),
                               rtol=0, atol=1e-12)
    drag = BlimpReference(params=dataclasses.replace(DEFAULT, quadratic_drag=(0.2, *DEFAULT.quadratic_drag[1:])),
                          max_step=1.0)
    np.testing.assert_allclose(_states([{"effect": "quadratic_drag", "term": "X_UU", "value": -0.2}], time, inputs),
                               drag.simulate_states(time, inputs), rtol=0, atol=1e-10)


def test_jittered_delay_and_lag_are_exact_interval_means(manoeuvre):
    """On jittered times a delay holds the exact mean of the delayed zero-order-held input over
    each interval (cut at the delayed switch times), and a lag the exact mean of
    ``T z_dot = -z + u`` (here solved with its integral by scipy's DOP853 at rtol 1e-11)."""
    time, inputs = manoeuvre
    time = _jittered(time, seed=4)
    tau, lag = 0.137, 0.25

    def delayed_means(u):
        means = []
        for start, stop in zip(time[:-1], time[1:]):
            edges = np.unique(np.clip(np.concatenate(([start, stop], time + tau)), start, stop))
            rows = np.searchsorted(time, 0.5 * (edges[:-1] + edges[1:]) - tau, side="right") - 1
            values = np.where(rows >= 0, u[np.maximum(rows, 0)], 0.0)
            means.append(np.sum(values * np.diff(edges)) / (stop - start))
        return np.array(means)

    def lagged_means(u):
        state, means = np.zeros(2), []  # z and its integral
        for k, (start, stop) in enumerate(zip(time[:-1], time[1:])):
            solution = integrate.solve_ivp(lambda _t, y, held=u[k]: [(held - y[0]) / lag, y[0]], (start, stop),
                                           state, method="DOP853", rtol=1e-11, atol=1e-13)
            means.append((solution.y[1, -1] - state[1]) / (stop - start))
            state = solution.y[:, -1]
        return np.array(means)

    means = inputs[:-1].copy()
    means[:, 2] = delayed_means(inputs[:, 2])
    means[:, 0] = lagged_means(inputs[:-1, 0])
    effects = [{"effect": "time_delay", "input": "u_tail", "value": tau},
               {"effect": "input_lag", "input": "u_gondola", "value": lag}]
    # The ODE solution's error (~1e-11 per interval) bounds the agreement.
    np.testing.assert_allclose(_states(effects, time, inputs), _held_states(time, means), rtol=0, atol=1e-9)


def test_noise_estimator_handles_an_uneven_design():
    """Gasser et al.'s pseudo-residuals on jittered times recover white noise on a drifting
    signal that the even-grid weights misread (jitter times slope looks like noise: 4 ms at
    0.5 m/s is 2 mm against 1 mm of noise); on an even grid both weightings agree."""
    rng = np.random.default_rng(0)
    time = _jittered(np.arange(0, 40, SAMPLE_TIME), seed=5)
    # Locally linear at 20 Hz: curvature h^2 y'' <= 2e-5 m, far below the noise.
    smooth = 0.5 * time + 0.3 * np.sin(0.3 * time)
    measured = smooth + 0.001 * rng.standard_normal(len(time))
    # 800 samples: the MAD estimate's relative sd is about 1.65/sqrt(800) = 6 %; 2.5 sigma.
    assert estimate_noise_sd(measured, time=time) == pytest.approx(0.001, rel=0.15)
    assert estimate_noise_sd(measured) > 1.5e-3
    even = np.arange(0, 40, SAMPLE_TIME)
    y = np.sin(even) + 0.001 * rng.standard_normal(len(even))
    assert estimate_noise_sd(y, time=even) == pytest.approx(estimate_noise_sd(y), rel=1e-9)


def _jittered_recordings(effects, *, duration=20.0):
    vehicle = EffectVehicle("blimp", effects, noise_sd=SENSOR_NOISE_STD)
    fit_time, fit_inputs = identification_manoeuvre(duration=duration, variant=0)
    held_time, held_inputs = identification_manoeuvre(duration=duration, variant=1)
    return (vehicle.simulate(_jittered(fit_time, seed=10), fit_inputs, seed=1),
            vehicle.simulate(_jittered(held_time, seed=11), held_inputs, seed=2))


def test_jittered_blimp_recording_without_effect_is_consistent():
    fit, held = _jittered_recordings([], duration=12.0)
    assert fit.metadata["uneven_sampling"] is True
    result = diagnose([fit], reference="blimp", holdout=[held]).as_dict()
    assert result["verdict"] == "consistent" and result["findings"] == [] and result["mismatch"] == []
    assert not result["locate"]["bands"] and "nominal" in result["locate"]["spectra"]
    for name in ("x", "y", "psi", "R"):  # noise estimated on the uneven design (15 % margin)
        assert result["locate"]["noise_sd"][name] == pytest.approx(SENSOR_NOISE_STD[name], rel=0.15)


@pytest.mark.slow
def test_concealed_effect_in_jittered_recording_files_is_named(tmp_path):
    """A concealed tail-fan lag in motion-capture-like recordings (jittered frames, written with
    an ``uneven_sampling`` sidecar and read back) is named with its value."""
    truth = [{"effect": "input_lag", "input": "u_tail", "value": 0.3}]
    fit, held = _jittered_recordings(truth, duration=14.0)
    write_recording(tmp_path / "fit.csv", fit)
    write_recording(tmp_path / "held.csv", held)
    result = diagnose([tmp_path / "fit.csv"], reference="blimp", holdout=[tmp_path / "held.csv"]).as_dict()
    _check_named(result, truth)


def test_recordings_at_different_nominal_rates_are_refused():
    fit, _ = _jittered_recordings([], duration=6.0)
    time, inputs = identification_manoeuvre(duration=6.0, sample_time=0.04, variant=1)
    other = EffectVehicle("blimp", []).simulate(_jittered(time, seed=6), inputs)
    with pytest.raises(BadInputError, match="different intervals"):
        diagnose([fit], reference="blimp", holdout=[other])


def test_bo105_refuses_uneven_sampling_with_exit_2(tmp_path, capsys):
    """The Bo105's exact discretisation needs one step: an unevenly sampled recording (declared
    in its sidecar, so the file itself reads) exits 2 with one line saying so."""
    time = _jittered(np.arange(0, 4.0, 0.01), seed=7, sd=0.0005)
    rows = [[t, 0.0, 0.01 * (t > 0.5), 0.0, 0.0, 0.0] for t in time]
    path = _write_table(tmp_path / "uneven.csv", ["time", "theta_0", "theta_1s", "theta_1c", "theta_0T", "q"], rows)
    path.with_suffix(".json").write_text(json.dumps({"uneven_sampling": True}))
    out = tmp_path / "out"
    assert main(["diagnose", str(path), "--reference", "bo105-80kt", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "uneven sampling" in err and "evenly sampled recordings" in err and "bo105-80kt" in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_search_terms_are_checked_against_the_blimps_library_and_replay_limit():
    named = [{"effect": "search_term", "term": "M_Q", "value": 0.01}]  # the named pitch damping
    with pytest.raises(BadInputError, match="stability_derivative"):
        EffectVehicle("blimp", named)
    five = [{"effect": "search_term", "term": term, "value": 0.01}
            for term in ("M_U", "N_V", "X_U^3", "Y_V*R", "L_phi")]
    with pytest.raises(BadInputError, match="at most 4"):
        EffectVehicle("blimp", five)
    four = EffectVehicle("blimp", five[:4])
    assert [e["term"] for e in four.effects] == ["M_U", "N_V", "X_U^3", "Y_V*R"]
