"""Build the pythonfmu GP-NARX rate predictor FMU of a trained model file, and what the native
one is built from too (runs in the flightgp environment, not inside an FMU)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fmu_src.fmi.naming import default_name, fmu_target
from fmu_src.fmi.pythonfmu import build_pythonfmu
from fmu_src.fmi.signals import signal
from fmu_src.rate_predictor.predictor import NarxPredictor, pack_model
from fmu_src.rate_predictor.slave import RatePredictor, rate_predictor_variables
from validation.core.errors import BadInputError
from validation.core.manoeuvres import three_two_one_one
from validation.models.narx import load_trained, training_envelope


def build_rate_predictor_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the GP-NARX rate predictor FMU of a trained model file.

    Parameters
    ----------
    model_path : path
        A model file written by :func:`validation.models.narx.save_trained` (``flightgp train``).
    out_dir : path
        Folder for the FMU (created if missing).
    name : str, optional
        The FMU's model identifier and file name (``<name>.fmu``): a letter, then letters,
        digits or underscores. Default: the model file's stem, made into such a name.

    Returns
    -------
    Path
        ``out_dir/<name>.fmu``.

    Raises
    ------
    gp_model.ModelFileError
        The model file is missing, corrupt or not a GP-NARX model.
    validation.core.errors.BadInputError
        Bad ``name``; a model the FMU cannot run (an input lag 0, a signal without a known unit);
        ``out_dir`` is a file.
    """
    parts = rate_predictor_parts(model_path, out_dir, name=name)
    return build_pythonfmu(parts.target, slave_class=RatePredictor,
                           variables=(rate_predictor_variables, parts.interface),
                           attributes={"STEP_SIZE": parts.step}, description=parts.description,
                           arrays=parts.arrays)


@dataclass(frozen=True)
class RatePredictorParts:
    """What every rate-predictor FMU (pythonfmu or native) is built from.

    Attributes
    ----------
    target : Path
        ``out_dir/<name>.fmu`` (name checked; default the model file's stem made into a name).
    arrays : dict of str -> ndarray
        :func:`export_narx_arrays` of the model.
    interface : dict
        ``inputs``, ``outputs`` and ``exact_moments`` (the default :func:`fast_path_error` chose)
        for :func:`fmu_src.rate_predictor.slave.rate_predictor_variables`.
    description : str
        The FMU's one-line description.
    step : float
        The NARX step, s: the FMU's communication step.
    predictor : NarxPredictor
        The model as the FMUs run it (built from ``arrays``, which checks them).
    """

    target: Path
    arrays: dict
    interface: dict
    description: str
    step: float
    predictor: NarxPredictor


def rate_predictor_parts(model_path, out_dir, *, name: str | None = None) -> RatePredictorParts:
    """What every rate-predictor FMU (pythonfmu or native) is built from, for the trained model
    file ``model_path``, ``out_dir`` and ``name`` of :func:`build_rate_predictor_fmu`.

    Raises
    ------
    As :func:`build_rate_predictor_fmu`.
    """
    model_path = Path(model_path)
    target = fmu_target(out_dir, default_name(model_path.stem) if name is None else name)
    trained = load_trained(model_path)
    arrays = export_narx_arrays(trained)
    interface = _interface(trained.config)
    predictor = NarxPredictor(arrays)  # checks shapes and finiteness
    error = fast_path_error(predictor)
    exact = error > FAST_PATH_CHECK
    outputs, inputs = ", ".join(trained.config.outputs), ", ".join(trained.config.inputs)
    description = (f"Gaussian-process (GP-NARX) rate predictor: predicts {outputs} one step of {trained.step:g} s "
                   f"ahead, with confidence bounds, from {inputs} and the previous {outputs}. "
                   f"{condition_words(trained.condition)}. {len(arrays['0/basis'])} basis points, "
                   f"{len(arrays['0/weights'])} hyperparameter samples; model file {model_path.name}. "
                   f"{_fast_path_words(error, exact=exact)}")
    return RatePredictorParts(target=target, arrays=arrays, interface={**interface, "exact_moments": exact},
                              description=description, step=float(trained.step), predictor=predictor)


def condition_words(condition: dict) -> str:
    """The flight condition a model is valid for, in words, from the condition it was trained at
    (:attr:`validation.models.narx.TrainedNarx.condition`): ``"Trained on recordings of
    bo105-80kt-flight, trimmed at 80 kt: valid near that flight condition only"``."""
    vehicle, speed = condition.get("vehicle"), condition.get("speed_kt")
    if vehicle is None:
        return ("The model file does not name the vehicle or flight condition it was trained on: valid only "
                "near the conditions of its training recordings")
    if speed is None:
        return f"Trained on recordings of {vehicle}: valid near the conditions flown in them only"
    return f"Trained on recordings of {vehicle}, trimmed at {speed:g} kt: valid near that flight condition only"


def _fast_path_words(error: float, *, exact: bool) -> str:
    """What the build measured of the free run's faster arithmetic (:func:`fast_path_error`) and
    the default of ``exact_moments`` it chose, in words."""
    default = f"so exact_moments defaults to {'true' if exact else 'false'}"
    if not math.isfinite(error):
        return (f"Free run: its faster arithmetic (exact_moments = false) failed its check along a test 3-2-1-1, "
                f"{default}.")
    return (f"Free run: its faster arithmetic (exact_moments = false), checked along a test 3-2-1-1, differs from "
            f"the exact one by at most {100 * error:.2g} % of the predicted standard deviation "
            f"({'over' if exact else 'within'} the {100 * FAST_PATH_CHECK:g} % allowed), {default}.")


