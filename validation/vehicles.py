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
from .recordings import Recording

#: Trim speeds, kt, at which Padfield tabulates the Bo105 linear models.
BO105_SPEEDS_KT = (0, 20, 40, 60, 80, 100, 120, 140)


class Vehicle(Protocol):
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
    return names + ["blimp", "blimp-flight", "jsbsim:c172x", "jsbsim:ah1s"]


def get_vehicle(name: str) -> Vehicle:
    """The vehicle called ``name``; :class:`BadInputError` naming the valid choices otherwise."""
    bo105 = re.fullmatch(r"bo105-(\d+)kt(-flight)?", name)
    if bo105:
        speed = int(bo105.group(1))
        if speed not in BO105_SPEEDS_KT:
            raise BadInputError(
                f"no Bo105 model at {speed} kt: Padfield tabulates {', '.join(map(str, BO105_SPEEDS_KT))} kt"
            )
        from . import bo105

        return bo105.Bo105FlightTest(speed) if bo105.group(2) else bo105.Bo105Reference(speed)
    if name in ("blimp", "blimp-flight"):
        from . import blimp

        return blimp.BlimpFlightTest() if name == "blimp-flight" else blimp.BlimpReference()
    if name.startswith("jsbsim:"):
        from . import jsbsim_vehicles

        return jsbsim_vehicles.JSBSimVehicle(name.split(":", 1)[1])
    raise BadInputError(f"unknown vehicle {name!r}; known: {', '.join(vehicle_names())} (any JSBSim aircraft as jsbsim:<name>)")
