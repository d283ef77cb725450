"""Recordings: time histories of a vehicle's inputs and measured outputs.

The file format (docs/conventions.md, "Recording files"): CSV with one header row; first column ``time``
(s, strictly increasing, evenly sampled unless the sidecar says otherwise); the other columns
named exactly as the vehicle's inputs and states. An optional JSON sidecar ``<name>.json``
carries metadata (vehicle, flight condition, trim values, sensor noise).

:func:`write_recording` writes both files with every float in its shortest exact decimal form
(``repr``), so a write/read round trip returns the same numbers bit for bit, and it writes each
file to a temporary file in the same folder before renaming it, so a reader never sees half a
file. :func:`parse_recording` checks everything a user can get wrong and raises
:class:`~validation.core.errors.BadInputError` with one line naming the file, row (1-based line
number in the file; the header is row 1) and column. It knows vehicles only as objects with
names; :func:`validation.vehicles.read_recording` resolves vehicle names (given, or the
sidecar's ``vehicle`` key) through the registry.

Sidecar keys read here: ``uneven_sampling`` (``true`` lets ``time`` steps differ); ``vehicle`` is
resolved by the registry. Everything is kept as :attr:`Recording.metadata`.
"""
from __future__ import annotations

import csv
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from validation.core.errors import BadInputError
from validation.core.files import write_files_atomically
from validation.core.sampling import uneven_steps


@dataclass
class Recording:
    """One recording, in memory.

    Attributes
    ----------
    time : ndarray, shape (n,)
        Sample times, s, strictly increasing.
    inputs : ndarray, shape (n, n_inputs)
        Control inputs at each sample, in the units of ``input_names`` (rad for angles).
    input_names : tuple of str
        Column names of ``inputs``, e.g. ``("theta_0", "theta_1s", "theta_1c", "theta_0T")``.
    outputs : ndarray, shape (n, n_outputs)
        Measured states at each sample (SI units, rad, rad/s).
    output_names : tuple of str
        Column names of ``outputs``, a subset of the vehicle's states.
    metadata : dict
        JSON-serialisable extras (``vehicle``, ``sample_time``, ``seed``, ...).
    """

    time: np.ndarray
    inputs: np.ndarray
    input_names: tuple[str, ...]
    outputs: np.ndarray
    output_names: tuple[str, ...]
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.time = np.asarray(self.time, dtype=float)
        self.inputs = np.asarray(self.inputs, dtype=float).reshape(len(self.time), -1)
        self.outputs = np.asarray(self.outputs, dtype=float).reshape(len(self.time), -1)
        self.input_names = tuple(self.input_names)
        self.output_names = tuple(self.output_names)
        if self.inputs.shape[1] != len(self.input_names):
            raise ValueError(
                f"inputs has {self.inputs.shape[1]} columns but {len(self.input_names)} names"
            )
        if self.outputs.shape[1] != len(self.output_names):
            raise ValueError(
                f"outputs has {self.outputs.shape[1]} columns but {len(self.output_names)} names"
            )

    def input(self, name: str) -> np.ndarray:
        """Column ``name`` of the inputs, shape (n,)."""
        return self.inputs[:, self.input_names.index(name)]

    def output(self, name: str) -> np.ndarray:
        """Column ``name`` of the outputs, shape (n,)."""
        return self.outputs[:, self.output_names.index(name)]


