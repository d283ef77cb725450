"""Tests of the RGBlimp model and its recordings (validation/vehicles/rgblimp_equations.py,
validation/vehicles/rgblimp_data.py).

The port test: at every recorded state and input, our accelerations equal the ones the source's
model stored in the same file (``vb_dot_sim_*``, ``wb_dot_sim_*``). Then properties of the
equations (sinking at rest, the signs of the thrust moments, broadcasting), the RK4 step
against a fine adaptive integration, and the reader's one-line errors.

The recordings are read from ``$FLIGHTGP_RGBLIMP_DATA`` when it is set (a copy of the folder
``data/`` of ``zhu-yj/ABNODE``, MIT licence, copyright 2024 zhu-yj; CI sets it when the full
folder is at hand), else from the repository's excerpt of six flights
(:data:`validation.vehicles.rgblimp_data.EXCERPT_FOLDER`); the test that needs all 35
configurations is skipped with the excerpt. One recorded row (:data:`RECORDED_ROW`) is carried
here too.
"""
import dataclasses
import math
import os
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from validation.core.errors import BadInputError
from validation.vehicles.rgblimp_data import (
    EXCERPT_FOLDER,
    RECORDED_MODEL_PARAMETERS,
    SOURCE_COLUMNS,
    configuration_index,
    flights_by_configuration,
    read_rgblimp_flight,
)
from validation.vehicles.rgblimp_equations import (
    INPUT_NAMES,
    SAMPLE_TIME,
    STATE_NAMES,
    RGBlimpParameters,
    body_accelerations,
    rgblimp_dynamics,
    rk4_step,
)

DATA = Path(os.environ.get("FLIGHTGP_RGBLIMP_DATA", EXCERPT_FOLDER))
PUBLISHED = RGBlimpParameters()

#: The first row of the source's data_1.csv (zhu-yj/ABNODE, MIT licence), the 38 columns of
#: SOURCE_COLUMNS: a spiral at 0.26 m/s with thrusts 0.01666 N and 0.05292 N.
RECORDED_ROW = (
    0.0909488706576665, 0.207607196554284, -1.10977807000056, -0.021610771892882, 0.0847253505835717,
    1.11115334440126, 0.24244823748133, -0.0177197330326424, 0.0909952339158465, -0.0106494636970684,
    0.0721749269355973, -0.273504107349412, 0.0747, 0.0006, 0.238, 0, 0, 0, 0.01666, 0.05292, 0, 0, 0,
    0.15247081435165, -0.0114733428104569, 0.04676603544705, 0.0152478070077939, 0.0100739080812756,
    -0.152840040060113, 0.359049603104353, -0.0683195219418275, 0.359441261267285, 0.0762916464529793,
    0.34433862859577, 0.067277588855878, 0.20890019204962, -0.134183803865867, 0.944775621161494,
)
RECORDED_STATE = np.array(RECORDED_ROW[:12])
RECORDED_INPUTS = np.array([RECORDED_ROW[18], RECORDED_ROW[19], *RECORDED_ROW[12:15]])
RECORDED_ACCELERATIONS = np.array(RECORDED_ROW[31:37])

#: Port tolerance, m/s^2 and rad/s^2. Measured over all 105 flights of the shared folder:
#: 3.8e-10 (wb_dot_sim_2) with RECORDED_MODEL_PARAMETERS, the rounding of the files' 15
#: significant digits carried through the solve; the accelerations themselves reach 0.5.
PORT_TOLERANCE = 1e-9

AERODYNAMIC_COEFFICIENTS = tuple(field.name for field in dataclasses.fields(RGBlimpParameters)
                                 if field.name.startswith("c_"))


@pytest.fixture(scope="module")
def flights():
    """Every flight of :data:`DATA`, read once (about 1 s for 105 files)."""
    if not DATA.is_dir():
        pytest.skip(f"the RGBlimp recordings are not at {DATA} (set FLIGHTGP_RGBLIMP_DATA to a copy of "
                    "the folder data/ of zhu-yj/ABNODE)")
    return [read_rgblimp_flight(DATA / f"data_{number}.csv")
            for numbers in flights_by_configuration(DATA).values() for number in numbers]


