"""Any FMI 2.0 co-simulation FMU as a reference: ``flightgp diagnose --reference PATH.fmu``
(docs/diagnose.md, "FMU references").

:class:`FMUReference` reads the FMU's model description (fmpy), maps recording columns to its
Real inputs and outputs by name, and replays a recording through one instance that it keeps
(extracted once, instantiated once, reset between replays): inputs set, ``fmi2DoStep`` at the
recording's step, outputs read, from the recording's first state where the FMU has start-value
parameters ``<output>_start`` for it. :class:`FMUEffects` is its
:class:`~validation.vehicles.effects.EffectModel`. Effects available for any FMU:

- on an input: ``time_delay`` and ``input_lag`` (the interval means of
  :func:`~validation.vehicles.effects.delayed_interval_means` and
  :func:`~validation.vehicles.effects.lagged_interval_means`, as for the blimp), ``input_gain``
  (the FMU sees ``gain * u``: control effectiveness);
- on an output: ``sensor_bias`` (``+ b``) and ``output_scale`` (``* s``; the scale first);
- ``fmu_parameter``: any Real parameter the FMU exposes (``causality="parameter"``, not a
  ``<output>_start``), set before initialisation; named by the FMU's own name and described by
  its own description.

A replay the FMU refuses (a status of Error or Fatal, which fmpy raises) ends that candidate as
diverged (its outputs NaN, so the fit steps back) and is logged once per message; the diagnosis
goes on. A crash of the FMU's process cannot be caught in the same process.
"""
from __future__ import annotations

import logging
import math
import shutil
import tempfile
import weakref
from pathlib import Path

import numpy as np

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.core.sampling import check_history
from validation.vehicles.effects import (
    Hypothesis,
    delayed_interval_means,
    lagged_interval_means,
    simulate_each_recording,
)
from validation.vehicles.linear_effects import sequential_three_two_one_one
from validation.vehicles.state_space import DEFAULT_SAMPLE_TIME

_log = logging.getLogger(__name__)
#: Suffix of the start-value parameters flightgp's FMUs (and others) expose per output.
START_SUFFIX = "_start"
#: Longest stretch of a recording's start averaged into the start state, s (:meth:`FMUEffects.start_state`).
START_WINDOW = 0.5


def _read_description(path: Path):
    """fmpy's model description of ``path``, checked: FMI 2.0, co-simulation, Real inputs and
    outputs; BadInputError in one line otherwise."""
    from fmpy import read_model_description  # fmpy loads only when an FMU reference is used

    if not path.is_file():
        raise BadInputError(f"{path}: no such FMU")
    try:
        description = read_model_description(str(path), validate=False)
    except Exception as error:  # noqa: BLE001 - fmpy raises many kinds for a file that is not an FMU
        raise BadInputError(f"{path}: not an FMU ({type(error).__name__}: {str(error).splitlines()[0][:200]})") \
            from None
    if description.fmiVersion != "2.0":
        raise BadInputError(f"{path}: an FMI {description.fmiVersion} FMU; diagnose takes FMI 2.0 co-simulation FMUs")
    if description.coSimulation is None:
        raise BadInputError(f"{path}: a model-exchange FMU; diagnose takes FMI 2.0 co-simulation FMUs")
    return description


def _start(variable) -> float:
    """A Real variable's start value (0 without one)."""
    return float(variable.start) if variable.start is not None else 0.0


def _unit(variable) -> str:
    """A Real variable's unit, its declared type's, or ``"1"``."""
    declared = variable.declaredType.unit if variable.declaredType is not None else None
    return variable.unit or declared or "1"


