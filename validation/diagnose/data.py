"""The data a diagnosis works on: recordings read and checked against the reference, split into
fitted and held-out samples, with the sensor noise of every measured output.

Held-out data: the ``holdout`` recordings if given; otherwise the last recording when there are
several; otherwise the last :data:`HOLDOUT_FRACTION` of the single recording (the model is then
still replayed from trim over the whole recording, but only earlier samples enter any fit).

Sampling: recordings of a reference whose replays need even sampling (a Bo105's exact
discretisation has one step; :attr:`validation.vehicles.effects.EffectModel.needs_even_sampling`)
must be evenly sampled; others (the blimp's, motion capture with frame-timing jitter) may not
be. All recordings must share one nominal interval ``h``
(:func:`validation.core.sampling.nominal_step`, within :data:`RATE_TOLERANCE`).
The recording format is in docs/conventions.md, "Recording files"; the stages are in
docs/diagnose.md, "How it works".

Heading: a measured ``psi`` is unwrapped along each recording (:func:`numpy.unwrap`) before
anything compares it, so that a heading that crosses +-pi (the RGBlimp source's files keep it in
[-pi, pi]) does not count as a turn of misfit; replays carry heading continuously.

Start and weights: each recording is replayed from the state its reference says
(:meth:`validation.vehicles.effects.EffectModel.start_state`: trim, or the first recorded
state), and each output's noise standard deviation is floored at the reference's
:attr:`~validation.vehicles.effects.EffectModel.min_noise_sd`.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from validation.core.errors import BadInputError
from validation.core.files import read_document
from validation.core.recordings import Recording
from validation.core.sampling import nominal_step, uneven_steps
from validation.diagnose.fitting import FitData
from validation.diagnose.noise import estimate_noise_sd
from validation.vehicles import read_recording
from validation.vehicles.effects import EffectModel

#: Held-out share of a single recording's time when no other held-out data exist.
HOLDOUT_FRACTION = 0.3
#: Least fit data that can identify anything: 2 s (a 3-2-1-1 with 0.3 s steps lasts 2.1 s).
MIN_FIT_DURATION = 2.0
#: An input "moves" when its peak-to-peak exceeds this (rad, or normalised command).
EXCITATION_THRESHOLD = 1e-6
#: Relative difference of nominal sample intervals above which recordings count as sampled at
#: different rates. Timing jitter of sd ``s`` moves :func:`validation.core.sampling.nominal_step`
#: by about ``sqrt(2) s / (n - 1)`` (0.03 % for 4 ms on 20 s at 20 Hz), while the rates people
#: record at (20, 25, 50, 100 Hz ...) differ by 20 % or more.
RATE_TOLERANCE = 0.01
#: Relative tolerance of evenly sampled data: how closely evenly sampled recordings must agree on
#: their rate, and the offset of grid look-ups (far above the rounding of ``t0 + k*h`` grids, far
#: below any real jitter; the tolerance of :func:`validation.core.sampling.uneven_steps`).
EVEN_TOLERANCE = 1e-6


@dataclass
class PreparedData(FitData):
    """The recordings of one diagnosis, ready for every stage (:func:`prepare`).

    Attributes
    ----------
    time, inputs, measured, output_names, noise_sd, fit_mask
        As :class:`validation.diagnose.fitting.FitData`, one entry per recording (diagnosed
        ones first, then the held-out ones).
    input_names : tuple of str
        The reference's inputs, the column order of ``inputs``.
    holdout_mask : list of ndarray of bool, shape (n_r,)
        Samples that only score the models.
    recording_names : list of str
    held_out : list of bool
        Per recording: used only to score the models.
    holdout_description : str
        What is held out, for the report.
    step : float
        The common nominal sample interval, s.
    even : bool
        Whether every recording is evenly sampled.
    excited : list of str
        Inputs that move in the fitted samples (:data:`EXCITATION_THRESHOLD`).
    untestable : list of str
        Why effects on the other inputs cannot be tested.
    typical_noise_sd : dict of str to float
        Per output: the median over recordings of its noise standard deviation, output units.
    ignored_columns : list of str
        Columns of the recordings that are none of the reference's variables (a reduced model,
        or another instrument's channels), left out of the diagnosis; sorted, each once.
    """

    input_names: tuple
    holdout_mask: list
    recording_names: list
    held_out: list
    holdout_description: str
    step: float
    even: bool
    excited: list
    untestable: list
    typical_noise_sd: dict
    ignored_columns: list = field(default_factory=list)

    @property
    def sample_rate(self) -> float:
        """``1 / step``, Hz."""
        return 1.0 / self.step

    def output_residual(self, replay: list, output: int, masks: list) -> np.ndarray:
        """Measured minus ``replay`` (per recording, shape (n_r, n_out)) of output index
        ``output`` on the samples of ``masks``, recordings concatenated, shape (N,), output units."""
        return np.concatenate([(m[:, output] - r[:, output])[mask]
                               for m, r, mask in zip(self.measured, replay, masks)])

    def weighted_output_residual(self, replay: list, output: int, masks: list) -> np.ndarray:
        """:meth:`output_residual` over each recording's noise standard deviation, shape (N,)."""
        return np.concatenate([(m[:, output] - r[:, output])[mask] / sd[output]
                               for m, r, mask, sd in zip(self.measured, replay, masks, self.noise_sd)])


