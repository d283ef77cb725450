"""The one base of every flightgp pythonfmu FMU: lifecycle, variable table, logging, status
policy, state save/restore and the sampling convention (docs/fmus.md, "Sampling, status and
state"; docs/conventions.md, "FMU sampling convention"). As in the Modelica Reference-FMUs, the
FMI plumbing lives once, here (and in C in ``fmi2_slave.c`` for the native FMUs); each FMU only
declares its variables, as data, and its equations.

Every pythonfmu FMU carries a copy of this file, under a name unique to the FMU
(:mod:`fmu_src.fmi.pythonfmu`), so it imports only pythonfmu, numpy and the standard library.

Sampling convention
-------------------
Communication points are ``t_k = t0 + k h``, ``k`` counted by the FMU (never accumulated), ``h``
the FMU's fixed communication step: :attr:`FlightgpSlave.STEP_SIZE`, or, if that is None, the step
of the first ``fmi2DoStep`` after initialisation (FMI 2.0 tells an FMU its step no earlier), which
the FMU may restrict (:meth:`FlightgpSlave.step_problem`) and then keeps until reset. Every FMU
declares ``canHandleVariableCommunicationStepSize = false``.

- ``fmi2ExitInitializationMode``: the outputs at ``t0`` are computed from the inputs and
  parameters set during initialisation, so they are valid before the first ``fmi2DoStep``.
- ``fmi2DoStep(t_k, h)`` reads the inputs as set at ``t_k``, advances the internal state and
  sets the outputs to their values at ``t_{k+1} = t_k + h``.

Hence no output depends on an input set at the same communication point (no direct
feedthrough): a host may wire an output straight back to an input without an algebraic loop.

Status policy
-------------
A Python exception in a pythonfmu slave becomes ``fmi2Fatal`` (the instance is then unusable),
so no exception leaves this class. pythonfmu 0.7 lets a slave return only ``fmi2OK`` or
``fmi2Discard`` (``do_step`` returning False); every other function returns ``fmi2OK``. So:

- ``do_step`` refuses (logs an Error, returns ``fmi2Discard``, state and outputs unchanged, so the
  host may fix the cause and retry at the same ``t_k``) when: an input or parameter is NaN,
  infinite or outside its declared ``min``/``max``; the communication point or step is not the
  expected one; a setter was refused since the last step; initialisation failed; or the model
  code raised.
- Setters never raise: values are stored and checked at the next ``do_step`` (or at the end of
  initialisation). Setting an output, a ``fixed`` parameter after initialisation, or an unknown
  value reference is refused (old value kept, Error logged) and makes the next ``do_step``
  return ``fmi2Discard``. Getters never raise either: an unknown value reference is logged as an
  Error and reads as NaN (Real), 0, false or "".
- ``exit_initialization_mode`` failures (e.g. an unreadable model file) are logged as Errors;
  the outputs keep their start values and every ``do_step`` returns ``fmi2Discard``.
- A model that cannot undo a failed step (an external simulator that has already advanced)
  raises :class:`ModelFailure`: that step and every later one return ``fmi2Discard`` (logged
  Error) until the host resets or re-instantiates the FMU.
- Warnings (e.g. inputs outside the training envelope) are logged; the step succeeds.
- pythonfmu 0.7 forwards log messages to the host only while the host has logging enabled
  (``loggingOn`` in ``fmi2Instantiate`` or ``fmi2SetDebugLogging``); the FMU cannot override
  that. The status codes above reach every host.

State
-----
``fmi2GetFMUstate`` saves every variable value, the base's bookkeeping (start time, step count,
mode, pending refusal) and every attribute a subclass names in :attr:`STATE_ATTRIBUTES`
(numpy arrays copied); attributes in :attr:`CONSTANT_ATTRIBUTES` (loaded models) are shared and
not saved, and are loaded again (:meth:`FlightgpSlave.load_constants`) when a state is restored
into an instance that has not loaded them (a fresh instance, a deserialised state). Any other
instance attribute is a bug: saving then logs an Error naming it. The saved state is JSON data,
so it also serialises (``fmi2SerializeFMUstate``).

An FMU whose state cannot be captured completely (e.g. one that wraps an external simulator
whose API does not expose all of its internal state) sets :attr:`CAN_GET_AND_SET_FMU_STATE` to
False: it is built without ``canGetAndSetFMUstate`` and ``canSerializeFMUstate``, and if a host
asks anyway, saving logs an Error and restoring is refused (next ``do_step``: ``fmi2Discard``).
"""
from __future__ import annotations

