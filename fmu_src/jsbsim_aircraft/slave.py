"""The JSBSim aircraft FMU: one of the aircraft that ship with the ``jsbsim`` package, flown by
JSBSim inside the FMU from a steady starting condition (``jsbsim:<aircraft>``; docs/fmus.md,
"JSBSim aircraft", lists the variables).

The host's Python needs the ``jsbsim`` package (1.3.x; it brings the aircraft) besides numpy and
pythonfmu. Every JSBSim FMU carries a copy of this file (:mod:`fmu_src.fmi.pythonfmu`), so it
imports only the FMI layer (:mod:`fmu_src.fmi.slave`), the shared FMU runtime, JSBSim's
starting procedure (:mod:`validation.vehicles.jsbsim_start`), numpy, the standard library and
``jsbsim`` (at initialisation, so that a host without it gets a logged Error, not a failed
instantiation).

Starting condition
------------------
The recipe of :class:`validation.vehicles.jsbsim.JSBSimVehicle`
(:class:`validation.vehicles.jsbsim_start.StartingRecipe`: fixed-wing aircraft, e.g. ``c172x``,
trimmed in level flight at 100 kt calibrated, 4000 ft, heading east; the ``ah1s`` flown by its
own flight-test script to the hover) travels in the FMU's model file (:func:`pack_model`), and
the FMU reaches it with the vehicle's own function
(:func:`validation.vehicles.jsbsim_start.start_fdm`) at JSBSim's step of 0.01 s.

Inputs are normalised stick and pedal commands (``fcs/<control>-cmd-norm``) as perturbations
from their values at the starting condition; outputs are JSBSim's body velocities (m/s), body
rates (rad/s) and Euler angles (rad), absolute values, in SI.

FMU parameters
--------------
Fixed parameters (:data:`PARAMETERS`; which ones an FMU has is in its model file) change JSBSim
before the starting procedure, so the FMU starts in the steady condition they make: a steady
wind (``wind_north``, ``wind_east``) and, for a trimmed aircraft, the aerodynamic reference
point (``aero_ref_shift_x``). Before, not after: a recording that starts at trim started in
steady flight in those conditions, and a change made after the trim would be a step (a gust, a
pitching moment) at ``t0`` that such a recording does not show. Each starts at 0, where nothing
is written to JSBSim, so by default the FMU is the one without parameters bit for bit.

Timing (docs/conventions.md, "FMU sampling convention")
-------------------------------------------------------
JSBSim integrates with a fixed step of 0.01 s. The communication step ``h`` must be a whole
multiple ``n`` of it (0.01 s in the default experiment); the first ``fmi2DoStep`` fixes it until
reset. ``fmi2DoStep(t_k, h)`` sets the commands to trim + the inputs at ``t_k``, holds them over
``n`` JSBSim steps and sets the outputs to the state at ``t_{k+1}``. With ``h = 0.01`` s this is
``JSBSimVehicle.simulate`` step for step (``states[k]`` is the output at ``t_k``). The outputs at
``t0`` (valid after initialisation) are the starting condition.

Limits: a command (trim + input) outside its travel (-1..1; collective 0..1) is refused with a
logged Error and ``fmi2Discard``, as is NaN or inf. If JSBSim fails inside a step (its state
stops being finite, or it raises), the step cannot be undone: it and every later step return
``fmi2Discard`` until the host resets the FMU.

State: JSBSim's Python API does not expose its complete internal state (the integrators' past
derivatives, flight-control filter and actuator histories, engine and propeller states), so
this FMU does not claim ``canGetAndSetFMUstate``. JSBSim's messages (banner, warnings), which
it would print on standard output, go to the FMI logger: the FMU never prints.
"""
from __future__ import annotations

import weakref
from pathlib import Path

import numpy as np

from fmu_src.fmi.runtime import check_header, model_header, read_model_file
from fmu_src.fmi.slave import FlightgpSlave, ModelFailure, Variable
from validation.vehicles.jsbsim_start import (
    StartingRecipe,
    TrimFailure,
    message_buffer,
    routed_messages,
    start_fdm,
)

