"""Tests of the RGBlimp's rollout-trained hybrid (validation/models/rgblimp_rollout.py).

Properties: the physics written in jax.numpy equals the numpy free run (wind and thrust gain
included); the loss's gradient through the RK4 rollouts equals central differences in every kind
of parameter; the correction is zero far from its inducing inputs; a correction concealed in a
known model is recovered from its flight and carries over to a flight from another start; the
model file reads back to the same free run and bad files are refused with one line.
"""
import dataclasses
import json

import numpy as np
import pytest

from tests.validation.models.test_rgblimp_identification import INPUTS, START, synthetic_flight
from validation.core.errors import BadInputError
from validation.models import rgblimp_rollout as rollout
from validation.models.rgblimp_identification import STATE_SCALE, RGBlimpModel, cut_segments, wrapped_difference
from validation.reproduce.rgblimp import read_score_ranges
from validation.vehicles.rgblimp_data import EXCERPT_FOLDER
from validation.vehicles.rgblimp_equations import RGBlimpParameters, body_accelerations

#: Samples of every free run here (4 s): one compiled run for all of them.
RUN_SAMPLES = 241
#: A small, fast setup: 2 s segments, 8 inducing inputs (the shapes of the other tests' small
#: setups: they share one compiled loss through JAX's compilation cache, tests/conftest.py).
QUICK = rollout.RolloutSetup(inducing_points=8, segment_duration=2.0, max_segments=8, max_iterations=40,
                             prior_weight=1.0, tune_physics=False)


def test_jax_physics_equals_the_numpy_free_run_with_wind_and_thrust_gain():
    model = RGBlimpModel(thrust_gain=0.9, wind=(0.02, -0.03))
    inputs = np.tile(INPUTS, (RUN_SAMPLES, 1))
    expected = model.simulate(START, inputs)
    hybrid = rollout.RolloutHybrid(model, None, QUICK)
    path = hybrid.simulate(START, inputs)
    assert np.max(np.abs(wrapped_difference(path, expected))) < 1e-9


def _loss_and_gradient(x_physics, theta, segments, *, prior_weight=0.7, state_scale=rollout.LOSS_SCALE):
    """The module's loss and its gradient at one physics and correction, and the loss as a
    function of both (its value from the same compiled function)."""
    compiled = rollout._compiled()  # noqa: SLF001 - the test differentiates the module's own loss
    jnp = compiled["jnp"]
    data = tuple(jnp.asarray(part) for part in rollout._padded(segments))  # noqa: SLF001
    groups = jnp.zeros(len(data[0]), dtype=int)

    def evaluate(physics, correction):
        # As the fit passes them: groups padded to the batch (the fit's compiled shape).
        p = {name: jnp.repeat(jnp.asarray(value)[None], rollout._GROUP_BATCH, axis=0)  # noqa: SLF001
             for name, value in physics.items()}
        th = {name: jnp.asarray(value) for name, value in correction.items()}
        return compiled["value_and_grad"](p, th, groups, *data, prior_weight, jnp.asarray(state_scale))

    value, (gp, gtheta) = evaluate(x_physics, theta)
    gp = {name: np.asarray(value)[0] for name, value in gp.items()}
    return float(value), gp, gtheta, lambda pp, tt: float(evaluate(pp, tt)[0])


def test_rollout_gradient_equals_central_differences():
    flight = synthetic_flight(RGBlimpModel(), samples=241)
    segments = cut_segments([flight], duration=QUICK.segment_duration, max_segments=2)
    rng = np.random.default_rng(1)
    theta = rollout.initial_correction([flight], QUICK)
    theta["whitened"] = 0.3 * rng.standard_normal(theta["whitened"].shape)
    physics = rollout.physics_parameters(RGBlimpModel(wind=(0.01, 0.02)))
    loss_at_start, gp, gtheta, loss = _loss_and_gradient(physics, theta, segments)
    checks = [("physics", "c_my0", (), 1e-6), ("physics", "buoyancy_mass", (), 1e-8), ("physics", "wind", (1,), 1e-6),
              ("theta", "whitened", (3, 4), 1e-6), ("theta", "log_length_scale", (5,), 1e-6),
              ("theta", "inducing", (2, 0), 1e-6), ("theta", "log_amplitude", (4,), 1e-6)]
    for kind, name, index, step in checks:
        values = physics if kind == "physics" else theta
        plus = {k: np.array(v, dtype=float) for k, v in values.items()}
        minus = {k: np.array(v, dtype=float) for k, v in values.items()}
        plus[name][index] += step
        minus[name][index] -= step
        if kind == "physics":
            numeric = (loss(plus, theta) - loss(minus, theta)) / (2 * step)
            exact = float(np.asarray(gp[name])[index])
        else:
            numeric = (loss(physics, plus) - loss(physics, minus)) / (2 * step)
            exact = float(np.asarray(gtheta[name])[index])
        assert exact != 0, name
        # 1e-5 relative (the differences' truncation and the compiled loss's rounding, which
        # differs between CPUs: 3e-6 measured on one) and eps |loss| / step ten times.
        rounding = 10 * np.finfo(float).eps * abs(loss_at_start) / step
        assert abs(exact - numeric) <= 1e-5 * abs(exact) + rounding, (name, exact, numeric, rounding)