@dataclass
class _Source:
    name: str
    recording: Recording
    held_out: bool


def read_column_map(path) -> dict[str, str]:
    """The column map in the JSON file ``path``: ``{"recording column": "reference name", ...}``
    (docs/diagnose.md, "FMU references"), checked as far as it can be without a reference: an
    object of distinct, non-empty names that does not rename ``time``.

    Raises
    ------
    BadInputError
        A missing or unreadable file, or a map that is not as above.
    """
    path = Path(path)
    column_map = read_document(path, what="column map")
    if not isinstance(column_map, dict) or not all(isinstance(k, str) and k and isinstance(v, str) and v
                                                   for k, v in column_map.items()):
        raise BadInputError(f'{path}: a column map is a JSON object of names, {{"recording column": '
                            '"reference name", ...}')
    if "time" in column_map or "time" in column_map.values():
        raise BadInputError(f"{path}: the column map cannot rename time")
    targets = list(column_map.values())
    doubled = sorted({t for t in targets if targets.count(t) > 1})
    if doubled:
        raise BadInputError(f"{path}: the column map gives {', '.join(doubled)} to more than one column")
    return column_map


def prepare(recordings, reference: EffectModel, *, holdout=None, file_format: str | None = None,
            column_map: dict | None = None) -> PreparedData:
    """Read and check ``recordings`` (and ``holdout``; files in ``file_format``,
    :func:`validation.vehicles.read_recording`; columns renamed by ``column_map``,
    :func:`read_column_map`), split them (module docstring) and estimate their noise
    (:func:`validation.diagnose.noise.estimate_noise_sd`).

    Raises
    ------
    BadInputError
        No recordings; recordings that miss the reference's inputs, hold another vehicle's
        columns, have no outputs, hold NaN, are too short to identify anything, are unevenly
        sampled for a reference that needs even sampling, or are sampled at different nominal
        rates; no output measured in every recording; no input moving in the fitted data; a
        column map that renames a column to none of the reference's variables, or names a
        column no recording has.
    """
    if not recordings:
        raise BadInputError("no recordings to diagnose")
    column_map = _checked_column_map(column_map or {}, reference)
    sources = _load(recordings, reference, held_out=False, file_format=file_format, column_map=column_map)
    if holdout:
        sources += _load(holdout, reference, held_out=True, start_index=len(sources), file_format=file_format,
                         column_map=column_map)
    present = {n for s in sources for n in (*s.recording.input_names, *s.recording.output_names)}
    unused = [column for column, name in column_map.items() if name not in present]
    if unused:
        raise BadInputError(f"the column map names column(s) {', '.join(unused)}, which no recording has")
    elif len(sources) > 1:
        sources[-1].held_out = True
    step, even = _common_step(sources)
    fit_mask, holdout_mask, description = _split(sources)
    fit_duration = sum(mask.sum() for mask in fit_mask) * step
    if fit_duration < MIN_FIT_DURATION:
        raise BadInputError(f"too short to identify anything: {fit_duration:.2f} s of data to fit "
                            f"after holding out {description}; need at least {MIN_FIT_DURATION:g} s")
    output_names = tuple(n for n in reference.state_names if all(n in s.recording.output_names for s in sources))
    if not output_names:
        raise BadInputError("the recordings share no measured output; diagnose needs the same "
                            "outputs in every recording (including --holdout)")
    excited = _excited_inputs(sources, fit_mask, reference)
    untestable = [f"{name}: never moves in the fitted data, so delays, lags and control derivatives "
                  "on it cannot be tested" for name in reference.input_names
                  if not reference.absolute_inputs and name not in excited]
    measured = [np.column_stack([s.recording.output(n) for n in output_names]) for s in sources]
    floors = np.array([reference.min_noise_sd.get(n, 0.0) for n in output_names])
    noise_sd = [np.maximum(floors, [estimate_noise_sd(column, time=s.recording.time) for column in m.T])
                for s, m in zip(sources, measured)]
    typical = {name: float(np.median([sd[i] for sd in noise_sd])) for i, name in enumerate(output_names)}
    return PreparedData(time=[s.recording.time for s in sources], inputs=[s.recording.inputs for s in sources],
                        measured=measured, output_names=output_names, noise_sd=noise_sd, fit_mask=fit_mask,
                        starts=[reference.start_state(s.recording) for s in sources],
                        input_names=reference.input_names, holdout_mask=holdout_mask,
                        recording_names=[s.name for s in sources], held_out=[s.held_out for s in sources],
                        holdout_description=description, step=step, even=even, excited=excited,
                        untestable=untestable, typical_noise_sd=typical,
                        ignored_columns=sorted({c for s in sources for c in s.recording.metadata.get(IGNORED_KEY, ())}))


