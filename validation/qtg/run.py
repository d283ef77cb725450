"""Running a QTG: every test of a spec against one model, each output scored against its band
(docs/qtg.md, "How a test is run and scored").

The model is one of

- a vehicle of the registry (``--reference bo105-80kt``, a state-space ``FILE.json``):
  ``simulate(time, inputs)`` on the recorded inputs from the recorded start;
- an FMI 2.0 co-simulation FMU: run in fmpy on the recorded inputs, from its own start, on the
  recording's grid (:func:`validation.cosim.cosimulation.simulate`), one instance for all tests;
- a flightgp GP rate-predictor FMU (outputs with ``<name>_prev`` inputs and a ``free_run``
  parameter): in free-run mode from the recording's first rates, on its own step grid
  (:func:`validation.cosim.cosimulation.free_run`); its samples are the ones compared.

A recording is simulated once however many tests use it. A test runs only when the model has all
of its outputs and takes every input the recording moves (else it is *not run*, with the reason);
a model that refuses to run or diverges gives an *error*. Each output is scored on the samples of
its window: the band's largest excursion and its time, the share inside, and beside them the
fidelity scorecard's RMSE, Theil's U and Tischler's frequency-domain cost
(:mod:`validation.diagnose.fidelity`).
"""
from __future__ import annotations

import time as clock
from contextlib import ExitStack
from dataclasses import dataclass, field

import numpy as np

from validation.core.errors import BadInputError
from validation.core.metrics import rmse, theil_inequality
from validation.core.progress import progress_bar
from validation.core.recordings import Recording, column_unit
from validation.cosim.cosimulation import OpenFmu, free_run, rate_predictor_axes, rate_predictor_controls, simulate
from validation.diagnose.fidelity import STATED_UNITS, frequency_costs
from validation.qtg.spec import OutputCheck, QtgSpec, QtgTest
from validation.vehicles import get_vehicle
from validation.vehicles.effect_vehicle import EffectVehicle, is_effect_vehicle_file, takes_effects
from validation.vehicles.fmu_reference import read_cosimulation_fmu

#: The verdicts of a test.
PASSED, FAILED, ERROR, NOT_RUN = "passed", "failed", "error", "not run"


@dataclass
class ModelRun:
    """A model's simulation of one recording: the recording's samples it has (``rows``, an index
    into the recording), their ``time`` (m,), s, and ``outputs``, name -> ndarray (m,) in SI."""

    rows: slice
    time: np.ndarray
    outputs: dict


class VehicleModel:
    """A vehicle of the registry (a built-in reference or a state-space ``FILE.json``), or the
    model file of a diagnosis (``corrected_model.json``: a reference with named effects,
    :class:`~validation.vehicles.effect_vehicle.EffectVehicle`), as a QTG model.

    A reference that takes effects flies each recording from the state its replays start from
    (:meth:`~validation.vehicles.effect_vehicle.EffectVehicle.replay_states`: the Bo105's and the
    blimp's own trim or rest, the RGBlimp's first recorded state), noise-free; any other vehicle
    (a flight-test stand-in, a JSBSim aircraft) flies it from its own start."""

    kind = "reference"

    def __init__(self, name: str):
        if is_effect_vehicle_file(name):
            self.vehicle, self.name = EffectVehicle.load(name), None
        elif takes_effects(name):
            self.vehicle = EffectVehicle(name, [])
            self.name = self.vehicle.reference_name
        else:
            self.vehicle, self.name = get_vehicle(name), None
        self.name = self.name or self.vehicle.name
        self.input_names, self.output_names = tuple(self.vehicle.input_names), tuple(self.vehicle.state_names)

    def run(self, recording: Recording, outputs) -> ModelRun:
        inputs = np.column_stack([recording.input(name) for name in self.input_names])
        if isinstance(self.vehicle, EffectVehicle):
            ordered = Recording(recording.time, inputs, self.input_names, recording.outputs, recording.output_names)
            states = self.vehicle.replay_states(ordered)
            return ModelRun(slice(None), recording.time,
                            {name: states[:, self.output_names.index(name)] for name in outputs})
        simulated = self.vehicle.simulate(recording.time, inputs)
        return ModelRun(slice(None), recording.time, {name: simulated.output(name) for name in outputs})


