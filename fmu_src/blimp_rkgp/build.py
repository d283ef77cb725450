"""Build the pythonfmu blimp RKGP FMU of a trained grey-box model file, and what the native one
is built from too (runs in the flightgp environment, not inside an FMU)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fmu_src.blimp_rkgp.model import pack_model
from fmu_src.blimp_rkgp.slave import BlimpRKGP, blimp_rkgp_variables
from fmu_src.fmi.naming import default_name, fmu_target
from fmu_src.fmi.pythonfmu import build_pythonfmu
from fmu_src.fmi.signals import signal
from gp_model import GreyBoxGP, ModelFileError, load_model, read_header
from validation.core.errors import BadInputError
from validation.models.blimp_identification import blimp_physics_from_description
from validation.vehicles.blimp import INPUT_NAMES, STATE_NAMES, hanging_state


def build_blimp_rkgp_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the blimp RKGP FMU (:mod:`fmu_src.blimp_rkgp.slave`) of a trained grey-box model file.

    Parameters
    ----------
    model_path : path
        A ``GreyBoxGP`` saved by :func:`gp_model.save_model` with
        ``physics=blimp_physics_description(params)``, trained on 12 blimp states and the inputs
        ``u_gondola, mu, u_tail, dt`` (:func:`validation.models.blimp_identification.recording_arrays`).
    out_dir : path
        Folder for the FMU (created if missing).
    name : str, optional
        Model identifier and file name; default the model file's stem, made into a name.

    Returns
    -------
    Path
        ``out_dir/<name>.fmu``.

    Raises
    ------
    gp_model.ModelFileError
        Missing, corrupt or not a grey-box model file.
    validation.core.errors.BadInputError
        Other physics than ``blimp_rk4``; hyperparameter samples; a bad ``name`` or ``out_dir``.
    """
    parts = blimp_rkgp_parts(model_path, out_dir, name=name)
    return build_pythonfmu(parts.target, slave_class=BlimpRKGP, variables=(blimp_rkgp_variables, parts.interface),
                           attributes={"DEFAULT_STEP_SIZE": parts.nominal_step}, description=parts.description,
                           arrays=parts.arrays)


@dataclass(frozen=True)
class BlimpRKGPParts:
    """What every blimp RKGP FMU (pythonfmu or native) is built from.

    Attributes
    ----------
    target : Path
        ``out_dir/<name>.fmu`` (name checked; default the model file's stem made into a name).
    arrays : dict of str -> ndarray
        The FMU model file's arrays (:func:`fmu_src.blimp_rkgp.model.pack_model`): the physics
        parameters, the longest RK4 substep, the GP inputs and their training envelope, and per
        GP part (one shared, or one per state) its point-hyperparameter predictive form.
    interface : dict
        ``inputs`` and ``states`` for :func:`fmu_src.blimp_rkgp.slave.blimp_rkgp_variables`.
    description : str
        The FMU's one-line description.
    nominal_step : float
        The default experiment's step: the median training frame interval, s.
    """

    target: Path
    arrays: dict
    interface: dict
    description: str
    nominal_step: float


def blimp_rkgp_parts(model_path, out_dir, *, name: str | None = None) -> BlimpRKGPParts:
    """What every blimp RKGP FMU (pythonfmu or native) is built from, for the grey-box model file
    ``model_path``, ``out_dir`` and ``name`` of :func:`build_blimp_rkgp_fmu`.

    Raises
    ------
    As :func:`build_blimp_rkgp_fmu`.
    """
    model_path = Path(model_path)
    target = fmu_target(out_dir, default_name(model_path.stem) if name is None else name)
    model = load_model(model_path)
    if not isinstance(model, GreyBoxGP):
        raise ModelFileError(f"{model_path}: a {type(model).__name__}, not a GreyBoxGP; the blimp RKGP "
                             "FMU needs a grey-box model")
    physics = read_header(model_path)["physics"]
    params, _ = blimp_physics_from_description(physics)
    if (model.n_states_, model.n_inputs_) != (len(STATE_NAMES), len(INPUT_NAMES) + 1):
        raise BadInputError(f"the model has {model.n_states_} states and {model.n_inputs_} inputs; the "
                            f"blimp RKGP FMU needs {len(STATE_NAMES)} and {len(INPUT_NAMES) + 1} "
                            "(u_gondola, mu, u_tail, dt)")
    gps = [model.gp_] if model.shared else model.gp_.gps
    X = gps[0].input_scaler_.inverse_transform(gps[0].X_train_)
    arrays = pack_model(
        parameter_names=physics["parameter_names"], parameters=physics["parameters"],
        max_step=physics["max_step"], state_columns=model.state_columns_,
        envelope_low=X.min(axis=0), envelope_high=X.max(axis=0), parts=[_gp_part(gp) for gp in gps])
    nominal_step = float(np.median(X[:, -1]))
    start = hanging_state(params)
    inputs = tuple(signal(n, "input").row() for n in INPUT_NAMES)
    states = tuple((*signal(n, "state").row(), float(s)) for n, s in zip(STATE_NAMES, start))
    gp_inputs = [STATE_NAMES[c] for c in model.state_columns_] + [*INPUT_NAMES, "dt"]
    description = (f"Blimp RKGP (Ko et al. 2007): RK4 blimp ODE plus a GP residual "
                   f"({'shared' if model.shared else 'one GP per state'}, {len(X)} points, inputs "
                   f"{', '.join(gp_inputs)}); commands u_gondola, mu, u_tail in, the 12 states and their "
                   f"one-step standard deviations out; communication step = frame interval dt "
                   f"(trained {X[:, -1].min():.4g} .. {X[:, -1].max():.4g} s); model {model_path.name}")
    return BlimpRKGPParts(target=target, arrays=arrays, interface={"inputs": inputs, "states": states},
                          description=description, nominal_step=nominal_step)


def _gp_part(gp) -> dict:
    """The model-file arrays (:data:`fmu_src.blimp_rkgp.model.PER_PART`) of one GP part: its
    point-hyperparameter predictive form, kernel weights and scalers."""
    if gp.theta_samples_ is not None:
        raise BadInputError("the blimp RKGP FMU evaluates point hyperparameters; this model mixes "
                            f"{len(gp.theta_samples_)} samples. Train it by maximum likelihood")
    form = gp.predictive_forms(use_samples=False)[0]
    return {"basis": form.basis, "weights": form.weights.reshape(len(form.basis), -1),
            "variance_factor": form.variance_factor, "kernel_weights": gp.kernel.weights(form.theta[:-1]),
            "log_signal_variance": form.theta[0],
            "input_mean": gp.input_scaler_.mean_, "input_scale": gp.input_scaler_.scale_,
            "output_mean": gp.output_scaler_.mean_, "output_scale": gp.output_scaler_.scale_}