def evenly_sampled(time: np.ndarray) -> bool:
    """Whether ``time`` (n,) is evenly sampled (:func:`validation.core.sampling.uneven_steps`)."""
    return not len(uneven_steps(time))


def _checked_column_map(column_map: dict, reference: EffectModel) -> dict:
    """``column_map`` if every name it gives is one of ``reference``'s inputs or outputs."""
    known = (*reference.input_names, *reference.state_names)
    wrong = [f"{column} -> {name}" for column, name in column_map.items() if name not in known]
    if wrong:
        raise BadInputError(f"the column map renames {', '.join(wrong)}, which is none of {reference.name}'s "
                            f"inputs ({', '.join(reference.input_names)}) or outputs "
                            f"({', '.join(reference.state_names)})")
    return dict(column_map)


def _renamed(recording: Recording, column_map: dict) -> Recording:
    """``recording`` with its columns renamed by ``column_map`` (columns not in it keep their names)."""
    if not column_map:
        return recording
    return Recording(recording.time, recording.inputs, tuple(column_map.get(n, n) for n in recording.input_names),
                     recording.outputs, tuple(column_map.get(n, n) for n in recording.output_names),
                     recording.metadata)


def _load(items, reference: EffectModel, *, held_out: bool, start_index: int = 0,
          file_format: str | None = None, column_map: dict | None = None) -> list[_Source]:
    """Recordings (paths or :class:`Recording`) checked against ``reference``, their columns
    renamed by ``column_map`` first."""
    sources = []
    for index, item in enumerate(items, start=start_index + 1):
        if isinstance(item, Recording):
            name = str(item.metadata.get("name", f"recording {index}"))
            recording = _checked_recording(_renamed(item, column_map), name, reference)
        else:
            name = Path(item).name
            recording = _renamed(_read(Path(item), reference, file_format, column_map or {}), column_map)
        if len(recording.time) < 3:
            raise BadInputError(f"{name}: {len(recording.time)} samples; too short to identify anything")
        steps = np.diff(recording.time)
        if np.any(steps <= 0):
            raise BadInputError(f"{name}: time must increase strictly from sample to sample")
        recording = _heading_unwrapped(recording)
        if reference.needs_even_sampling and not evenly_sampled(recording.time):
            raise BadInputError(f"{name}: uneven sampling (intervals {steps.min():.6g} to {steps.max():.6g} s); "
                                f"the {reference.name} reference is discretised exactly with one step, so "
                                "diagnose needs evenly sampled recordings for it: resample onto an even grid")
        sources.append(_Source(name, recording, held_out))
    return sources