@pytest.fixture(scope="module")
def stacked(flights):
    """All recorded states (n, 12), inputs (n, 5) and model accelerations (n, 6), stacked."""
    return (np.concatenate([flight.recording.outputs for flight in flights]),
            np.concatenate([flight.recording.inputs for flight in flights]),
            np.concatenate([flight.model_accelerations for flight in flights]))


# --- the port test ---------------------------------------------------------------------------

def test_port_reproduces_the_recorded_row_carried_here():
    assert np.abs(body_accelerations(RECORDED_STATE, RECORDED_INPUTS, RECORDED_MODEL_PARAMETERS)
                  - RECORDED_ACCELERATIONS).max() < PORT_TOLERANCE


def test_port_reproduces_the_source_models_accelerations_in_every_recording(flights, stacked):
    states, inputs, recorded = stacked
    assert len(flights) >= 6  # the excerpt's six; the shared folder holds 105 (the 4j+4 are held back)
    error = np.abs(body_accelerations(states, inputs, RECORDED_MODEL_PARAMETERS) - recorded)
    assert error.max() < PORT_TOLERANCE, f"max error per column {error.max(axis=0)}"


def test_published_four_decimal_coefficients_differ_only_by_their_rounding(stacked):
    # With utils/parameters.py as published, the largest difference is 1.06e-4 rad/s^2
    # (wb_dot_sim_2, the pitch acceleration; rms over all columns 1.3e-5): the six rounded
    # coefficients (c_d_alpha2 by 5e-6, c_l0, c_l_alpha, c_my_beta4 by 2e-5, c_my0 by 1.5e-5,
    # c_my_alpha by 3e-5). A wrong term (a sign, an axis, degrees) would be off by 1e-2 or more.
    states, inputs, recorded = stacked
    error = np.abs(body_accelerations(states, inputs, PUBLISHED) - recorded).max()
    assert 1e-5 < error < 2e-4


def test_least_squares_recovers_the_recorded_coefficients_which_round_to_the_published(stacked):
    """The accelerations are affine in the 18 aerodynamic coefficients (forces and moments are
    linear in them; the mass matrix and the rotations do not depend on them), so fitting them to
    the recorded columns is linear least squares, exact up to the files' rounding."""
    states, inputs, recorded = (array[::50] for array in stacked)  # 3.8k rows are plenty for 18 unknowns
    zero = dataclasses.replace(PUBLISHED, **dict.fromkeys(AERODYNAMIC_COEFFICIENTS, 0.0))
    base = body_accelerations(states, inputs, zero)
    basis = np.stack([(body_accelerations(states, inputs, dataclasses.replace(zero, **{name: 1.0})) - base).ravel()
                      for name in AERODYNAMIC_COEFFICIENTS], axis=1)
    fitted, *_ = np.linalg.lstsq(basis, (recorded - base).ravel(), rcond=None)
    assert np.abs(basis @ fitted - (recorded - base).ravel()).max() < PORT_TOLERANCE
    for name, value in zip(AERODYNAMIC_COEFFICIENTS, fitted):
        # Measured: each within 3.3e-9 of RECORDED_MODEL_PARAMETERS (the largest: c_my_beta4).
        assert value == pytest.approx(getattr(RECORDED_MODEL_PARAMETERS, name), abs=1e-7), name
        assert round(value, 4) == pytest.approx(getattr(PUBLISHED, name), abs=1e-12), name


# --- properties of the equations ---------------------------------------------------------------

def level_at_rest(*, thrust_left=0.0, thrust_right=0.0):
    """Level, at rest, with the hull's CG and the gondola straight below the CB."""
    params = dataclasses.replace(PUBLISHED, hull_cg=(0.0, 0.0, 0.0079))
    inputs = np.array([thrust_left, thrust_right, 0.0, 0.0, 0.238])
    return np.zeros(len(STATE_NAMES)), inputs, params


