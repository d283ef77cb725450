"""JSBSim vehicles: c172x trimmed cruise, ah1s hover, errors, silence, determinism."""
import logging

import jsbsim
import numpy as np
import pytest

from validation.core.errors import BadInputError
from validation.core.manoeuvres import manoeuvre, time_grid
from validation.vehicles import get_vehicle
from validation.vehicles.jsbsim import JSBSimVehicle, starting_recipe
from validation.vehicles.jsbsim_start import StartingRecipe

KT = 0.514444  # m/s per kt


def _fly(vehicle, *, input_name=None, amplitude=0.0, duration=10.0, seed=0):
    """A 3-2-1-1 (0.4 s steps from 1 s) on ``input_name``, every other input at trim."""
    time = time_grid(duration=duration, sample_time=vehicle.sample_time)
    inputs = np.zeros((len(time), len(vehicle.input_names)))
    if input_name is not None:
        inputs[:, vehicle.input_names.index(input_name)] = manoeuvre(
            "3211", time, amplitude=amplitude, step_time=0.4, start=1.0)
    return vehicle.simulate(time, inputs, seed=seed)


@pytest.fixture(scope="module")
def c172x():
    return get_vehicle("jsbsim:c172x")


@pytest.fixture(scope="module")
def ah1s():
    return get_vehicle("jsbsim:ah1s")


def test_registry_names_and_columns(c172x, ah1s):
    assert (c172x.name, c172x.input_names) == ("jsbsim:c172x", ("elevator", "aileron", "rudder"))
    assert ah1s.input_names == ("collective", "longitudinal_cyclic", "lateral_cyclic", "pedal")
    for vehicle in (c172x, ah1s):
        assert vehicle.state_names == ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi")
        assert vehicle.sample_time == 0.01


def test_c172x_trims_in_level_cruise(c172x):
    recording = _fly(c172x, duration=3.0)
    assert recording.metadata["initial_condition"]["airspeed_kt"] == pytest.approx(100.0, abs=0.1)
    assert set(recording.metadata["trim"]) == {"elevator", "aileron", "rudder"}
    # True airspeed at 4000 ft is about 6 % above the calibrated 100 kt, and it is in SI (m/s).
    assert recording.output("u")[0] == pytest.approx(106 * KT, rel=0.02)
    # Trimmed: without input, 3 s later the rates are still tiny and the speed unchanged.
    assert np.abs(recording.outputs[:, 3:6]).max() < 1e-4
    assert np.ptp(recording.output("u")) < 0.01
    assert recording.output("psi")[0] == pytest.approx(np.pi / 2, abs=1e-6)  # heading east


def test_c172x_elevator_3211_pitches_the_aircraft(c172x):
    recording = _fly(c172x, input_name="elevator", amplitude=0.2)
    q = recording.output("q")
    assert np.all(np.isfinite(recording.outputs))
    assert np.abs(q[recording.time < 1.0]).max() < 1e-4  # at trim before the manoeuvre
    assert np.abs(q).max() > 0.1  # about 0.22 rad/s
    # Positive elevator command = trailing edge down = nose down: q first goes negative.
    assert q[np.flatnonzero(np.abs(q) > 0.01)[0]] < 0
    assert recording.input("elevator").max() == 0.2  # inputs are recorded as perturbations


def test_c172x_elevator_hysteresis_swallows_small_commands(c172x):
    """c172x.xml gives the elevator actuator a 0.05 rad hysteresis (documented in the module)."""
    small = _fly(c172x, input_name="elevator", amplitude=0.03, duration=4.0)
    aileron = _fly(c172x, input_name="aileron", amplitude=0.03, duration=4.0)
    assert np.abs(small.output("q")).max() < 1e-4
    assert np.abs(aileron.output("p")).max() > 0.01