FORMAT = "flightgp-fmu-jsbsim"
VERSION = 3
#: JSBSim's integration step, s (validation.vehicles.jsbsim.JSBSimVehicle.sample_time).
JSBSIM_STEP = 0.01
#: Relative tolerance on "the step is a whole multiple of JSBSIM_STEP".
_MULTIPLE_TOLERANCE = 1e-6
#: Metres per foot and per inch (exact: the international foot and inch), JSBSim's units.
_FOOT, _INCH = 0.3048, 0.0254
#: The parameters of :func:`validation.vehicles.jsbsim_start.start_fdm` that move the wind.
_WIND = ("wind_north", "wind_east")
#: Every parameter a JSBSim aircraft FMU may have (docs/fmus.md, "JSBSim aircraft"): name ->
#: (unit, the JSBSim property it changes, factor from the parameter to that change in JSBSim's
#: unit, what it is). Each starts at 0 and is applied before the starting procedure
#: (:func:`start_changes`). JSBSim's structural x axis points aft, body x forward: hence the sign
#: of ``aero_ref_shift_x``'s factor.
PARAMETERS = {
    "wind_north": ("m/s", "atmosphere/wind-north-fps", 1.0 / _FOOT,
                   "steady wind, the air's velocity toward the north, present before the starting "
                   "condition is reached (default 0: still air)"),
    "wind_east": ("m/s", "atmosphere/wind-east-fps", 1.0 / _FOOT,
                  "steady wind, the air's velocity toward the east, present before the starting "
                  "condition is reached (default 0: still air)"),
    "aero_ref_shift_x": ("m", "metrics/aero-rp-x-in", -1.0 / _INCH,
                         "forward shift of the aerodynamic reference point, where JSBSim applies the "
                         "aerodynamic forces, made before trim: for the aerodynamic moments, the centre of "
                         "gravity that much further aft (default 0: as in the aircraft file)"),
}


def pack_model(*, recipe: StartingRecipe, jsbsim_version: str, controls, states, parameters=()) -> dict:
    """Arrays of the FMU's model file (strings as numpy unicode arrays; no pickle).

    Parameters
    ----------
    recipe : validation.vehicles.jsbsim_start.StartingRecipe
        How JSBSim reaches the starting condition (stored as its JSON,
        :meth:`~validation.vehicles.jsbsim_start.StartingRecipe.to_json`).
    jsbsim_version : str
        The version the recipe was checked with at build time.
    controls : sequence of (input name, property, low, high)
        Each input, the JSBSim command it perturbs and that command's travel.
    states : sequence of (output name, property, factor to SI)
    parameters : sequence of str
        The FMU's parameters, names of :data:`PARAMETERS`.
    """
    unknown = [name for name in parameters if name not in PARAMETERS]
    if unknown:
        raise ValueError(f"unknown JSBSim FMU parameters {unknown}; known: {list(PARAMETERS)}")
    return {**model_header(FORMAT, VERSION), "recipe": np.array(recipe.to_json()),
            "jsbsim_version": np.array(jsbsim_version),
            "input_names": np.array([c[0] for c in controls], dtype=str),
            "control_properties": np.array([c[1] for c in controls], dtype=str),
            "control_low": np.array([c[2] for c in controls], dtype=float),
            "control_high": np.array([c[3] for c in controls], dtype=float),
            "state_names": np.array([s[0] for s in states], dtype=str),
            "state_properties": np.array([s[1] for s in states], dtype=str),
            "state_factors": np.array([s[2] for s in states], dtype=float),
            "parameter_names": np.array(list(parameters), dtype=str)}


def start_changes(parameters: dict) -> dict:
    """The ``wind`` and ``shifts`` of :func:`validation.vehicles.jsbsim_start.start_fdm` for
    parameter values.

    Parameters
    ----------
    parameters : dict of str -> float
        Names of :data:`PARAMETERS` and their values in SI units (m/s, m); an absent one is 0.

    Returns
    -------
    dict
        ``{"wind": (north, east) in ft/s, "shifts": ((property, amount in JSBSim's unit), ...)}``.
    """
    wind = tuple(parameters.get(name, 0.0) * PARAMETERS[name][2] for name in _WIND)
    shifts = tuple((PARAMETERS[name][1], value * PARAMETERS[name][2])
                   for name, value in parameters.items() if name not in _WIND)
    return {"wind": wind, "shifts": shifts}


