"""The RGBlimp's motion-capture recordings, read as the source publishes them.

Zhu, Cheng & Zhang (IEEE RA-L 2024, arXiv 2404.18580) publish 140 real indoor flights of the
RGBlimp in the folder ``data/`` of the repository ``zhu-yj/ABNODE`` (MIT licence, copyright
2024 zhu-yj), one flight per file ``data_N.csv``: 38 columns, one header row, no time column,
60 Hz, SI units and radians (the source's readme says degrees; the values are radians). Flight
``N = 4 j + k`` (``k = 1 .. 4``) is the ``k``-th repeat of input configuration ``j = 0 .. 34``
(:func:`configuration_index`); each flight holds its thrusts and gondola position constant, and
configurations 30 .. 34 are straight flights, the others spirals. The source's protocol fits on
flights ``4j+1 .. 4j+3`` and tests on ``4j+4``. docs/rgblimp.md describes the columns.

:func:`read_rgblimp_flight` turns one file into flightgp's
:class:`~validation.core.recordings.Recording` (time ``k / 60`` s, the 12 states of
:data:`validation.vehicles.rgblimp_equations.STATE_NAMES` as outputs, the 5 inputs of
:data:`~validation.vehicles.rgblimp_equations.INPUT_NAMES`) together with the accelerations
the file stores: the source model's at the recorded state (``vb_dot_sim_*``, ``wb_dot_sim_*``)
and the measured ones (``vb_dot_*``, ``wb_dot_*``). It refuses what it cannot read faithfully
with :class:`~validation.core.errors.BadInputError`, one line naming file, row (1-based line
number; the header is row 1) and column. :func:`flights_by_configuration` lists the flights a
folder holds; :func:`is_source_file` tells a file of the source's format by its header, which is
how :func:`validation.vehicles.read_recording` reads these files as they are. :data:`EXCERPT_FOLDER`
holds a few of the flights, unchanged, with the source's licence.
"""
from __future__ import annotations

import csv
import dataclasses
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from validation.core.errors import BadInputError
from validation.core.recordings import Recording, column_limit
from validation.vehicles.rgblimp import VEHICLE_NAME
from validation.vehicles.rgblimp_equations import (
    INPUT_NAMES,
    SAMPLE_RATE,
    SAMPLE_TIME,
    STATE_NAMES,
    RGBlimpParameters,
)

#: The source's 38 columns, in its order: position, Euler angles, body velocity and rates
#: (the states), gondola position, velocity and acceleration, the two thrusts, the measured
#: accelerations, angle of attack and sideslip, the model's accelerations and the spiral radius.
SOURCE_COLUMNS = (
    "p_1", "p_2", "p_3", "e_1", "e_2", "e_3", "vb_1", "vb_2", "vb_3", "wb_1", "wb_2", "wb_3",
    "rb_series_1", "rb_series_2", "rb_series_3", "rb_dot_1", "rb_dot_2", "rb_dot_3",
    "Fl_series", "Fr_series", "rb_dot_dot_1", "rb_dot_dot_2", "rb_dot_dot_3",
    "vb_dot_1", "vb_dot_2", "vb_dot_3", "wb_dot_1", "wb_dot_2", "wb_dot_3", "alpha", "beta",
    "vb_dot_sim_1", "vb_dot_sim_2", "vb_dot_sim_3", "wb_dot_sim_1", "wb_dot_sim_2", "wb_dot_sim_3",
    "radius",
)
#: Source columns of :data:`~validation.vehicles.rgblimp_equations.STATE_NAMES`, in that order.
STATE_COLUMNS = SOURCE_COLUMNS[:12]
#: Source columns of :data:`~validation.vehicles.rgblimp_equations.INPUT_NAMES`, in that order.
INPUT_COLUMNS = ("Fl_series", "Fr_series", "rb_series_1", "rb_series_2", "rb_series_3")
#: The source model's body accelerations at the recorded state and inputs.
MODEL_ACCELERATION_COLUMNS = ("vb_dot_sim_1", "vb_dot_sim_2", "vb_dot_sim_3",
                              "wb_dot_sim_1", "wb_dot_sim_2", "wb_dot_sim_3")
#: The measured body accelerations (the source's derivatives of the motion capture).
MEASURED_ACCELERATION_COLUMNS = ("vb_dot_1", "vb_dot_2", "vb_dot_3", "wb_dot_1", "wb_dot_2", "wb_dot_3")