class FmuModel:
    """An FMI 2.0 co-simulation FMU as a QTG model, its inputs and outputs its Real ones; one
    instance for every run (:class:`validation.cosim.cosimulation.OpenFmu`)."""

    kind = "fmu"

    def __init__(self, fmu: OpenFmu):
        self.fmu = fmu
        self.name = fmu.description.modelName
        real = [v for v in fmu.description.modelVariables if v.type == "Real"]
        self.input_names = tuple(v.name for v in real if v.causality == "input")
        self.output_names = tuple(v.name for v in real if v.causality == "output")

    def run(self, recording: Recording, outputs) -> ModelRun:
        run = simulate(self.fmu, time=recording.time, inputs={n: recording.input(n) for n in self.input_names},
                       outputs=list(outputs))
        return ModelRun(slice(None), recording.time, run.outputs)


class RatePredictorModel:
    """A flightgp GP rate-predictor FMU in free-run mode (module docstring); its outputs are its
    rates, its inputs its controls."""

    kind = "gp-rate-predictor-fmu"

    def __init__(self, fmu: OpenFmu):
        self.fmu = fmu
        self.name = fmu.description.modelName
        self.output_names = rate_predictor_axes(fmu.description)
        self.input_names = rate_predictor_controls(fmu.description)

    def run(self, recording: Recording, outputs) -> ModelRun:
        run = free_run(self.fmu, recording)
        return ModelRun(run.rows, recording.time[run.rows], {name: run.run.outputs[name] for name in outputs})

    def cannot_run(self, recording: Recording) -> str | None:
        """Why the free run cannot start from ``recording``: a rate it does not hold."""
        lacking = [name for name in self.output_names if name not in recording.output_names]
        return f"the recording has no {', '.join(lacking)}, the model's starting rates" if lacking else None


def open_model(stack: ExitStack, *, fmu=None, reference: str | None = None):
    """The model of ``flightgp qtg``: ``fmu`` (a path) or ``reference`` (a registry name or a
    state-space ``FILE.json``), exactly one; an FMU is opened in ``stack`` (closed with it).
    BadInputError for a file that is no FMI 2.0 co-simulation FMU or an unknown name."""
    if (fmu is None) == (reference is None):
        raise BadInputError("give the model to qualify: --fmu FILE.fmu or --reference NAME")
    if reference is not None:
        if str(reference).endswith(".fmu"):
            raise BadInputError(f"--reference {reference}: an FMU goes after --fmu")
        return VehicleModel(str(reference))
    read_cosimulation_fmu(fmu, purpose="qtg")
    opened = stack.enter_context(OpenFmu(fmu))
    parameters = {v.name for v in opened.description.modelVariables if v.causality == "parameter"}
    if rate_predictor_axes(opened.description) and "free_run" in parameters:
        return RatePredictorModel(opened)
    return FmuModel(opened)


#: The units a reviewer reads angles and rates in (plots, reports, failure messages): SI unit ->
#: (unit shown, its number per SI unit).
READING_UNITS = {si: (shown, 1.0 / STATED_UNITS[shown][1]) for si, shown in (("rad", "deg"), ("rad/s", "deg/s"))}


def display(name: str, tolerance) -> tuple[str, float]:
    """The unit output ``name`` is shown in and its number per SI unit: the unit its tolerance is
    stated in, else :data:`READING_UNITS` (deg, deg/s), else its SI unit."""
    unit = column_unit(name)
    if tolerance.as_stated and not tolerance.relative:
        stated = tolerance.as_stated.split(" ", 1)[1]
        return stated, 1.0 / STATED_UNITS[stated][1]
    return READING_UNITS.get(unit, (unit, 1.0))


