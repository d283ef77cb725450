"""The QTG spec: a qualification test guide as a TOML file (docs/qtg.md, "The spec").

A title and a list of ``[[test]]`` tables, each a flight-test recording and the outputs a
simulation must match it in, each within a tolerance band:

.. code-block:: toml

    title = "Bo105 at 80 kt"

    [[test]]
    id = "2.c.3.b pitch rate response, 3-2-1-1"
    recording = "flights/theta_1s_3211.csv"      # relative to this file
    outputs = { q = "2 deg/s", theta = { tolerance = "10 %", window = [1.0, 6.0] } }
    share = 1.0                                   # the pass rule: share of samples inside (default all)

A tolerance is a number (a half-width in the output's SI unit, docs/conventions.md, "Units and
axes"), a string with a unit (``"2 deg/s"``, ``"1.5 deg"``, ``"5 kt"``; the units of
:data:`validation.diagnose.fidelity.STATED_UNITS`), or a share of the recorded output's peak
magnitude over the compared samples (``"10 %"``); an output without one takes its band of 14 CFR
Part 60, Appendix C, Table C2A (:data:`validation.diagnose.fidelity.DEFAULT_TOLERANCES`). Every
fault is refused with one line naming the spec, the test and the key (:class:`BadInputError`).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from validation.core.errors import BadInputError, unknown_name_message
from validation.core.files import read_document
from validation.core.recordings import Recording, column_unit
from validation.core.sampling import uneven_steps
from validation.diagnose.fidelity import DEFAULT_TOLERANCES, STATED_UNITS, TOLERANCE_SOURCE
from validation.vehicles import read_recording

#: The keys of the spec, of a test and of an output's table.
SPEC_KEYS = ("title", "description", "test")
TEST_KEYS = ("id", "recording", "outputs", "window", "share", "note")
OUTPUT_KEYS = ("tolerance", "window", "share")
#: A tolerance string: a positive number, optionally after ``+-`` or ``±``, and a unit or ``%``.
_TOLERANCE = re.compile(r"\s*(?:\+-|±)?\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*(\S.*?)?\s*")


@dataclass(frozen=True)
class Tolerance:
    """A tolerance band about the flight test.

    Attributes
    ----------
    value : float
        The half-width in the output's SI unit, or for a relative band the fraction of the
        recorded output's peak magnitude (0.1 for ``"10 %"``).
    relative : bool
    source : str
        Where it comes from: ``"spec"`` or the Table C2A test (``"2.c.3.b: +-2 deg/s pitch rate"``).
    as_stated : str or None
        As written (``"2 deg/s"``, ``"10 %"``); None for a number in SI.
    """

    value: float
    relative: bool = False
    source: str = "spec"
    as_stated: str | None = None

    def half_width(self, recorded) -> float:
        """The band's half-width about ``recorded`` (ndarray, the compared samples), in the
        output's SI unit."""
        return self.value * float(np.max(np.abs(recorded))) if self.relative else self.value

    def words(self, unit: str) -> str:
        """The band in words: ``"+-2 deg/s"``, ``"+-10 % of peak"``, ``"+-0.035 rad/s"``."""
        if self.relative:
            return f"+-{100 * self.value:g} % of peak"
        return f"+-{self.as_stated}" if self.as_stated else f"+-{self.value:.4g} {unit}"


@dataclass(frozen=True)
class OutputCheck:
    """One output of a test: its name, its band, the time window it holds in (s, or None: the whole
    recording) and the share of samples that must lie inside the band (1: all)."""

    name: str
    tolerance: Tolerance
    window: tuple[float, float] | None
    share: float


@dataclass(frozen=True)
class QtgTest:
    """One test of a QTG: its ``id`` in the QTG's numbering, the recording (its path as given, relative
    to the spec, and the recording read), the outputs it checks and an optional ``note``."""

    id: str
    recording_path: str
    recording: Recording
    outputs: tuple[OutputCheck, ...]
    note: str | None = None


