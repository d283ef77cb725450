"""Vehicle names (DESIGN.md, "Vehicles and reference names") and the interface they share.

Every vehicle, physics reference or flight-test stand-in, is an object with

- ``name`` : str, the registry name (``"bo105-80kt"``, ``"blimp-flight"``, ``"jsbsim:c172x"``);
- ``input_names`` : tuple of str, the control inputs in recording-column order;
- ``state_names`` : tuple of str, the states it records (its measured outputs);
- ``sample_time`` : float, s, the interval at which it records by default;
- ``simulate(time, inputs, *, seed=0) -> Recording``: fly the input history ``inputs``
  (shape (n, n_inputs), held constant over each interval, sampled at ``time``, shape (n,),
  ``time = t0 + k*h``) and return the recording the vehicle would produce. Reference models are
  deterministic; stand-ins draw turbulence and sensor noise from ``seed``.

:func:`get_vehicle` turns a name into such an object; the modules are imported lazily so that
``jsbsim`` is only loaded when a JSBSim vehicle is asked for.
"""
from __future__ import annotations

import re
from typing import Protocol

import numpy as np

from .errors import BadInputError
from .recordings import Recording, uneven_steps

#: Trim speeds, kt, at which Padfield tabulates the Bo105 linear models.
BO105_SPEEDS_KT = (0, 20, 40, 60, 80, 100, 120, 140)


class Vehicle(Protocol):
    name: str
    input_names: tuple[str, ...]
    state_names: tuple[str, ...]
    sample_time: float

    def simulate(self, time: np.ndarray, inputs: np.ndarray, *, seed: int = 0) -> Recording:
        ...


def check_history(time, inputs, input_names, *, evenly_sampled: bool = True):
    """Validate a ``simulate`` call's arguments; the one check every vehicle uses.

    Parameters
    ----------
    time : array_like, shape (n,)
        Sample times, s; at least 2, finite, strictly increasing, and (if ``evenly_sampled``)
        evenly spaced (:func:`validation.recordings.uneven_steps`: to 1e-6 of the median step, far
        above the rounding of ``t0 + k*h`` grids, far below any real irregularity).
    inputs : array_like, shape (n, len(input_names))
    input_names : sequence of str
        Column names, for messages.

    Returns
    -------
    time : ndarray, shape (n,)
    inputs : ndarray, shape (n, n_inputs)
    step : float
        Mean sample interval, s.
    """
    time = np.asarray(time, dtype=float)
    inputs = np.asarray(inputs, dtype=float)
    n_inputs = len(input_names)
    if time.ndim != 1 or len(time) < 2:
        raise BadInputError(f"time must be a 1-D array of at least 2 samples, got shape {time.shape}")
    if inputs.shape != (len(time), n_inputs):
        raise BadInputError(f"inputs must have shape ({len(time)}, {n_inputs}), one row per time sample "
                            f"with columns {', '.join(input_names)}; got shape {inputs.shape}")
    if not np.all(np.isfinite(time)):
        raise BadInputError(f"time has a non-finite value at sample {int(np.argmin(np.isfinite(time)))}")
    bad = np.argwhere(~np.isfinite(inputs))
    if len(bad):
        row, column = bad[0]
        raise BadInputError(f"inputs have a non-finite value at row {row}, column {input_names[column]!r}")
    steps = np.diff(time)
    step = (time[-1] - time[0]) / (len(time) - 1)
    if np.any(steps <= 0):
        worst = int(np.argmin(steps))
        raise BadInputError(f"time must be strictly increasing; it goes from {time[worst]:.9g} s to "
                            f"{time[worst + 1]:.9g} s at sample {worst}")
    uneven = uneven_steps(time) if evenly_sampled else ()
    if len(uneven):
        raise BadInputError(f"time must be evenly spaced; the step at sample {uneven[0]} is "
                            f"{steps[uneven[0]]:.9g} s against a usual {np.median(steps):.9g} s")
    return time, inputs, float(step)


def vehicle_names() -> list[str]:
    """Every name :func:`get_vehicle` accepts, JSBSim aircraft shown as ``jsbsim:<aircraft>``."""
    names = []
    for speed in BO105_SPEEDS_KT:
        names += [f"bo105-{speed}kt", f"bo105-{speed}kt-flight"]
    return names + ["blimp", "blimp-flight", "jsbsim:c172x", "jsbsim:ah1s"]


def get_vehicle(name: str) -> Vehicle:
    """The vehicle called ``name``; :class:`BadInputError` naming the valid choices otherwise."""
    match = re.fullmatch(r"bo105-(\d+)kt(-flight)?", name)
    if match:
        speed = int(match.group(1))
        if speed not in BO105_SPEEDS_KT:
            raise BadInputError(
                f"no Bo105 model at {speed} kt: Padfield tabulates {', '.join(map(str, BO105_SPEEDS_KT))} kt"
            )
        from . import bo105

        return bo105.Bo105FlightTest(speed) if match.group(2) else bo105.Bo105Reference(speed)
    if name in ("blimp", "blimp-flight"):
        from . import blimp

        return blimp.BlimpFlightTest() if name == "blimp-flight" else blimp.BlimpReference()
    if name.startswith("jsbsim:"):
        from . import jsbsim_vehicles

        return jsbsim_vehicles.JSBSimVehicle(name.split(":", 1)[1])
    raise BadInputError(f"unknown vehicle {name!r}; known: {', '.join(vehicle_names())} (any JSBSim aircraft as jsbsim:<name>)")
