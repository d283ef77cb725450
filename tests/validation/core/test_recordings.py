"""Recording files: exact round trip, atomic writes, and one clear line for every malformed file."""
import json
import os
import re
from types import SimpleNamespace

import numpy as np
import pytest

from validation.core.errors import BadInputError
from validation.core.files import WRITTEN_LIST
from validation.core.recordings import Recording, column_unit, write_recording
from validation.vehicles import read_recording

# A vehicle that needs nothing but its names (read_recording only uses name, inputs and states).
VEHICLE = SimpleNamespace(name="testcraft", input_names=("elevator", "aileron"),
                          state_names=("u", "q", "theta", "psi"))
GOOD_ROWS = [
    "time,elevator,aileron,q,theta",
    "0.0,0.0,0.0,0.0,0.01",
    "0.01,0.1,0.0,0.002,0.01",
    "0.02,0.1,0.0,0.004,0.01",
    "0.03,0.1,0.0,0.006,0.02",
    "0.04,0.0,0.0,0.004,0.02",
]


def _recording(n=200, seed=0):
    rng = np.random.default_rng(seed)
    return Recording(
        time=np.arange(n) * 0.01,  # t = k*h, not repeated addition
        inputs=rng.normal(scale=0.1, size=(n, 3)),
        input_names=("elevator", "aileron", "rudder"),
        outputs=np.column_stack([50 + rng.normal(size=n), rng.normal(scale=0.1, size=(n, 3))]),
        output_names=("u", "q", "theta", "psi"),
        metadata={"vehicle": "jsbsim:c172x", "seed": seed, "trim": {"elevator": 0.25}},
    )


def _write(tmp_path, rows, sidecar=None, name="run.csv"):
    path = tmp_path / name
    path.write_text("\n".join(rows) + "\n")
    if sidecar is not None:
        path.with_suffix(".json").write_text(sidecar if isinstance(sidecar, str) else json.dumps(sidecar))
    return path


def _replace(rows, line, text):
    """``rows`` with 1-based file line ``line`` replaced by ``text``."""
    rows = list(rows)
    rows[line - 1] = text
    return rows


def _drop_column(rows, index):
    """``rows`` without the 0-based column ``index``."""
    return [",".join(cell for k, cell in enumerate(row.split(",")) if k != index) for row in rows]


def test_round_trip_is_exact(tmp_path):
    recording = _recording()
    recording.inputs[3, 0] = 1 / 3  # needs all 17 significant digits
    recording.outputs[4, 1] = 5e-324  # smallest subnormal
    path = tmp_path / "deep" / "folder" / "run.csv"  # folders are created
    write_recording(path, recording)
    back = read_recording(path)  # vehicle from the sidecar
    assert np.array_equal(back.time, recording.time)
    assert np.array_equal(back.inputs, recording.inputs)
    assert np.array_equal(back.outputs, recording.outputs)
    assert back.input_names == ("elevator", "aileron", "rudder")
    assert back.output_names == ("u", "q", "theta", "psi")
    assert back.metadata == recording.metadata
    assert path.read_text().splitlines()[0] == "time,elevator,aileron,rudder,u,q,theta,psi"


def test_write_leaves_only_the_two_files_and_the_list_of_files_written(tmp_path):
    write_recording(tmp_path / "run.csv", _recording())
    assert sorted(os.listdir(tmp_path)) == [WRITTEN_LIST, "run.csv", "run.json"]


def test_failed_write_keeps_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    path = tmp_path / "run.csv"
    write_recording(path, _recording(seed=1))
    before = path.read_bytes()

    def fail(source, destination):
        raise OSError("disk full")

    monkeypatch.setattr("validation.core.files.os.replace", fail)
    with pytest.raises(OSError, match="disk full"):
        write_recording(path, _recording(seed=2))
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == [WRITTEN_LIST, "run.csv", "run.json"]