@dataclass
class OutputResult:
    """One output of a test, scored on the samples of its window (module docstring).

    Attributes
    ----------
    check : OutputCheck
        The output, its band, window and pass rule as the spec states them.
    unit : str
        The output's SI unit.
    half_width : float
        The band's half-width, in ``unit`` (a relative band's computed from the recorded peak).
    inside_share : float
        Share of the compared samples inside the band.
    max_error, max_error_time : float
        Largest absolute difference from the flight test, in ``unit``, and its time, s.
    excursion : float
        How far ``max_error`` lies beyond the band, in ``unit`` (0 when every sample is inside).
    passed : bool
        ``inside_share`` at least the check's ``share``.
    rmse, theil : float
        RMSE (``unit``) and Theil's inequality coefficient over the compared samples.
    frequency_cost, frequency_input
        Tischler's cost J and the input it is taken from (None without a coherent input).
    time, recorded, simulated : ndarray, shape (m,)
        The model's samples' times (s) and values (``unit``), for the plot; not in ``qtg.json``.
    in_window : ndarray of bool, shape (m,)
        The samples compared (inside the check's window).
    """

    check: OutputCheck
    unit: str
    half_width: float
    inside_share: float
    max_error: float
    max_error_time: float
    excursion: float
    passed: bool
    rmse: float
    theil: float
    frequency_cost: float | None
    frequency_input: str | None
    time: np.ndarray = field(repr=False)
    recorded: np.ndarray = field(repr=False)
    simulated: np.ndarray = field(repr=False)
    in_window: np.ndarray = field(repr=False)

    def failure(self) -> str:
        """Why the output fails, in one line: the excursion, its time and the share inside."""
        unit, scale = display(self.check.name, self.check.tolerance)
        band = self.check.tolerance.words(self.unit)
        words = (f"{self.check.name} off the flight test by {self.max_error * scale:.3g} {unit} at "
                 f"t = {self.max_error_time:.2f} s, {self.excursion * scale:.3g} {unit} beyond its {band} band")
        if self.check.share < 1:
            words += f"; {100 * self.inside_share:.0f} % of samples inside, {100 * self.check.share:g} % required"
        return words


@dataclass
class TestResult:
    """One test's verdict (:data:`PASSED`, :data:`FAILED`, :data:`ERROR` or :data:`NOT_RUN`), the
    ``reason`` for the last two, and its ``outputs`` (name -> :class:`OutputResult`, empty unless
    run), with the recording's inputs on the model's samples for the plot (``input_time`` (m,),
    ``inputs`` name -> (m,))."""

    __test__ = False  # not a pytest test class

    test: QtgTest
    status: str
    reason: str | None = None
    outputs: dict = field(default_factory=dict)
    input_time: np.ndarray | None = field(default=None, repr=False)
    inputs: dict = field(default_factory=dict, repr=False)
    seconds: float = 0.0

    def failure(self) -> str | None:
        """The failing outputs' :meth:`OutputResult.failure`, joined; None when none fails."""
        failing = [result.failure() for result in self.outputs.values() if not result.passed]
        return "; ".join(failing) or None


@dataclass
class QtgResult:
    """A QTG run: the spec, the model's ``model_name`` and ``model_kind``, every test's
    :class:`TestResult` in the spec's order, the time it took (s) and how often the FMU was
    instantiated (None for a built-in model)."""

    spec: QtgSpec
    model_name: str
    model_kind: str
    tests: list
    seconds: float
    instantiations: int | None = None

    def count(self, status: str) -> int:
        """How many tests ended with ``status``."""
        return sum(result.status == status for result in self.tests)

    @property
    def passed(self) -> bool:
        """True when at least one test ran and none failed or erred."""
        return self.count(PASSED) > 0 and self.count(FAILED) == 0 and self.count(ERROR) == 0


def run_qtg(spec: QtgSpec, model, *, progress: bool = True) -> QtgResult:
    """Run every test of ``spec`` against ``model`` (:func:`open_model`; module docstring).

    Returns
    -------
    QtgResult
    """
    started = clock.perf_counter()
    needed = {}  # recording -> the outputs its tests need of the model
    for test in spec.tests:
        needed.setdefault(id(test.recording), set()).update(c.name for c in test.outputs)
    runs = {}
    results = []
    with progress_bar("qtg", total=len(spec.tests), unit="test", enabled=progress) as update:
        for test in spec.tests:
            test_started = clock.perf_counter()
            result = _run_test(test, model, runs, needed)
            result.seconds = clock.perf_counter() - test_started
            results.append(result)
            if update:
                update(1, last=f"{test.id}: {result.status}")
    instantiations = model.fmu.instantiations if hasattr(model, "fmu") else None
    return QtgResult(spec, model.name, model.kind, results, clock.perf_counter() - started, instantiations)


