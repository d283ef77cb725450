"""Build the pythonfmu RGBlimp RKGP FMU of a trained grey-box model file, and what the native one
is built from too (runs in the flightgp environment, not inside an FMU)."""
from __future__ import annotations

from pathlib import Path

from fmu_src.fmi.greybox_build import (
    GreyBoxParts,
    build_greybox_pythonfmu,
    gp_parts,
    read_greybox,
    training_inputs,
)
from fmu_src.fmi.naming import default_name, fmu_target
from fmu_src.fmi.signals import signal
from fmu_src.rgblimp_rkgp.model import pack_model
from fmu_src.rgblimp_rkgp.slave import START_DEFAULT, RGBlimpRKGP
from gp_model import PROPAGATION_STEP
from validation.core.errors import BadInputError
from validation.models.rgblimp_greybox import RGBLIMP_PHYSICS, RGBlimpStepDescription
from validation.vehicles.rgblimp_equations import INPUT_NAMES, SAMPLE_TIME, STATE_NAMES


def build_rgblimp_rkgp_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the RGBlimp RKGP FMU (:mod:`fmu_src.rgblimp_rkgp.slave`) of a trained grey-box model file.

    Parameters
    ----------
    model_path : path
        A ``GreyBoxGP`` saved by :func:`gp_model.save_model` with
        ``physics=RGBlimpStepDescription(model).as_dict()``
        (:class:`validation.models.rgblimp_greybox.RGBlimpStepDescription`), trained on the 12
        RGBlimp states and its 5 inputs (:func:`validation.models.rgblimp_greybox.fit_rkgp`; e.g.
        ``OUT/models/rgblimp_rkgp_<j>.npz`` of ``flightgp reproduce rgblimp``).
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
        Other physics than ``rgblimp_rk4`` or an unusable description of it; other states or
        inputs than the RGBlimp's; hyperparameter samples; a bad ``name`` or ``out_dir``.
    """
    return build_greybox_pythonfmu(rgblimp_rkgp_parts(model_path, out_dir, name=name), slave_class=RGBlimpRKGP)


def rgblimp_rkgp_parts(model_path, out_dir, *, name: str | None = None) -> GreyBoxParts:
    """What every RGBlimp RKGP FMU (pythonfmu or native) is built from, for the grey-box model file
    ``model_path``, ``out_dir`` and ``name`` of :func:`build_rgblimp_rkgp_fmu`: the FMU model
    file's arrays (:func:`fmu_src.rgblimp_rkgp.model.pack_model`: the physics description, the
    propagation step, the GP inputs and their training envelope, and each GP part's
    point-hyperparameter predictive form and noise variance) and the variables.

    Raises
    ------
    As :func:`build_rgblimp_rkgp_fmu`.
    """
    model_path = Path(model_path)
    target = fmu_target(out_dir, default_name(model_path.stem) if name is None else name)
    model, physics = read_greybox(model_path, fmu="RGBlimp RKGP")
    step = RGBlimpStepDescription.from_dict(physics)
    if (model.n_states_, model.n_inputs_) != (len(STATE_NAMES), len(INPUT_NAMES)):
        raise BadInputError(f"{model_path.name}: the model has {model.n_states_} states and {model.n_inputs_} "
                            f"inputs; its {RGBLIMP_PHYSICS} physics steps the RGBlimp's {len(STATE_NAMES)} states "
                            f"under its {len(INPUT_NAMES)} inputs ({', '.join(INPUT_NAMES)})")
    X = training_inputs(model)
    gp_inputs = [STATE_NAMES[c] for c in model.state_columns_] + list(INPUT_NAMES)
    arrays = pack_model(physics=step.as_dict(), state_columns=model.state_columns_,
                        propagation_step=PROPAGATION_STEP, gp_input_names=gp_inputs,
                        envelope_low=X.min(axis=0), envelope_high=X.max(axis=0), parts=gp_parts(model))
    inputs = tuple(signal(n, "input").row() for n in INPUT_NAMES)
    states = tuple((*signal(n, "state").row(), 0.0) for n in STATE_NAMES)
    identified = step.model
    description = (f"RGBlimp RKGP (Zhu, Cheng & Zhang 2024 model, identified: thrust gain "
                   f"{identified.thrust_gain:.4g}, wind {identified.wind[0]:.3g}, {identified.wind[1]:.3g} m/s; "
                   f"plus GP residuals: {'shared' if model.shared else 'one GP per state'}, {len(X)} points, "
                   f"inputs {', '.join(gp_inputs)}); propeller thrusts and gondola position in, the 12 states "
                   f"and their standard deviations propagated along the run out; communication step "
                   f"{SAMPLE_TIME:.6g} s (one RK4 sample); model {model_path.name}")
    return GreyBoxParts(target=target, arrays=arrays,
                        interface={"inputs": inputs, "states": states, "start_default": START_DEFAULT},
                        description=description, attributes={})