def test_at_rest_with_the_masses_below_the_buoyancy_centre_it_sinks_without_turning():
    state, inputs, params = level_at_rest()
    total_mass = params.hull_mass + params.gondola_mass
    expected = [0, 0, (total_mass - params.buoyancy_mass) / total_mass * params.gravity, 0, 0, 0]
    np.testing.assert_allclose(body_accelerations(state, inputs, params), expected, rtol=1e-13, atol=1e-15)


def test_thrust_pushes_forward_pitches_up_and_the_stronger_left_propeller_yaws_right():
    state, inputs, params = level_at_rest(thrust_left=0.03, thrust_right=0.01)
    _, no_thrust, _ = level_at_rest()
    accelerations = body_accelerations(state, inputs, params) - body_accelerations(state, no_thrust, params)
    assert accelerations[0] > 0  # forward
    assert accelerations[4] > 0  # thrust below the CB: nose up (Q_dot > 0, z down)
    assert accelerations[5] > 0  # left > right: nose right (R_dot > 0)
    # Only the differential thrust yaws: equal thrusts leave R_dot at zero.
    state, inputs, params = level_at_rest(thrust_left=0.02, thrust_right=0.02)
    assert body_accelerations(state, inputs, params)[5] == pytest.approx(0.0, abs=1e-15)


def test_kinematics_rotate_the_body_velocity_and_the_dynamics_append_the_accelerations():
    derivative = rgblimp_dynamics(RECORDED_STATE, RECORDED_INPUTS, PUBLISHED)
    speed = np.linalg.norm(RECORDED_STATE[6:9])
    assert np.linalg.norm(derivative[:3]) == pytest.approx(speed, rel=1e-12)  # a rotation
    assert derivative[5] == pytest.approx(  # psi_dot = (sin phi Q + cos phi R) / cos theta
        (math.sin(RECORDED_STATE[3]) * RECORDED_STATE[10] + math.cos(RECORDED_STATE[3]) * RECORDED_STATE[11])
        / math.cos(RECORDED_STATE[4]), rel=1e-12)
    np.testing.assert_array_equal(derivative[6:], body_accelerations(RECORDED_STATE, RECORDED_INPUTS, PUBLISHED))


def test_leading_axes_broadcast_and_rows_are_independent():
    rng = np.random.default_rng(0)
    states = RECORDED_STATE + 0.05 * rng.standard_normal((4, 3, 12))
    inputs = RECORDED_INPUTS + np.array([0.0, 0.0, 0.01, 0.0, 0.0]) * rng.standard_normal((3, 1))
    together = rgblimp_dynamics(states, inputs, PUBLISHED)
    assert together.shape == (4, 3, 12)
    one_by_one = np.array([[rgblimp_dynamics(states[i, j], inputs[j], PUBLISHED) for j in range(3)]
                           for i in range(4)])
    np.testing.assert_allclose(together, one_by_one, rtol=1e-12, atol=1e-15)


def test_names_and_parameters():
    assert len(STATE_NAMES) == 12 and len(INPUT_NAMES) == 5
    assert PUBLISHED.hull_cg == (-0.0432, -0.0003, 0.0079) and PUBLISHED.c_my_beta4 == 5.2357
    with pytest.raises(BadInputError, match="inertia needs 3 numbers"):
        RGBlimpParameters(inertia=(0.03, 0.015))
    with pytest.raises(BadInputError, match="air_density must be finite"):
        RGBlimpParameters(air_density=float("nan"))


# --- the RK4 step --------------------------------------------------------------------------

def fine_solution(state, inputs, params):
    """The state one sample later by DOP853 at rtol 1e-13, far below RK4's error."""
    solution = solve_ivp(lambda _t, y: rgblimp_dynamics(y, inputs, params), (0.0, SAMPLE_TIME), state,
                         method="DOP853", rtol=1e-13, atol=1e-15)
    return solution.y[:, -1]