def _run_test(test: QtgTest, model, runs: dict, needed: dict) -> TestResult:
    recording = test.recording
    lacking = [c.name for c in test.outputs if c.name not in model.output_names]
    if lacking:
        return TestResult(test, NOT_RUN, f"the model has no output {', '.join(lacking)}")
    unused = [name for name in recording.input_names
              if name not in model.input_names and np.ptp(recording.input(name)) > 0]
    if unused:
        return TestResult(test, NOT_RUN, f"the model has no input {', '.join(unused)}, which the recording moves")
    missing = [name for name in model.input_names if name not in recording.input_names]
    if missing:
        return TestResult(test, NOT_RUN, f"the recording has no input {', '.join(missing)}, which the model takes")
    reason = model.cannot_run(recording) if hasattr(model, "cannot_run") else None
    if reason:
        return TestResult(test, NOT_RUN, reason)
    key = id(recording)
    if key not in runs:
        try:
            runs[key] = model.run(recording, sorted(set(model.output_names) & needed[key]))
        except BadInputError as error:
            runs[key] = str(error)
    run = runs[key]
    if isinstance(run, str):
        return TestResult(test, ERROR, f"the model did not run: {run}")
    for check in test.outputs:
        bad = np.flatnonzero(~np.isfinite(run.outputs[check.name]))
        if len(bad):
            return TestResult(test, ERROR, f"the model's {check.name} is not finite from t = {run.time[bad[0]]:g} s")
    inputs = recording.inputs[run.rows]
    step = float(run.time[1] - run.time[0])
    empty = [check.name for check in test.outputs if not window_mask(run.time, check.window, step).any()]
    if empty:
        return TestResult(test, NOT_RUN, f"the model's samples (every {step:g} s) fall outside the window of "
                                         f"{', '.join(empty)}")
    outputs = {check.name: score(check, run.time, recording.output(check.name)[run.rows],
                                 run.outputs[check.name], inputs=inputs, input_names=recording.input_names,
                                 step=step)
               for check in test.outputs}
    status = PASSED if all(result.passed for result in outputs.values()) else FAILED
    return TestResult(test, status, None, outputs, run.time,
                      {name: recording.input(name)[run.rows] for name in recording.input_names})


def window_mask(time: np.ndarray, window, step: float) -> np.ndarray:
    """Which of the samples ``time`` (m,), s, evenly spaced by ``step``, lie in ``window``
    (``(t0, t1)`` s, or None: all), shape (m,) bool; a half-sample margin, so a window edge on a
    sample includes it despite rounding."""
    if window is None:
        return np.ones(len(time), dtype=bool)
    return (time >= window[0] - step / 2) & (time <= window[1] + step / 2)


def score(check: OutputCheck, time: np.ndarray, recorded: np.ndarray, simulated: np.ndarray, *,
          inputs: np.ndarray, input_names, step: float) -> OutputResult:
    """Score one output against the flight test on the samples of its window.

    Parameters
    ----------
    check : OutputCheck
    time : ndarray, shape (m,)
        The compared samples' times, s, evenly spaced by ``step``.
    recorded, simulated : ndarray, shape (m,)
        Flight test and model, in the output's SI unit.
    inputs : ndarray, shape (m, n_inputs)
        The recorded inputs at those samples (for the frequency-domain cost).
    input_names : sequence of str
    step : float
        s.
    """
    in_window = window_mask(time, check.window, step)
    compared_time, compared, model = time[in_window], recorded[in_window], simulated[in_window]
    half_width = check.tolerance.half_width(compared)
    error = np.abs(model - compared)
    worst = int(np.argmax(error))
    inside_share = float(np.mean(error <= half_width))
    frequency_input, costs = frequency_costs(inputs[in_window], input_names, compared, {"model": model}, step=step)
    return OutputResult(check, column_unit(check.name), half_width, inside_share, float(error[worst]),
                        float(compared_time[worst]), max(0.0, float(error[worst]) - half_width),
                        inside_share >= check.share - 1e-12, rmse(compared, model), theil_inequality(compared, model),
                        costs.get("model"), frequency_input, time, recorded, simulated, in_window)
