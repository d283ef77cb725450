"""Build the FMU of a JSBSim aircraft (runs in the flightgp environment, not inside an FMU).

``jsbsim`` (and :mod:`validation.vehicles.jsbsim`, which imports it) is imported only when a
JSBSim FMU is built, as the vehicle registry imports it only when a JSBSim aircraft is flown.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fmu_src.fmi.naming import default_name, fmu_target
from fmu_src.fmi.pythonfmu import build_pythonfmu
from fmu_src.fmi.signals import signal
from fmu_src.jsbsim_aircraft.slave import JSBSimAircraft, jsbsim_variables, pack_model

#: Travel of each normalised JSBSim command (``fcs/<control>-cmd-norm``); every other command
#: travels -1..1.
COMMAND_TRAVEL = {"fcs/collective-cmd-norm": (0.0, 1.0)}
#: The FMU's parameters (:data:`fmu_src.jsbsim_aircraft.slave.PARAMETERS`) by how it reaches its
#: starting condition (``StartingRecipe.method``). A helicopter flown by its script to the hover
#: has the wind only: its rotors' forces do not act at the aerodynamic reference point, which
#: carries the fuselage's small aerodynamic forces alone (moving it 0.1 m either way changes the
#: ah1s's starting body velocities by about 0.02 m/s, measured with JSBSim 1.3.3).
METHOD_PARAMETERS = {"trim": ("wind_north", "wind_east", "aero_ref_shift_x"), "script": ("wind_north", "wind_east")}


def build_jsbsim_fmu(aircraft: str, out_dir, *, name: str | None = None) -> Path:
    """Build the FMU of a JSBSim aircraft (``jsbsim:<aircraft>``, :mod:`fmu_src.jsbsim_aircraft.slave`).

    The FMU reaches the starting condition of :class:`validation.vehicles.jsbsim.JSBSimVehicle`
    (fixed-wing: trimmed level cruise; ``ah1s``: hover from its flight-test script) with the same
    code and recipe (:mod:`validation.vehicles.jsbsim_start`); the recipe travels in the model
    file. Its parameters (:data:`METHOD_PARAMETERS`) change the starting condition; at their start
    values it is the vehicle's. The host's Python needs the ``jsbsim`` package.

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
    properties = vehicle.control_properties
    controls = [(n, properties[n], *COMMAND_TRAVEL.get(properties[n], (-1.0, 1.0))) for n in vehicle.input_names]
    states = [(n, *jsbsim_vehicle.STATE_PROPERTIES[n]) for n in vehicle.state_names]
    parameters = METHOD_PARAMETERS[vehicle.recipe.method]
    arrays = pack_model(recipe=vehicle.recipe, jsbsim_version=jsbsim.__version__, controls=controls, states=states,
                        parameters=parameters)
    trim = ", ".join(f"{k} {v:.4g}" for k, v in steady.metadata["trim"].items())
    description = (f"JSBSim {aircraft} {_condition_phrase(vehicle.recipe)} (trim: {trim}); inputs "
                   f"{', '.join(vehicle.input_names)} (normalised command perturbations), outputs "
                   f"{', '.join(vehicle.state_names)} (SI, absolute), parameters {', '.join(parameters)} "
                   f"(applied before the start); step a multiple of 0.01 s. Needs the jsbsim "
                   f"Python package ({jsbsim.__version__}) in the host's Python")
    state_signals = [signal(n, "state") for n in vehicle.state_names]
    interface = {"inputs": tuple((n, low, high, signal(n, "input").phrase) for n, _, low, high in controls),
                 "states": tuple((s.name, s.unit, s.phrase, float(steady.output(s.name)[0])) for s in state_signals),
                 "parameters": parameters}
    return build_pythonfmu(target, slave_class=JSBSimAircraft, variables=(jsbsim_variables, interface),
                           attributes={}, description=description, arrays=arrays, runtime_packages=("jsbsim",))


def _condition_phrase(recipe) -> str:
    """The starting condition of a :class:`validation.vehicles.jsbsim_start.StartingRecipe` in
    words, for the FMU's description."""
    if recipe.method == "script":
        return f"hovering, {recipe.script_time:g} s into its flight-test script {recipe.script}"
    conditions = dict(recipe.initial_conditions)
    return (f"trimmed in level flight at {conditions['ic/vc-kts']:g} kt calibrated, "
            f"{conditions['ic/h-sl-ft']:g} ft, heading east")