def jsbsim_variables(*, inputs, states, parameters=()) -> tuple:
    """The variable table of a JSBSim aircraft FMU.

    Parameters
    ----------
    inputs : sequence of (name, low, high, phrase)
        Controls: name, the command's travel (normalised) and what it is.
    states : sequence of (name, unit, phrase, start)
        ``start``: the value at the starting condition (measured at build time, so that the
        outputs' ``initial="exact"`` start values are the values after initialisation with the
        parameters at their start values).
    parameters : sequence of str
        Names of :data:`PARAMETERS`.

    Returns
    -------
    tuple of Variable
        The control perturbations (inputs; declared range: the travel's width either way, the
        command itself is checked against the travel at each step), the states (outputs) and
        the parameters (fixed, start 0, any finite value: the starting procedure says at
        initialisation what JSBSim cannot start with).
    """
    table = [Variable(name, "input", "continuous", None, "1",
                      f"{phrase} (normalised, full travel {low:g}..{high:g}): perturbation from its "
                      "value at the starting condition, held from this communication point to the next",
                      0.0, -(high - low), high - low)
             for name, low, high, phrase in inputs]
    table += [Variable(name, "output", "continuous", "exact", unit, f"{phrase} (JSBSim, absolute value)",
                       float(start))
              for name, unit, phrase, start in states]
    table += [Variable(name, "parameter", "fixed", "exact", PARAMETERS[name][0],
                       f"{PARAMETERS[name][3]}; JSBSim {PARAMETERS[name][1]}", 0.0)
              for name in parameters]
    return tuple(table)