@dataclass(frozen=True)
class QtgSpec:
    """A QTG spec read and checked (module docstring): ``path``, ``title``, ``description`` (or
    None) and the ``tests`` in the file's order."""

    path: Path
    title: str
    description: str | None
    tests: tuple[QtgTest, ...]


def read_spec(path) -> QtgSpec:
    """Read and check the QTG spec at ``path`` and the recordings it names.

    Parameters
    ----------
    path : path-like
        A TOML file (module docstring); recordings are relative to its folder.

    Returns
    -------
    QtgSpec

    Raises
    ------
    BadInputError
        One line for a missing or malformed file, an unknown key (with the nearest known one), a
        missing or unreadable recording, an output the recording does not hold, a tolerance in a
        unit that does not measure the output, or an output with no tolerance and no default.
    """
    path = Path(path)
    content = read_document(path, what="QTG spec", syntax="TOML")
    _refuse_unknown(content, SPEC_KEYS, f"{path}")
    title = content.get("title")
    if not isinstance(title, str) or not title.strip():
        raise BadInputError(f"{path}: 'title' must be a non-empty string (the QTG's title)")
    description = content.get("description")
    if description is not None and not isinstance(description, str):
        raise BadInputError(f"{path}: 'description' must be a string")
    tables = content.get("test")
    if not isinstance(tables, list) or not tables or not all(isinstance(t, dict) for t in tables):
        raise BadInputError(f"{path}: no [[test]] tables; a QTG spec lists its tests as [[test]] tables")
    recordings = {}
    tests = []
    for number, table in enumerate(tables, start=1):
        test = _read_test(table, path, number, recordings)
        if any(test.id == other.id for other in tests):
            raise BadInputError(f"{path}: test {number}: id {test.id!r} is used twice; every test needs its own")
        tests.append(test)
    return QtgSpec(path, title.strip(), description, tuple(tests))


def _refuse_unknown(table: dict, known, where: str) -> None:
    for key in table:
        if key not in known:
            raise BadInputError(f"{where}: {unknown_name_message(key, known)}")


def _read_test(table: dict, path: Path, number: int, recordings: dict) -> QtgTest:
    test_id = table.get("id")
    if not isinstance(test_id, str) or not test_id.strip():
        raise BadInputError(f"{path}: test {number}: 'id' must be a non-empty string (the test's number and "
                            "title in the QTG, e.g. \"2.c.3.b pitch rate response, 3-2-1-1\")")
    where = f"{path}: test {test_id!r}"
    _refuse_unknown(table, TEST_KEYS, where)
    recording_path = table.get("recording")
    if not isinstance(recording_path, str) or not recording_path:
        raise BadInputError(f"{where}: 'recording' must be the path of a recording CSV file, relative to the spec")
    recording = _recording(path.parent / recording_path, recording_path, where, recordings)
    note = table.get("note")
    if note is not None and not isinstance(note, str):
        raise BadInputError(f"{where}: 'note' must be a string")
    window = _window(table.get("window"), recording, where)
    share = _share(table.get("share", 1.0), where)
    outputs = table.get("outputs")
    if isinstance(outputs, list) and all(isinstance(name, str) for name in outputs):
        outputs = dict.fromkeys(outputs, {})
    if not isinstance(outputs, dict) or not outputs:
        raise BadInputError(f"{where}: 'outputs' must name the outputs to check: a list of names (their Table C2A "
                            "bands) or a table of name = tolerance")
    checks = tuple(_output(name, value, recording, window, share, where) for name, value in outputs.items())
    return QtgTest(test_id.strip(), recording_path, recording, checks, note)


def _recording(file: Path, as_given: str, where: str, recordings: dict) -> Recording:
    """The recording at ``file`` (read once per spec)."""
    key = file.resolve()
    if key not in recordings:
        if not file.is_file():
            raise BadInputError(f"{where}: recording {as_given}: no such file (paths are relative to the spec's "
                                "folder)")
        try:
            recordings[key] = read_recording(file)
        except BadInputError as error:
            raise BadInputError(f"{where}: {error}") from None
        if uneven_steps(recordings[key].time).size:
            raise BadInputError(f"{where}: recording {as_given} is unevenly sampled; a QTG compares the model with "
                                "it sample by sample on one step: resample it onto an even grid")
    return recordings[key]