#: A few of the source's flights, copied unchanged with its ``LICENSE`` (their ``README.md`` says
#: which): the three at hand of configurations 29 (spirals) and 30 (straight), and the source's
#: ``data_info`` folder.
EXCERPT_FOLDER = Path(__file__).resolve().with_name("data") / "rgblimp"

#: Repeated flights of each input configuration: flight ``N = 4 j + k``, ``k = 1 .. 4``.
FLIGHTS_PER_CONFIGURATION = 4

#: The parameters with which the source computed the recordings' ``vb_dot_sim_*`` and
#: ``wb_dot_sim_*`` columns: those of ``utils/parameters.py`` (the defaults of
#: :class:`~validation.vehicles.rgblimp_equations.RGBlimpParameters`) but six aerodynamic
#: coefficients, which that file rounds to four decimals. The accelerations are affine in the 18
#: coefficients, so a linear least-squares fit of the columns recovers them exactly (residual
#: 4e-10 m/s^2; ``tests/validation/vehicles/test_rgblimp.py`` repeats the fit), and each value
#: rounds to the published one.
RECORDED_MODEL_PARAMETERS = dataclasses.replace(
    RGBlimpParameters(), c_d_alpha2=4.419495, c_l0=0.15938, c_l_alpha=2.93748, c_my0=0.056815,
    c_my_alpha=0.09327, c_my_beta4=5.23568)

_FILE_NAME = re.compile(r"data_([1-9][0-9]*)\.csv")


@dataclass(frozen=True)
class RGBlimpFlight:
    """One recorded flight of the RGBlimp.

    Attributes
    ----------
    number : int
        ``N`` of ``data_N.csv``.
    configuration : int
        Its input configuration ``j`` (:func:`configuration_index`).
    recording : Recording
        ``time`` (n,), s, ``k / 60``; ``inputs`` (n, 5) named
        :data:`~validation.vehicles.rgblimp_equations.INPUT_NAMES` (N, m); ``outputs`` (n, 12),
        all states, named :data:`~validation.vehicles.rgblimp_equations.STATE_NAMES` (m, rad,
        m/s, rad/s); ``metadata`` with ``source``, ``flight``, ``configuration`` and
        ``sample_time``, and ``vehicle`` (``"rgblimp"``), so that the recording, written with
        :func:`~validation.core.recordings.write_recording`, reads back as the ``rgblimp``'s.
    model_accelerations : ndarray, shape (n, 6)
        The source model's ``U_dot, V_dot, W_dot`` (m/s^2), ``P_dot, Q_dot, R_dot`` (rad/s^2) at
        each recorded state and input (:data:`MODEL_ACCELERATION_COLUMNS`), computed with
        :data:`RECORDED_MODEL_PARAMETERS`.
    measured_accelerations : ndarray, shape (n, 6)
        The same accelerations from the motion capture (:data:`MEASURED_ACCELERATION_COLUMNS`).
    """

    number: int
    configuration: int
    recording: Recording
    model_accelerations: np.ndarray
    measured_accelerations: np.ndarray


def flight_number(path: str | os.PathLike) -> int:
    """``N`` of a recording named ``data_N.csv`` (``N >= 1``), or :class:`BadInputError`."""
    match = _FILE_NAME.fullmatch(Path(path).name)
    if match is None:
        raise BadInputError(f"{path}: an RGBlimp recording is named data_N.csv (N = 1, 2, ...), as in "
                            "the source; the name carries the flight number and its configuration")
    return int(match.group(1))


def configuration_index(number: int) -> int:
    """Input configuration ``j`` of flight ``number`` ``N = 4 j + k``, ``k = 1 .. 4``:
    ``(N - 1) // 4``; flights ``1 .. 4`` are configuration 0."""
    if number < 1:
        raise BadInputError(f"RGBlimp flight numbers start at 1, got {number}")
    return (number - 1) // FLIGHTS_PER_CONFIGURATION


