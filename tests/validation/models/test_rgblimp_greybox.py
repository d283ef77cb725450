"""Tests of the RGBlimp RKGP (validation/models/rgblimp_greybox.py): yaw carried across the wrap,
training transitions that never straddle flights, residual GPs that learn what the physics
leaves out (synthetic flights of a model with other coefficients), and the model file's
description of the physics."""
import numpy as np
import pytest

from gp_model import GreyBoxGP, load_model, read_header, save_model
from tests.validation.models.test_rgblimp_identification import INPUTS, START, synthetic_flight
from validation.core.errors import BadInputError
from validation.models.rgblimp_greybox import (
    GP_INPUT_NAMES,
    GP_STATE_COLUMNS,
    RGBLIMP_PHYSICS,
    RGBlimpStepDescription,
    continuous_states,
    fit_rkgp,
    physics_step,
    smoothed_states,
    training_transitions,
)
from validation.models.rgblimp_identification import RGBlimpModel
from validation.vehicles.rgblimp_equations import STATE_NAMES


def test_yaw_is_carried_across_the_wrap():
    model = RGBlimpModel()
    state = START.copy()
    state[5], state[11] = np.pi - 1e-3, 0.5  # turning right through +pi
    wrapped = model.step(state[None], INPUTS[None])[0]
    carried = physics_step(model)(state[None], INPUTS[None])[0]
    assert wrapped[5] < 0 < np.pi < carried[5]
    assert np.isclose(carried[5] - wrapped[5], 2 * np.pi)
    np.testing.assert_array_equal(np.delete(carried, 5), np.delete(wrapped, 5))
    yaw = np.array([3.0, 3.1, -3.1, -3.0])
    states = np.zeros((4, 12))
    states[:, 5] = yaw
    np.testing.assert_allclose(np.diff(continuous_states(states)[:, 5]), [0.1, 2 * np.pi - 6.2, 0.1])


def test_training_transitions_are_consecutive_samples_of_one_flight():
    first = synthetic_flight(RGBlimpModel(), samples=300, number=1)
    second = synthetic_flight(RGBlimpModel(thrust_gain=0.8), samples=200, number=2)
    states, inputs, next_states = training_transitions([first, second], n_points=50, smoothing=None)
    assert len(states) <= 50 and states.shape == next_states.shape == (len(states), 12)
    assert inputs.shape == (len(states), 5)
    flights = [continuous_states(f.recording.outputs) for f in (first, second)]
    for state, following in zip(states, next_states):
        matches = [(f, k) for f in flights for k in np.flatnonzero(np.all(f[:-1] == state, axis=1))]
        assert any(np.array_equal(f[k + 1], following) for f, k in matches)


def test_smoothed_states_of_a_flight_of_the_model_are_its_states():
    """On a noise-free flight of the model (kinematics exact) the states re-estimated from the
    poses equal the flown ones up to the quadratic fit's bias over 0.15 s (measured: 7.5e-6 in
    pose, 3.5e-4 in velocity and rate away from the ends, 1e-3 at the one-sided ends)."""
    flight = synthetic_flight(RGBlimpModel(), samples=300)
    smooth = smoothed_states(flight.recording)
    flown = continuous_states(flight.recording.outputs)
    np.testing.assert_allclose(smooth[:, :6], flown[:, :6], atol=1e-5)      # m, rad
    np.testing.assert_allclose(smooth[10:-10, 6:], flown[10:-10, 6:], atol=2e-3)  # m/s, rad/s; ends one-sided


def test_residual_gps_learn_what_the_physics_leaves_out():
    """Flights of a weaker, windy blimp; RKGP on the published model. On transitions it was not
    trained on, its one-step prediction is closer to the flight than the physics alone."""
    truth = RGBlimpModel(thrust_gain=0.8, wind=(0.02, 0.0))
    flight = synthetic_flight(truth, samples=900)
    rkgp = fit_rkgp([flight], RGBlimpModel(), n_points=120)
    states = continuous_states(flight.recording.outputs)
    rows = np.arange(5, 895, 7)  # off the training grid of every 8th transition
    step = physics_step(RGBlimpModel())
    mean, variance = rkgp.predict_one_step(states[rows], flight.recording.inputs[rows], step)
    physics = step(states[rows], flight.recording.inputs[rows])
    velocity = slice(6, 9)
    rkgp_error = np.sqrt(np.mean((mean - states[rows + 1])[:, velocity] ** 2))
    physics_error = np.sqrt(np.mean((physics - states[rows + 1])[:, velocity] ** 2))
    assert rkgp_error < 0.2 * physics_error
    assert np.all(variance > 0)
    assert tuple(rkgp.state_columns_) == GP_STATE_COLUMNS
    assert [STATE_NAMES[c] for c in GP_STATE_COLUMNS] == ["phi", "theta", "U", "V", "W", "P", "Q", "R"]
    assert len(GP_INPUT_NAMES) == len(GP_STATE_COLUMNS) + 5


def test_step_description_round_trips_exactly_through_a_model_file(tmp_path):
    """RGBlimpStepDescription holds every number of the identified model as plain JSON: written
    into a model file and read back it rebuilds the same model (equal doubles) and the same
    physics step; descriptions of other physics or with a number missing or unusable are
    refused."""
    identified = RGBlimpModel().replaced({"thrust_gain": 0.91234567891, "buoyancy_mass": 0.1523456789,
                                          "c_d0": 0.31415926535, "rate_damping_z": -1 / 70, "wind_x": 0.0123,
                                          "wind_y": -1 / 3})
    description = RGBlimpStepDescription(identified)
    model = GreyBoxGP(state_columns=GP_STATE_COLUMNS, n_restarts=0).fit(
        np.tile(START, (4, 1)) + np.arange(4)[:, None] * 1e-3, np.tile(INPUTS, (4, 1)),
        np.tile(START, (4, 1)), None, optimize=False)
    path = save_model(tmp_path / "rkgp.npz", model, physics=description.as_dict())
    physics = read_header(path)["physics"]
    assert physics["kind"] == RGBLIMP_PHYSICS and isinstance(load_model(path), GreyBoxGP)
    again = RGBlimpStepDescription.from_dict(physics)
    assert again == description and again.model == identified
    states = np.vstack([START, START + 0.01])
    np.testing.assert_array_equal(again.physics_step()(states, np.tile(INPUTS, (2, 1))),
                                  physics_step(identified)(states, np.tile(INPUTS, (2, 1))))
    for change, phrase in [({"kind": "blimp_rk4"}, "needs 'rgblimp_rk4'"), ({"thrust_gain": None}, "unusable"),
                           ({"wind": [0.1]}, "wind"), ({"sample_time": 0.01}, "sample time"),
                           ({"input_names": ["thrust"]}, "names")]:
        with pytest.raises(BadInputError, match=phrase):
            RGBlimpStepDescription.from_dict({**physics, **change})
    for name in ("parameters", "wind"):
        with pytest.raises(BadInputError, match=name):
            RGBlimpStepDescription.from_dict({key: value for key, value in physics.items() if key != name})
    with pytest.raises(BadInputError, match="inertia"):
        RGBlimpStepDescription.from_dict({**physics, "parameters": {**physics["parameters"], "inertia": [1.0, 2.0]}})