class FMUReference:
    """An FMU as a reference vehicle (module docstring).

    Parameters
    ----------
    path : path-like
        The ``.fmu`` file.

    Attributes
    ----------
    name : str
        The path as given.
    input_names, state_names : tuple of str
        The FMU's Real inputs and outputs.
    parameters : dict of str to (float, str, str)
        Its Real parameters that are not start values: start value, unit (``"1"`` without one)
        and description (its name without one).
    units : dict of str to str
        Each input's and output's declared unit (``"1"`` without one).
    start_parameters, start_values : dict of str to str, dict of str to float
        Output -> the name of its start-value parameter and that parameter's start value, for the
        outputs that have one.
    sample_time : float
        The default experiment's step, or
        :data:`validation.vehicles.state_space.DEFAULT_SAMPLE_TIME`.
    """

    def __init__(self, path):
        self.path = Path(path)
        description = _read_description(self.path)
        self._description = description
        self.name = str(path)
        real = [v for v in description.modelVariables if v.type == "Real"]
        self.input_names = tuple(v.name for v in real if v.causality == "input")
        self.state_names = tuple(v.name for v in real if v.causality == "output")
        if not self.input_names or not self.state_names:
            raise BadInputError(f"{path}: the FMU needs Real inputs and outputs to replay recordings; it has "
                                f"{len(self.input_names)} and {len(self.state_names)}")
        by_name = {v.name: v for v in real}
        self._references = {name: v.valueReference for name, v in by_name.items()}
        self.start_parameters = {v.name[:-len(START_SUFFIX)]: v.name for v in real
                                 if v.causality == "parameter" and v.name.endswith(START_SUFFIX)
                                 and v.name[:-len(START_SUFFIX)] in self.state_names}
        self.start_values = {output: _start(by_name[parameter]) for output, parameter in self.start_parameters.items()}
        self.parameters = {v.name: (_start(v), _unit(v), v.description or v.name) for v in real
                           if v.causality == "parameter" and v.name not in self.start_parameters.values()}
        self.units = {name: _unit(by_name[name]) for name in self.input_names + self.state_names}
        experiment = description.defaultExperiment
        self.sample_time = float(experiment.stepSize) if experiment is not None and experiment.stepSize else \
            DEFAULT_SAMPLE_TIME
        self._instance = None
        self._unzipdir = None

    def _fmu(self):
        """The kept instance: extracted and instantiated at the first replay, reset before the next
        (instantiated afresh when it cannot be reset, e.g. after a Fatal status)."""
        from fmpy import extract
        from fmpy.fmi2 import FMU2Slave

        if self._unzipdir is None:
            self._unzipdir = extract(str(self.path), unzipdir=tempfile.mkdtemp(prefix="flightgp-fmu-"))
            weakref.finalize(self, shutil.rmtree, self._unzipdir, True)
        if self._instance is not None:
            try:
                self._instance.reset()
                return self._instance
            except Exception:  # noqa: BLE001 - after a Fatal status the instance cannot be reset
                self._instance.freeInstance()
        self._instance = FMU2Slave(guid=self._description.guid, unzipDirectory=self._unzipdir,
                                   modelIdentifier=self._description.coSimulation.modelIdentifier,
                                   instanceName="flightgp_diagnose")
        self._instance.instantiate()
        return self._instance

    def replay(self, time: np.ndarray, inputs: np.ndarray, *, parameters: dict | None = None,
               start: dict | None = None) -> np.ndarray:
        """Outputs at ``time`` (n,) with ``inputs`` (n, n_inputs) held over each interval.

        ``parameters`` (name -> value) and the start values ``start`` (output -> value, for the
        outputs with a ``<output>_start`` parameter) are set before initialisation. Returns shape
        (n, n_outputs); raises what fmpy raises when the FMU refuses a call.
        """
        fmu = self._fmu()
        settings = dict(parameters or {})
        settings.update({self.start_parameters[name]: value for name, value in (start or {}).items()})
        if settings:
            fmu.setReal([self._references[n] for n in settings], [float(v) for v in settings.values()])
        input_refs = [self._references[n] for n in self.input_names]
        output_refs = [self._references[n] for n in self.state_names]
        fmu.setReal(input_refs, [float(v) for v in inputs[0]])
        fmu.setupExperiment(startTime=float(time[0]))
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        outputs = np.empty((len(time), len(output_refs)))
        outputs[0] = fmu.getReal(output_refs)
        for k in range(len(time) - 1):
            fmu.setReal(input_refs, [float(v) for v in inputs[k]])
            fmu.doStep(currentCommunicationPoint=float(time[k]), communicationStepSize=float(time[k + 1] - time[k]))
            outputs[k + 1] = fmu.getReal(output_refs)
        return outputs

    def simulate(self, time, inputs, *, seed: int = 0) -> Recording:
        """Replay ``inputs`` from the FMU's own start; ``seed`` is accepted for the Vehicle interface."""
        time, inputs, step = check_history(time, inputs, self.input_names)
        return Recording(time, inputs, self.input_names, self.replay(time, inputs), self.state_names,
                         {"vehicle": self.name, "sample_time": step})


