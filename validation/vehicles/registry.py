"""Vehicle names (docs/vehicles.md) and the interface they share.

Every vehicle, physics reference or flight-test stand-in, is an object with

- ``name`` : str, the registry name (``"bo105-80kt"``, ``"blimp-flight"``, ``"jsbsim:c172x"``);
- ``input_names`` : tuple of str, the control inputs in recording-column order;
- ``state_names`` : tuple of str, the states it records (its measured outputs);
- ``sample_time`` : float, s, the interval at which it records by default;
- ``simulate(time, inputs, *, seed=0) -> Recording``: fly the input history ``inputs``
  (shape (n, n_inputs), held constant over each interval, sampled at ``time``, shape (n,),
  ``time = t0 + k*h``) and return the recording the vehicle would produce. Reference models are
  deterministic; stand-ins draw turbulence and sensor noise from ``seed``.

:func:`get_vehicle` turns a name into such an object (the JSBSim module is imported only when a
JSBSim aircraft is asked for, so that ``jsbsim`` loads only then); :func:`read_recording` reads a
recording file with the vehicle named by the caller or by its sidecar, in flightgp's format or
in the RGBlimp source's (:data:`RECORDING_FORMATS`).
"""
from __future__ import annotations

import functools
import re
from pathlib import Path
from typing import Protocol

import numpy as np

from validation.core.errors import BadInputError
from validation.core.recordings import Recording, parse_recording, read_sidecar, sidecar_path
from validation.vehicles.blimp import BlimpReference
from validation.vehicles.blimp_flight import BlimpFlightTest
from validation.vehicles.bo105 import BO105_SPEEDS_KT, Bo105Reference
from validation.vehicles.bo105_flight import Bo105FlightTest
from validation.vehicles.rgblimp import RGBlimpReference
from validation.vehicles.rgblimp_data import is_source_file, read_rgblimp_flight
from validation.vehicles.state_space import read_state_space

#: The recording file formats :func:`read_recording` reads (docs/conventions.md, "Recording
#: files"): flightgp's own (a ``time`` column and a sidecar) and the RGBlimp source's
#: ``data_N.csv`` (38 columns, no time column, 60 Hz; docs/rgblimp.md).
RECORDING_FORMATS = ("flightgp", "rgblimp")


class Vehicle(Protocol):
    """What every vehicle of the registry is (module docstring): a name, its input and state
    names, a default recording interval, s, and ``simulate(time, inputs, *, seed=0)`` returning
    a :class:`~validation.core.recordings.Recording` (``time`` (n,), s; ``inputs`` (n, n_inputs))."""

    name: str
    input_names: tuple[str, ...]
    state_names: tuple[str, ...]
    sample_time: float

    def simulate(self, time: np.ndarray, inputs: np.ndarray, *, seed: int = 0) -> Recording:
        ...


def vehicle_names() -> list[str]:
    """Every name :func:`get_vehicle` accepts, JSBSim aircraft shown as ``jsbsim:<aircraft>``."""
    names = []
    for speed in BO105_SPEEDS_KT:
        names += [f"bo105-{speed}kt", f"bo105-{speed}kt-flight"]
    return names + ["blimp", "blimp-flight", "rgblimp", "jsbsim:c172x", "jsbsim:ah1s"]


def get_vehicle(name: str) -> Vehicle:
    """The vehicle called ``name``; :class:`BadInputError` naming the valid choices otherwise."""
    match = re.fullmatch(r"bo105-(\d+)kt(-flight)?", name)
    if match:
        speed = int(match.group(1))
        if speed not in BO105_SPEEDS_KT:
            raise BadInputError(
                f"no Bo105 model at {speed} kt: Padfield tabulates {', '.join(map(str, BO105_SPEEDS_KT))} kt"
            )
        return Bo105FlightTest(speed) if match.group(2) else Bo105Reference(speed)
    if name in ("blimp", "blimp-flight"):
        return BlimpFlightTest() if name == "blimp-flight" else BlimpReference()
    if name == RGBlimpReference.name:
        return RGBlimpReference()
    if name.startswith("jsbsim:"):
        from validation.vehicles.jsbsim import JSBSimVehicle  # loads jsbsim only when asked for

        return JSBSimVehicle(name.split(":", 1)[1])
    if name.endswith(".json"):
        return read_state_space(name)
    if name.endswith(".fmu"):
        from validation.vehicles.fmu_reference import FMUReference  # loads fmpy only when asked for

        return FMUReference(name)
    raise BadInputError(f"unknown vehicle {name!r}; known: {', '.join(vehicle_names())} "
                        "(any JSBSim aircraft as jsbsim:<name>, a state-space model as FILE.json, an FMU as FILE.fmu)")