import math
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pythonfmu import Boolean, DefaultExperiment, Fmi2Slave, Integer, Real
from pythonfmu.enums import Fmi2Causality, Fmi2Initial, Fmi2Status, Fmi2Variability

#: Units an FMU variable may carry: name -> (SI base-unit exponents, display units {name: factor}).
UNITS = {
    "1": ({}, {}),
    "s": ({"s": 1}, {}),
    "m": ({"m": 1}, {}),
    "m/s": ({"m": 1, "s": -1}, {}),
    "N": ({"kg": 1, "m": 1, "s": -2}, {}),
    "rad": ({"rad": 1}, {"deg": 180.0 / math.pi}),
    "rad/s": ({"rad": 1, "s": -1}, {"deg/s": 180.0 / math.pi}),
    # The units of a linear model's stability and control derivatives (a row's rate per column).
    "1/s": ({"s": -1}, {}),
    "1/s2": ({"s": -2}, {}),
    "m/(s.rad)": ({"m": 1, "s": -1, "rad": -1}, {}),
    "m/(s2.rad)": ({"m": 1, "s": -2, "rad": -1}, {}),
    "rad/(m.s)": ({"rad": 1, "m": -1, "s": -1}, {}),
    # The units of the blimp's physical parameters (validation.vehicles.blimp.BlimpParameters).
    "kg": ({"kg": 1}, {}),
    "kg.m2": ({"kg": 1, "m": 2}, {}),
    "kg/m": ({"kg": 1, "m": -1}, {}),
    "N.s/m": ({"kg": 1, "s": -1}, {}),
    "N.s2/m2": ({"kg": 1, "m": -1}, {}),
    "N.m.s/rad": ({"kg": 1, "m": 2, "s": -1, "rad": -1}, {}),
}

#: Relative tolerance on the communication point and step, as a fraction of the step.
TIME_TOLERANCE = 1e-6

#: The model file in the FMU's package folder under ``resources/`` (numpy arrays, no pickle).
MODEL_FILE = "model.npz"

#: Models loaded once per process and FMU (each FMU carries its own copy of this module), keyed
#: by model-file path; read-only, so every instance shares them.
_SHARED_MODELS: dict = {}

_STATE_FORMAT = "flightgp-fmu-state-1"
_NO_STATE_FORMAT = "flightgp-fmu-no-state"


class ModelFailure(RuntimeError):
    """Raised by a model that failed a step it cannot undo; the FMU stops stepping until reset."""


