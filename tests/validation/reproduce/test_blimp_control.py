"""Tests of the Table III yaw controller and its PEGASUS policy search (validation/reproduce/blimp_control.py)."""
import math

import numpy as np
import pytest

from gp_model import GreyBoxGP
from validation.models.blimp_greybox import (
    COMMAND_LAGS,
    GP_STATE_COLUMNS,
    MIN_NOISE_VARIANCE,
    lagged_commands,
    smoothed_states,
    step_inputs,
)
from validation.models.blimp_identification import physics_step
from validation.reproduce.blimp_control import (
    FRAMES_PER_DECISION,
    INITIAL_PARAMETERS,
    TurnPolicy,
    TurnTask,
    fly_stand_in,
    pegasus_cost,
    rk_simulator,
    rkgp_simulator,
    scenarios,
    switching_function,
    yaw_command,
)
from validation.reproduce.blimp_prediction import RK_MAX_STEP, random_command_flight
from validation.vehicles.blimp import SAMPLE_TIME, hanging_state
from validation.vehicles.blimp_flight import FLIGHT_TEST_PARAMETERS, BlimpFlightTest

PARAMS = np.array([0.5, 0.3, 0.5, 3.0])


def test_command_is_saturated_and_signed_like_the_yaw_error():
    errors = np.radians([-170.0, -90.0, -1.0, 0.0, 1.0, 90.0, 170.0])
    u = yaw_command(errors, 0.0, PARAMS)
    assert np.all(np.abs(u) <= 1.0)
    assert np.all(np.sign(u) == np.sign(errors))  # target to the right -> yaw right (u > 0)
    assert u[-1] == pytest.approx(1.0, abs=1e-6) and u[0] == pytest.approx(-1.0, abs=1e-6)
    assert np.all(np.abs(yaw_command(errors, 5.0, PARAMS * [1, 1, 1, 1e6])) <= 1.0)


def test_tanh_slope_sharpens_toward_bang_bang():
    e = math.radians(5.0)
    gentle, steep = yaw_command(e, 0.0, PARAMS), yaw_command(e, 0.0, [*PARAMS[:3], 300.0])
    assert 0 < gentle < steep and steep == pytest.approx(1.0, abs=1e-6)
    # Small s: u = tanh(k s) ~ k s (slope k at the switching curve).
    assert yaw_command(1e-6, 0.0, PARAMS) == pytest.approx(3.0e-6, rel=1e-9)


def test_switching_curve_is_the_braking_distance_of_the_yaw_model():
    b_plus, b_minus, a = PARAMS[:3]
    r = 0.4
    # Turning right at r, braking uses the weaker b_minus: s = 0 where e equals the braking distance.
    stop = r / a - b_minus / a**2 * math.log1p(a * r / b_minus)
    assert switching_function(stop, r, PARAMS) == pytest.approx(0.0, abs=1e-12)
    assert switching_function(-stop * b_plus / b_minus, -r, PARAMS) < 0  # mirror uses b_plus
    # Double-integrator limit (a -> 0): r^2 / (2 b).
    assert switching_function(0.0, r, [b_plus, b_minus, 1e-6, 3.0]) == pytest.approx(-r**2 / (2 * b_minus), rel=1e-5)
    # Rate toward the target moves the switch earlier: braking begins before e reaches 0.
    assert yaw_command(math.radians(10), 1.0, PARAMS) < 0 < yaw_command(math.radians(10), 0.0, PARAMS)


@pytest.fixture(scope="module")
def simulators():
    """RK and RKGP simulators of the stand-in's true parameters; the RKGP's GPs (fixed
    hyperparameters, one per output, the lagged fan commands among their inputs) on 4 s of a
    random-command flight, every second transition."""
    rk = physics_step(FLIGHT_TEST_PARAMETERS, max_step=RK_MAX_STEP)
    recording = random_command_flight(4.0, [9, 0, 0]).recording
    states, inputs = smoothed_states(recording), step_inputs(recording)
    model = GreyBoxGP(state_columns=GP_STATE_COLUMNS, shared=False, min_noise_variance=MIN_NOISE_VARIANCE).fit(
        states[:-1:2], inputs[:-1:2], states[1::2], rk, optimize=False)
    return {"RK": rk_simulator(rk), "RKGP": rkgp_simulator(model, rk), "model": model, "rk": rk}


