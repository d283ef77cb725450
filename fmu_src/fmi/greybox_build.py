"""What the builders of every grey-box (RKGP) FMU share (runs in the flightgp environment, not
inside an FMU): reading a grey-box model file, its residual GPs as FMU model-file arrays
(:mod:`fmu_src.fmi.greybox`), building the pythonfmu FMU and the native FMU's slave class from
the parts a model's builder assembles (:class:`GreyBoxParts`), and what a native grey-box FMU
reads (``model.bin``, laid out as ``greybox.h`` says) and compiles in (``model_config.h``: value
references, the GP structure, the propagation step and the training envelope, the names
``greybox.c`` and the model's C file use)."""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fmu_src.fmi.greybox import ResidualGPs, greybox_variables
from fmu_src.fmi.native import (
    DATA_FILE,
    c_array,
    c_number,
    c_string,
    envelope_lines,
    lower_triangular,
    packed_variance_factor,
)
from fmu_src.fmi.pythonfmu import build_pythonfmu
from gp_model import GreyBoxGP, ModelFileError, load_model, read_header
from validation.core.errors import BadInputError


@dataclass(frozen=True)
class GreyBoxParts:
    """What a grey-box FMU (pythonfmu or native) is built from.

    Attributes
    ----------
    target : Path
        ``out_dir/<name>.fmu`` (name checked).
    arrays : dict of str -> ndarray
        The FMU model file's arrays (the model's ``pack_model``).
    interface : dict
        ``inputs``, ``states`` and ``start_default`` for
        :func:`fmu_src.fmi.greybox.greybox_variables` (plain data, written into the generated
        slave script by ``repr``).
    description : str
        The FMU's one-line description.
    attributes : dict
        Class attributes of the generated slave (e.g. ``DEFAULT_STEP_SIZE``), with exact ``repr``.
    """

    target: Path
    arrays: dict
    interface: dict
    description: str
    attributes: dict


def build_greybox_pythonfmu(parts: GreyBoxParts, *, slave_class) -> Path:
    """The pythonfmu FMU of ``parts`` run by ``slave_class`` (a
    :class:`fmu_src.fmi.greybox.GreyBoxSlave`), written to ``parts.target``."""
    return build_pythonfmu(parts.target, slave_class=slave_class, variables=(greybox_variables, parts.interface),
                           attributes=parts.attributes, description=parts.description, arrays=parts.arrays)


def native_slave_class(parts: GreyBoxParts, *, slave_class) -> type:
    """The slave class whose ``modelDescription.xml`` the native FMU of ``parts`` declares: that
    of the pythonfmu FMU (:func:`build_greybox_pythonfmu`), its description marked native."""
    return type(parts.target.stem, (slave_class,), {
        "description": parts.description + "; native C (no Python at run time)",
        "VARIABLES": greybox_variables(**parts.interface), **parts.attributes})


def read_greybox(model_path, *, fmu: str) -> tuple[GreyBoxGP, object]:
    """The :class:`gp_model.GreyBoxGP` of the model file ``model_path`` and the description of
    its physics (the header's ``physics``, as saved).

    Parameters
    ----------
    model_path : path
    fmu : str
        The FMU being built, for messages (e.g. ``"blimp RKGP"``).

    Raises
    ------
    gp_model.ModelFileError
        Missing, corrupt or not a grey-box model file.
    """
    model = load_model(model_path)
    if not isinstance(model, GreyBoxGP):
        raise ModelFileError(f"{model_path}: a {type(model).__name__}, not a GreyBoxGP; the {fmu} FMU needs a "
                             "grey-box model")
    return model, read_header(model_path).get("physics")


def residual_gps(model: GreyBoxGP) -> list:
    """The residual GPs of ``model``: one when shared, else one per state."""
    return [model.gp_] if model.shared else list(model.gp_.gps)


def training_inputs(model: GreyBoxGP) -> np.ndarray:
    """The GP inputs ``model`` was trained on, physical units, shape (n, d)."""
    gp = residual_gps(model)[0]
    return gp.input_scaler_.inverse_transform(gp.X_train_)


def gp_parts(model: GreyBoxGP) -> list[dict]:
    """The model-file arrays (:data:`fmu_src.fmi.greybox.PER_PART`) of each residual GP of
    ``model``: its point-hyperparameter predictive form, kernel weights, noise variance and
    scalers.

    Raises
    ------
    validation.core.errors.BadInputError
        A GP mixes hyperparameter samples (the grey-box FMUs evaluate point hyperparameters).
    """
    parts = []
    for gp in residual_gps(model):
        if gp.theta_samples_ is not None:
            raise BadInputError("the grey-box FMUs evaluate point hyperparameters; this model mixes "
                                f"{len(gp.theta_samples_)} samples. Train it by maximum likelihood")
        form = gp.predictive_forms(use_samples=False)[0]
        parts.append({"basis": form.basis, "weights": form.weights.reshape(len(form.basis), -1),
                      "variance_factor": form.variance_factor, "kernel_weights": gp.kernel.weights(form.theta[:-1]),
                      "log_signal_variance": form.theta[0], "log_noise_variance": form.theta[-1],
                      "input_mean": gp.input_scaler_.mean_, "input_scale": gp.input_scaler_.scale_,
                      "output_mean": gp.output_scaler_.mean_, "output_scale": gp.output_scaler_.scale_})
    return parts


