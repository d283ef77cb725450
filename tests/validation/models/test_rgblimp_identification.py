"""Tests of the RGBlimp's output-error identification (validation/models/rgblimp_identification.py).

Properties: the batched parameter sets equal one evaluation per set; the whole-run free run
equals stepping; a steady wind is a Galilean change of frame; coefficients of a known model are
recovered from its noise-free flight; segments of short flights are masked; and on real flights
the identified model free-runs its own fitting flights better than the published one (flights of
the excerpt shipped with the package, :data:`validation.vehicles.rgblimp_data.EXCERPT_FOLDER`).
"""
import numpy as np
import pytest

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.models.rgblimp_identification import (
    IDENTIFIED_PARAMETERS,
    RGBlimpModel,
    batched_parameters,
    between_spread,
    cut_segments,
    identify_configurations,
    identify_parameters,
    wrapped_difference,
)
from validation.vehicles.blimp_equations import rotation_body_to_earth
from validation.vehicles.rgblimp_data import EXCERPT_FOLDER, RGBlimpFlight, read_rgblimp_flight
from validation.vehicles.rgblimp_equations import (
    INPUT_NAMES,
    SAMPLE_TIME,
    STATE_NAMES,
    advance,
    free_run,
    rk4_step,
    simulate,
)

#: The first recorded state of the source's data_1.csv and its inputs (zhu-yj/ABNODE, MIT licence).
START = np.array([0.0909488706576665, 0.207607196554284, -1.10977807000056, -0.021610771892882,
                  0.0847253505835717, 1.11115334440126, 0.24244823748133, -0.0177197330326424,
                  0.0909952339158465, -0.0106494636970684, 0.0721749269355973, -0.273504107349412])
INPUTS = np.array([0.01666, 0.05292, 0.0747, 0.0006, 0.238])


def synthetic_flight(model: RGBlimpModel, *, samples: int, number: int = 1) -> RGBlimpFlight:
    """A noise-free flight of ``model`` from :data:`START` under constant :data:`INPUTS`."""
    inputs = np.tile(INPUTS, (samples, 1))
    states = model.simulate(START, inputs)
    recording = Recording(time=np.arange(samples) * SAMPLE_TIME, inputs=inputs, input_names=INPUT_NAMES,
                          outputs=states, output_names=STATE_NAMES)
    return RGBlimpFlight(number=number, configuration=(number - 1) // 4, recording=recording,
                         model_accelerations=np.zeros((samples, 6)), measured_accelerations=np.zeros((samples, 6)))


def test_batched_parameter_sets_equal_one_evaluation_per_set():
    model = RGBlimpModel()
    names = IDENTIFIED_PARAMETERS
    rng = np.random.default_rng(0)
    vectors = np.array([model.value(n) for n in names]) * (1 + 0.2 * rng.standard_normal((3, len(names))))
    vectors[:, names.index("wind_x")] = [0.03, -0.02, 0.0]
    states = START + 0.01 * rng.standard_normal((4, 12))
    params, gain, wind = batched_parameters(model, names, vectors)
    batched = advance(np.broadcast_to(states, (3, 4, 12)), np.broadcast_to(INPUTS, (3, 4, 5)), params,
                      thrust_gain=gain, wind=wind)
    one_by_one = np.stack([model.replaced(dict(zip(names, v))).step(states, np.broadcast_to(INPUTS, (4, 5)))
                           for v in vectors])
    # Same operations in another order of the broadcast axes: rounding only.
    np.testing.assert_allclose(batched, one_by_one, rtol=0, atol=1e-14)


def test_free_run_equals_stepping_and_still_air_is_the_source_step():
    windy = RGBlimpModel(thrust_gain=0.9, wind=(0.03, -0.02))
    inputs = np.tile(INPUTS, (120, 1))
    stepped = simulate(windy.step, START, inputs)
    # The frame conversions cancel between steps up to rounding of the velocity offset (1e-17 m/s).
    np.testing.assert_allclose(wrapped_difference(windy.simulate(START, inputs), stepped), 0, atol=1e-12)
    still = RGBlimpModel()
    np.testing.assert_array_equal(still.step(START, INPUTS), rk4_step(START, INPUTS, still.params))