def test_write_refuses_non_finite_values_and_writes_nothing(tmp_path):
    recording = _recording()
    recording.outputs[50, 1] = np.nan
    with pytest.raises(BadInputError, match=r"column 'q'.*t = 0.5 s is not finite"):
        write_recording(tmp_path / "run.csv", recording)
    assert os.listdir(tmp_path) == []


def test_write_needs_a_csv_name(tmp_path):
    with pytest.raises(BadInputError, match=r"must end in \.csv"):
        write_recording(tmp_path / "run.json", _recording())


def test_vehicle_puts_columns_in_its_order(tmp_path):
    rows = ["time,theta,aileron,q,elevator", "0,0.1,0.2,0.3,0.4", "0.5,0.5,0.6,0.7,0.8"]
    recording = read_recording(_write(tmp_path, rows), vehicle=VEHICLE)
    assert recording.input_names == ("elevator", "aileron")
    assert recording.output_names == ("q", "theta")
    assert recording.inputs[1].tolist() == [0.8, 0.6]
    assert recording.outputs[1].tolist() == [0.7, 0.5]


def test_without_vehicle_registry_inputs_are_inputs(tmp_path):
    rows = ["time,q,theta_1s,r,theta_0,theta_0T,theta_1c", "0,0.1,0.2,0.3,0.4,0,0",
            "0.5,0.5,0.06,0.7,0.08,0,0"]
    recording = read_recording(_write(tmp_path, rows))
    assert recording.input_names == ("theta_1s", "theta_0", "theta_0T", "theta_1c")
    assert recording.output_names == ("q", "r")


def test_without_vehicle_unknown_column_is_named(tmp_path):
    with pytest.raises(BadInputError, match=r"row 1, column 2 \('foo'\): unknown column"):
        read_recording(_write(tmp_path, ["time,foo", "0,1", "0.01,2"]))


def test_without_vehicle_columns_must_fit_one_vehicle(tmp_path):
    # q alone, with none of the Bo105 inputs: no vehicle records that.
    with pytest.raises(BadInputError, match="fit no vehicle"):
        read_recording(_write(tmp_path, ["time,q", "0,0.1", "0.01,0.2"]))


def test_degrees_within_magnitude_limits_caught_by_kinematics(tmp_path):
    """A gentle manoeuvre logged in degrees: every value is below the radian limits, but
    d theta/dt is 57.3 x q."""
    time = np.arange(200) * 0.01
    q = 0.05 * np.sin(2 * np.pi * 0.5 * time)  # rad/s
    theta = np.degrees(np.cumsum(q) * 0.01)  # deg, at most 0.9 "rad": inside the limit
    rows = ["time,theta_0,theta_1s,theta_1c,theta_0T,q,theta"]
    rows += [f"{t!r},0,0,0,0,{a!r},{b!r}" for t, a, b in zip(time.tolist(), q.tolist(), theta.tolist())]
    with pytest.raises(BadInputError, match=r"column 7 \('theta'\).*looks like degrees"):
        read_recording(_write(tmp_path, rows))
    # The same data in radians passes.
    rows = rows[:1] + [f"{t!r},0,0,0,0,{a!r},{b!r}"
                       for t, a, b in zip(time.tolist(), q.tolist(), np.radians(theta).tolist())]
    assert read_recording(_write(tmp_path, rows)).output_names == ("q", "theta")


def test_sidecar_may_allow_uneven_sampling(tmp_path):
    rows = _replace(GOOD_ROWS, 5, "0.035,0.1,0.0,0.006,0.02")
    recording = read_recording(_write(tmp_path, rows, {"uneven_sampling": True}), vehicle=VEHICLE)
    assert recording.time[3] == 0.035


def test_unwrapped_heading_is_not_degrees(tmp_path):
    rows = ["time,elevator,aileron,psi", "0,0,0,3.2", "0.01,0,0,9.5"]  # 1.5 turns, in rad
    assert read_recording(_write(tmp_path, rows), vehicle=VEHICLE).output("psi")[1] == 9.5