@dataclass(frozen=True)
class Variable:
    """One row of an FMU's variable table.

    Attributes
    ----------
    name : str
    causality : {"input", "output", "parameter"}
    variability : {"continuous", "discrete", "fixed", "tunable"}
    initial : {"exact"} or None
        Outputs and parameters: ``"exact"`` (outputs have a valid start value, so
        ``ModelStructure/InitialUnknowns`` stays empty); inputs: None (FMI 2.0 forbids it).
    unit : str or None
        A key of :data:`UNITS` for Real variables; None for Boolean and Integer ones.
    description : str
    start : float, bool or int
        Its type sets the variable's type (float: Real, bool: Boolean, int: Integer).
    minimum, maximum : float or None
        Declared range (``min``/``max``); a value outside is refused at the next step.
    """

    name: str
    causality: str
    variability: str
    initial: str | None
    unit: str | None
    description: str
    start: float | bool | int
    minimum: float | None = None
    maximum: float | None = None

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"variable name {self.name!r} is not an identifier")
        if self.causality not in ("input", "output", "parameter"):
            raise ValueError(f"{self.name}: unknown causality {self.causality!r}")
        if self.variability not in ("continuous", "discrete", "fixed", "tunable"):
            raise ValueError(f"{self.name}: unknown variability {self.variability!r}")
        expected_initial = None if self.causality == "input" else "exact"
        if self.initial != expected_initial:
            raise ValueError(f"{self.name}: a flightgp {self.causality} has initial={expected_initial!r}")
        if (self.unit is None) != (self.kind != "Real") or (self.unit is not None and self.unit not in UNITS):
            raise ValueError(f"{self.name}: Real variables need a unit from UNITS, others none "
                             f"(got {self.unit!r})")
        if not self.description:
            raise ValueError(f"{self.name}: needs a description")

    @property
    def kind(self) -> str:
        """FMI type: ``"Boolean"``, ``"Integer"`` or ``"Real"``."""
        if isinstance(self.start, bool):
            return "Boolean"
        return "Integer" if isinstance(self.start, int) else "Real"

    def problem(self, value) -> str | None:
        """Why ``value`` is not acceptable for this variable, or None."""
        if self.kind != "Real":
            return None
        if not math.isfinite(value):
            return f"{self.name} = {value} is not a finite number"
        if self.minimum is not None and value < self.minimum:
            return f"{self.name} = {value:.16g} is below its minimum {self.minimum:.16g} [{self.unit}]"
        if self.maximum is not None and value > self.maximum:
            return f"{self.name} = {value:.16g} is above its maximum {self.maximum:.16g} [{self.unit}]"
        return None


class _TableReal(Real):
    """pythonfmu's Real plus ``unit``, ``displayUnit``, ``min`` and ``max``, and a ``start``
    written with 17 significant digits (pythonfmu writes 16, which does not round-trip a double)."""

    def __init__(self, variable: Variable, **kwargs) -> None:
        super().__init__(variable.name, **kwargs)
        self._extra = {"unit": variable.unit}
        if variable.minimum is not None:
            self._extra["min"] = f"{variable.minimum:.16g}"
        if variable.maximum is not None:
            self._extra["max"] = f"{variable.maximum:.16g}"

    def to_xml(self):
        node = super().to_xml()
        real = node.find("Real")
        for key, value in self._extra.items():
            real.set(key, value)
        if self.start is not None:
            real.set("start", repr(float(self.start)))
        return node


_TYPES = {"Real": _TableReal, "Boolean": Boolean, "Integer": Integer}