def test_ah1s_hovers_with_its_afcs(ah1s):
    recording = _fly(ah1s, duration=5.0)
    condition = recording.metadata["initial_condition"]
    assert condition["airspeed_kt"] < 5
    assert 50 < condition["altitude_agl_ft"] < 100
    assert np.all(np.isfinite(recording.outputs))
    assert np.abs(recording.outputs[:, 0:3]).max() < 1.5  # u, v, w: drifting < 1.5 m/s
    assert np.abs(recording.outputs[:, 3:6]).max() < 0.02  # p, q, r: rad/s
    assert np.abs(recording.outputs[:, 6:8]).max() < 0.1  # phi, theta: near level
    assert recording.metadata["trim"]["collective"] == pytest.approx(0.6007)  # the script's hover value


def test_ah1s_longitudinal_cyclic_moves_q(ah1s):
    recording = _fly(ah1s, input_name="longitudinal_cyclic", amplitude=0.1, duration=5.0)
    assert np.all(np.isfinite(recording.outputs))
    assert np.abs(recording.output("q")).max() > 0.02  # about 0.05 rad/s, 20x the hover wander


def test_deterministic_and_seed_ignored(c172x):
    first = _fly(c172x, input_name="rudder", amplitude=0.1, duration=2.0, seed=0)
    second = _fly(c172x, input_name="rudder", amplitude=0.1, duration=2.0, seed=7)
    assert np.array_equal(first.outputs, second.outputs)


def test_jsbsim_prints_nothing(capfd, ah1s):
    _fly(ah1s, duration=0.5)  # the script's notify events print a lot without the redirect
    assert capfd.readouterr().out == ""


def test_jsbsim_messages_go_to_the_python_log(caplog, ah1s):
    """Whole messages (validation.vehicles.jsbsim_start.message_buffer), one log record each."""
    before = jsbsim.get_logger()
    with caplog.at_level(logging.DEBUG, logger="validation.vehicles.jsbsim"):
        _fly(ah1s, duration=0.1)
    messages = [record.getMessage() for record in caplog.records if record.name == "validation.vehicles.jsbsim"]
    assert messages and all(m.startswith("JSBSim: ") and m == m.strip() for m in messages)
    assert jsbsim.get_logger() is before  # only while the simulation ran


@pytest.mark.parametrize("aircraft, method", [("c172x", "trim"), ("ah1s", "script")])
def test_starting_recipe_is_data_that_survives_json(aircraft, method):
    """The recipe the JSBSim FMU stores in its model file reads back equal (floats exact)."""
    recipe = starting_recipe(aircraft)
    assert recipe.method == method and recipe.aircraft == aircraft
    assert StartingRecipe.from_json(recipe.to_json()) == recipe


def test_jsbsim_writes_no_files(tmp_path, monkeypatch, c172x):
    monkeypatch.chdir(tmp_path)  # c172x.xml asks for JSBout172B.csv in the current folder
    _fly(c172x, duration=0.5)
    assert list(tmp_path.iterdir()) == []


def test_unknown_aircraft_lists_similar_ones():
    with pytest.raises(BadInputError, match=r"no aircraft 'c17'; try jsbsim:c172x.*aircraft in "):
        JSBSimVehicle("c17")


def test_aircraft_that_cannot_trim_is_bad_input():
    airship = JSBSimVehicle("ZLT-NT")
    with pytest.raises(BadInputError, match="JSBSim cannot trim jsbsim:ZLT-NT in level flight at 100 kt"):
        _fly(airship, duration=0.1)


@pytest.mark.parametrize("time, inputs, message", [
    (np.arange(5) * 0.01, np.zeros((4, 3)), r"inputs must have shape \(5, 3\)"),
    (np.array([0.0, 0.01, 0.03]), np.zeros((3, 3)), "evenly spaced"),
    (np.arange(3) * 0.01, np.full((3, 3), np.nan), "finite"),
])
def test_bad_time_or_inputs(c172x, time, inputs, message):
    with pytest.raises(BadInputError, match=message):
        c172x.simulate(time, inputs)