def _read(path: Path, reference: EffectModel, file_format: str | None, column_map: dict) -> Recording:
    """The recording file at ``path`` (in ``file_format``, or recognised) read as one of
    ``reference`` whose variables carry the names ``column_map`` gives them in the file."""
    in_file = {name: column for column, name in column_map.items()}
    inputs = tuple(in_file.get(n, n) for n in reference.input_names)
    states = tuple(in_file.get(n, n) for n in reference.state_names)
    extra = _other_columns(path, (*inputs, *states))
    expected = SimpleNamespace(name=reference.name, input_names=inputs, state_names=states + extra)
    try:
        recording = read_recording(path, vehicle=expected if column_map or extra else reference,
                                   file_format=file_format)
        return _without_columns(recording, extra, name=path.name, reference=reference)
    except BadInputError as error:
        if "unknown column" in str(error) or "missing input column" in str(error):
            raise BadInputError(f"{error} (a recording of another vehicle than {reference.name}? Its inputs are "
                                f"{', '.join(reference.input_names)}, its outputs "
                                f"{', '.join(reference.state_names)}; --map renames columns)") from None
        raise


#: The metadata key under which a recording keeps the columns left out of it.
IGNORED_KEY = "ignored_columns"


def _other_columns(path: Path, variables: tuple) -> tuple:
    """The columns of the flightgp recording file at ``path`` that are none of ``variables``
    (nor ``time``), in file order; none when the file is not one (its reader says why)."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as file:
            header = next((row for row in csv.reader(file) if row), [])
    except (OSError, UnicodeDecodeError, csv.Error):
        return ()
    names = [name.strip() for name in header]
    if not names or names[0] != "time":
        return ()
    return tuple(dict.fromkeys(n for n in names[1:] if n and n not in variables))


def _without_columns(recording: Recording, columns, *, name: str, reference: EffectModel) -> Recording:
    """``recording`` without the outputs ``columns`` (read as outputs only to be dropped), which
    its metadata lists under :data:`IGNORED_KEY`; a recording left without outputs is refused."""
    columns = [c for c in columns if c in recording.output_names or c in recording.input_names]
    if not columns:
        return recording
    keep = [i for i, n in enumerate(recording.output_names) if n not in columns]
    if not keep:
        raise BadInputError(f"{name}: none of its columns is an output of {reference.name} "
                            f"({', '.join(reference.state_names)}): a recording of another vehicle?")
    order = [i for i, n in enumerate(recording.input_names) if n not in columns]  # the file's names, before --map
    return Recording(recording.time, recording.inputs[:, order], tuple(recording.input_names[i] for i in order),
                     recording.outputs[:, keep], tuple(recording.output_names[i] for i in keep),
                     {**recording.metadata, IGNORED_KEY: list(columns)})


def _heading_unwrapped(recording: Recording) -> Recording:
    """``recording`` with a measured ``psi`` unwrapped along it (module docstring)."""
    if "psi" not in recording.output_names:
        return recording
    outputs = np.array(recording.outputs, dtype=float)
    column = recording.output_names.index("psi")
    outputs[:, column] = np.unwrap(outputs[:, column])
    return Recording(recording.time, recording.inputs, recording.input_names, outputs, recording.output_names,
                     recording.metadata)


def _checked_recording(recording: Recording, name: str, reference: EffectModel) -> Recording:
    """A :class:`Recording` object checked as :func:`read_recording` checks files, its inputs
    put in the reference's order."""
    missing = [n for n in reference.input_names if n not in recording.input_names]
    if missing:
        raise BadInputError(f"{name}: missing input(s) {', '.join(missing)} of {reference.name}")
    if not recording.output_names:
        raise BadInputError(f"{name}: no measured outputs")
    variables = (*reference.input_names, *reference.state_names)
    recording = _without_columns(recording, [n for n in (*recording.input_names, *recording.output_names)
                                             if n not in variables], name=name, reference=reference)
    for what, array in (("time", recording.time), ("inputs", recording.inputs), ("outputs", recording.outputs)):
        if not np.all(np.isfinite(array)):
            raise BadInputError(f"{name}: {what} hold NaN or infinite values")
    order = [recording.input_names.index(n) for n in reference.input_names]
    return Recording(recording.time, recording.inputs[:, order], reference.input_names,
                     recording.outputs, recording.output_names, recording.metadata)


