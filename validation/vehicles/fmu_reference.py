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
  (the FMU sees ``gain * u``: control effectiveness), ``dead_band``, ``backlash`` and
  ``saturation`` (a dead band, free play or a limit about the input's first value) and
  ``rate_limit`` (an actuator ramping no faster than the limit,
  :func:`~validation.vehicles.effects.rate_limited_interval_means`);
- on an output, the measurement chain of every reference
  (:func:`~validation.vehicles.effects.apply_measurement_chain`): ``output_scale``,
  ``sensor_cross_axis``, ``sensor_lag``, ``sensor_bias`` and ``sensor_drift``;
- ``fmu_parameter``: any Real parameter the FMU exposes (``causality="parameter"``, not a
  ``<output>_start``), set before initialisation; named by the FMU's own name and described by
  its own description;
- ``search_term`` ``<row>_<factor>``, when asked for (:meth:`FMUEffects.take_input_terms`,
  ``flightgp diagnose --input-terms``; the terms the residual search of ``flightgp diagnose``
  regresses on; an FMU's equations are closed, so a term enters through an input): the input
  of the row (:attr:`FMUEffects.search_rows`: the input's name without its underscores,
  ``theta1s`` for ``theta_1s``) receives ``value * factor`` on top of what the recording and the
  input effects give it, the factor one of the FMU's outputs or inputs
  (:attr:`FMUEffects.search_signals`: the outputs as the FMU gives them at the start of each
  communication step, the inputs after the input effects), or the signed square or cube of an
  output or of the row's own input, or a product of two of those
  (:mod:`validation.vehicles.polynomial_terms`; :attr:`FMUEffects.search_library`). Held over each step at its
  value at the step's start (explicit feedback: an error of first order in the step, against
  the second order of the linear references' terms). Through the control the term acts as a
  force or moment would that the control's derivatives map onto it: ``theta1s_q|q|`` is a pitch
  damping quadratic in the pitch rate, as seen through the longitudinal cyclic.

A replay the FMU refuses (a status of Error or Fatal, which fmpy raises) ends that candidate as
diverged (its outputs NaN, so the fit steps back) and is logged once per message; the diagnosis
goes on. A crash of the FMU's process cannot be caught in the same process.
"""
from __future__ import annotations

import logging
import math
import multiprocessing
import os
import shutil
import tempfile
import weakref
import zipfile
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.core.sampling import check_history
from validation.vehicles.effects import (
    Hypothesis,
    apply_measurement_chain,
    delayed_interval_means,
    lagged_interval_means,
    shaped_inputs,
    simulate_each_recording,
    true_first_values,
)
from validation.vehicles.linear_effects import sequential_three_two_one_one
from validation.vehicles.polynomial_terms import (
    library,
    scalar_factor,
    search_term_description,
    search_term_unit,
    slot_indices,
)
from validation.vehicles.state_space import DEFAULT_SAMPLE_TIME

_log = logging.getLogger(__name__)
#: Suffix of the start-value parameters flightgp's FMUs (and others) expose per output.
START_SUFFIX = "_start"
#: Interval between the states a replay saves to resume later replays from, s (:meth:`FMUReference.replay`).
CHECKPOINT_INTERVAL = 0.5
#: Replays kept to resume from (:meth:`FMUReference.replay`).
KEPT_REPLAYS = 8
#: Sensor noise standard deviation of the concealed-effect bench's recordings through an FMU
#: (:attr:`FMUEffects.sensor_noise_sd`), per output unit: the Bo105 flight-test stand-in's
#: (:data:`validation.vehicles.bo105_flight.SENSOR_NOISE_STD`: velocities, rates, attitudes);
#: outputs in other units are recorded without noise.
BENCH_NOISE_BY_UNIT = {"m/s": 0.1, "rad/s": 0.003, "rad": 0.002}
#: Longest stretch of a recording's start averaged into the start state, s (:meth:`FMUEffects.start_state`).
START_WINDOW = 0.5


def read_cosimulation_fmu(path, *, purpose: str = "diagnose"):
    """fmpy's model description of the FMU at ``path``, checked: an FMI 2.0 co-simulation FMU
    with a binary for this platform; BadInputError in one line otherwise, saying that
    ``purpose`` (the command) needs one. The version is read from the description's root element
    before fmpy parses the rest, so that an FMU of another version is named as such whatever else
    its description holds."""
    from fmpy import platform, read_model_description, supported_platforms  # loaded only for FMU references

    path = Path(path)
    if not path.is_file():
        raise BadInputError(f"{path}: no such FMU")
    try:
        with zipfile.ZipFile(path) as archive:
            version = ElementTree.fromstring(archive.read("modelDescription.xml")).get("fmiVersion")
        description = read_model_description(str(path), validate=False) if version == "2.0" else None
    except Exception as error:  # noqa: BLE001 - zipfile, the XML parser and fmpy raise many kinds
        raise BadInputError(f"{path}: not an FMU ({type(error).__name__}: {str(error).splitlines()[0][:200]})") \
            from None
    if version != "2.0":
        raise BadInputError(f"{path}: an FMI {version} FMU; {purpose} takes FMI 2.0 co-simulation FMUs")
    if description.coSimulation is None:
        raise BadInputError(f"{path}: a model-exchange FMU; {purpose} takes FMI 2.0 co-simulation FMUs")
    shipped = supported_platforms(str(path))
    binaries = [p for p in shipped if p != "c-code"]
    if platform not in binaries:
        has = f"binaries for {', '.join(binaries)} only" if binaries else "no binaries"
        raise BadInputError(f"{path}: this FMU has {has}; this machine needs {platform}"
                            + (" (it ships C sources: `fmpy compile` builds them)" if "c-code" in shipped else ""))
    return description


def _start(variable) -> float:
    """A Real variable's start value (0 without one)."""
    return float(variable.start) if variable.start is not None else 0.0


def _unit(variable) -> str:
    """A Real variable's unit, its declared type's, or ``"1"``."""
    declared = variable.declaredType.unit if variable.declaredType is not None else None
    return variable.unit or declared or "1"


def available_cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


class FMUReference:
    """An FMU as a reference vehicle (module docstring).

    Parameters
    ----------
    path : path-like
        The ``.fmu`` file.
    workers : int, optional
        Processes that run the replays of :meth:`replay_many` side by side, each with its own
        instance (default: :func:`available_cores`; 1: all in this process).
    instance_name : str
        The FMU instance's name (``fmi2Instantiate``'s); give each instance in one process its own.

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
    workers : int
        As the parameter; may be changed between calls.
    steps_resumed : int
        Communication steps that replays in this process did not integrate because they resumed
        from a kept replay's saved state (:meth:`replay`).
    """

    def __init__(self, path, *, workers: int | None = None, instance_name: str = "flightgp_diagnose"):
        self.path = Path(path)
        self._instance_name = instance_name
        description = read_cosimulation_fmu(self.path)
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
        self._can_save = bool(description.coSimulation.canGetAndSetFMUstate)
        self._bases = []  # kept replays: (settings and time key, inputs, outputs, [(row, state)])
        self.workers = available_cores() if workers is None else max(1, int(workers))
        self._executor, self._executor_size = None, 0
        self.steps_resumed = 0

    def _fmu(self):
        """The kept instance: extracted and instantiated at the first replay, reset before the next
        (instantiated afresh when it cannot be reset, e.g. after a Fatal status, which also drops
        the saved states :meth:`replay` resumes from)."""
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
                self._bases.clear()
                self._instance.freeInstance()
        self._instance = FMU2Slave(guid=self._description.guid, unzipDirectory=self._unzipdir,
                                   modelIdentifier=self._description.coSimulation.modelIdentifier,
                                   instanceName=self._instance_name)
        self._instance.instantiate()
        return self._instance

    def replay(self, time: np.ndarray, inputs: np.ndarray, *, parameters: dict | None = None,
               start: dict | None = None, feedback: tuple = ()) -> np.ndarray:
        """Outputs at ``time`` (n,) with ``inputs`` (n, n_inputs) held over each interval.

        ``parameters`` (name -> value) and the start values ``start`` (output -> value, for the
        outputs with a ``<output>_start`` parameter) are set before initialisation. ``feedback``
        holds terms added to the inputs at each step, ``(input, kind, first, second, value)``:
        input ``input`` receives ``value`` times the factor of kind ``kind``
        (:data:`~validation.vehicles.polynomial_terms.SLOT_FACTOR_KINDS` by index) of signals
        ``first`` and ``second`` of the outputs at the step's start followed by the step's
        inputs (the search terms of :class:`FMUEffects`). Returns shape (n, n_outputs); raises
        what fmpy raises when the FMU refuses a call.

        When the FMU can save its state (``canGetAndSetFMUstate``), each replay saves it every
        :data:`CHECKPOINT_INTERVAL` s, and a later replay with the same settings, time grid and
        feedback whose inputs agree with a kept one's up to some row resumes from the last state saved
        before that row: outputs up to row ``k`` depend only on the inputs of rows before ``k``
        (zero-order hold), so the shared beginning is not integrated again. Candidates that
        change one input of a manoeuvre that moves the inputs one after the other share most of
        their replay. The last :data:`KEPT_REPLAYS` replays are kept. An input row equal to the
        one before is not set again (an FMU's inputs keep their values until set; the inputs
        are held over long stretches of a manoeuvre): one call into the FMU fewer on such a step
        (with feedback every row is set).
        """
        fmu = self._fmu()
        settings = dict(parameters or {})
        settings.update({self.start_parameters[name]: value for name, value in (start or {}).items()})
        if settings:
            fmu.setReal([self._references[n] for n in settings], [float(v) for v in settings.values()])
        input_refs = [self._references[n] for n in self.input_names]
        output_refs = [self._references[n] for n in self.state_names]
        rows = np.asarray(inputs, dtype=float).tolist()
        fmu.setReal(input_refs, rows[0])
        fmu.setupExperiment(startTime=float(time[0]))
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        outputs = np.empty((len(time), len(output_refs)))
        key = (tuple(sorted(settings.items())), time.tobytes(), tuple(feedback))
        resumed, checkpoints = self._resume(fmu, key, inputs, outputs)
        if not resumed:
            outputs[0] = fmu.getReal(output_refs)
        every = max(1, round(CHECKPOINT_INTERVAL / float(time[1] - time[0]))) if len(time) > 1 else 1
        for k in range(resumed, len(time) - 1):
            if self._can_save and k % every == 0 and k > resumed:
                checkpoints.append((k, fmu.getFMUstate()))
            if feedback:
                fmu.setReal(input_refs, _fed_back(rows[k], outputs[k], feedback))
            elif k == resumed or rows[k] != rows[k - 1]:
                fmu.setReal(input_refs, rows[k])
            fmu.doStep(currentCommunicationPoint=float(time[k]), communicationStepSize=float(time[k + 1] - time[k]))
            outputs[k + 1] = fmu.getReal(output_refs)
        if self._can_save:
            self._keep(fmu, key, inputs, outputs, checkpoints)
        return outputs

    def _resume(self, fmu, key, inputs: np.ndarray, outputs: np.ndarray) -> tuple[int, list]:
        """Restore the kept replay that shares the longest beginning with ``inputs`` (same
        ``key``: settings, time grid and feedback): the row it resumes at (0: none), with ``outputs`` filled
        up to it, and the checkpoints up to it (the new replay's own)."""
        best, best_row, best_state = None, 0, None
        for base in self._bases:
            if base[0] != key:
                continue
            differ = np.flatnonzero(np.any(base[1] != inputs, axis=1))
            agree = int(differ[0]) if len(differ) else len(inputs) - 1
            usable = [c for c in base[3] if c[0] <= agree]
            if usable and usable[-1][0] > best_row:
                best, (best_row, best_state) = base, usable[-1]
        if best is None:
            return 0, []
        row, state = best_row, best_state
        fmu.setFMUstate(state)
        outputs[:row + 1] = best[2][:row + 1]
        self.steps_resumed += row
        return row, [c for c in best[3] if c[0] <= row]

    def _keep(self, fmu, key, inputs: np.ndarray, outputs: np.ndarray, checkpoints: list) -> None:
        """Keep this replay for :meth:`_resume`, dropping (and freeing the states of) the oldest
        beyond :data:`KEPT_REPLAYS`; states shared with a kept replay are freed with the last."""
        self._bases.append((key, inputs.copy(), outputs.copy(), checkpoints))
        while len(self._bases) > KEPT_REPLAYS:
            dropped = self._bases.pop(0)
            kept = {id(state) for base in self._bases for _, state in base[3]}
            for _, state in dropped[3]:
                if id(state) not in kept:
                    fmu.freeFMUstate(state)

    def replay_many(self, requests) -> list:
        """:meth:`replay` of each request, on :attr:`workers` processes when there are several.

        Parameters
        ----------
        requests : sequence of (time, inputs, parameters, start, feedback)
            The arguments of :meth:`replay`.

        Returns
        -------
        list
            Per request, its outputs (n, n_outputs), or a message in words when the FMU refused
            the replay (Error or Fatal) or its process died during it (a crash inside the FMU;
            only parallel replays survive that: the crashed replay is found by running the
            unfinished ones again one by one, each in a fresh process).
        """
        if self.workers <= 1 or len(requests) < 2:
            return [_replay_or_message(self, request) for request in requests]
        results = []
        try:
            chunk = -(-len(requests) // self.workers)  # one chunk per worker: its kept replays serve its chunk
            for result in self._pool().map(_replay_in_worker, requests, chunksize=chunk):
                results.append(result)
        except BrokenProcessPool:
            self._executor = None
            for request in requests[len(results):]:
                results.append(self._replay_alone(request))
        return results

    def _pool(self) -> ProcessPoolExecutor:
        """The worker processes (started at the first parallel batch, each extracting and
        instantiating its own copy of the FMU; :data:`_WORKER_CONTEXT`)."""
        if self._executor is None or self._executor_size != self.workers:
            if self._executor is not None:
                self._executor.shutdown(cancel_futures=True)
            self._executor_size = self.workers
            self._executor = ProcessPoolExecutor(max_workers=self.workers,
                                                 mp_context=_WORKER_CONTEXT,
                                                 initializer=_start_worker, initargs=(str(self.path),))
            weakref.finalize(self, self._executor.shutdown, wait=False, cancel_futures=True)
        return self._executor

    def _replay_alone(self, request):
        """One replay in a fresh process of its own: its outputs, its refusal, or the crash."""
        with ProcessPoolExecutor(max_workers=1, mp_context=_WORKER_CONTEXT,
                                 initializer=_start_worker, initargs=(str(self.path),)) as alone:
            try:
                return alone.submit(_replay_in_worker, request).result()
            except BrokenProcessPool:
                return "the FMU's process died during the replay (a crash inside the FMU)"

    def simulate(self, time, inputs, *, seed: int = 0) -> Recording:
        """Replay ``inputs`` from the FMU's own start; ``seed`` is accepted for the Vehicle interface."""
        time, inputs, step = check_history(time, inputs, self.input_names)
        return Recording(time, inputs, self.input_names, self.replay(time, inputs), self.state_names,
                         {"vehicle": self.name, "sample_time": step})


#: How worker processes start: forked where the system can (they only step their own FMU
#: instance, so nothing this process holds is used in them, and a caller's script needs no
#: ``if __name__ == "__main__"`` guard, as it would to be imported again by a spawned process),
#: spawned elsewhere.
_WORKER_CONTEXT = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods()
                                              else "spawn")
#: The FMU reference of a worker process (:meth:`FMUReference.replay_many`).
_WORKER_REFERENCE = None


def input_row(name: str) -> str:
    """The row letter of an input's search terms: its name without underscores (``theta1s`` for
    ``theta_1s``; a term's name splits its row from its factor at the first underscore)."""
    return name.replace("_", "")


def _fed_back(row: list, outputs: np.ndarray, feedback: tuple) -> list:
    """The input row ``row`` plus the feedback terms of :meth:`FMUReference.replay` at the
    step's start (``outputs``)."""
    signals = [*outputs.tolist(), *row]
    fed = list(row)
    for column, kind, first, second, value in feedback:
        fed[column] += value * scalar_factor(kind, signals[first], signals[second])
    return fed


def _start_worker(path: str) -> None:
    global _WORKER_REFERENCE
    _WORKER_REFERENCE = FMUReference(path, workers=1)


def _replay_in_worker(request):
    return _replay_or_message(_WORKER_REFERENCE, request)


def _replay_or_message(reference: FMUReference, request):
    """``reference.replay(*request)``, or the first line of what the FMU said when it refused."""
    time, inputs, parameters, start, feedback = request
    try:
        with np.errstate(all="ignore"):  # a candidate that blows the FMU up is refused, not warned about
            return reference.replay(time, inputs, parameters=parameters, start=start, feedback=feedback)
    except Exception as error:  # noqa: BLE001 - fmpy raises its own kinds for Error/Fatal
        return str(error).splitlines()[0] if str(error) else type(error).__name__


class FMUEffects:
    """The :class:`~validation.vehicles.effects.EffectModel` of an FMU reference (module docstring).

    Parameters
    ----------
    reference : FMUReference
    """

    family = "fmu"
    kinds = ("time_delay", "input_lag", "dead_band", "backlash", "saturation", "rate_limit", "input_gain",
             "sensor_bias", "output_scale", "sensor_cross_axis", "sensor_lag", "sensor_drift", "fmu_parameter")
    batches_simulations = True  # a batch's replays run side by side on the reference's workers
    absolute_inputs = False
    needs_even_sampling = True
    min_noise_sd = {}
    simulate_recordings = simulate_each_recording

    def __init__(self, reference: FMUReference):
        self.reference = reference
        self.name, self.sample_time = reference.name, reference.sample_time
        self.input_names, self.state_names = reference.input_names, reference.state_names
        self.residual_gp_states = reference.state_names
        self.search_rows = {input_row(name): name for name in reference.input_names}
        self.search_signals = reference.state_names + reference.input_names
        # Per input: every signal linear (another input: the controls mixed); the powers and
        # products of the outputs and of the input itself (its own nonlinearity, its couplings with
        # the motion), not of the other inputs.
        self.search_library = tuple(f"{letter}_{signal}" for letter in self.search_rows
                                    for signal in self.search_signals) + tuple(
            term for letter, own in self.search_rows.items() for term in library([letter], (*self.state_names, own)))
        # A term linear in the row's own input is the named input gain: regressed on, never offered.
        own = {f"{letter}_{name}" for letter, name in self.search_rows.items()}
        self.terms = {"fmu_parameter": tuple(reference.parameters)}
        self._search_terms = tuple(term for term in self.search_library if term not in own)
        self.sensor_noise_sd = {name: BENCH_NOISE_BY_UNIT.get(reference.units[name], 0.0)
                                for name in reference.state_names}
        self.signal_units = reference.units
        self._refusals = set()

    def take_input_terms(self) -> None:
        """Let the residual search add terms through the FMU's inputs (``search_term``, module
        docstring; off by default: measured on the Bo105 suite through its FMU it names more of
        what no list holds, loses cases it named without, and costs about 5x the time,
        docs/diagnose.md, "How it works").

        Raises
        ------
        BadInputError
            Input names that are not distinct without their underscores (the rows' names).
        """
        if len(self.search_rows) < len(self.input_names) or not all(
                letter.isidentifier() for letter in self.search_rows):
            raise BadInputError(f"{self.name}: the input terms name each input without its underscores, and "
                                f"the inputs {', '.join(self.input_names)} do not stay distinct that way")
        self.kinds = (*type(self).kinds, "search_term")
        self.terms = {**self.terms, "search_term": self._search_terms}

    @property
    def workers(self) -> int:
        """The reference's worker processes (:class:`FMUReference`)."""
        return self.reference.workers

    @workers.setter
    def workers(self, count: int) -> None:
        self.reference.workers = max(1, int(count))

    def model_value(self, term: str) -> float:
        """The parameter's start value in the FMU; 0 for a search term (none in the FMU)."""
        if self._searched(term):
            return 0.0
        return self.reference.parameters[term][0]

    def term_unit(self, term: str) -> str:
        """The parameter's unit; a search term's, its input's unit per unit of its factor."""
        if self._searched(term):
            units = self.reference.units
            return search_term_unit(term, self.search_rows, self.search_signals, signal_units=units,
                                    row_units={letter: units[name] for letter, name in self.search_rows.items()})
        return self.reference.parameters[term][1]

    def term_description(self, term: str) -> str:
        """The FMU's own description of the parameter (its name without one); a search term's
        ``"extra <input> input proportional to <factor>"``."""
        if self._searched(term):
            return search_term_description(term, {letter: f"extra {name} input"
                                                  for letter, name in self.search_rows.items()})
        return self.reference.parameters.get(term, (None, None, term))[2]

    def _searched(self, term: str) -> bool:
        """Whether ``term`` names a search term, not a parameter of the FMU."""
        return term not in self.reference.parameters and term in self._search_terms

    def search_jacobian(self, states, inputs) -> np.ndarray:
        """Every signal on every row's axis: one over each signal's RMS along the replays (the
        search weighs the Jacobian by the RMS), shape (n_inputs, n_signals). An FMU's equations
        are closed, so which outputs a term of an input should use is not known before the
        replays, and the library holds every signal's powers and products for each input.

        Parameters
        ----------
        states : list of ndarray, each shape (n_r, n_outputs)
        inputs : list of ndarray, each shape (n_r, n_inputs)
        """
        signals = np.concatenate([np.concatenate([x, u], axis=1) for x, u in zip(states, inputs)])
        rms = np.sqrt(np.mean(signals**2, axis=0))
        scale = np.divide(1.0, rms, out=np.zeros_like(rms), where=rms > 0)
        return np.tile(scale, (len(self.search_rows), 1))

    def term_value_problem(self, term: str, value: float) -> None:
        """Any finite value: the FMU says at initialisation what it refuses."""
        return None

    def term_hypotheses(self, excited_inputs) -> list[Hypothesis]:
        """Every parameter (step 5 % of its value, 1e-3 where it is zero); the gain on each
        excited input and the measurement chain of each output are diagnose's
        (:func:`validation.diagnose.explain.hypotheses_for`)."""
        hypotheses = [Hypothesis("fmu_parameter", name, value, -math.inf, math.inf, max(0.05 * abs(value), 1e-3))
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
        """One replay per effect list (module docstring; side by side on the reference's
        workers), shape (B, n, n_outputs); a refused replay gives NaN."""
        time = np.asarray(time, dtype=float)
        inputs = np.asarray(inputs, dtype=float)
        starts = {} if start is None else {n: v for n, v in zip(self.state_names, start) if np.isfinite(v)}
        requests = [(time, self._effective_inputs(effects, time, inputs),
                     {e["term"]: e["value"] for e in effects if e["effect"] == "fmu_parameter"},
                     starts if start is None else self._true_start(effects, starts), self._feedback(effects))
                    for effects in effect_lists]
        replays = []
        for effects, result in zip(effect_lists, self.reference.replay_many(requests)):
            if isinstance(result, str):
                if result not in self._refusals:
                    self._refusals.add(result)
                    _log.warning("%s refused a replay with %s: %s", self.name, effects, result)
                result = np.full((len(time), len(self.state_names)), math.nan)
            replays.append(apply_measurement_chain(result, time, effects, self.state_names))
        return np.stack(replays)

    def _feedback(self, effects) -> tuple:
        """The search terms of ``effects`` as :meth:`FMUReference.replay`'s feedback terms."""
        terms = []
        for effect in effects:
            if effect["effect"] == "search_term":
                kind, first, second, row = slot_indices(effect["term"], self.search_rows, self.search_signals)
                terms.append((row, kind, first, second, float(effect["value"])))
        return tuple(terms)

    def _true_start(self, effects, starts: dict) -> dict:
        """The start values of a replay from a recording with ``effects``: the recorded start
        (``starts``, or the FMU's own start value where the recording agrees with it) through
        the inverse of the measurement chain at the first sample
        (:func:`~validation.vehicles.effects.true_first_values`: scale, cross-axis sensitivity and
        bias taken off), so that a sensor that reads wrong from the first sample is not a state
        the aircraft started in."""
        recorded = np.array([starts.get(n, self.reference.start_values.get(n, math.nan)) for n in self.state_names])
        true = true_first_values(recorded, effects, self.state_names)
        if true is recorded:
            return dict(starts)
        corrected = dict(starts)
        for name in self.reference.start_parameters:
            value = true[self.state_names.index(name)]
            if math.isfinite(value) and value != recorded[self.state_names.index(name)]:
                corrected[name] = float(value)
        return corrected

    def _effective_inputs(self, effects, time: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """The inputs the FMU sees: through a dead band and a limit about the recording's first
        value and a rate limit from it, then delayed and lagged as changes from that value
        (interval means, so row k is the mean over interval k; the last row repeats; before the
        recording, the input held its first value), then scaled (``gain * u``)."""
        first = inputs[0].copy()
        held = shaped_inputs(effects, time, inputs, self.input_names, centre=first).copy()
        steps = np.diff(time)
        moved = held.copy()
        for effect in effects:
            if effect["effect"] == "time_delay" and effect["value"] > 0:
                j = self.input_names.index(effect["input"])
                held[:-1, j] = first[j] + delayed_interval_means(moved[:, j] - first[j], effect["value"], time)
        for effect in effects:
            if effect["effect"] == "input_lag" and effect["value"] > 0:
                j = self.input_names.index(effect["input"])
                held[:-1, j] = first[j] + lagged_interval_means(held[None, :-1, j] - first[j],
                                                                np.array([effect["value"]]), steps)[0]
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