#: The fast path's tolerance (docs/fmus.md, "Free run at simulator speed"): the free run's means
#: and standard deviations within this fraction of the exact predicted standard deviation.
FAST_PATH_TOLERANCE = 0.02
#: What :func:`fast_path_error` may measure for the FMU to default to the fast path: half the
#: tolerance, as the test manoeuvre is one of many a simulator flies.
FAST_PATH_CHECK = FAST_PATH_TOLERANCE / 2


#: The test manoeuvre of :func:`fast_path_error`, in NARX steps: each 3-2-1-1 unit, and the steps
#: flown after the manoeuvre (its 7 units) ends.
FAST_PATH_UNIT_STEPS, FAST_PATH_AFTER_STEPS = 4, 12


def fast_path_error(predictor: NarxPredictor) -> float:
    """The largest error of the free run's fast path (``exact_moments = false``: the pair terms
    in single precision) against the exact moments, in exact predicted standard deviations, of
    the means and of the standard deviations, along a test manoeuvre from rest: a 3-2-1-1 on the
    first input (amplitude its training standard deviation, units of
    :data:`FAST_PATH_UNIT_STEPS` NARX steps, from 1 s) and :data:`FAST_PATH_AFTER_STEPS` steps
    after it (5 s at the paper's 0.1 s step; a step of each path costs 2-3 ms for the paper's
    model). The error grows with the cancellation in eq. 6's sums (GPs of very low noise, large
    weights), so it is measured per model (:func:`rate_predictor_parts`). A free run that fails
    or turns non-finite on either path counts as an infinite error (the FMU then defaults to the
    exact moments, and its own checks report the failure when it is flown)."""
    start = int(round(1.0 / predictor.step))
    n = start + 7 * FAST_PATH_UNIT_STEPS + FAST_PATH_AFTER_STEPS
    controls = np.zeros((n, len(predictor.input_names)))
    controls[:, 0] = three_two_one_one(np.arange(n) * predictor.step, amplitude=float(predictor.matcher.input_scale[0]),
                                       step_time=FAST_PATH_UNIT_STEPS * predictor.step, start=start * predictor.step)
    history = np.zeros((predictor.max_lag, len(predictor.input_names)))  # row i: i steps ago
    exact = fast = predictor.free_run_start(np.zeros(len(predictor.output_names)))
    worst = 0.0
    for row in controls:
        history = np.vstack([row, history[:-1]])
        try:
            exact_mean, exact_var, exact = predictor.free_run_step(history, exact, exact_moments=True)
            fast_mean, fast_var, fast = predictor.free_run_step(history, fast, exact_moments=False)
        except ValueError:  # the belief turned non-finite or lost positive definiteness
            return math.inf
        sd = np.sqrt(exact_var)
        errors = np.concatenate([np.abs(fast_mean - exact_mean) / sd, np.abs(np.sqrt(fast_var) - sd) / sd])
        if not np.isfinite(errors).all():
            return math.inf
        worst = max(worst, float(errors.max()))
    return worst


def export_narx_arrays(trained) -> dict:
    """The FMU model file's arrays (:mod:`fmu_src.rate_predictor.predictor`) of a
    :class:`validation.models.narx.TrainedNarx`: every output's predictive forms (one per
    hyperparameter sample, as ``GaussianProcess.predict`` mixes them), kernel weights, signal
    and noise variances, scalers, the NARX structure and step, and the training envelope.

    Raises
    ------
    validation.core.errors.BadInputError
        The model has an input lag 0 (direct feedthrough, which an FMU output cannot have).
    """
    structure = trained.model.structure
    if 0 in structure.input_lags:
        raise BadInputError(f"the model uses input lag 0 (direct feedthrough: y(k) from u(k)); an FMU "
                            f"output cannot depend on the input set at the same communication point. "
                            f"Retrain with input lags >= 1 (got {structure.input_lags})")
    outputs = []
    for gp in trained.model.model.gps:
        forms = gp.predictive_forms(use_samples=True)
        thetas = np.array([form.theta for form in forms])
        basis = forms[0].basis
        if any(not np.array_equal(form.basis, basis) for form in forms):
            raise ValueError("the hyperparameter samples of one GP must share its basis points")
        outputs.append({
            "basis": basis,
            "weights": np.array([form.weights for form in forms]),
            "variance_factor": np.array([form.variance_factor for form in forms]),
            "kernel_weights": np.array([gp.kernel.weights(theta[:-1]) for theta in thetas]),
            "log_signal_variance": thetas[:, 0],
            "noise_variance": np.exp(thetas[:, -1]),
            "input_mean": gp.input_scaler_.mean_, "input_scale": gp.input_scaler_.scale_,
            "output_mean": gp.output_scaler_.mean_[0], "output_scale": gp.output_scaler_.scale_[0],
        })
    envelope_low, envelope_high = training_envelope(trained)
    return pack_model(step=trained.step, input_names=structure.input_names, output_names=structure.output_names,
                      input_lags=structure.input_lags, output_lags=structure.output_lags,
                      envelope_low=envelope_low, envelope_high=envelope_high, outputs=outputs)


def _interface(config) -> dict:
    """(name, unit, limit, phrase) of every input and output, from the recording conventions."""
    inputs = tuple(signal(n, "input").row() for n in config.inputs)
    outputs = tuple(signal(n, "output").row() for n in config.outputs)
    generated = {f"{n}{suffix}" for n in config.outputs for suffix in ("_prev", "_lower", "_upper")}
    reserved = generated | {"confidence_level", "free_run", "exact_moments", "parallel"}
    clash = sorted((set(config.inputs) | set(config.outputs)) & reserved)
    if clash:
        raise BadInputError(f"signal name(s) {', '.join(clash)} clash with the FMU's generated variables")
    return {"inputs": inputs, "outputs": outputs}
