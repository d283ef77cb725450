"""Build the pythonfmu RGBlimp hybrid FMU of a rollout-trained hybrid's model file, and what the
native one is built from too (runs in the flightgp environment, not inside an FMU)."""
from __future__ import annotations

import json
from pathlib import Path

from fmu_src.fmi.greybox_build import GreyBoxParts, build_greybox_pythonfmu
from fmu_src.fmi.naming import default_name, fmu_target
from fmu_src.fmi.signals import signal
from fmu_src.rgblimp_hybrid.model import pack_model
from fmu_src.rgblimp_hybrid.slave import MEAN_PHRASE, SD_PHRASE, RGBlimpHybrid
from fmu_src.rgblimp_rkgp.slave import START_DEFAULT
from gp_model import PROPAGATION_STEP
from validation.core.errors import BadInputError
from validation.models.rgblimp_rollout import RolloutHybrid
from validation.models.rgblimp_step import parameters_as_dict
from validation.vehicles.rgblimp_equations import INPUT_NAMES, SAMPLE_TIME, STATE_NAMES


def build_rgblimp_hybrid_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the RGBlimp hybrid FMU (:mod:`fmu_src.rgblimp_hybrid.slave`) of a hybrid model file.

    Parameters
    ----------
    model_path : path
        A :class:`validation.models.rgblimp_rollout.RolloutHybrid` as JSON
        (``RolloutHybrid.as_dict``; e.g. ``OUT/models/rgblimp_hybrid_<j>.json`` of ``flightgp
        reproduce rgblimp``).
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
    validation.core.errors.BadInputError
        Missing or unreadable file, not a hybrid model (or one without its fitting envelope), a
        bad ``name`` or ``out_dir``.
    """
    return build_greybox_pythonfmu(rgblimp_hybrid_parts(model_path, out_dir, name=name), slave_class=RGBlimpHybrid)


def read_hybrid(model_path) -> RolloutHybrid:
    """The hybrid of the JSON model file ``model_path``; BadInputError with one line otherwise."""
    model_path = Path(model_path)
    try:
        data = json.loads(model_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise BadInputError(f"{model_path}: not a readable RGBlimp hybrid model file ({error})") from None
    hybrid = RolloutHybrid.from_dict(data)
    if hybrid.envelope is None:
        raise BadInputError(f"{model_path.name}: the model has no fitting envelope (written by an older flightgp); "
                            "refit it with `flightgp reproduce rgblimp`")
    return hybrid


def rgblimp_hybrid_parts(model_path, out_dir, *, name: str | None = None) -> GreyBoxParts:
    """What every RGBlimp hybrid FMU (pythonfmu or native) is built from: the FMU model file's
    arrays (:func:`fmu_src.rgblimp_hybrid.model.pack_model`) and the variables (arguments and
    errors as :func:`build_rgblimp_hybrid_fmu`)."""
    model_path = Path(model_path)
    target = fmu_target(out_dir, default_name(model_path.stem) if name is None else name)
    hybrid = read_hybrid(model_path)
    physics = hybrid.physics
    arrays = pack_model(physics={"parameters": parameters_as_dict(physics.params),
                                 "thrust_gain": float(physics.thrust_gain), "wind": [float(v) for v in physics.wind]},
                        correction=hybrid.numpy_correction(), disturbance_sd=hybrid.disturbance_sd,
                        disturbance_time=hybrid.disturbance_time, propagation_step=PROPAGATION_STEP,
                        envelope=hybrid.envelope)
    inputs = tuple(signal(n, "input").row() for n in INPUT_NAMES)
    states = tuple((*signal(n, "state").row(), 0.0) for n in STATE_NAMES)
    description = (f"RGBlimp hybrid (Zhu, Cheng & Zhang 2024 model, identified and refined: thrust gain "
                   f"{physics.thrust_gain:.4g}, wind {physics.wind[0]:.3g}, {physics.wind[1]:.3g} m/s; plus a "
                   f"sparse-GP "
                   f"correction of the accelerations with {len(hybrid.correction['inducing'])} inducing points, "
                   f"trained through free runs); propeller thrusts and gondola position in, the 12 states and "
                   f"their standard deviations out; communication step {SAMPLE_TIME:.6g} s (one RK4 sample); "
                   f"model {model_path.name}")
    return GreyBoxParts(target=target, arrays=arrays,
                        interface={"inputs": inputs, "states": states, "start_default": START_DEFAULT,
                                   "mean_phrase": MEAN_PHRASE, "sd_phrase": SD_PHRASE},
                        description=description, attributes={})