# Unit of every column name the vehicles use, and the largest magnitude that is still plausible
# in that unit (None: no check). A larger value in an angle or rate column almost always means
# the column was written in degrees. "1" marks a normalised (dimensionless) command.
_MAX_ATTITUDE = math.pi        # |phi| <= pi, |theta| <= pi/2 by definition of Euler angles
_MAX_HEADING = 4 * math.pi     # heading may be unwrapped; two full turns is still plausible
_MAX_RATE = 10.0               # rad/s = 573 deg/s, beyond aerobatic roll rates (~400 deg/s)
_MAX_BLADE_PITCH = 0.5         # rad = 29 deg, more than a helicopter's whole control travel
_MAX_THRUST_ANGLE = 2 * math.pi  # the blimp's gondola fans may point anywhere in a full turn
_COLUMNS = {  # name: (unit, largest plausible magnitude or None, what it is)
    "time": ("s", None, "time"),
    # Bo105 (Padfield 2007) states and inputs; the blimp and JSBSim share phi, theta, psi.
    "u": ("m/s", None, "forward velocity"), "v": ("m/s", None, "lateral velocity"),
    "w": ("m/s", None, "vertical velocity (positive down)"),
    "p": ("rad/s", _MAX_RATE, "roll rate"), "q": ("rad/s", _MAX_RATE, "pitch rate"),
    "r": ("rad/s", _MAX_RATE, "yaw rate"),
    "phi": ("rad", _MAX_ATTITUDE, "roll angle"), "theta": ("rad", _MAX_ATTITUDE, "pitch angle"),
    "psi": ("rad", _MAX_HEADING, "heading"),
    "theta_0": ("rad", _MAX_BLADE_PITCH, "main-rotor collective pitch"),
    "theta_1s": ("rad", _MAX_BLADE_PITCH, "longitudinal cyclic pitch"),
    "theta_1c": ("rad", _MAX_BLADE_PITCH, "lateral cyclic pitch"),
    "theta_0T": ("rad", _MAX_BLADE_PITCH, "tail-rotor collective pitch (pedals)"),
    # Blimp (Ko et al. 2007): NED position, body velocities and rates, gondola angle mu.
    "x": ("m", None, "north position"), "y": ("m", None, "east position"),
    "z": ("m", None, "down position"),
    "U": ("m/s", None, "forward body velocity"), "V": ("m/s", None, "rightward body velocity"),
    "W": ("m/s", None, "downward body velocity"),
    "P": ("rad/s", _MAX_RATE, "roll rate"), "Q": ("rad/s", _MAX_RATE, "pitch rate"),
    "R": ("rad/s", _MAX_RATE, "yaw rate"),
    "u_gondola": ("1", None, "gondola fan command (positive pushes forward)"),
    "mu": ("rad", _MAX_THRUST_ANGLE, "gondola thrust angle (positive tilts the thrust up)"),
    "u_tail": ("1", None, "tail fan command (positive yaws the nose right)"),
    # RGBlimp (Zhu, Cheng & Zhang 2024; docs/rgblimp.md): the blimp's states, absolute inputs.
    "thrust_left": ("N", None, "left propeller thrust along body x"),
    "thrust_right": ("N", None, "right propeller thrust along body x"),
    "gondola_x": ("m", None, "gondola position along body x"),
    "gondola_y": ("m", None, "gondola position along body y"),
    "gondola_z": ("m", None, "gondola position along body z (positive below the centre of buoyancy)"),
    # JSBSim (validation.vehicles.jsbsim): normalised stick and pedal commands.
    "elevator": ("1", None, "elevator (pitch stick) command"),
    "aileron": ("1", None, "aileron (roll stick) command"), "rudder": ("1", None, "rudder pedal command"),
    "collective": ("1", None, "collective lever command"),
    "longitudinal_cyclic": ("1", None, "longitudinal cyclic stick command"),
    "lateral_cyclic": ("1", None, "lateral cyclic stick command"),
    "pedal": ("1", None, "tail rotor pedal command"),
}
_UNKNOWN_COLUMN = ("?", None, None)


def column_unit(name: str) -> str:
    """SI unit of column ``name`` (``"1"``: normalised command; ``"?"``: not a known column)."""
    return _COLUMNS.get(name, _UNKNOWN_COLUMN)[0]


def column_phrase(name: str) -> str:
    """What column ``name`` is, in words (``"pitch rate"``, ``"longitudinal cyclic pitch"``): the
    one phrase FMU variable descriptions, reports and plots use; the name itself for an unknown
    column."""
    return _COLUMNS.get(name, _UNKNOWN_COLUMN)[2] or name