def test_units():
    assert column_unit("q") == "rad/s"
    assert column_unit("theta_1s") == "rad"
    assert column_unit("u_gondola") == "1"
    assert column_unit("altitude") == "?"


# (id, rows, sidecar, vehicle, fragments the one-line message must contain). Rows are file lines:
# the header is row 1, so GOOD_ROWS[k] is row k + 1.
BAD_FILES = [
    ("empty file", [""], None, VEHICLE, ["row 1", "empty"]),
    ("header only", GOOD_ROWS[:1], None, VEHICLE, ["row 2", "at least two samples"]),
    ("one sample", GOOD_ROWS[:2], None, VEHICLE, ["row 3", "at least two samples"]),
    ("no time column", _replace(GOOD_ROWS, 1, "t,elevator,aileron,q,theta"), None, VEHICLE,
     ["row 1, column 1 ('t')", "first column must be 'time'"]),
    ("time not first", _replace(GOOD_ROWS, 1, "elevator,time,aileron,q,theta"), None, VEHICLE,
     ["row 1, column 1 ('elevator')", "'time' must be the first column"]),
    ("unknown column", _replace(GOOD_ROWS, 1, "time,elevator,aileron,q,alpha"), None, VEHICLE,
     ["row 1, column 5 ('alpha')", "unknown column for vehicle testcraft"]),
    ("missing input", _drop_column(GOOD_ROWS, 2), None, VEHICLE, ["row 1", "missing input column(s) 'aileron'"]),
    ("no output", _drop_column(_drop_column(GOOD_ROWS, 4), 3), None, VEHICLE,
     ["row 1", "no output columns", "u, q, theta, psi"]),
    ("repeated column", _replace(GOOD_ROWS, 1, "time,elevator,aileron,q,q"), None, VEHICLE,
     ["row 1, column 5 ('q')", "repeated column"]),
    ("nan", _replace(GOOD_ROWS, 4, "0.02,0.1,0.0,nan,0.01"), None, VEHICLE,
     ["row 4, column 4 ('q')", "'nan' is not a finite number"]),
    ("inf", _replace(GOOD_ROWS, 3, "0.01,0.1,0.0,0.002,-inf"), None, VEHICLE,
     ["row 3, column 5 ('theta')", "'-inf' is not a finite number"]),
    ("text", _replace(GOOD_ROWS, 5, "0.03,high,0.0,0.006,0.02"), None, VEHICLE,
     ["row 5, column 2 ('elevator')", "'high' is not a number"]),
    ("empty cell", _replace(GOOD_ROWS, 5, "0.03,0.1,,0.006,0.02"), None, VEHICLE,
     ["row 5, column 3 ('aileron')", "empty cell"]),
    ("short row", _replace(GOOD_ROWS, 3, "0.01,0.1,0.0,0.002"), None, VEHICLE,
     ["row 3, column 5 ('theta')", "missing value"]),
    ("long row", _replace(GOOD_ROWS, 6, "0.04,0.0,0.0,0.004,0.02,7"), None, VEHICLE,
     ["row 6, column 6", "extra value '7'"]),
    ("duplicate time", _replace(GOOD_ROWS, 4, "0.01,0.1,0.0,0.004,0.01"), None, VEHICLE,
     ["row 4, column 1 ('time')", "time repeats"]),
    ("time goes backwards", _replace(GOOD_ROWS, 5, "0.015,0.1,0.0,0.006,0.02"), None, VEHICLE,
     ["row 5, column 1 ('time')", "time goes backwards"]),
    ("uneven sampling", _replace(GOOD_ROWS, 5, "0.035,0.1,0.0,0.006,0.02"), None, VEHICLE,
     ["row 5, column 1 ('time')", "uneven sampling", '"uneven_sampling": true']),
    ("time in ms", ["time,elevator,aileron,q", "0,0,0,0", "10,0,0,0", "20,0,0,0"], None, VEHICLE,
     ["row 3, column 1 ('time')", "time steps by 10 s", "Is time in milliseconds? flightgp reads seconds"]),
    ("time in ms at 1 kHz", ["time,elevator,aileron,q", "0,0,0,0", "1,0,0,0", "2,0,0,0"], None, VEHICLE,
     ["row 3, column 1 ('time')", "time steps by 1 s", "Is time in milliseconds?"]),
    ("rate in deg/s", _replace(GOOD_ROWS, 4, "0.02,0.1,0.0,11.5,0.01"), None, VEHICLE,
     ["row 4, column 4 ('q')", "looks like degrees; flightgp expects radians (rad/s)"]),
    ("attitude in deg", _replace(GOOD_ROWS, 6, "0.04,0.0,0.0,0.004,5.0"), None, VEHICLE,
     ["row 6, column 5 ('theta')", "looks like degrees; flightgp expects radians (rad)"]),
    ("heading in deg", ["time,elevator,aileron,psi", "0,0,0,180", "0.01,0,0,180"], None, VEHICLE,
     ["row 2, column 4 ('psi')", "looks like degrees"]),
    ("blade pitch in deg", ["time,theta_0,theta_1s,theta_1c,theta_0T,q", "0,0,0,0,0,0",
                            "0.01,0,1.0,0,0,0"], None, None,
     ["row 3, column 3 ('theta_1s')", "looks like degrees"]),
    ("malformed sidecar", GOOD_ROWS, '{"vehicle": "blimp",\n "seed": }', None,
     ["run.json, row 2, column 10", "malformed JSON sidecar"]),
    ("sidecar not an object", GOOD_ROWS, "[1, 2]", None, ["run.json, row 1, column 1", "JSON object"]),
    ("sidecar unknown vehicle", GOOD_ROWS, {"vehicle": "zeppelin"}, None,
     ["run.json", "key 'vehicle'", "unknown vehicle 'zeppelin'"]),
    ("sidecar vehicle mismatch", GOOD_ROWS, {"vehicle": "jsbsim:c172x"}, None,
     ["row 1", "missing input column(s) 'rudder'"]),
    ("sidecar uneven_sampling not bool", GOOD_ROWS, {"uneven_sampling": "yes"}, VEHICLE,
     ["run.json", "'uneven_sampling' must be true or false"]),
]