class FlightgpSlave(Fmi2Slave):
    """Base of every flightgp FMU; subclasses declare data and two model methods.

    Class attributes a subclass sets
    --------------------------------
    description : str
        One line for the model description.
    PACKAGE : str
        The FMU's package folder under ``resources/``, which holds its code and
        :data:`MODEL_FILE` (set by the class the build generates, :mod:`fmu_src.fmi.pythonfmu`).
    VARIABLES : tuple of Variable
        The variable table (value references in this order).
    STEP_SIZE : float or None
        Required communication step, s (None: the first step's, see :meth:`step_problem`).
    DEFAULT_STEP_SIZE : float or None
        Step of the default experiment when ``STEP_SIZE`` is None, s.
    CAN_GET_AND_SET_FMU_STATE : bool
        Whether the FMU can save and restore its complete state (module docstring, "State").
    DEFAULT_STOP_TIME : float
        Stop time of the default experiment, s.
    STATE_ATTRIBUTES : tuple of str
        Hidden instance attributes that make up the model's state (saved and restored).
    CONSTANT_ATTRIBUTES : tuple of str
        Instance attributes that never change after loading (not saved).

    Methods a subclass implements
    -----------------------------
    load_constants()
        Load what the model needs (:attr:`CONSTANT_ATTRIBUTES`); called before ``start_model``
        and when a state is restored into an instance that has not loaded it.
    start_model()
        Set the hidden state and the outputs at the start time, from the inputs and parameters
        (already checked).
    advance_model(t, h)
        One step from ``t = t_k`` to ``t + h`` (s; ``t`` for messages): read inputs, update
        state, set outputs. If it
        raises, it must leave the state as it was (compute first, commit last): the step is
        then refused and may be retried; if it cannot (the state has already moved), it raises
        :class:`ModelFailure`.
    step_problem(h), optional
        When ``STEP_SIZE`` is None: why steps of ``h`` s are impossible, or None.
    """

    PACKAGE = ""
    VARIABLES: tuple = ()
    STEP_SIZE: float | None = None
    DEFAULT_STEP_SIZE: float | None = None
    CAN_GET_AND_SET_FMU_STATE = True
    DEFAULT_STOP_TIME = 10.0
    STATE_ATTRIBUTES: tuple = ()
    CONSTANT_ATTRIBUTES: tuple = ()
    _BASE_STATE = ("_start_time", "_step_count", "_step_size", "_mode", "_refused")

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.default_experiment = DefaultExperiment(
            start_time=0.0, stop_time=self.DEFAULT_STOP_TIME,
            step_size=self.DEFAULT_STEP_SIZE if self.STEP_SIZE is None else self.STEP_SIZE)
        names = [v.name for v in self.VARIABLES]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.modelName}: duplicate variable names in {names}")
        self._checked = [(v, -sys.float_info.max if v.minimum is None else v.minimum,
                          sys.float_info.max if v.maximum is None else v.maximum)
                         for v in self.VARIABLES if v.causality != "output" and v.kind == "Real"]
        self.values = {v.name: v.start for v in self.VARIABLES}
        # Value reference -> variable, per FMI type (pythonfmu numbers them in table order).
        self._references = {kind: {} for kind in ("Real", "Integer", "Boolean", "String")}
        for reference, variable in enumerate(self.VARIABLES):
            self._references[variable.kind][reference] = variable
            self.register_variable(_TYPES[variable.kind](
                variable if variable.kind == "Real" else variable.name,
                causality=Fmi2Causality[variable.causality],
                variability=Fmi2Variability[variable.variability],
                initial=None if variable.initial is None else Fmi2Initial[variable.initial],
                description=variable.description,
                getter=lambda name=variable.name: self.values[name]))
        self._start_time = 0.0
        self._step_count = 0
        self._step_size = self.STEP_SIZE  # None until the first step fixes it
        self._mode = "instantiated"  # -> "initialization" -> "stepping"; or "failed"
        self._refused = None  # message of a refused setter, reported by the next do_step
        self._own_attributes = (set(vars(self)) | {"_own_attributes"}) - set(self._BASE_STATE)

    # -- model description --------------------------------------------------------------------
    def to_xml(self, model_options=None):
        """pythonfmu's model description plus ``UnitDefinitions`` (FMI 2.0 schema order: after
        ``CoSimulation``, before ``LogCategories``)."""
        from xml.etree.ElementTree import Element, SubElement

        root = super().to_xml({} if model_options is None else model_options)
        definitions = Element("UnitDefinitions")
        for name in sorted({v.unit for v in self.VARIABLES if v.unit is not None}):
            base, display = UNITS[name]
            unit = SubElement(definitions, "Unit", {"name": name})
            SubElement(unit, "BaseUnit", {key: str(value) for key, value in base.items()})
            for display_name, factor in display.items():
                SubElement(unit, "DisplayUnit", {"name": display_name, "factor": f"{factor:.16g}"})
        position = list(root).index(root.find("CoSimulation")) + 1
        root.insert(position, definitions)
        # Outputs at t_k do not depend on the inputs set at t_k (the sampling convention), so
        # every output lists no dependencies: no direct feedthrough, no algebraic loop.
        for unknown in root.iter("Unknown"):
            unknown.set("dependencies", "")
        return root

    # -- variable access ----------------------------------------------------------------------
    # pythonfmu's own get_/set_ functions raise (fmi2Fatal) on an unknown value reference or a
    # wrong type; these log an Error instead (setters also refuse the next step, getters return
    # NaN / the type's zero for the unknown references).
    def get_real(self, vrs):
        return self._get("Real", vrs, math.nan)

    def get_integer(self, vrs):
        return self._get("Integer", vrs, 0)

    def get_boolean(self, vrs):
        return self._get("Boolean", vrs, False)

    def get_string(self, vrs):
        return self._get("String", vrs, "")

    def set_real(self, vrs, values):
        self._set("Real", vrs, values)

    def set_integer(self, vrs, values):
        self._set("Integer", vrs, values)

    def set_boolean(self, vrs, values):
        self._set("Boolean", vrs, values)

    def set_string(self, vrs, values):
        self._set("String", vrs, values)

    def _get(self, kind: str, vrs, missing):
        references, values = self._references[kind], self.values
        try:
            return [values[references[vr].name] for vr in vrs]
        except Exception:  # noqa: BLE001 - an exception here would be fmi2Fatal
            unknown = [vr for vr in vrs if vr not in references]
            self._log_error(f"fmi2Get{kind}: value reference(s) {unknown} are not {kind} variables "
                            "of this FMU")
            return [values[references[vr].name] if vr in references else missing for vr in vrs]

    def _set(self, kind: str, vrs, values) -> None:
        references = self._references[kind]
        for vr, value in zip(vrs, values):
            variable = references.get(vr)
            if variable is None:
                self._refuse(f"fmi2Set{kind}: value reference {vr} is not a {kind} variable of this FMU")
            elif variable.causality == "output":
                self._refuse(f"{variable.name} is an output; it cannot be set")
            elif variable.variability == "fixed" and self._mode not in ("instantiated", "initialization"):
                self._refuse(f"{variable.name} is a fixed parameter; it can only be set before the "
                             f"end of initialisation (kept {self.values[variable.name]!r})")
            else:
                try:
                    self.values[variable.name] = type(variable.start)(value)
                except Exception as error:  # noqa: BLE001 - an exception here would be fmi2Fatal
                    self._refuse(f"setting {variable.name} = {value!r} failed: {error}")

    def _refuse(self, message: str) -> None:
        self._log_error(message)
        self._refused = message

    def input_problems(self) -> list[str]:
        """Problems of the current input and parameter values (NaN, inf, outside min/max)."""
        values = self.values
        # Fast path first: NaN fails both comparisons, +/-inf the finite default limits.
        return [variable.problem(values[variable.name]) for variable, low, high in self._checked
                if not low <= values[variable.name] <= high]

    # -- logging ------------------------------------------------------------------------------
    def log_info(self, message: str) -> None:
        self._log(message, Fmi2Status.ok)

    def log_warning(self, message: str) -> None:
        self._log(message, Fmi2Status.warning)

    def _log_error(self, message: str) -> None:
        self._log(message, Fmi2Status.error)

    def _log(self, message: str, status: Fmi2Status) -> None:
        # The FMI 2.0 logger takes the message as a printf format with #<type><vr># variable
        # references (FMI 2.0.5, 2.1.5): a literal % is %%, a literal # is ##.
        self.log(message.replace("%", "%%").replace("#", "##"), status)

    def _log_exception(self, where: str, error: BaseException) -> None:
        frames = traceback.extract_tb(error.__traceback__)[-3:]
        trail = "; ".join(f"{f.filename.rsplit('/', 1)[-1]}:{f.lineno} in {f.name}" for f in frames)
        self._log_error(f"{where}: {type(error).__name__}: {error} ({trail})")

    # -- lifecycle ----------------------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        try:
            self._start_time = float(start_time)
        except Exception as error:  # noqa: BLE001
            self._log_exception("fmi2SetupExperiment", error)
            self._mode = "failed"

    def enter_initialization_mode(self):
        if self._mode == "instantiated":
            self._mode = "initialization"

    def exit_initialization_mode(self):
        try:
            if self._mode == "failed":
                return
            problems = self.input_problems()
            if problems:
                self._log_error("initialisation refused: " + "; ".join(problems))
                self._mode = "failed"
                return
            self._step_count = 0
            self._step_size = self.STEP_SIZE
            self._refused = None
            self.load_constants()
            self.start_model()
            self._mode = "stepping"
        except Exception as error:  # noqa: BLE001 - would be fmi2Fatal
            self._log_exception("fmi2ExitInitializationMode", error)
            self._mode = "failed"

    def do_step(self, current_time, step_size):
        try:
            refusal = self._step_refusal(current_time, step_size)
            if refusal:
                self._log_error(f"fmi2DoStep at t = {current_time:.16g} s refused (fmi2Discard): {refusal}")
                return False
            h = float(step_size) if self._step_size is None else self._step_size
            self.advance_model(float(current_time), h)
            self._step_size = h
            self._step_count += 1
            return True
        except ModelFailure as error:
            self._mode = "failed"
            self._log_exception(f"fmi2DoStep at t = {current_time:.16g} s (fmi2Discard; the FMU cannot "
                                "continue: reset or re-instantiate it)", error)
            return False
        except Exception as error:  # noqa: BLE001 - would be fmi2Fatal
            self._log_exception(f"fmi2DoStep at t = {current_time:.16g} s (fmi2Discard)", error)
            return False

    def _step_refusal(self, current_time, step_size) -> str | None:
        if self._mode == "failed":
            return "the FMU failed earlier (see the earlier error); reset or re-instantiate it"
        if self._mode != "stepping":
            return f"not ready to step (the FMU is {self._mode}; step after fmi2ExitInitializationMode)"
        if self._refused is not None:
            message, self._refused = self._refused, None
            return f"a value was refused since the last step: {message}"
        problems = self.input_problems()
        if problems:
            return "; ".join(problems)
        h = self._step_size
        if h is None:  # the first step fixes the step
            if not step_size > 0:
                return f"communicationStepSize must be positive, got {step_size:.16g}"
            problem = self.step_problem(float(step_size))
            if problem:
                return problem
            h = float(step_size)
        elif abs(step_size - h) > TIME_TOLERANCE * h:
            why = ("its model step" if self.STEP_SIZE is not None
                   else "the step of its first fmi2DoStep, until reset")
            return (f"expected communicationStepSize = {h:.16g} s but was {step_size:.16g} s "
                    f"(this FMU advances in steps of exactly {why})")
        expected = self._start_time + self._step_count * h
        if abs(current_time - expected) > TIME_TOLERANCE * h:
            return (f"expected currentCommunicationPoint = {expected:.16g} s but was "
                    f"{current_time:.16g} s")
        return None

    def terminate(self):
        self._mode = "terminated" if self._mode != "failed" else "failed"

    # -- helpers for subclasses ---------------------------------------------------------------
    def model_file(self) -> Path:
        """The path of the FMU's model file, :data:`MODEL_FILE` in its package folder."""
        return Path(self.resources) / self.PACKAGE / MODEL_FILE

    def shared_model(self, load, path, what: str):
        """The model file at ``path``, loaded by ``load(path)`` once per process and logged;
        the loaded object must be read-only (every instance of the FMU shares it) and have a
        ``describe()`` line."""
        key = str(path)
        if key not in _SHARED_MODELS:
            model = load(path)
            self.log_info(f"loaded {what} {Path(path).name}: {model.describe()}")
            _SHARED_MODELS[key] = model
        return _SHARED_MODELS[key]

    def report_envelope(self, outside: list, was_outside: bool, t: float, consequence: str) -> bool:
        """Log leaving (warning, once, with the offending inputs and ``consequence``) and
        re-entering (info) the training envelope at time ``t``; returns whether outside now."""
        if outside and not was_outside:
            self.log_warning(f"t = {t:.16g} s: input outside the training envelope: "
                             + "; ".join(outside) + f". The GP extrapolates; {consequence}.")
        elif was_outside and not outside:
            self.log_info(f"t = {t:.16g} s: back inside the training envelope")
        return bool(outside)

    # -- model (subclasses) -------------------------------------------------------------------
    def load_constants(self) -> None:
        pass

    def step_problem(self, h: float) -> str | None:
        """Why the FMU cannot take communication steps of ``h`` s, or None (asked at the first step
        when ``STEP_SIZE`` is None; the step is then fixed until reset)."""
        return None

    def start_model(self) -> None:
        raise NotImplementedError

    def advance_model(self, t: float, h: float) -> None:
        raise NotImplementedError

    # -- state --------------------------------------------------------------------------------
    def _get_fmu_state(self):
        if not self.CAN_GET_AND_SET_FMU_STATE:
            self._log_error("fmi2GetFMUstate: this FMU cannot save its complete state "
                            "(canGetAndSetFMUstate is false); the state returned cannot be restored")
            return {"format": _NO_STATE_FORMAT}
        state_names = self._BASE_STATE + tuple(self.STATE_ATTRIBUTES)
        unsaved = set(vars(self)) - self._own_attributes - set(state_names) - set(self.CONSTANT_ATTRIBUTES)
        if unsaved:
            self._log_error(f"internal: attribute(s) {', '.join(sorted(unsaved))} are neither state "
                            "nor constants; the saved FMU state is incomplete")
        return {"format": _STATE_FORMAT, "values": dict(self.values),
                "hidden": {name: _to_data(getattr(self, name, None)) for name in state_names}}

    def _set_fmu_state(self, state):
        try:
            if not self.CAN_GET_AND_SET_FMU_STATE:
                raise ValueError("this FMU cannot restore a state (canGetAndSetFMUstate is false)")
            if not isinstance(state, dict) or state.get("format") != _STATE_FORMAT:
                raise ValueError("not an FMU state saved by this FMU")
            if set(state["values"]) != set(self.values):
                raise ValueError("the saved state holds other variables than this FMU")
            for name, value in state["values"].items():
                self.values[name] = value
            for name, value in state["hidden"].items():
                setattr(self, name, _from_data(value))
            if self._mode == "stepping" and not all(hasattr(self, n) for n in self.CONSTANT_ATTRIBUTES):
                self.load_constants()
        except Exception as error:  # noqa: BLE001 - would be fmi2Fatal
            self._refuse(f"fmi2SetFMUstate failed: {type(error).__name__}: {error}")


def _to_data(value):
    """JSON-safe copy of a state attribute (arrays become tagged nested lists)."""
    if isinstance(value, np.ndarray):
        return {"ndarray": value.tolist(), "dtype": str(value.dtype)}
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_to_data(v) for v in value]
    if isinstance(value, dict):
        return {k: _to_data(v) for k, v in value.items()}
    return value


def _from_data(value):
    """Inverse of :func:`_to_data`; always a fresh object (a state may be restored many times)."""
    if isinstance(value, dict) and set(value) == {"ndarray", "dtype"}:
        return np.array(value["ndarray"], dtype=value["dtype"])
    if isinstance(value, list):
        return [_from_data(v) for v in value]
    if isinstance(value, dict):
        return {k: _from_data(v) for k, v in value.items()}
    return value