def test_steady_wind_carries_the_still_air_flight_along():
    """A uniform steady wind w is a Galilean change of frame: the flight in wind, seen from the air
    mass (position minus w t, body velocity minus R^T w), is the still-air flight from the
    air-relative start."""
    wind = np.array([0.04, -0.03, 0.0])
    model = RGBlimpModel(wind=tuple(wind[:2]))
    inputs = np.tile(INPUTS, (240, 1))
    in_wind = model.simulate(START, inputs)
    air_start = START.copy()
    air_start[6:9] -= rotation_body_to_earth(START[3:6]).T @ wind
    still = free_run(air_start, inputs, model.params)
    seen_from_air = in_wind.copy()
    seen_from_air[:, :3] -= np.arange(240)[:, None] * SAMPLE_TIME * wind
    seen_from_air[:, 6:9] -= np.einsum("nji,j->ni", rotation_body_to_earth(in_wind[:, 3:6]), wind)
    np.testing.assert_allclose(wrapped_difference(seen_from_air, still), 0, atol=1e-12)
    assert np.linalg.norm(in_wind[-1, :3] - still[-1, :3]) > 0.1  # 4 s of 5 cm/s wind moved it


def test_coefficients_of_a_known_model_are_recovered_from_its_flight():
    names = ("thrust_gain", "buoyancy_mass", "rate_damping_z", "wind_x", "wind_y")
    truth = RGBlimpModel().replaced({"thrust_gain": 0.85, "buoyancy_mass": 0.1525, "rate_damping_z": -0.016,
                                     "wind_x": 0.02, "wind_y": -0.01})
    flight = synthetic_flight(truth, samples=901)  # 15 s: ten 1.5 s segments
    result = identify_parameters([flight], names=names, segment_duration=1.5, prior_sd=None)
    expected = np.array([truth.value(n) for n in names])
    # Noise-free data of the model's own structure: only the optimiser's tolerance remains.
    np.testing.assert_allclose(result.values, expected, rtol=1e-4, atol=1e-6)
    assert result.rms_residual < 1e-3 < result.initial_rms_residual
    assert result.n_segments == 10 and result.flights == (1,)


def test_a_prior_keeps_coefficients_the_flight_does_not_show_near_their_start():
    """With a tight prior on the yaw damping and none on the rest, the damping stays near its
    published value although the flight was flown with another."""
    names = ("thrust_gain", "rate_damping_z")
    truth = RGBlimpModel().replaced({"thrust_gain": 0.9, "rate_damping_z": -0.02})
    flight = synthetic_flight(truth, samples=601)
    free = identify_parameters([flight], names=names, segment_duration=2.0, prior_sd=None)
    tight = identify_parameters([flight], names=names, segment_duration=2.0,
                                prior_sd={"thrust_gain": 10.0, "rate_damping_z": 1e-6})
    assert abs(free.values[1] - (-0.02)) < 1e-5
    assert abs(tight.values[1] - RGBlimpModel().value("rate_damping_z")) < 1e-5
    with pytest.raises(BadInputError, match="rate_damping_z"):
        identify_parameters([flight], names=names, prior_sd={"thrust_gain": 1.0})


def test_configurations_are_drawn_toward_the_vehicle_by_their_spread():
    """Four configurations flown with thrust gains 0.8 .. 1.3: fitted alone each finds its own;
    drawn toward the published model (gain 1) by a prior of ``shrinkage`` times their spread,
    each lands between its own gain and 1, nearer 1 the smaller the shrinkage."""
    gains = (0.8, 0.9, 1.05, 1.3)
    # 2 s flights cut into two 1 s segments (noise-free: each gain is found to 1e-4 alone).
    groups = [[synthetic_flight(RGBlimpModel().replaced({"thrust_gain": g}), samples=121, number=4 * j + 1)]
              for j, g in enumerate(gains)]
    options = {"names": ("thrust_gain",), "segment_duration": 1.0}
    alone = identify_configurations(groups, RGBlimpModel(), shrinkage=None, **options)
    np.testing.assert_allclose([r.values[0] for r in alone], gains, atol=1e-4)
    # 1.4826 times the median absolute deviation from the median 0.975: (0.075, 0.075, 0.175, 0.325).
    np.testing.assert_allclose(between_spread(alone), [1.4826 * 0.125], rtol=1e-3)
    loose, tight = (np.array([r.values[0] for r in identify_configurations(
        groups, RGBlimpModel(), shrinkage=s, alone=alone, **options)]) for s in (0.1, 0.01))
    own = np.array(gains) - 1.0
    assert np.all(np.abs(tight - 1.0) < np.abs(loose - 1.0) - 1e-4)
    assert np.all(np.abs(loose - 1.0) <= np.abs(own) + 1e-6)
    assert np.all(np.sign(tight - 1.0) == np.sign(own))
    # Two configurations give no spread to estimate: each is fitted alone.
    pair = identify_configurations(groups[:2], RGBlimpModel(), shrinkage=0.01, alone=alone[:2], **options)
    assert all(p is a for p, a in zip(pair, alone[:2], strict=True))
    with pytest.raises(BadInputError, match="shrinkage"):
        identify_configurations(groups, RGBlimpModel(), shrinkage=0.0, alone=alone, **options)
    with pytest.raises(BadInputError, match="3 first fits for 4"):
        identify_configurations(groups, RGBlimpModel(), shrinkage=0.1, alone=alone[:3], **options)