@functools.lru_cache(maxsize=1)
def reference_vehicles() -> tuple:
    """Every reference vehicle of the registry (stand-ins share their reference's columns)."""
    return tuple(get_vehicle(name) for name in vehicle_names() if not name.endswith("-flight"))


def read_recording(path, *, vehicle=None, file_format: str | None = None) -> Recording:
    """Read and check the recording at ``path`` (and its sidecar, if there is one).

    Parameters
    ----------
    path : str or path-like
        The CSV file (docs/conventions.md, "Recording files"), or a flight of the RGBlimp source
        as published (``data_N.csv``, docs/rgblimp.md).
    vehicle : str or Vehicle, optional
        The vehicle the recording must fit: a registry name or an object with ``name``,
        ``input_names`` and ``state_names``. Default: the sidecar's ``vehicle``, if any. With a
        vehicle, every one of its inputs must be present, the outputs must be a non-empty subset
        of its states, any other column is an error, and the columns come back in the vehicle's
        order. Without one, the columns must fit one of the registry's references: those named
        like its inputs are inputs and the rest outputs, in file order.
    file_format : {"flightgp", "rgblimp"}, optional
        Default: ``"rgblimp"`` for a file whose header is the source's
        (:func:`validation.vehicles.rgblimp_data.is_source_file`), else ``"flightgp"``. An
        ``"rgblimp"`` file is read by :func:`~validation.vehicles.rgblimp_data.read_rgblimp_flight`
        (time ``k / 60`` s, no sidecar) as a recording of ``rgblimp``: all of its states are
        outputs, and a ``vehicle`` must have its inputs and states, in its order.

    Returns
    -------
    Recording
        As :func:`validation.core.recordings.parse_recording`, which raises the same
        :class:`BadInputError` s; here also when the sidecar names an unknown vehicle, and as
        ``read_rgblimp_flight`` raises them for the source's format.
    """
    if file_format is None:
        file_format = "rgblimp" if is_source_file(path) else "flightgp"
    elif file_format not in RECORDING_FORMATS:
        raise BadInputError(f"unknown recording format {file_format!r}; known: {', '.join(RECORDING_FORMATS)}")
    if isinstance(vehicle, str):
        vehicle = get_vehicle(vehicle)
    if file_format == "rgblimp":
        return _read_rgblimp_source(Path(path), vehicle)
    if vehicle is None:
        name = read_sidecar(Path(path)).get("vehicle")
        if name is not None:
            vehicle = _sidecar_vehicle(Path(path), name)
    return parse_recording(path, vehicle=vehicle, candidates=reference_vehicles())


def _read_rgblimp_source(path: Path, vehicle) -> Recording:
    """A flight of the RGBlimp source as a recording of ``rgblimp``; a ``vehicle`` given must have
    the same inputs and states."""
    recording = read_rgblimp_flight(path).recording
    if vehicle is not None and (tuple(vehicle.input_names), tuple(vehicle.state_names)) != (
            recording.input_names, recording.output_names):
        raise BadInputError(
            f"{path}: a recording in the RGBlimp source's format is one of {RGBlimpReference.name} "
            f"(inputs {', '.join(recording.input_names)}), not of {vehicle.name} "
            f"(inputs {', '.join(vehicle.input_names)})")
    return recording


def _sidecar_vehicle(path: Path, name):
    """The vehicle the sidecar of ``path`` names, with the sidecar named in any error."""
    if not isinstance(name, str):
        raise BadInputError(f"{sidecar_path(path)}: key 'vehicle' must be a vehicle name (a string)")
    try:
        return get_vehicle(name)
    except BadInputError as error:
        raise BadInputError(f"{sidecar_path(path)}: key 'vehicle': {error}") from None