def flights_by_configuration(folder: str | os.PathLike) -> dict[int, tuple[int, ...]]:
    """The flights a folder holds: configuration ``j`` -> its flight numbers, ascending.

    Only files named ``data_N.csv`` count (their content is not read); a configuration lists the
    flights present, so a folder without the held-back ``4j+4`` lists three per configuration.

    Raises
    ------
    BadInputError
        ``folder`` is not a folder or holds no ``data_N.csv``.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise BadInputError(f"{folder}: no such folder of RGBlimp recordings")
    flights: dict[int, list[int]] = {}
    for path in folder.iterdir():
        if _FILE_NAME.fullmatch(path.name) and path.is_file():
            number = flight_number(path)
            flights.setdefault(configuration_index(number), []).append(number)
    if not flights:
        raise BadInputError(f"{folder}: no RGBlimp recordings (data_N.csv) in this folder")
    return {j: tuple(sorted(numbers)) for j, numbers in sorted(flights.items())}


def is_source_file(path: str | os.PathLike) -> bool:
    """Whether the file at ``path`` has the source's header: its first line holds column names of
    :data:`SOURCE_COLUMNS` (at least half of the 38, so that a damaged header still goes to
    :func:`read_rgblimp_flight`, which says what is wrong with it) and no ``time`` column. Only
    the first line is read; an unreadable file is not one (the caller's reader says why)."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as file:
            header = [name.strip() for name in next(csv.reader([file.readline()]), [])]
    except (OSError, UnicodeDecodeError):
        return False
    return "time" not in header and sum(name in SOURCE_COLUMNS for name in header) >= len(SOURCE_COLUMNS) // 2


def read_rgblimp_flight(path: str | os.PathLike) -> RGBlimpFlight:
    """Read one source recording ``data_N.csv`` as it is.

    Parameters
    ----------
    path : str or path-like
        A file of the source's format (module docstring; docs/rgblimp.md).

    Returns
    -------
    RGBlimpFlight

    Raises
    ------
    BadInputError
        One line naming file, row and column: a name other than ``data_N.csv``; a missing,
        empty or non-text file; a header other than the source's 38 columns in its order; a row
        with too few or too many fields; an empty, non-numeric, NaN or infinite cell; fewer than
        two samples; an angle or rate too large to be in radians.
    """
    path = Path(path)
    number = flight_number(path)
    table, line_numbers = _read_table(path)
    _check_radians(path, table, line_numbers)
    column = {name: index for index, name in enumerate(SOURCE_COLUMNS)}
    time = np.arange(len(table)) / SAMPLE_RATE  # t = k h (docs/conventions.md, "Time")
    configuration = configuration_index(number)
    recording = Recording(
        time=time,
        inputs=table[:, [column[name] for name in INPUT_COLUMNS]],
        input_names=INPUT_NAMES,
        outputs=table[:, [column[name] for name in STATE_COLUMNS]],
        output_names=STATE_NAMES,
        metadata={"vehicle": VEHICLE_NAME, "source": f"zhu-yj/ABNODE data/{path.name}", "flight": number,
                  "configuration": configuration, "sample_time": SAMPLE_TIME},
    )
    return RGBlimpFlight(
        number=number, configuration=configuration, recording=recording,
        model_accelerations=table[:, [column[name] for name in MODEL_ACCELERATION_COLUMNS]],
        measured_accelerations=table[:, [column[name] for name in MEASURED_ACCELERATION_COLUMNS]],
    )


def _read_table(path: Path) -> tuple[np.ndarray, list[int]]:
    """The data rows as floats, shape (n, 38), and each row's 1-based line number in the file."""
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except FileNotFoundError:
        raise BadInputError(f"{path}: no such RGBlimp recording") from None
    except IsADirectoryError:
        raise BadInputError(f"{path}: is a folder, not an RGBlimp recording") from None
    except UnicodeDecodeError:
        raise BadInputError(f"{path}: not a CSV text file") from None
    if not lines or not lines[0].strip():
        raise BadInputError(f"{path}, row 1: the file is empty; expected the source's header "
                            f"{SOURCE_COLUMNS[0]},{SOURCE_COLUMNS[1]},...,{SOURCE_COLUMNS[-1]}")
    _check_header(path, [name.strip() for name in next(csv.reader([lines[0]]))])
    rows = [(number, line) for number, line in enumerate(lines[1:], start=2) if line.strip()]
    if len(rows) < 2:
        raise BadInputError(f"{path}: {len(rows)} data row(s); a recording needs at least two samples")
    line_numbers = [number for number, _ in rows]
    try:
        table = np.loadtxt([line for _, line in rows], delimiter=",", ndmin=2)
    except ValueError:
        table = None  # located cell by cell below
    if table is None or table.shape[1] != len(SOURCE_COLUMNS) or not np.all(np.isfinite(table)):
        table = _parse_cell_by_cell(path, rows)
    return table, line_numbers


def _check_header(path: Path, header: list[str]) -> None:
    if len(header) != len(SOURCE_COLUMNS):
        raise BadInputError(
            f"{path}, row 1: {len(header)} columns, but an RGBlimp recording has the source's "
            f"{len(SOURCE_COLUMNS)} ({SOURCE_COLUMNS[0]}, {SOURCE_COLUMNS[1]}, ..., {SOURCE_COLUMNS[-1]})")
    for index, (found, expected) in enumerate(zip(header, SOURCE_COLUMNS)):
        if found != expected:
            raise BadInputError(
                f"{path}, row 1, column {index + 1} ({found!r}): expected {expected!r}; an RGBlimp "
                "recording has the source's 38 columns in the source's order")


def _parse_cell_by_cell(path: Path, rows: list[tuple[int, str]]) -> np.ndarray:
    """The rows numpy's fast reader refused, read as CSV cell by cell (quoted numbers are fine):
    the table, shape (n, 38), or :class:`BadInputError` for the first ragged row or unreadable
    or non-finite cell."""
    table = np.empty((len(rows), len(SOURCE_COLUMNS)))
    for k, (number, line) in enumerate(rows):
        cells = next(csv.reader([line]))
        if len(cells) != len(SOURCE_COLUMNS):
            raise BadInputError(f"{path}, row {number}: {len(cells)} fields, but the header has "
                                f"{len(SOURCE_COLUMNS)} columns")
        for index, cell in enumerate(cells):
            where = f"{path}, row {number}, column {index + 1} ({SOURCE_COLUMNS[index]!r})"
            try:
                table[k, index] = float(cell)
            except ValueError:
                what = "empty cell" if not cell.strip() else f"{cell.strip()!r} is not a number"
                raise BadInputError(f"{where}: {what}") from None
            if not np.isfinite(table[k, index]):
                raise BadInputError(f"{where}: {cell.strip()!r} is not a finite number")
    return table


def _check_radians(path: Path, table: np.ndarray, line_numbers: list[int]) -> None:
    """Euler angles and body rates beyond flightgp's plausible magnitudes in rad and rad/s
    (docs/conventions.md, "Units and axes") are degrees."""
    for index, (source, name) in enumerate(zip(STATE_COLUMNS, STATE_NAMES)):
        limit = column_limit(name)
        if limit is None:
            continue
        beyond = np.flatnonzero(np.abs(table[:, index]) > limit)
        if len(beyond):
            row = beyond[0]
            raise BadInputError(
                f"{path}, row {line_numbers[row]}, column {index + 1} ({source!r}): |{source}| = "
                f"{abs(table[row, index]):g} exceeds the plausible {limit:.3g} for {name} in radians; "
                "looks like degrees; the source's recordings and flightgp hold radians")


#: The source's state width: its score is a mean over 23 columns, 17 of them weighted zero
#: (``F.mse_loss`` over the 23-wide state in ``methods/comp_NODE.py`` of ``zhu-yj/ABNODE``).
SOURCE_STATE_WIDTH = 23


def source_score(predicted, recorded, ranges, *, wrap_yaw: bool = True) -> float:
    """The source's score of a free run: ``sum_c mean_k ((y_hat - y)_kc / range_c)^2 / 23``.

    Over the six columns ``x, y, z, phi, theta, psi``: the source multiplies state and
    prediction by ``1 / range_c`` (zero for its other 17 columns) and takes ``F.mse_loss``, the
    mean over samples and all 23 columns (:data:`SOURCE_STATE_WIDTH`) of the squared difference
    (``methods/comp_NODE.py`` of ``zhu-yj/ABNODE``). The source does not wrap the yaw
    difference (both yaws lie in [-pi, pi], so a run a little behind across the wrap counts
    almost a full turn); with ``wrap_yaw`` (the default) it is wrapped, without it the predicted
    yaw is first brought into [-pi, pi) as the source's integrator keeps it (a grey-box free run
    carries yaw continuously).

    Parameters
    ----------
    predicted, recorded : ndarray, shape (n, >= 6)
        States in :data:`~validation.vehicles.rgblimp_equations.STATE_NAMES` order.
    ranges : ndarray, shape (6,)
        (max - min) of each column (:func:`read_score_ranges`).
    wrap_yaw : bool

    Returns
    -------
    float
    """
    predicted, recorded = np.asarray(predicted, dtype=float), np.asarray(recorded, dtype=float)
    difference = predicted[:, :6] - recorded[:, :6]
    if wrap_yaw:
        difference[:, 5] = (difference[:, 5] + np.pi) % (2 * np.pi) - np.pi
    else:
        difference[:, 5] = (predicted[:, 5] + np.pi) % (2 * np.pi) - np.pi - recorded[:, 5]
    return float(np.sum(np.mean((difference / np.asarray(ranges)) ** 2, axis=0)) / SOURCE_STATE_WIDTH)