def test_rk4_step_matches_a_fine_integration_over_one_sample():
    # RK4's local error is about h^5 times the state's fifth derivative; h^5 = 1.3e-9 s^5 at
    # 60 Hz. Measured here 8e-11; over every 50th state of four flights (spiral and straight)
    # at most 2.6e-9 (W). A second-order step would be off by about h^3 = 5e-6 times the third.
    step = rk4_step(RECORDED_STATE, RECORDED_INPUTS, PUBLISHED)
    np.testing.assert_allclose(step, fine_solution(RECORDED_STATE, RECORDED_INPUTS, PUBLISHED), rtol=0, atol=1e-9)


def test_rk4_step_wraps_the_heading_into_plus_minus_pi_as_the_source():
    state = RECORDED_STATE.copy()
    state[5], state[11] = math.pi - 1e-4, 0.3  # yawing right through +pi within the step
    step = rk4_step(state, RECORDED_INPUTS, PUBLISHED)
    fine = fine_solution(state, RECORDED_INPUTS, PUBLISHED)
    assert fine[5] > math.pi and -math.pi <= step[5] < -math.pi + 0.01
    assert step[5] == pytest.approx(fine[5] - 2 * math.pi, abs=1e-9)


def test_rk4_step_broadcasts_like_the_dynamics():
    states = np.stack([RECORDED_STATE, RECORDED_STATE + 0.01])
    steps = rk4_step(states, RECORDED_INPUTS, PUBLISHED)
    np.testing.assert_allclose(steps[1], rk4_step(states[1], RECORDED_INPUTS, PUBLISHED), rtol=1e-13, atol=1e-15)


# --- the reader ----------------------------------------------------------------------------

def write_recording(folder: Path, name: str = "data_7.csv", *, header=SOURCE_COLUMNS, rows=None) -> Path:
    """A recording of the source's format: three copies of RECORDED_ROW unless ``rows``."""
    rows = [[repr(float(value)) for value in RECORDED_ROW]] * 3 if rows is None else rows
    path = folder / name
    path.write_text("\n".join([",".join(header)] + [",".join(row) for row in rows]) + "\n", encoding="utf-8")
    return path


def test_reader_returns_states_inputs_and_both_accelerations(tmp_path):
    flight = read_rgblimp_flight(write_recording(tmp_path))
    assert (flight.number, flight.configuration) == (7, 1)
    recording = flight.recording
    np.testing.assert_array_equal(recording.time, [0.0, 1 / 60, 2 / 60])
    assert recording.output_names == STATE_NAMES and recording.input_names == INPUT_NAMES
    np.testing.assert_array_equal(recording.outputs[0], RECORDED_STATE)
    np.testing.assert_array_equal(recording.inputs[0], RECORDED_INPUTS)
    np.testing.assert_array_equal(flight.model_accelerations[0], RECORDED_ACCELERATIONS)
    np.testing.assert_array_equal(flight.measured_accelerations[0], RECORDED_ROW[23:29])
    assert recording.metadata == {"vehicle": "rgblimp", "source": "zhu-yj/ABNODE data/data_7.csv", "flight": 7,
                                  "configuration": 1, "sample_time": 1 / 60}


def test_reader_reads_quoted_numbers_and_skips_blank_lines(tmp_path):
    path = write_recording(tmp_path, rows=[[f'"{value!r}"' for value in RECORDED_ROW]] * 2 + [[""]])
    flight = read_rgblimp_flight(path)
    assert len(flight.recording.time) == 2
    np.testing.assert_array_equal(flight.recording.outputs[1], RECORDED_STATE)


def bad_cell(column: str, text: str) -> list[list[str]]:
    """Three rows of RECORDED_ROW, the second with ``text`` in ``column``."""
    rows = [[repr(float(value)) for value in RECORDED_ROW] for _ in range(3)]
    rows[1][SOURCE_COLUMNS.index(column)] = text
    return rows


