"""GP-NARX on recordings: which columns, at which step, trained how, and predictions back on
the recording's time axis.

The maths lives in :mod:`gp_model` (:class:`~gp_model.NarxStructure`, :class:`~gp_model.GPNarx`);
this module ties it to :class:`~validation.core.recordings.Recording` s:

- the NARX step is ``decimation`` recording samples (default 10: 0.1 s at 100 Hz). At 100 Hz a
  rate changes by less than its sensor noise from one sample to the next, so a one-sample NARX
  learns mostly noise and drifts in free run; at 0.1 s the step-to-step change is well above the
  noise (measured on the Bo105 stand-in; docs/reproductions.md, "Bo105 GP-NARX");
- training rows are every ``stride``-th *recording sample* (the Bo105 paper: every 25th), each
  with its regressors ``decimation`` samples apart; ``stride`` need not be a multiple of
  ``decimation``, and ``stride=1`` trains on all samples (every phase of the NARX grid);
- the configuration travels inside the model file (JSON header), so ``predict`` needs nothing
  but the model and a recording; so does the condition it was trained at, the training
  recordings' vehicle and trim speed (:func:`training_condition`), which an FMU of the model
  states.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from gp_model import GPNarx, NarxStructure, load_model, model_bytes, read_header
from validation.core.errors import BadInputError
from validation.core.files import write_atomically
from validation.core.metrics import rmse
from validation.core.progress import progress_bar
from validation.core.recordings import Recording, column_unit

#: Kernels and hyperparameter methods ``train`` accepts (names of :meth:`GPNarx.fit`).
KERNELS = ("higdon", "squared_exponential_ard")
HYPERPARAMETER_METHODS = ("annealing", "maximum_likelihood")


@dataclass(frozen=True)
class NarxConfig:
    """How to build and train a GP-NARX from recordings.

    Parameters
    ----------
    inputs : tuple of str
        Recording input columns used as exogenous regressors, e.g. ``("theta_1s",)``.
    outputs : tuple of str
        Recording output columns predicted and fed back, e.g. ``("p", "q", "r")``.
    input_lags, output_lags : tuple of int
        In NARX steps (see :class:`gp_model.NarxStructure`).
    decimation : int, default 10
        NARX step in recording samples.
    stride : int, default 25
        Every ``stride``-th recording sample becomes a training point (the Bo105 paper's 25).
    kernel : {"higdon", "squared_exponential_ard"}
    hyperparameters : {"annealing", "maximum_likelihood"}
    n_inducing : int or None
        Train a sparse GP with this many inducing points instead of an exact GP.
    """

    inputs: tuple = ("theta_1s",)
    outputs: tuple = ("p", "q", "r")
    input_lags: tuple = (1, 2)
    output_lags: tuple = (1,)
    decimation: int = 10
    stride: int = 25
    kernel: str = "higdon"
    hyperparameters: str = "annealing"
    n_inducing: int | None = None

    def __post_init__(self) -> None:
        for name in ("inputs", "outputs", "input_lags", "output_lags"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        if self.decimation < 1 or self.stride < 1:
            raise BadInputError(f"decimation and stride must be >= 1, got {self.decimation}, {self.stride}")
        if self.kernel not in KERNELS:
            raise BadInputError(f"unknown kernel {self.kernel!r}; choose {', '.join(KERNELS)}")
        if self.hyperparameters not in HYPERPARAMETER_METHODS:
            raise BadInputError(f"unknown hyperparameter method {self.hyperparameters!r}; "
                                f"choose {', '.join(HYPERPARAMETER_METHODS)}")
        try:
            self.structure()
        except ValueError as error:
            raise BadInputError(str(error)) from None

    def structure(self) -> NarxStructure:
        return NarxStructure(self.inputs, self.outputs, self.input_lags, self.output_lags)

    def to_json(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


@dataclass
class TrainedNarx:
    """A GP-NARX with the configuration and recording sample time it was trained with.

    Attributes
    ----------
    model : gp_model.GPNarx
    config : NarxConfig
    recording_sample_time : float
        s, of the training recordings; the NARX step is ``decimation`` times this.
    training_time : ndarray, shape (n_train,)
        Times (s, on the first training recording's axis) of the training targets, for plots.
    condition : dict
        The condition the model was trained at (:func:`training_condition`): ``vehicle`` (its
        name, e.g. ``"bo105-80kt-flight"``) and ``speed_kt`` (trim speed, kt), each where every
        training recording's metadata gives the same; empty for a model file that does not say.
    """

    model: GPNarx
    config: NarxConfig
    recording_sample_time: float
    training_time: np.ndarray = field(default_factory=lambda: np.empty(0))
    condition: dict = field(default_factory=dict)

    @property
    def step(self) -> float:
        """NARX step, s."""
        return self.config.decimation * self.recording_sample_time


@dataclass
class NarxPrediction:
    """Predictions on a recording's decimated time axis.

    Attributes
    ----------
    time : ndarray, shape (n,)
        s.
    measured : ndarray, shape (n, n_outputs)
        The recording's outputs at ``time``.
    mean, var : ndarray, shape (n, n_outputs)
        Predictive mean and variance (noise included); rows before the first prediction hold
        the measured start values and zero variance.
    first : int
        Index of the first predicted row.
    """

    time: np.ndarray
    measured: np.ndarray
    mean: np.ndarray
    var: np.ndarray
    first: int

    def rmse(self) -> np.ndarray:
        """RMSE per output over the predicted rows, shape (n_outputs,)."""
        return rmse(self.measured[self.first:], self.mean[self.first:], axis=0)

    def coverage(self, *, z: float = 1.96) -> np.ndarray:
        """Fraction of predicted rows whose measurement lies inside ``mean +/- z sd``."""
        error = np.abs(self.mean[self.first:] - self.measured[self.first:])
        return np.mean(error <= z * np.sqrt(self.var[self.first:]), axis=0)


def narx_arrays(recording: Recording, config: NarxConfig, *, name: str = "recording"):
    """Decimated time, inputs and outputs of ``recording`` for ``config``.

    Returns
    -------
    time : ndarray, shape (n,)
    inputs : ndarray, shape (n, n_inputs)
    outputs : ndarray, shape (n, n_outputs)

    Raises
    ------
    BadInputError
        Missing columns, uneven sampling, or too few samples for the lags.
    """
    missing = [c for c in config.inputs if c not in recording.input_names]
    missing += [c for c in config.outputs if c not in recording.output_names]
    if missing:
        raise BadInputError(f"{name}: missing column(s) {', '.join(missing)} needed by the model "
                            f"(has {', '.join(recording.input_names + recording.output_names)})")
    if recording.metadata.get("uneven_sampling"):
        raise BadInputError(f"{name}: GP-NARX needs evenly sampled data; this recording is unevenly "
                            "sampled (resample it first)")
    rows = slice(None, None, config.decimation)
    time = recording.time[rows]
    inputs = np.column_stack([recording.input(c) for c in config.inputs])[rows]
    outputs = np.column_stack([recording.output(c) for c in config.outputs])[rows]
    needed = config.structure().max_lag + 2
    if len(time) < needed:
        raise BadInputError(f"{name}: {len(recording.time)} samples give {len(time)} NARX steps of "
                            f"{config.decimation} samples; need at least {needed}")
    return time, inputs, outputs


def sample_time_of(recordings) -> float:
    """The common sample time of ``recordings``, s; BadInputError if they differ."""
    steps = [float(np.mean(np.diff(r.time))) for r in recordings]
    if max(steps) - min(steps) > 1e-9 * max(steps):
        raise BadInputError(f"recordings have different sample times ({', '.join(f'{s:g}' for s in steps)} s); "
                            "a NARX model has one step")
    return steps[0]


#: The metadata keys of a recording (docs/conventions.md, "Recording files") that say the
#: condition a model was trained at.
CONDITION_KEYS = ("vehicle", "speed_kt")


def training_condition(recordings) -> dict:
    """The condition the recordings were flown at: each of :data:`CONDITION_KEYS` that every
    recording's metadata gives, with the same value (``{"vehicle": "bo105-80kt-flight",
    "speed_kt": 80}``); a key they lack or disagree on is left out."""
    condition = {}
    for key in CONDITION_KEYS:
        values = [recording.metadata.get(key) for recording in recordings]
        if values and values[0] is not None and all(value == values[0] for value in values):
            condition[key] = values[0]
    speed = condition.get("speed_kt")
    if isinstance(speed, bool) or not isinstance(speed, (int, float)) or not math.isfinite(speed):
        condition.pop("speed_kt", None)  # a hand-written sidecar's "80" or null says no speed
    return condition


def train_narx(recordings, config: NarxConfig, *, seed: int = 0, progress: bool = False,
               **inference_options) -> TrainedNarx:
    """Train a GP-NARX on one or more recordings (never straddling two of them).

    ``inference_options`` go to the hyperparameter method (e.g. ``n_samples`` for annealing,
    ``n_restarts`` for maximum likelihood).
    """
    recordings = list(recordings)
    if not recordings:
        raise BadInputError("no training recordings")
    for i, recording in enumerate(recordings):  # checks columns, sampling and length
        narx_arrays(recording, config, name=recording.metadata.get("source", f"recording {i}"))
    sample_time = sample_time_of(recordings)
    # Every phase of the NARX grid is its own sequence (regressors never mix phases); a row is
    # kept when its target's sample index in the recording is a multiple of the stride.
    sequences, target_index, target_time = [], [], []
    first = config.structure().max_lag
    for recording in recordings:
        for phase in range(config.decimation):
            rows = slice(phase, None, config.decimation)
            if len(recording.time[rows]) <= first:
                continue
            sequences.append((np.column_stack([recording.input(c) for c in config.inputs])[rows],
                              np.column_stack([recording.output(c) for c in config.outputs])[rows]))
            index = np.arange(len(recording.time))[rows][first:]
            target_index.append(index)
            target_time.append(recording.time[index] if recording is recordings[0] else np.full(len(index), np.nan))
    target_index, target_time = np.concatenate(target_index), np.concatenate(target_time)
    keep = np.flatnonzero(target_index % config.stride == 0)
    needed = min_training_points(config)
    if len(keep) < needed:
        raise BadInputError(
            f"the recordings give {len(keep)} training point(s) (every {config.stride}th NARX target) for "
            f"{len(config.structure().regressor_names)} regressors; a GP needs at least {needed}, two per "
            "hyperparameter: record longer, or lower the stride")
    options = dict(inference_options)
    if config.n_inducing is not None:
        options["n_inducing"] = config.n_inducing
    with progress_bar(f"training ({config.hyperparameters.replace('_', ' ')})", enabled=progress,
                      total=len(config.outputs), unit="GP") as update:
        model = GPNarx.fit(config.structure(), sequences, kernel=config.kernel,
                           hyperparameters=config.hyperparameters, rows=keep, seed=seed,
                           progress=update, **options)
    training_time = np.sort(target_time[keep][np.isfinite(target_time[keep])])
    return TrainedNarx(model, config, sample_time, training_time, training_condition(recordings))


def min_training_points(config: NarxConfig) -> int:
    """Fewest training points :func:`train_narx` accepts: two per hyperparameter of one output's
    GP (a length scale per regressor, the signal and the noise variance); with fewer, the
    marginal likelihood cannot tell the hyperparameters apart and the bands mean nothing."""
    return 2 * (len(config.structure().regressor_names) + 2)


def training_envelope(trained: TrainedNarx) -> tuple[np.ndarray, np.ndarray]:
    """The range of every regressor over the training rows, in physical units: ``(low, high)``,
    each shape (n_regressors,) in the order of ``config.structure().regressor_names``."""
    first = trained.model.model.gps[0]
    training = first.input_scaler_.inverse_transform(first.X_train_)
    return training.min(axis=0), training.max(axis=0)


def unseen_inputs(trained: TrainedNarx, recording: Recording, *, margin: float) -> list[str]:
    """What in ``recording``'s inputs the model never saw in training, one phrase each: an input
    column it moves that the model does not take, or a model input that leaves the training
    range by more than ``margin`` of that range (the FMUs' envelope rule). Empty when the
    recording stays inside what the model learnt from."""
    phrases = [f"{name} moves, but the model does not take it as an input (its inputs: "
               f"{', '.join(trained.config.inputs)}), so the response to it is missing"
               for name in recording.input_names
               if name not in trained.config.inputs and np.ptp(recording.input(name)) > 0]
    low, high = training_envelope(trained)
    structure = trained.config.structure()
    for name in (n for n in trained.config.inputs if n in recording.input_names):  # else refused later
        columns = [i for i, regressor in enumerate(structure.regressor_names) if regressor.startswith(f"{name}(")]
        trained_low, trained_high = low[columns].min(), high[columns].max()
        widen = margin * (trained_high - trained_low)
        values = recording.input(name)
        if values.min() < trained_low - widen or values.max() > trained_high + widen:
            phrases.append(f"{name} spans {values.min():.4g} .. {values.max():.4g} {column_unit(name)}, but the model "
                           f"was trained on {trained_low:.4g} .. {trained_high:.4g}: the GP extrapolates there")
    return phrases


def one_step(trained: TrainedNarx, recording: Recording, *, name: str = "recording") -> NarxPrediction:
    """One-step-ahead prediction (OSAP) from the recording's measured outputs."""
    time, u, y = _checked_arrays(trained, recording, name)
    first = trained.config.structure().max_lag
    mean, var = trained.model.one_step(u, y)
    return NarxPrediction(time, y, np.vstack([y[:first], mean]),
                          np.vstack([np.zeros((first, y.shape[1])), var]), first)


def free_run(trained: TrainedNarx, recording: Recording, *, method: str = "monte_carlo",
             n_runs: int = 1000, seed: int = 0, progress: bool = False,
             name: str = "recording") -> NarxPrediction:
    """Free-run (full-model) prediction under the recording's inputs, started from its first
    measured outputs."""
    time, u, y = _checked_arrays(trained, recording, name)
    first = trained.config.structure().max_lag
    with progress_bar(f"free run ({method.replace('_', ' ')})", enabled=progress and method == "monte_carlo",
                      total=len(u) - first, unit="step") as update:
        result = trained.model.free_run(u, y[:first], method=method, n_runs=n_runs, seed=seed,
                                        progress=update)
    return NarxPrediction(time, y, result.mean, result.var, first)


def _checked_arrays(trained: TrainedNarx, recording: Recording, name: str):
    step = float(np.mean(np.diff(recording.time)))
    if abs(step - trained.recording_sample_time) > 1e-6 * trained.recording_sample_time:
        raise BadInputError(f"{name}: sampled every {step:g} s but the model was trained on "
                            f"{trained.recording_sample_time:g} s data")
    return narx_arrays(recording, trained.config, name=name)


def save_trained(path, trained: TrainedNarx, *, meta: dict | None = None) -> Path:
    """Write a trained GP-NARX, its configuration and the condition it was trained at (the
    header's ``vehicle`` and ``speed_kt``) to the portable model file ``path`` (``.npz``;
    atomically, never over a file flightgp did not write: docs/conventions.md, "Writing files")."""
    header = {"narx_config": trained.config.to_json(),
              "recording_sample_time": trained.recording_sample_time,
              "training_time": trained.training_time.tolist(), **trained.condition, **(meta or {})}
    return write_atomically(path, model_bytes(trained.model, meta=header))


def load_trained(path) -> TrainedNarx:
    """Read a model file written by :func:`save_trained` (ModelFileError if it is not one)."""
    from gp_model import ModelFileError

    model = load_model(path)
    meta = read_header(path)["meta"]
    if not isinstance(model, GPNarx) or "narx_config" not in meta:
        raise ModelFileError(f"{path}: not a GP-NARX model file (no NARX configuration)")
    config = NarxConfig(**meta["narx_config"])
    return TrainedNarx(model, config, float(meta["recording_sample_time"]),
                       np.asarray(meta.get("training_time", []), dtype=float),
                       {key: meta[key] for key in CONDITION_KEYS if meta.get(key) is not None})