class FMUEffects:
    """The :class:`~validation.vehicles.effects.EffectModel` of an FMU reference (module docstring).

    Parameters
    ----------
    reference : FMUReference
    """

    family = "fmu"
    kinds = ("time_delay", "input_lag", "input_gain", "sensor_bias", "output_scale", "fmu_parameter")
    batches_simulations = False
    absolute_inputs = False
    needs_even_sampling = True
    min_noise_sd = {}
    simulate_recordings = simulate_each_recording

    def __init__(self, reference: FMUReference):
        self.reference = reference
        self.name, self.sample_time = reference.name, reference.sample_time
        self.input_names, self.state_names = reference.input_names, reference.state_names
        self.residual_gp_states = reference.state_names
        self.terms = {"fmu_parameter": tuple(reference.parameters)}
        self.sensor_noise_sd = dict.fromkeys(reference.state_names, 0.0)
        self._refusals = set()

    def model_value(self, term: str) -> float:
        """The parameter's start value in the FMU."""
        return self.reference.parameters[term][0]

    def term_unit(self, term: str) -> str:
        return self.reference.parameters[term][1]

    def term_description(self, term: str) -> str:
        """The FMU's own description of the parameter (its name without one)."""
        return self.reference.parameters.get(term, (None, None, term))[2]

    def term_value_problem(self, term: str, value: float) -> None:
        """Any finite value: the FMU says at initialisation what it refuses."""
        return None

    def term_hypotheses(self, excited_inputs) -> list[Hypothesis]:
        """A gain on each excited input and a scale on each output (null 1, positive, step 5 %),
        and every parameter (step 5 % of its value, 1e-3 where it is zero)."""
        hypotheses = [Hypothesis("input_gain", name, 1.0, 0.0, math.inf, 0.05) for name in excited_inputs]
        hypotheses += [Hypothesis("output_scale", name, 1.0, 0.0, math.inf, 0.05) for name in self.state_names]
        hypotheses += [Hypothesis("fmu_parameter", name, value, -math.inf, math.inf, max(0.05 * abs(value), 1e-3))
                       for name, (value, _, _) in self.reference.parameters.items()]
        return hypotheses

    def start_state(self, recording) -> np.ndarray | None:
        """The recorded state before the first input moves, for the outputs the FMU has start
        values for (NaN for the others), or None when it has none (the FMU starts where it
        starts). The state is the mean over the samples before the first input change, at most
        :data:`START_WINDOW` s (at least the first row): one noisy sample would start the replay
        a noise standard deviation off, which slow modes (a phugoid) carry for the whole run. An
        output whose mean lies within three standard errors of the FMU's own start value keeps
        that (NaN here): a recording that starts at the FMU's trim is replayed from the trim
        itself, not from its noise."""
        if not self.reference.start_parameters:
            return None
        moved = np.flatnonzero(np.any(np.abs(recording.inputs - recording.inputs[0]) > 0, axis=1))
        quiet = moved[0] if len(moved) else len(recording.time)
        window = max(1, min(quiet, int(np.searchsorted(recording.time, recording.time[0] + START_WINDOW))))
        leading = recording.outputs[:window]
        mean = leading.mean(axis=0)
        standard_error = leading.std(axis=0, ddof=1) / math.sqrt(window) if window > 1 else np.zeros(len(mean))
        start = np.full(len(self.state_names), math.nan)
        for i, name in enumerate(self.state_names):
            if name in self.reference.start_parameters and name in recording.output_names:
                column = recording.output_names.index(name)
                default = self.reference.start_values[name]
                if abs(mean[column] - default) > 3 * standard_error[column]:
                    start[i] = mean[column]
        return start

    def simulate_many(self, effect_lists, time, inputs, *, start=None) -> np.ndarray:
        """One replay per effect list (module docstring), shape (B, n, n_outputs); a refused
        replay gives NaN."""
        time = np.asarray(time, dtype=float)
        inputs = np.asarray(inputs, dtype=float)
        starts = {} if start is None else {n: v for n, v in zip(self.state_names, start) if np.isfinite(v)}
        replays = []
        for effects in effect_lists:
            held = self._effective_inputs(effects, time, inputs)
            parameters = {e["term"]: e["value"] for e in effects if e["effect"] == "fmu_parameter"}
            try:
                with np.errstate(all="ignore"):  # a candidate that blows the FMU up is refused, not warned about
                    outputs = self.reference.replay(time, held, parameters=parameters, start=starts)
            except Exception as error:  # noqa: BLE001 - fmpy raises its own kinds for Error/Fatal
                message = str(error).splitlines()[0] if str(error) else type(error).__name__
                if message not in self._refusals:
                    self._refusals.add(message)
                    _log.warning("%s refused a replay with %s: %s", self.name, effects, message)
                outputs = np.full((len(time), len(self.state_names)), math.nan)
            for effect in effects:
                if effect["effect"] == "output_scale":
                    outputs[:, self.state_names.index(effect["output"])] *= effect["value"]
            for effect in effects:
                if effect["effect"] == "sensor_bias":
                    outputs[:, self.state_names.index(effect["output"])] += effect["value"]
            replays.append(outputs)
        return np.stack(replays)

    def _effective_inputs(self, effects, time: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """The inputs the FMU sees: delayed, lagged (interval means, so row k is the mean over
        interval k; the last row repeats) and scaled."""
        held = inputs.copy()
        steps = np.diff(time)
        for effect in effects:
            if effect["effect"] == "time_delay" and effect["value"] > 0:
                j = self.input_names.index(effect["input"])
                held[:-1, j] = delayed_interval_means(inputs[:, j], effect["value"], time)
        for effect in effects:
            if effect["effect"] == "input_lag" and effect["value"] > 0:
                j = self.input_names.index(effect["input"])
                held[:-1, j] = lagged_interval_means(held[None, :-1, j], np.array([effect["value"]]), steps)[0]
        for effect in effects:
            if effect["effect"] == "input_gain":
                held[:, self.input_names.index(effect["input"])] *= effect["value"]
        held[-1] = held[-2] if len(held) > 1 else held[-1]
        return held

    def identification_manoeuvre(self, *, duration: float = 20.0, sample_time: float = DEFAULT_SAMPLE_TIME,
                                 variant: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """:func:`~validation.vehicles.linear_effects.sequential_three_two_one_one` of the inputs
        (1 deg for an input in rad, 10 % of full travel otherwise)."""
        return sequential_three_two_one_one(self.input_names, self.reference.units, duration=duration,
                                            sample_time=sample_time, variant=variant)