@pytest.mark.parametrize(("name", "header", "rows", "message"), [
    ("data_7.csv", SOURCE_COLUMNS[:-1], None, r"row 1: 37 columns, but an RGBlimp recording has the source's 38"),
    ("data_7.csv", ("p_2", "p_1", *SOURCE_COLUMNS[2:]), None, r"row 1, column 1 \('p_2'\): expected 'p_1'"),
    ("data_7.csv", SOURCE_COLUMNS, bad_cell("e_2", "nan"), r"row 3, column 5 \('e_2'\): 'nan' is not a finite number"),
    ("data_7.csv", SOURCE_COLUMNS, bad_cell("Fl_series", "inf"), r"row 3, column 19 .*'inf' is not a finite"),
    ("data_7.csv", SOURCE_COLUMNS, bad_cell("vb_1", "fast"), r"row 3, column 7 \('vb_1'\): 'fast' is not a number"),
    ("data_7.csv", SOURCE_COLUMNS, bad_cell("wb_3", ""), r"row 3, column 12 \('wb_3'\): empty cell"),
    ("data_7.csv", SOURCE_COLUMNS, bad_cell("e_3", "63.7"), r"row 3, column 6 \('e_3'\): \|e_3\| = 63.7 .*degrees"),
    ("data_7.csv", SOURCE_COLUMNS, [["0.1"] * 37] * 3, r"row 2: 37 fields, but the header has 38 columns"),
    ("data_7.csv", SOURCE_COLUMNS, [[repr(float(v)) for v in RECORDED_ROW]], r"1 data row\(s\)"),
    ("flight_7.csv", SOURCE_COLUMNS, None, r"named data_N.csv"),
])
def test_reader_refuses_bad_files_with_one_line(tmp_path, name, header, rows, message):
    path = write_recording(tmp_path, name, header=header, rows=rows)
    with pytest.raises(BadInputError, match=message) as error:
        read_rgblimp_flight(path)
    assert "\n" not in str(error.value) and str(path) in str(error.value)


def test_reader_refuses_missing_and_empty_files(tmp_path):
    with pytest.raises(BadInputError, match="no such RGBlimp recording"):
        read_rgblimp_flight(tmp_path / "data_1.csv")
    (tmp_path / "data_2.csv").write_text("", encoding="utf-8")
    with pytest.raises(BadInputError, match="row 1: the file is empty"):
        read_rgblimp_flight(tmp_path / "data_2.csv")


def test_configurations_and_the_flights_a_folder_holds(tmp_path):
    assert [configuration_index(n) for n in (1, 4, 5, 120, 121, 140)] == [0, 0, 1, 29, 30, 34]
    with pytest.raises(BadInputError, match="start at 1"):
        configuration_index(0)
    for number in (2, 1, 5, 121):
        write_recording(tmp_path, f"data_{number}.csv")
    (tmp_path / "notes.csv").write_text("x\n", encoding="utf-8")
    (tmp_path / "data_0.csv").write_text("x\n", encoding="utf-8")
    assert flights_by_configuration(tmp_path) == {0: (1, 2), 1: (5,), 30: (121,)}
    with pytest.raises(BadInputError, match="no such folder"):
        flights_by_configuration(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BadInputError, match=r"no RGBlimp recordings \(data_N.csv\)"):
        flights_by_configuration(tmp_path / "empty")


def test_the_data_folder_holds_the_flights_of_all_35_configurations(flights):
    if DATA == EXCERPT_FOLDER:
        pytest.skip("the repository's excerpt holds two configurations; set FLIGHTGP_RGBLIMP_DATA to the "
                    "source's data/ folder for this test")
    by_configuration = flights_by_configuration(DATA)
    assert list(by_configuration) == list(range(35))
    # Flights 4j+1 .. 4j+3 of each (4j+4 is held back here; a full copy of the source has it too).
    assert all(set(numbers) >= {4 * j + 1, 4 * j + 2, 4 * j + 3} and set(numbers) <= {4 * j + k for k in (1, 2, 3, 4)}
               for j, numbers in by_configuration.items())
    assert all(flight.recording.metadata["sample_time"] == SAMPLE_TIME for flight in flights)
