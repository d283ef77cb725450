"""Build the FMU of a JSBSim aircraft (runs in the flightgp environment, not inside an FMU).

``jsbsim`` (and :mod:`validation.vehicles.jsbsim`, which imports it) is imported only when a
JSBSim FMU is built, as the vehicle registry imports it only when a JSBSim aircraft is flown.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fmu_src.fmi.naming import default_name, fmu_target
from fmu_src.fmi.pythonfmu import build_pythonfmu
from fmu_src.fmi.signals import SIGNAL_PHRASES, signal
from fmu_src.jsbsim_aircraft.slave import JSBSimAircraft, jsbsim_variables, pack_model

#: Travel of each normalised JSBSim command (``fcs/<control>-cmd-norm``); every other command
#: travels -1..1.
COMMAND_TRAVEL = {"fcs/collective-cmd-norm": (0.0, 1.0)}


def build_jsbsim_fmu(aircraft: str, out_dir, *, name: str | None = None) -> Path:
    """Build the FMU of a JSBSim aircraft (``jsbsim:<aircraft>``, :mod:`fmu_src.jsbsim_aircraft.slave`).

    The FMU reaches the starting condition of :class:`validation.vehicles.jsbsim.JSBSimVehicle`
    (fixed-wing: trimmed level cruise; ``ah1s``: hover from its flight-test script) with the same
    recipe, whose numbers travel in the model file. The host's Python needs the ``jsbsim``
    package.

    Parameters
    ----------
    aircraft : str
        An aircraft that ships with the ``jsbsim`` package, e.g. ``"c172x"``, ``"ah1s"``.
    out_dir : path
        Folder for the FMU (created if missing).
    name : str, optional
        Model identifier and file name; default ``jsbsim_<aircraft>``.

    Returns
    -------
    Path
        ``out_dir/<name>.fmu``.

    Raises
    ------
    validation.core.errors.BadInputError
        JSBSim has no such aircraft (the message names similar ones) or cannot trim it; a bad
        ``name``; ``out_dir`` a file.
    """
    import jsbsim

    from validation.vehicles import jsbsim as jsbsim_vehicle

    vehicle = jsbsim_vehicle.JSBSimVehicle(aircraft)
    target = fmu_target(out_dir, default_name(f"jsbsim_{aircraft}") if name is None else name)
    # Reaching the starting condition here raises BadInputError for an aircraft JSBSim cannot trim.
    steady = vehicle.simulate(np.array([0.0, vehicle.sample_time]), np.zeros((2, len(vehicle.input_names))))
    hover = jsbsim_vehicle.HOVER_SCRIPTS.get(aircraft)
    properties = jsbsim_vehicle.HELICOPTER_CONTROLS if hover else jsbsim_vehicle.FIXED_WING_CONTROLS
    controls = [(n, properties[n], *COMMAND_TRAVEL.get(properties[n], (-1.0, 1.0))) for n in vehicle.input_names]
    states = [(n, *jsbsim_vehicle.STATE_PROPERTIES[n]) for n in vehicle.state_names]
    recipe, condition = _starting_recipe(hover, altitude_ft=jsbsim_vehicle.CRUISE_ALTITUDE_FT,
                                         airspeed_kt=jsbsim_vehicle.CRUISE_AIRSPEED_KT)
    arrays = pack_model(aircraft=aircraft, jsbsim_version=jsbsim.__version__, controls=controls, states=states,
                        **recipe)
    trim = ", ".join(f"{k} {v:.4g}" for k, v in steady.metadata["trim"].items())
    description = (f"JSBSim {aircraft} {condition} (trim: {trim}); inputs {', '.join(vehicle.input_names)} "
                   f"(normalised command perturbations), outputs {', '.join(vehicle.state_names)} (SI, "
                   f"absolute); step a multiple of 0.01 s. Needs the jsbsim Python package "
                   f"({jsbsim.__version__}) in the host's Python")
    interface = {"inputs": tuple((n, low, high, SIGNAL_PHRASES[n]) for n, _, low, high in controls),
                 "states": tuple((n, signal(n, "state")[1], SIGNAL_PHRASES[n], float(steady.output(n)[0]))
                                 for n in vehicle.state_names)}
    return build_pythonfmu(target, slave_class=JSBSimAircraft, variables=(jsbsim_variables, interface),
                           attributes={}, description=description, arrays=arrays, runtime_packages=("jsbsim",))


def _starting_recipe(hover, *, altitude_ft: float, airspeed_kt: float) -> tuple[dict, str]:
    """The recipe of ``JSBSimVehicle``'s starting condition as data for
    :func:`fmu_src.jsbsim_aircraft.slave.pack_model` (the contract tests prove the FMU flies the
    same), and a phrase describing the condition.

    Parameters
    ----------
    hover : (str, float) or None
        The aircraft's flight-test script and its hover time, s; None for a fixed-wing aircraft.
    altitude_ft, airspeed_kt : float
        Level-flight trim of a fixed-wing aircraft: altitude above sea level, ft, and calibrated
        airspeed, kt.
    """
    if hover:
        recipe = {"start": "script", "script": hover[0], "script_time": hover[1],
                  "after_start": [("simulation/test-variant", 0.0)]}
        return recipe, f"hovering, {hover[1]:g} s into its flight-test script {hover[0]}"
    recipe = {"start": "trim",
              "initial_conditions": [("ic/h-sl-ft", altitude_ft), ("ic/vc-kts", airspeed_kt),
                                     ("ic/gamma-deg", 0.0), ("ic/psi-true-deg", 90.0)]}
    return recipe, f"trimmed in level flight at {airspeed_kt:g} kt calibrated, {altitude_ft:g} ft, heading east"