def _common_step(sources: list[_Source]) -> tuple[float, bool]:
    """The recordings' common nominal interval, s, and whether all are evenly sampled;
    BadInputError when they differ by more than :data:`RATE_TOLERANCE` (:data:`EVEN_TOLERANCE`
    when all are evenly sampled: jittered recordings agree on their nominal rate only roughly)."""
    nominal = [nominal_step(s.recording.time) for s in sources]
    step = float(np.mean(nominal))
    even = all(evenly_sampled(s.recording.time) for s in sources)
    if max(nominal) - min(nominal) > (EVEN_TOLERANCE if even else RATE_TOLERANCE) * step:
        raise BadInputError(f"recordings are sampled at different intervals "
                            f"({', '.join(f'{h:.6g}' for h in sorted(set(nominal)))} s nominal); "
                            "resample them to one rate")
    return step, even


def _split(sources: list[_Source]) -> tuple[list, list, str]:
    """Fit and held-out sample masks per recording (module docstring), and what is held out."""
    fit_mask, holdout_mask, description = [], [], ""
    for source in sources:
        n = len(source.recording.time)
        if source.held_out:
            fit_mask.append(np.zeros(n, bool))
            holdout_mask.append(np.ones(n, bool))
        elif any(s.held_out for s in sources):
            fit_mask.append(np.ones(n, bool))
            holdout_mask.append(np.zeros(n, bool))
        else:
            time = source.recording.time
            split = time[0] + (1 - HOLDOUT_FRACTION) * (time[-1] - time[0])
            fit_mask.append(time < split)
            holdout_mask.append(time >= split)
            description = (f"last {HOLDOUT_FRACTION:.0%} of {source.name} "
                           f"(t >= {split:.2f} s; the model is replayed from the start throughout)")
    return fit_mask, holdout_mask, description or ", ".join(s.name for s in sources if s.held_out)


def _excited_inputs(sources: list[_Source], fit_mask: list, reference: EffectModel) -> list[str]:
    """Inputs that move in the fitted samples; BadInputError when none does on a reference whose
    inputs are perturbations from trim (nothing acts there without a move;
    :attr:`~validation.vehicles.effects.EffectModel.absolute_inputs`)."""
    fit_inputs = np.vstack([s.recording.inputs[m] for s, m in zip(sources, fit_mask) if m.any()])
    excited = [name for j, name in enumerate(reference.input_names) if np.ptp(fit_inputs[:, j]) > EXCITATION_THRESHOLD]
    if not excited and not reference.absolute_inputs:
        raise BadInputError("no input moves in the data to fit: nothing to identify (fly a 3-2-1-1 or "
                            "doublet on at least one control)")
    return excited