class JSBSimAircraft(FlightgpSlave):
    """A JSBSim aircraft (the class the build generates sets its description, PACKAGE and
    VARIABLES)."""

    DEFAULT_STEP_SIZE = JSBSIM_STEP
    CAN_GET_AND_SET_FMU_STATE = False
    CONSTANT_ATTRIBUTES = ("_jsbsim", "_model", "_recipe", "_log_sink")
    STATE_ATTRIBUTES = ("_fdm", "_trim")  # not savable: see the module docstring

    def load_constants(self) -> None:
        try:
            import jsbsim

            jsbsim.set_logger  # noqa: B018 - JSBSim >= 1.3 routes its messages through a logger
        except (ImportError, AttributeError):
            raise ImportError("this FMU runs JSBSim inside: install the jsbsim package, version 1.3 or "
                              "later (pip install jsbsim), in the host's Python") from None
        model = read_model_file(self.model_file())
        check_header(model, format_name=FORMAT, version=VERSION)
        declared = {v.name for v in self.VARIABLES}
        missing = [str(n) for n in (*model["input_names"], *model["state_names"]) if str(n) not in declared]
        if missing:
            raise ValueError(f"the model file's signals {missing} have no FMU variables")
        parameters = sorted(str(n) for n in model["parameter_names"])
        declared_parameters = sorted(v.name for v in self.VARIABLES if v.causality == "parameter")
        if parameters != declared_parameters or not set(parameters) <= set(PARAMETERS):
            raise ValueError(f"the model file's parameters {parameters} are not the FMU's parameter "
                             f"variables {declared_parameters} (known parameters: {list(PARAMETERS)})")
        self._jsbsim, self._model = jsbsim, model
        self._recipe = StartingRecipe.from_json(str(model["recipe"]))
        self._log_sink = message_buffer(_fmi_log_of(self))
        built_with = str(model["jsbsim_version"])
        if jsbsim.__version__ != built_with:
            self.log_warning(f"this FMU was built and checked with JSBSim {built_with}; the host has "
                             f"{jsbsim.__version__}: the starting condition and response may differ")

    def start_model(self) -> None:
        model, aircraft = self._model, self._recipe.aircraft
        root = Path(self._jsbsim.get_default_root_dir())
        if not (root / "aircraft" / aircraft / f"{aircraft}.xml").is_file():
            raise FileNotFoundError(f"the host's JSBSim ({root}) has no aircraft {aircraft!r}")
        self._fdm = None  # until started: input_problems checks no travel against an old trim
        parameters = {str(name): self.values[str(name)] for name in model["parameter_names"]}
        changed = ", ".join(f"{name} = {value:.6g} {PARAMETERS[name][0]}"
                            for name, value in parameters.items() if value)
        with routed_messages(self._log_sink):
            try:
                fdm = start_fdm(self._recipe, dt=JSBSIM_STEP, **start_changes(parameters))
            except TrimFailure as failure:
                raise TrimFailure(f"{failure} (parameters {changed})" if changed else str(failure)) from None
            trim = np.array([fdm[str(name)] for name in model["control_properties"]])
        self.log_info(f"JSBSim {self._jsbsim.__version__}, {aircraft} at its starting condition"
                      + (f" with {changed}" if changed else "") + ": "
                      + ", ".join(f"{n} trim {v:.6g}" for n, v in zip(model["input_names"], trim.tolist()))
                      + f"; {fdm['velocities/vc-kts']:.4g} kt calibrated, {fdm['position/h-sl-ft']:.6g} ft")
        self._fdm, self._trim = fdm, trim
        if not self._set_outputs():
            self._fdm = None
            raise RuntimeError(f"JSBSim's state at the starting condition of {aircraft} is not finite")

    def step_problem(self, h: float) -> str | None:
        n = round(h / JSBSIM_STEP)
        if n < 1 or abs(n * JSBSIM_STEP - h) > _MULTIPLE_TOLERANCE * JSBSIM_STEP:
            return (f"communicationStepSize = {h:.16g} s is not a whole multiple of JSBSim's "
                    f"{JSBSIM_STEP:g} s step")
        return None

    def input_problems(self) -> list[str]:
        problems = super().input_problems()
        if problems or getattr(self, "_fdm", None) is None:
            return problems
        model = self._model
        commands = self._commands()
        for i in np.flatnonzero((commands < model["control_low"]) | (commands > model["control_high"])):
            name = str(model["input_names"][i])
            problems.append(f"{name} = {self.values[name]:.16g} puts {model['control_properties'][i]} at "
                            f"{commands[i]:.6g} (trim {self._trim[i]:.6g}), outside its travel "
                            f"{model['control_low'][i]:g}..{model['control_high'][i]:g}")
        return problems

    def advance_model(self, t: float, h: float) -> None:
        fdm, model = self._fdm, self._model
        substeps = round(h / JSBSIM_STEP)
        commands = self._commands()
        try:
            with routed_messages(self._log_sink):
                for name, value in zip(model["control_properties"], commands.tolist()):
                    fdm[str(name)] = value
                for _ in range(substeps):
                    fdm.run()
        except Exception as error:  # noqa: BLE001 - JSBSim has moved on; the step cannot be undone
            raise ModelFailure(f"JSBSim failed between t = {t:.16g} s and {t + h:.16g} s: "
                               f"{type(error).__name__}: {error}") from None
        if not self._set_outputs():
            raise ModelFailure(f"JSBSim's states stopped being finite at t = {t + h:.16g} s "
                               f"(commands {commands.tolist()}); try smaller inputs")

    # -- helpers ------------------------------------------------------------------------------
    def _commands(self) -> np.ndarray:
        """trim + the input perturbations, as JSBSimVehicle computes them."""
        return self._trim + np.array([self.values[str(name)] for name in self._model["input_names"]])

    def _set_outputs(self) -> bool:
        """Outputs from JSBSim's state; False (outputs unchanged) if any is not finite."""
        model, fdm = self._model, self._fdm
        values = [fdm[str(p)] * f for p, f in zip(model["state_properties"], model["state_factors"].tolist())]
        if not np.isfinite(values).all():
            return False
        for name, value in zip(model["state_names"], values):
            self.values[str(name)] = float(value)
        return True


def _fmi_log_of(slave: FlightgpSlave):
    """The ``deliver`` of :func:`validation.vehicles.jsbsim_start.message_buffer` that hands each
    JSBSim message to ``slave``'s FMI log on one line: warnings and errors as Warnings, the rest
    (banner, notices) as information. It holds ``slave`` weakly (the slave holds the buffer)."""
    owner = weakref.ref(slave)

    def deliver(text: str, *, important: bool) -> None:
        slave = owner()
        if slave is not None:
            (slave.log_warning if important else slave.log_info)(f"JSBSim: {' '.join(text.split())}")

    return deliver