def _output(name: str, value, recording: Recording, window, share: float, where: str) -> OutputCheck:
    if name not in recording.output_names:
        raise BadInputError(f"{where}: {unknown_name_message(name, recording.output_names, what='output')} "
                            "(the recording's outputs)")
    where = f"{where}, output {name!r}"
    if isinstance(value, dict):
        _refuse_unknown(value, OUTPUT_KEYS, where)
        window = _window(value["window"], recording, where) if "window" in value else window
        share = _share(value["share"], where) if "share" in value else share
        value = value.get("tolerance")
    return OutputCheck(name, _tolerance(name, value, where), window, share)


def _tolerance(name: str, value, where: str) -> Tolerance:
    """The band ``value`` states for output ``name`` (module docstring), or its default."""
    unit = column_unit(name)
    if value is None:
        band = DEFAULT_TOLERANCES.get(name)
        if band is None:
            raise BadInputError(f"{where}: no tolerance given and {TOLERANCE_SOURCE} has none for {name!r} (it has "
                                f"{', '.join(DEFAULT_TOLERANCES)}); give one, e.g. {name} = \"10 %\" or a "
                                f"number in {unit}")
        return Tolerance(band.half_width, source=band.source, as_stated=band.as_stated)
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise BadInputError(f"{where}: a tolerance is a number in {unit} or a string with a unit (\"2 deg/s\") or "
                            f"%, got {value!r}")
    if not isinstance(value, str):
        if not (math.isfinite(value) and value > 0):
            raise BadInputError(f"{where}: the tolerance must be positive, got {value!r}")
        return Tolerance(float(value))
    match = _TOLERANCE.fullmatch(value)
    if match is None:
        raise BadInputError(f"{where}: cannot read the tolerance {value!r}; write a positive number and a unit, "
                            "e.g. \"2 deg/s\", \"1.5 deg\", \"5 kt\" or \"10 %\"")
    number, stated_unit = float(match.group(1)), match.group(2)
    if number <= 0:
        raise BadInputError(f"{where}: the tolerance must be positive, got {value!r}")
    if stated_unit is None:
        raise BadInputError(f"{where}: the tolerance {value!r} has no unit; give one (\"{number:g} {unit}\") or "
                            "write the number without quotes for SI")
    if stated_unit == "%":
        return Tolerance(number / 100.0, relative=True, as_stated=f"{number:g} %")
    if stated_unit not in STATED_UNITS:
        raise BadInputError(f"{where}: {unknown_name_message(stated_unit, STATED_UNITS, what='unit')}, %")
    measures, scale = STATED_UNITS[stated_unit]
    if measures != unit:
        fitting = [u for u, (m, _) in STATED_UNITS.items() if m == unit]
        hint = f"; use {' or '.join(fitting)}" if fitting else ""
        raise BadInputError(f"{where}: the tolerance {value!r} is in {stated_unit}, but {name} is in {unit}{hint}")
    return Tolerance(number * scale, as_stated=f"{number:g} {stated_unit}")


def _window(value, recording: Recording, where: str) -> tuple[float, float] | None:
    if value is None:
        return None
    if not (isinstance(value, list) and len(value) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise BadInputError(f"{where}: 'window' must be [t0, t1], two numbers in s, got {value!r}")
    start, end = float(value[0]), float(value[1])
    first, last = float(recording.time[0]), float(recording.time[-1])
    if not start < end:
        raise BadInputError(f"{where}: 'window' [{start:g}, {end:g}] s must end after it starts")
    if start < first or end > last:
        raise BadInputError(f"{where}: 'window' [{start:g}, {end:g}] s reaches beyond the recording "
                            f"({first:g} to {last:g} s)")
    return start, end


def _share(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= 1:
        raise BadInputError(f"{where}: 'share' (the share of samples that must lie inside the band) must be a "
                            f"number in (0, 1], e.g. 0.95; got {value!r}")
    return float(value)