def column_limit(name: str) -> float | None:
    """Largest plausible magnitude of column ``name`` in flightgp's units, or None if unbounded.

    Angles use the limits of the degrees check; normalised commands (unit ``1``) span full
    travel, so 1.
    """
    unit, limit, _ = _COLUMNS.get(name, _UNKNOWN_COLUMN)
    return 1.0 if unit == "1" else limit


def sidecar_path(path: str | os.PathLike) -> Path:
    """The JSON sidecar that belongs to recording ``path`` (``run.csv`` -> ``run.json``)."""
    return Path(path).with_suffix(".json")


def write_recording(path: str | os.PathLike, recording: Recording) -> None:
    """Write ``recording`` to ``path`` (CSV, must end in ``.csv``) and its JSON sidecar.

    The CSV holds ``time``, the inputs and the outputs, in that order; the sidecar holds
    ``recording.metadata``. Both are written as one atomic step
    (:func:`~validation.core.files.write_files_atomically`): either both are replaced or neither.
    """
    write_files_atomically(recording_files(path, recording))


def recording_files(path: str | os.PathLike, recording: Recording) -> dict:
    """The CSV and sidecar of ``recording`` as ``{path: text}``, for
    :func:`~validation.core.files.write_files_atomically` (with any other files of the same step).

    Raises
    ------
    BadInputError
        If ``path`` does not end in ``.csv``, column names repeat, ``time`` is not strictly
        increasing, or a value is not finite (typically a simulation that diverged).
    """
    path = Path(path)
    if path.suffix != ".csv":
        raise BadInputError(f"{path}: a recording file name must end in .csv")
    names = ("time", *recording.input_names, *recording.output_names)
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise BadInputError(f"{path}: column names repeat: {', '.join(repeated)}")
    table = np.column_stack([recording.time, recording.inputs, recording.outputs])
    bad = np.argwhere(~np.isfinite(table))
    if len(bad):
        row, column = bad[0]
        raise BadInputError(
            f"{path}: refusing to write column {names[column]!r}: value {table[row, column]} at "
            f"t = {recording.time[row]:g} s is not finite (did the simulation diverge? try a "
            "smaller amplitude)"
        )
    if np.any(np.diff(recording.time) <= 0):
        raise BadInputError(f"{path}: refusing to write: time is not strictly increasing")
    lines = [",".join(names)] + [",".join(map(repr, row)) for row in table.tolist()]
    sidecar = json.dumps(recording.metadata, indent=2, sort_keys=True, allow_nan=False,
                         default=_json_default)
    return {path: "\n".join(lines) + "\n", sidecar_path(path): sidecar + "\n"}


def parse_recording(path: str | os.PathLike, *, vehicle=None, candidates=()) -> Recording:
    """Read and check the recording at ``path`` and its sidecar, for a vehicle given as an object.

    Most callers want :func:`validation.vehicles.read_recording`, which also takes a vehicle
    name or the one the sidecar names.

    Parameters
    ----------
    path : str or path-like
        The CSV file.
    vehicle : object, optional
        The vehicle the recording must fit: anything with ``name``, ``input_names`` and
        ``state_names``. With it, every one of its inputs must be present, the outputs must be a
        non-empty subset of its states, any other column is an error, and the columns come back
        in the vehicle's order.
    candidates : sequence of objects like ``vehicle``
        Without ``vehicle``: the vehicles the columns may belong to; the first whose inputs all
        appear and whose states cover the rest decides which columns are inputs (file order).

    Returns
    -------
    Recording
        ``metadata`` is the sidecar's content (``{}`` without a sidecar).

    Raises
    ------
    BadInputError
        One line naming file, row and column: missing or empty file, header problems (``time``
        not first, missing, unknown or repeated columns), ragged rows, text or non-finite
        values, ``time`` not strictly increasing or unevenly sampled, angles or rates so large
        that they look like degrees, malformed sidecar.
    """
    path = Path(path)
    metadata = read_sidecar(path)
    header, rows, line_numbers = _read_table(path)
    input_names, output_names = _split_columns(path, header, vehicle, candidates)
    table = _parse_numbers(path, header, rows, line_numbers)
    _check_time(path, table[:, 0], line_numbers,
                uneven_allowed=metadata.get("uneven_sampling", False))
    _check_radians(path, header, table, line_numbers)
    _check_angle_rate_consistency(path, header, table)
    column = {name: index for index, name in enumerate(header)}
    return Recording(
        time=table[:, 0],
        inputs=table[:, [column[name] for name in input_names]],
        input_names=input_names,
        outputs=table[:, [column[name] for name in output_names]],
        output_names=output_names,
        metadata=metadata,
    )