# -- native grey-box FMUs ------------------------------------------------------------------------
def greybox_data(magic: bytes, gps: ResidualGPs) -> bytes:
    """``resources/model.bin`` of a native grey-box FMU: 8 bytes of ``magic``, the number of
    doubles (uint64) and the doubles of :func:`greybox_doubles`, little-endian."""
    if len(magic) != 8:
        raise ValueError(f"the data file's magic must be 8 bytes, got {magic!r}")
    data = greybox_doubles(gps)
    return magic + struct.pack("<Q", len(data)) + data.tobytes()


def greybox_doubles(gps: ResidualGPs) -> np.ndarray:
    """The doubles of ``model.bin`` in the layout of ``greybox.h``: per part its input mean and
    scale, output mean and scale, kernel weights, log signal and noise variances, basis (by rows),
    weights (by rows) and variance factor (:func:`fmu_src.fmi.native.packed_variance_factor`)."""
    chunks = []
    for p in gps.parts:
        factor = p["variance_factor"]
        chunks += [p["input_mean"], p["input_scale"], p["output_mean"], p["output_scale"], p["kernel_weights"],
                   [p["log_signal_variance"]], [p["log_noise_variance"]], p["basis"].ravel(), p["weights"].ravel(),
                   packed_variance_factor(factor, triangular=lower_triangular(factor))]
    return np.concatenate([np.ravel(np.asarray(c, dtype="<f8")) for c in chunks])


def value_reference_lines(*, variables: tuple, state_names, input_names, slave: str) -> list:
    """The lines of ``model_config.h`` naming a grey-box FMU's sizes and value references:
    ``N_STATES``, ``N_INPUTS``, ``INPUT_VR``, ``STATE_VR``, ``SD_VR`` and ``START_VR``
    (arguments as :func:`greybox_config_lines`)."""
    reference = {v.name: vr for vr, v in enumerate(variables)}
    return [
        f"#define N_STATES {len(state_names)}",
        f"#define N_INPUTS {len(input_names)}",
        f"/* Value references ({slave}): inputs, states, their sds, their start parameters */",
        c_array("unsigned", "INPUT_VR", [reference[n] for n in input_names]).rstrip(),
        c_array("unsigned", "STATE_VR", [reference[n] for n in state_names]).rstrip(),
        c_array("unsigned", "SD_VR", [reference[f"{n}_sd"] for n in state_names]).rstrip(),
        c_array("unsigned", "START_VR", [reference[f"{n}_start"] for n in state_names]).rstrip()]


def greybox_config_lines(*, variables: tuple, state_names, input_names, state_columns, gps: ResidualGPs,
                         propagation_step: float, envelope, slave: str) -> list:
    """The lines of ``model_config.h`` every native grey-box FMU has: its states and inputs, their
    value references, the propagation step, the GP structure, the training envelope and the data
    file.

    Parameters
    ----------
    variables : tuple of fmu_src.fmi.slave.Variable
        The FMU's variable table (:func:`fmu_src.fmi.greybox.greybox_variables`).
    state_names, input_names : sequence of str
        The states (outputs ``<s>``, ``<s>_sd``, parameters ``<s>_start``) and the inputs.
    state_columns : sequence of int
        The states the GP sees, first among its inputs.
    gps : fmu_src.fmi.greybox.ResidualGPs
    propagation_step : float
        Central-difference step, state units.
    envelope : fmu_src.fmi.runtime.Envelope
        Training range of the GP inputs.
    slave : str
        The module of the FMU's slave, for comments.
    """
    state_columns = [int(c) for c in state_columns]
    parts = gps.parts
    return [
        *value_reference_lines(variables=variables, state_names=state_names, input_names=input_names, slave=slave),
        "/* Central-difference step of the covariance propagation, state units (GreyBoxGP.propagate) */",
        f"#define PROPAGATION_STEP {c_number(propagation_step)}", "",
        "/* GP: inputs [states[STATE_COLUMNS], ...]; parts (one shared, or one per state);",
        "   GP_INPUT_OF_STATE: each state's GP input, -1 if the GP does not see it (greybox.h) */",
        f"#define N_STATE_COLUMNS {len(state_columns)}",
        f"#define N_GP_INPUTS {len(envelope.names)}",
        c_array("int", "STATE_COLUMNS", state_columns).rstrip(),
        c_array("int", "GP_INPUT_OF_STATE", [state_columns.index(i) if i in state_columns else -1
                                             for i in range(len(state_names))]).rstrip(),
        f"#define N_PARTS {len(parts)}",
        c_array("int", "BASIS_POINTS", [len(p["basis"]) for p in parts]).rstrip(),
        c_array("int", "PART_OUTPUTS", [p["weights"].shape[1] for p in parts]).rstrip(),
        c_array("int", "LOWER_TRIANGULAR", [int(lower_triangular(p["variance_factor"])) for p in parts]).rstrip(),
        *envelope_lines("GP_INPUT_NAMES", envelope), "",
        f"/* GP arrays in resources/{DATA_FILE} (layout: greybox.h) */",
        f"#define DATA_FILE {c_string(DATA_FILE)}",
        f"#define DATA_DOUBLES {len(greybox_doubles(gps))}"]