def test_turn_policy_holds_commands_at_4_hz_and_lags_them_like_a_recording():
    """Called step by step, the policy returns the inputs a recording of its commands would give:
    the yaw command recomputed every FRAMES_PER_DECISION steps and held, gondola off, dt the
    mocap interval, and the lagged commands of step_inputs (fans at rest at step 0)."""
    rng = np.random.default_rng(0)
    states = np.tile(hanging_state(FLIGHT_TEST_PARAMETERS), (2, 1))
    policy = TurnPolicy(INITIAL_PARAMETERS, 2, command_lags=COMMAND_LAGS)
    rows = []
    for k in range(12):
        states[:, 5] += rng.normal(0.0, 0.2, 2)  # yaw moves between decisions: the command must not
        rows.append(policy(k, states))
    inputs = np.stack(rows, axis=1)  # (2, 12, 4 + 6)
    assert inputs.shape == (2, 12, 4 + 2 * len(COMMAND_LAGS))
    for k in range(12):
        decided = k - k % FRAMES_PER_DECISION
        np.testing.assert_array_equal(inputs[:, k, 2], inputs[:, decided, 2])
    assert len(np.unique(inputs[0, ::FRAMES_PER_DECISION, 2])) == 3  # three decisions, three commands
    assert np.all(inputs[..., :2] == 0) and np.all(inputs[..., 3] == SAMPLE_TIME)
    for r in range(2):
        expected = lagged_commands(inputs[r, :, :3], inputs[r, :, 3], time_constants=COMMAND_LAGS)
        np.testing.assert_allclose(inputs[r, :, 4:], expected, rtol=0, atol=1e-15)


def test_rkgp_simulator_samples_with_the_policy_in_the_loop(simulators):
    """The RKGP simulator's turns are GreyBoxGP.sample_closed_loop with a fresh TurnPolicy: the
    same for the same normals (bit for bit), and the commands follow the sampled yaw, so
    different draws give different commands (the sampling cannot have been done from a command
    sequence fixed up front)."""
    task = TurnTask(horizon_s=2.0, yaw_start_std_deg=0.0, yaw_rate_start_std_deg_s=0.0)
    starts, normals = scenarios(task, hanging_state(FLIGHT_TEST_PARAMETERS), [1, 2])
    starts[1] = starts[0]
    paths = simulators["RKGP"](INITIAL_PARAMETERS, starts, normals, task.frames)
    np.testing.assert_array_equal(paths, simulators["RKGP"](INITIAL_PARAMETERS, starts, normals, task.frames))
    policy = TurnPolicy(INITIAL_PARAMETERS, 2, command_lags=COMMAND_LAGS)
    expected = simulators["model"].sample_closed_loop(starts, policy, task.frames, simulators["rk"], normals=normals,
                                                      include_noise=True)
    np.testing.assert_array_equal(paths, expected)
    # Replay the commands the policy chose from each sampled path: they differ between the two
    # draws, from the same start.
    replay = TurnPolicy(INITIAL_PARAMETERS, 2, command_lags=COMMAND_LAGS)
    commands = np.stack([replay(k, paths[:, k]) for k in range(task.frames)], axis=1)[..., 2]
    assert np.any(commands[0] != commands[1]) and np.all(commands[:, 0] == commands[0, 0])


@pytest.mark.parametrize("name", ["RK", "RKGP"])
def test_pegasus_cost_is_deterministic_for_a_fixed_seed_set(simulators, name):
    task = TurnTask(horizon_s=2.0)
    start = hanging_state(FLIGHT_TEST_PARAMETERS)
    cost = pegasus_cost(INITIAL_PARAMETERS, simulators[name], task, start, [1, 2, 3])
    assert pegasus_cost(INITIAL_PARAMETERS, simulators[name], task, start, [1, 2, 3]) == cost  # bit for bit
    assert pegasus_cost(INITIAL_PARAMETERS, simulators[name], task, start, [4, 5, 6]) != cost
    assert pegasus_cost(INITIAL_PARAMETERS * [1, 1, 1, 2], simulators[name], task, start, [1, 2, 3]) != cost


def test_rkgp_scenarios_differ_by_their_gp_draws_alone(simulators):
    # Zero start perturbations: only the seeded GP normals differ between seeds.
    task = TurnTask(horizon_s=2.0, yaw_start_std_deg=0.0, yaw_rate_start_std_deg_s=0.0)
    start = hanging_state(FLIGHT_TEST_PARAMETERS)
    rk_costs = {pegasus_cost(INITIAL_PARAMETERS, simulators["RK"], task, start, [s]) for s in (1, 2)}
    rkgp_costs = {pegasus_cost(INITIAL_PARAMETERS, simulators["RKGP"], task, start, [s]) for s in (1, 2)}
    assert len(rk_costs) == 1 and len(rkgp_costs) == 2


def test_stand_in_loop_matches_simulate_for_the_commands_it_flew():
    # The frame-by-frame loop replays the stand-in's jitter and drift streams: given the commands
    # it chose, the batch simulator reproduces the frame times exactly and the true states to
    # rounding (mocap off: simulate then returns the true states).
    vehicle = BlimpFlightTest(mocap=False)
    time, states, commands = fly_stand_in(PARAMS, seed=11, frames=40, vehicle=vehicle)
    recording = vehicle.simulate(time, commands, seed=11)
    np.testing.assert_array_equal(recording.time, time)
    np.testing.assert_allclose(recording.outputs, states, rtol=0, atol=1e-12)
    assert np.all(commands[::5, 2] != 0) and np.all(commands[1:5] == commands[0])  # held 0.25 s
    assert np.all(commands[:, :2] == 0)  # gondola off