def _json_default(value):
    """Make numpy scalars and arrays JSON-serialisable (used by ``json.dumps``)."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    raise TypeError(f"metadata value {value!r} of type {type(value).__name__} is not JSON-serialisable")


def _where(path: Path, row: int, column: int | None = None, name: str | None = None) -> str:
    """``"run.csv, row 5, column 3 ('q')"``: the location prefix of every message."""
    where = f"{path}, row {row}"
    if column is not None:
        where += f", column {column + 1}"
    if name is not None:
        where += f" ({name!r})"
    return where


def read_sidecar(path: Path) -> dict:
    """The sidecar of ``path`` as a dict (``{}`` if there is none)."""
    sidecar = sidecar_path(path)
    if sidecar == path or not sidecar.is_file():
        return {}
    try:
        metadata = json.loads(sidecar.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise BadInputError(
            f"{sidecar}, row {error.lineno}, column {error.colno}: malformed JSON sidecar: {error.msg}"
        ) from None
    except UnicodeDecodeError:
        raise BadInputError(f"{sidecar}: the sidecar is not UTF-8 text") from None
    if not isinstance(metadata, dict):
        raise BadInputError(
            f"{sidecar}, row 1, column 1: the sidecar must be a JSON object "
            f"({{\"vehicle\": ..., ...}}), not a {type(metadata).__name__}"
        )
    if not isinstance(metadata.get("uneven_sampling", False), bool):
        raise BadInputError(f"{sidecar}: key 'uneven_sampling' must be true or false")
    return metadata


def _read_table(path: Path) -> tuple[list[str], list[list[str]], list[int]]:
    """Header, data rows (lists of cell text) and each row's 1-based line number in the file."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as file:
            reader = csv.reader(file)
            header, rows, line_numbers = None, [], []
            for row in reader:
                if not row:  # blank line
                    continue
                if header is None:
                    header = [name.strip() for name in row]
                    header_line = reader.line_num
                    continue
                if len(row) != len(header):
                    _raise_ragged(path, reader.line_num, header, row)
                rows.append(row)
                line_numbers.append(reader.line_num)
    except FileNotFoundError:
        raise BadInputError(f"{path}: no such recording file") from None
    except IsADirectoryError:
        raise BadInputError(f"{path}: is a folder, not a recording file") from None
    except (UnicodeDecodeError, csv.Error) as error:
        raise BadInputError(f"{path}: not a CSV text file ({error})") from None
    if header is None:
        raise BadInputError(f"{path}, row 1: the file is empty; expected a header row starting with 'time'")
    if len(rows) < 2:
        raise BadInputError(
            f"{_where(path, header_line + len(rows) + 1)}: {len(rows)} data row(s); "
            "a recording needs at least two samples"
        )
    return header, rows, line_numbers


def _raise_ragged(path: Path, line: int, header: list[str], row: list[str]) -> None:
    if len(row) < len(header):
        column = len(row)
        what = f"missing value: the row has {len(row)} fields, the header {len(header)} columns"
        raise BadInputError(f"{_where(path, line, column, header[column])}: {what}")
    raise BadInputError(
        f"{_where(path, line, len(header))}: extra value {row[len(header)]!r}: the row has "
        f"{len(row)} fields, the header {len(header)} columns"
    )