@pytest.mark.parametrize("rows, sidecar, vehicle, fragments",
                         [case[1:] for case in BAD_FILES], ids=[case[0] for case in BAD_FILES])
def test_bad_file_gives_one_line_naming_file_row_and_column(tmp_path, rows, sidecar, vehicle, fragments):
    path = _write(tmp_path, rows, sidecar)
    with pytest.raises(BadInputError) as caught:
        read_recording(path, vehicle=vehicle)
    message = str(caught.value)
    assert "\n" not in message
    assert str(tmp_path) in message  # the file (the CSV or its sidecar) by its full path
    for fragment in fragments:
        assert fragment in message


def test_missing_file_is_named(tmp_path):
    with pytest.raises(BadInputError, match=re.escape(f"{tmp_path / 'gone.csv'}: no such recording file")):
        read_recording(tmp_path / "gone.csv")


def test_unknown_vehicle_name_is_bad_input(tmp_path):
    with pytest.raises(BadInputError, match="unknown vehicle 'zeppelin'"):
        read_recording(_write(tmp_path, GOOD_ROWS), vehicle="zeppelin")


def test_good_rows_pass(tmp_path):
    """The rows every bad case is derived from are themselves valid (so each case tests one flaw)."""
    recording = read_recording(_write(tmp_path, GOOD_ROWS), vehicle=VEHICLE)
    assert recording.time.tolist() == [0.0, 0.01, 0.02, 0.03, 0.04]