def test_the_loss_divides_each_state_error_by_the_setups_scale():
    flight = synthetic_flight(RGBlimpModel(), samples=241)
    segments = cut_segments([flight], duration=QUICK.segment_duration, max_segments=2)
    theta = rollout.initial_correction([flight], QUICK)
    theta["whitened"] = 0.3 * np.random.default_rng(2).standard_normal(theta["whitened"].shape)
    physics = rollout.physics_parameters(RGBlimpModel(wind=(0.01, 0.02)))
    scale = np.asarray(rollout.LOSS_SCALE)
    at_scale, *_ = _loss_and_gradient(physics, theta, segments, prior_weight=0.0, state_scale=scale)
    doubled, *_ = _loss_and_gradient(physics, theta, segments, prior_weight=0.0, state_scale=2 * scale)
    assert doubled == pytest.approx(at_scale / 4, rel=1e-12)
    roll_loose = scale.copy()
    roll_loose[3] *= 10  # the roll error weighs 100 times less
    loosened, *_ = _loss_and_gradient(physics, theta, segments, prior_weight=0.0, state_scale=roll_loose)
    assert 0 < loosened < at_scale
    # The default weighs roll and pitch as the score does: far more than position.
    assert scale[3] < scale[0] / 10 and scale[4] < scale[0] / 10
    for wrong in ((0.05,) * 11, (0.05,) * 11 + (float("nan"),), None):
        with pytest.raises(BadInputError, match="state_scale"):
            rollout.RolloutSetup(state_scale=wrong)
    for name, bad in (("max_iterations", 2.5), ("inducing_points", 0), ("max_segments", True)):
        with pytest.raises(BadInputError, match=rf"RolloutSetup\.{name} must be a whole number"):
            rollout.RolloutSetup(**{name: bad})
    # The score's ranges as the source's statistics give them (the excerpt ships them).
    spiral = read_score_ranges(EXCERPT_FOLDER, kinds=("spiral",))["spiral"]
    np.testing.assert_allclose(rollout.SCORE_RANGES, spiral, rtol=1e-4)


def test_correction_returns_to_zero_far_from_its_data():
    flight = synthetic_flight(RGBlimpModel(), samples=60)
    theta = rollout.initial_correction([flight], QUICK)
    theta["whitened"] = np.ones_like(theta["whitened"])
    hybrid = rollout.RolloutHybrid(RGBlimpModel(), theta, QUICK)
    near = hybrid.correction_at(flight.recording.outputs[0], flight.recording.inputs[0])
    far_state = flight.recording.outputs[0].copy()
    far_state[6] += 5.0  # 5 m/s faster: 50 feature scales away
    far = hybrid.correction_at(far_state, flight.recording.inputs[0])
    assert np.all(np.abs(near) > 1e-3)
    assert np.all(np.abs(far) < 1e-12)


@pytest.fixture(scope="module")
def concealed():
    """A model whose pitching moment at zero incidence is larger than the published one's (c_my0
    0.0568 -> 0.0868 m): the hybrid starts from the published model and fits the correction on
    one 6 s flight of the concealed one."""
    truth = RGBlimpModel(dataclasses.replace(RGBlimpParameters(), c_my0=0.0868))
    flight = synthetic_flight(truth, samples=361)
    calls = []
    hybrid = rollout.fit_rollout([flight], RGBlimpModel(), setup=QUICK,
                                 progress=lambda iteration, loss: calls.append((iteration, loss)))
    assert [i for i, _ in calls] == list(range(1, hybrid.iterations + 1)) and calls[-1][1] == hybrid.loss
    return truth, flight, hybrid


@pytest.mark.slow
def test_a_concealed_pitching_moment_is_recovered_and_carries_over(concealed):
    truth, flight, hybrid = concealed
    states, inputs = flight.recording.outputs[::30], flight.recording.inputs[::30]
    params = truth.params
    missing = body_accelerations(states, inputs, params) - body_accelerations(states, inputs, RGBlimpParameters())
    learned = hybrid.correction_at(states, inputs)
    # The pitch acceleration is the concealed moment's main effect: recovered to 25 %.
    assert np.sqrt(np.mean((learned[:, 4] - missing[:, 4]) ** 2)) < 0.25 * np.sqrt(np.mean(missing[:, 4] ** 2))
    # A flight from another start (pitched up and turning the other way) the fit never saw.
    start = START.copy()
    start[4] += 0.05
    start[11] *= -0.5
    unseen = np.tile(INPUTS, (RUN_SAMPLES, 1))
    recorded = truth.simulate(start, unseen)
    before = np.abs(wrapped_difference(RGBlimpModel().simulate(start, unseen), recorded)[:, 4]).max()
    after = np.abs(wrapped_difference(hybrid.simulate(start, unseen), recorded)[:, 4]).max()
    assert after < 0.25 * before, (before, after)