def _split_columns(path: Path, header: list[str], vehicle, candidates) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Check the header and split its columns into input names and output names."""
    if header[0] != "time":
        hint = ("'time' must be the first column" if "time" in header
                else "the first column must be 'time' (s)")
        raise BadInputError(f"{_where(path, 1, 0, header[0])}: {hint}")
    seen = set()
    for index, name in enumerate(header):
        if not name:
            raise BadInputError(f"{_where(path, 1, index)}: empty column name")
        if name in seen:
            raise BadInputError(f"{_where(path, 1, index, name)}: repeated column")
        seen.add(name)
    columns = header[1:]
    if vehicle is None:
        for index, name in enumerate(columns, start=1):
            if name not in _COLUMNS:
                raise BadInputError(f"{_where(path, 1, index, name)}: unknown column; flightgp's "
                                    "column names are the vehicles' inputs and states (see the "
                                    "docs/vehicles.md), or name the vehicle with --vehicle")
        # The vehicles whose inputs all appear and whose states cover the rest.
        signatures = [(frozenset(v.input_names), frozenset(v.state_names)) for v in candidates]
        matches = [(inputs, states) for inputs, states in signatures
                   if inputs <= set(columns) and set(columns) - inputs <= states]
        if not matches:
            raise BadInputError(f"{_where(path, 1)}: these columns fit no vehicle (a recording holds "
                                "all of a vehicle's inputs and some of its states); name the "
                                "vehicle with --vehicle or in the sidecar to see what is missing")
        inputs, _ = matches[0]
        input_names = tuple(name for name in columns if name in inputs)
        output_names = tuple(name for name in columns if name not in inputs)
        if not output_names:
            raise BadInputError(f"{_where(path, 1)}: no output columns, only time and inputs")
        return input_names, output_names
    for index, name in enumerate(columns, start=1):
        if name not in vehicle.input_names and name not in vehicle.state_names:
            raise BadInputError(
                f"{_where(path, 1, index, name)}: unknown column for vehicle {vehicle.name}; "
                f"inputs are {', '.join(vehicle.input_names)}; states are {', '.join(vehicle.state_names)}"
            )
    missing = [name for name in vehicle.input_names if name not in columns]
    if missing:
        raise BadInputError(
            f"{_where(path, 1)}: missing input column(s) {', '.join(map(repr, missing))}; a recording "
            f"of {vehicle.name} holds all of its inputs ({', '.join(vehicle.input_names)})"
        )
    output_names = tuple(name for name in vehicle.state_names if name in columns)
    if not output_names:
        raise BadInputError(
            f"{_where(path, 1)}: no output columns; a recording of {vehicle.name} holds at least one "
            f"of its states ({', '.join(vehicle.state_names)})"
        )
    return tuple(vehicle.input_names), output_names


def _parse_numbers(path: Path, header: list[str], rows: list[list[str]], line_numbers: list[int]) -> np.ndarray:
    """The cells as floats, shape (n, n_columns); text or non-finite cells are errors."""
    table = np.empty((len(rows), len(header)))
    for k, (row, line) in enumerate(zip(rows, line_numbers)):
        for column, cell in enumerate(row):
            try:
                value = float(cell)
            except ValueError:
                what = "empty cell" if not cell.strip() else f"{cell!r} is not a number"
                raise BadInputError(f"{_where(path, line, column, header[column])}: {what}") from None
            if not math.isfinite(value):
                raise BadInputError(
                    f"{_where(path, line, column, header[column])}: {cell.strip()!r} is not a finite number"
                )
            table[k, column] = value
    return table


#: Sample interval a recording must stay below, s: rigid-body modes of aircraft and airships
#: last seconds (a blimp's pitch oscillation, Ko et al. 2007, about 4 s), and sampling them at
#: 1 Hz or slower resolves none of them; a longer step is nearly always time in milliseconds.
MAX_SAMPLE_TIME = 1.0


def _check_time(path: Path, time: np.ndarray, line_numbers: list[int], *, uneven_allowed: bool) -> None:
    """``time`` must increase strictly, and by equal steps unless ``uneven_allowed``."""
    step = np.diff(time)
    backwards = np.flatnonzero(step <= 0)
    if len(backwards):
        k = backwards[0] + 1
        what = "repeats" if step[k - 1] == 0 else "goes backwards"
        raise BadInputError(
            f"{_where(path, line_numbers[k], 0, 'time')}: time {what} ({time[k - 1]:.9g} s, then "
            f"{time[k]:.9g} s); it must increase strictly"
        )
    nominal = float(np.median(step))
    if nominal >= MAX_SAMPLE_TIME:
        raise BadInputError(
            f"{_where(path, line_numbers[1], 0, 'time')}: time steps by {nominal:g} s; flight-dynamics recordings "
            f"are sampled well under {MAX_SAMPLE_TIME:g} s. Is time in milliseconds? flightgp reads seconds")
    if uneven_allowed:
        return
    uneven = uneven_steps(time)
    if len(uneven):
        k = uneven[0] + 1
        raise BadInputError(
            f"{_where(path, line_numbers[k], 0, 'time')}: uneven sampling: step {step[k - 1]:.9g} s "
            f"from the previous row, but the usual step is {nominal:.9g} s (resample, or set "
            '"uneven_sampling": true in the JSON sidecar)'
        )


def _check_radians(path: Path, header: list[str], table: np.ndarray, line_numbers: list[int]) -> None:
    """Angle and rate columns whose magnitude is implausible in rad (rad/s) look like degrees."""
    for column, name in enumerate(header):
        unit, limit, _ = _COLUMNS.get(name, _UNKNOWN_COLUMN)
        if limit is None:
            continue
        beyond = np.flatnonzero(abs(table[:, column]) > limit)
        if len(beyond):
            row = beyond[0]
            raise BadInputError(
                f"{_where(path, line_numbers[row], column, name)}: |{name}| = "
                f"{abs(table[row, column]):g} exceeds the plausible {limit:.3g} {unit}; looks like "
                f"degrees; flightgp expects radians ({unit})"
            )


#: Attitude and the body rate that drives it at small angles (theta_dot ~ q, phi_dot ~ p;
#: Padfield 2007, eq. 3.9): Bo105/JSBSim lower case, blimp upper case.
_ANGLE_RATE_PAIRS = (("theta", "q"), ("phi", "p"), ("theta", "Q"), ("phi", "P"))
_DEGREES_PER_RADIAN = 180.0 / math.pi


def looks_like_degrees(factor: float) -> bool:
    """Whether a quantity ``factor`` times what it should be in rad (rad/s) is most likely in
    degrees: ``factor`` within a factor of three of 57.3, far from any gain a model error gives."""
    return _DEGREES_PER_RADIAN / 3 < factor < _DEGREES_PER_RADIAN * 3


def _check_angle_rate_consistency(path: Path, header: list[str], table: np.ndarray) -> None:
    """Degrees that stay inside the magnitude limits: compare an attitude's rate of change with
    its body rate. At small angles ``d theta/dt ~ q``; a least-squares slope near 57.3 means the
    angle is in degrees, near 1/57.3 that the rate is. Needs a clear signal (correlation > 0.9),
    so noise or large-angle flight never triggers it."""
    time = table[:, 0]
    if len(time) < 10:
        return
    for angle, rate in _ANGLE_RATE_PAIRS:
        if angle not in header or rate not in header:
            continue
        angle_rate = np.gradient(table[:, header.index(angle)], time)
        body_rate = table[:, header.index(rate)]
        if np.std(body_rate) == 0 or np.std(angle_rate) == 0:
            continue
        correlation = np.corrcoef(angle_rate, body_rate)[0, 1]
        if correlation < 0.9:
            continue
        slope = float(angle_rate @ body_rate / (body_rate @ body_rate))
        for column, factor in ((angle, slope), (rate, 1.0 / slope)):
            if looks_like_degrees(factor):
                raise BadInputError(
                    f"{path}, column {header.index(column) + 1} ({column!r}): d{angle}/dt is "
                    f"{slope:.3g} x {rate}, where kinematics give about 1; {column!r} looks like "
                    "degrees; flightgp expects radians")
