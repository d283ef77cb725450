"""Build the pythonfmu blimp RKGP FMU of a trained grey-box model file, and what the native one
is built from too (runs in the flightgp environment, not inside an FMU)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fmu_src.blimp_rkgp.model import pack_model
from fmu_src.blimp_rkgp.slave import START_DEFAULT, BlimpRKGP
from fmu_src.fmi.greybox_build import (
    GreyBoxParts,
    build_greybox_pythonfmu,
    gp_parts,
    read_greybox,
    training_inputs,
)
from fmu_src.fmi.naming import default_name, fmu_target
from fmu_src.fmi.signals import signal
from gp_model import PROPAGATION_STEP
from validation.core.errors import BadInputError
from validation.models.blimp_greybox import FAN_COMMANDS, BlimpStepDescription
from validation.vehicles.blimp import INPUT_NAMES, STATE_NAMES, BlimpParameters, hanging_state


def build_blimp_rkgp_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the blimp RKGP FMU (:mod:`fmu_src.blimp_rkgp.slave`) of a trained grey-box model file.

    Parameters
    ----------
    model_path : path
        A ``GreyBoxGP`` saved by :func:`gp_model.save_model` with
        ``physics=BlimpStepDescription(params, max_step, command_lags).as_dict()``
        (:class:`validation.models.blimp_greybox.BlimpStepDescription`), trained on 12 blimp states
        and the inputs the description names: ``u_gondola, mu, u_tail, dt``
        (:func:`validation.models.blimp_identification.recording_arrays`) and, with command lags,
        the lagged fan commands (:func:`validation.models.blimp_greybox.step_inputs`).
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
        Other physics than ``blimp_rk4`` or an unusable description of it (e.g. command lags that
        are not positive times, or other inputs than the model was trained with); hyperparameter
        samples; a bad ``name`` or ``out_dir``.
    """
    return build_greybox_pythonfmu(blimp_rkgp_parts(model_path, out_dir, name=name), slave_class=BlimpRKGP)


def blimp_rkgp_parts(model_path, out_dir, *, name: str | None = None) -> GreyBoxParts:
    """What every blimp RKGP FMU (pythonfmu or native) is built from, for the grey-box model file
    ``model_path``, ``out_dir`` and ``name`` of :func:`build_blimp_rkgp_fmu`: the FMU model file's
    arrays (:func:`fmu_src.blimp_rkgp.model.pack_model`: the physics parameters, the longest RK4
    substep, the command lags, the propagation step, the GP inputs and their training envelope,
    and each GP part's point-hyperparameter predictive form and noise variance), the variables
    and the default experiment's step (the median training frame interval, s).

    Raises
    ------
    As :func:`build_blimp_rkgp_fmu`.
    """
    model_path = Path(model_path)
    target = fmu_target(out_dir, default_name(model_path.stem) if name is None else name)
    model, physics = read_greybox(model_path, fmu="blimp RKGP")
    step = BlimpStepDescription.from_dict(physics)
    if (model.n_states_, model.n_inputs_) != (len(STATE_NAMES), len(step.input_names)):
        raise BadInputError(f"{model_path.name}: the model has {model.n_states_} states and {model.n_inputs_} "
                            f"inputs; its blimp_rk4 physics description (command_lags {list(step.command_lags)}) "
                            f"names {len(STATE_NAMES)} states and {len(step.input_names)} inputs "
                            f"({', '.join(step.input_names)}). Save the model with the description of the "
                            "command lags it was trained with")
    X = training_inputs(model)
    dt = X[:, len(model.state_columns_) + len(INPUT_NAMES)]  # the frame intervals trained on, s
    gp_inputs = [STATE_NAMES[c] for c in model.state_columns_] + step.input_names
    arrays = pack_model(
        parameter_names=BlimpParameters.vector_names(), parameters=step.params.to_vector(),
        max_step=step.max_step, state_columns=model.state_columns_, command_lags=step.command_lags,
        lag_command_columns=[INPUT_NAMES.index(name) for name in FAN_COMMANDS],
        propagation_step=PROPAGATION_STEP, gp_input_names=gp_inputs,
        envelope_low=X.min(axis=0), envelope_high=X.max(axis=0), parts=gp_parts(model))
    nominal_step = float(np.median(dt))
    start = hanging_state(step.params)
    inputs = tuple(signal(n, "input").row() for n in INPUT_NAMES)
    states = tuple((*signal(n, "state").row(), float(s)) for n, s in zip(STATE_NAMES, start))
    description = (f"Blimp RKGP (Ko et al. 2007): RK4 blimp ODE plus a GP residual "
                   f"({'shared' if model.shared else 'one GP per state'}, {len(X)} points, inputs "
                   f"{', '.join(gp_inputs)}); commands u_gondola, mu, u_tail in, the 12 states and their "
                   f"standard deviations propagated along the run out; communication step = frame "
                   f"interval dt (trained {dt.min():.4g} .. {dt.max():.4g} s); model {model_path.name}")
    return GreyBoxParts(target=target, arrays=arrays,
                        interface={"inputs": inputs, "states": states, "start_default": START_DEFAULT},
                        description=description, attributes={"DEFAULT_STEP_SIZE": nominal_step})