@pytest.mark.slow
def test_model_file_round_trip_and_bad_files(concealed, tmp_path):
    _, flight, hybrid = concealed
    data = json.loads(json.dumps(hybrid.as_dict()))
    again = rollout.RolloutHybrid.from_dict(data)
    inputs = flight.recording.inputs[:RUN_SAMPLES]
    assert np.array_equal(again.simulate(START, inputs), hybrid.simulate(START, inputs))
    with pytest.raises(BadInputError, match="not a flightgp RGBlimp hybrid"):
        rollout.RolloutHybrid.from_dict({"format": "something else"})
    bad = json.loads(json.dumps(data))
    bad["correction"]["whitened"][0][0] = float("nan")
    with pytest.raises(BadInputError, match="whitened must be finite"):
        rollout.RolloutHybrid.from_dict(bad)
    assert again.setup.state_scale == hybrid.setup.state_scale == rollout.LOSS_SCALE
    older = json.loads(json.dumps(data))  # a file from before the loss had its own scales
    del older["setup"]["state_scale"]
    assert rollout.RolloutHybrid.from_dict(older).setup.state_scale == STATE_SCALE
    bad = json.loads(json.dumps(data))
    bad["setup"]["state_scale"][3] = float("nan")
    with pytest.raises(BadInputError, match="state_scale"):
        rollout.RolloutHybrid.from_dict(bad)
    bad = json.loads(json.dumps(data))
    bad["version"] = 99
    with pytest.raises(BadInputError, match="version 99"):
        rollout.RolloutHybrid.from_dict(bad)


def test_a_flight_with_a_nan_state_is_refused_with_one_line():
    flight = synthetic_flight(RGBlimpModel(), samples=30)
    flight.recording.outputs[5, 2] = np.nan
    with pytest.raises(BadInputError, match="non-finite"):
        rollout.fit_rollout([flight], RGBlimpModel(), setup=QUICK)
    with pytest.raises(BadInputError, match="no flights"):
        rollout.fit_rollout([], RGBlimpModel(), setup=QUICK)


@pytest.mark.slow
def test_band_is_the_spread_of_disturbed_runs_about_the_free_run(concealed):
    _, flight, hybrid = concealed
    inputs = flight.recording.inputs[:RUN_SAMPLES]
    still = dataclasses.replace(hybrid, disturbance_sd=(0.0,) * 6)
    mean, sd = still.band(START, inputs, n_samples=16)
    free_run = hybrid.simulate(START, inputs)
    assert np.max(np.abs(mean - free_run)) < 1e-12 and np.all(sd < 1e-12)  # equal runs, std to rounding
    # Small random accelerations (the response linear in them): the spread grows with time, and
    # accelerations twice the size double it.
    small = dataclasses.replace(hybrid, disturbance_sd=(0.002,) * 3 + (0.004,) * 3)
    mean, sd = small.band(START, inputs, n_samples=16, seed=3)
    assert np.max(np.abs(mean - free_run)) < 1e-12 and np.all(sd[0] == 0)
    assert np.all(sd[-1, :3] > 5 * sd[60, :3])
    doubled = dataclasses.replace(hybrid, disturbance_sd=(0.004,) * 3 + (0.008,) * 3)
    np.testing.assert_allclose(doubled.band(START, inputs, n_samples=16, seed=3)[1][-1, :3], 2 * sd[-1, :3], rtol=0.02)


def test_the_benchmarks_gradient_call_refuses_what_the_fit_refuses():
    flights = [synthetic_flight(RGBlimpModel(), samples=60)]
    with pytest.raises(BadInputError, match="no flights to fit"):
        rollout.gradient_call([], RGBlimpModel())
    correction = rollout.initial_correction(flights, rollout.RolloutSetup(inducing_points=4))
    correction["whitened"] = correction["whitened"][:3]
    with pytest.raises(BadInputError, match=r"gradient_call: correction inducing must be finite of shape \(3, 11\)"):
        rollout.gradient_call(flights, RGBlimpModel(), correction=correction)


def test_only_the_checkpointed_rollout_recomputes_its_steps():
    # The flag reaches the traced run: with it the scanned step is a checkpoint (remat) and its
    # reverse pass recomputes it; without it the step's intermediates are stored (the benchmark's
    # peer). Traced only, not compiled.
    from validation.vehicles.compiled_runs import jax_modules
    from validation.vehicles.rgblimp_jax import parameter_arrays, rollout_function

    jax, jnp = jax_modules()
    p = parameter_arrays(RGBlimpParameters())
    inputs = jnp.asarray(np.tile(INPUTS, (3, 1)))
    traced = {flag: str(jax.make_jaxpr(rollout_function(jax, jnp, checkpoint_steps=flag))(p, None, jnp.asarray(START),
                                                                                         inputs))
              for flag in (True, False)}
    assert "checkpoint" in traced[True] or "remat" in traced[True]
    assert "checkpoint" not in traced[False] and "remat" not in traced[False]