def test_short_flights_give_one_masked_segment_and_long_ones_are_thinned():
    short = synthetic_flight(RGBlimpModel(), samples=40, number=121)
    long = synthetic_flight(RGBlimpModel(), samples=1000, number=1)
    length = 60
    whole = cut_segments([long], duration=1.0, max_segments=100)
    # 999 transitions: 16 full segments and a last one masked past the flight's end (39 steps).
    assert len(whole.starts) == 17 and whole.mask[:16].all() and whole.mask[16].sum() == 999 - 16 * length
    segments = cut_segments([short, long], duration=1.0, max_segments=8)
    assert segments.inputs.shape[1:] == (length, 5) and segments.targets.shape[1:] == (length, 12)
    first = segments.flights == 121
    assert first.sum() == 1 and segments.mask[first].sum() == 39  # 39 transitions in 40 samples
    np.testing.assert_array_equal(segments.targets[first][0, :39], short.recording.outputs[1:])
    np.testing.assert_array_equal(segments.starts[first][0], short.recording.outputs[0])
    # The long flight keeps its share, evenly from its start to its end.
    kept = segments.starts[~first]
    assert len(kept) == 8
    np.testing.assert_array_equal(kept[0], long.recording.outputs[0])
    np.testing.assert_array_equal(kept[-1], long.recording.outputs[16 * length])
    # However small the budget, no flight is left out.
    assert set(cut_segments([short, long], duration=1.0, max_segments=1).flights) == {1, 121}
    with pytest.raises(BadInputError, match="max_segments"):
        cut_segments([long], max_segments=0)
    with pytest.raises(BadInputError, match="duration"):
        cut_segments([long], duration=float("nan"))


def test_unknown_coefficient_names_and_no_iterations_are_refused():
    with pytest.raises(BadInputError, match="c_d1"):
        RGBlimpModel().replaced({"c_d1": 0.3})
    flight = synthetic_flight(RGBlimpModel(), samples=200)
    with pytest.raises(BadInputError, match="unknown or repeated"):
        identify_parameters([flight], names=("c_d0", "c_d0"))
    for iterations in (0, 2.5, True):
        with pytest.raises(BadInputError, match=f"max_iterations must be a whole number of at least 1, got "
                                                f"{iterations!r}"):
            identify_parameters([flight], max_iterations=iterations)


def test_identified_model_free_runs_its_fitting_flights_better_than_the_published_one():
    """Flights 117 and 118 of the excerpt (configuration 29, spirals of 18 s and 14 s), two
    iterations of the fit, the fewest that take a step (the published model is beaten well before
    it converges)."""
    flights = [read_rgblimp_flight(EXCERPT_FOLDER / f"data_{n}.csv") for n in (117, 118)]
    result = identify_parameters(flights, max_iterations=2)
    assert result.rms_residual < result.initial_rms_residual
    assert np.all(result.standard_errors_iid > 0)
    # Six segments for nine coefficients: the cluster-robust covariance would be singular.
    assert result.n_segments == 6 and np.all(np.isnan(result.standard_errors))
    assert all(p["standard_error"] is None for p in result.as_dict()["parameters"].values())

    def position_rmse(model, flight):
        error = wrapped_difference(model.simulate(flight.recording.outputs[0], flight.recording.inputs),
                                   flight.recording.outputs)
        return np.sqrt(np.mean(np.sum(error[:, :3] ** 2, axis=1)))

    published = [position_rmse(RGBlimpModel(), f) for f in flights]
    identified = [position_rmse(result.model, f) for f in flights]
    assert np.mean(identified) < np.mean(published)
    entry = result.as_dict()
    assert set(entry["parameters"]) == set(IDENTIFIED_PARAMETERS) and entry["flights"] == [117, 118]


def test_cluster_robust_errors_with_enough_segments_per_coefficient():
    """Flights 117 .. 119 of the excerpt (18, 14 and 12 s: eight 6 s segments) and two coefficients."""
    flights = [read_rgblimp_flight(EXCERPT_FOLDER / f"data_{n}.csv") for n in (117, 118, 119)]
    result = identify_parameters(flights, names=("thrust_gain", "c_d0"))
    assert result.n_segments == 8 and result.converged
    assert np.all(np.isfinite(result.standard_errors)) and np.all(result.standard_errors > 0)
    assert np.all(np.isfinite(result.covariance))
