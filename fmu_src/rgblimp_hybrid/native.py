"""The native (C, Python-free) RGBlimp hybrid FMU (runs in the flightgp environment, not inside an
FMU; docs/fmus.md, "Native FMUs (no Python in the host)").

:func:`build_native_rgblimp_hybrid_fmu` writes an FMI 2.0 co-simulation FMU with the interface of
the pythonfmu RGBlimp hybrid FMU (:mod:`fmu_src.rgblimp_hybrid.slave`: its ``modelDescription.xml``
is written by the same class) and its numbers: ``rgblimp_hybrid_model.c`` evaluates the correction
and the covariance propagation of :class:`fmu_src.rgblimp_hybrid.model.RGBlimpHybridModel` over the
RGBlimp's physics in C that the RKGP's native FMU uses too (``rgblimp_physics.c``), with the FMI
layer's ``greybox.c`` for the covariance update, packaged by :mod:`fmu_src.fmi.native`.

``model_config.h`` holds the GUID, variable table, value references, the step, every physics
parameter, the thrust factor and the wind, the correction's sizes and feature scales, the random
acceleration's decay and process noise, the propagation step and the fitting envelope;
``resources/model.bin`` the correction's arrays (layout in ``rgblimp_hybrid_model.c``).
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from fmu_src.fmi.greybox_build import native_slave_class, value_reference_lines
from fmu_src.fmi.native import (
    DATA_FILE,
    c_array,
    c_number,
    c_string,
    config_header,
    envelope_lines,
    package_native_fmu,
    variable_table,
)
from fmu_src.rgblimp_hybrid.build import rgblimp_hybrid_parts
from fmu_src.rgblimp_hybrid.model import N_DISTURBANCES, N_STATES, RGBlimpHybridModel
from fmu_src.rgblimp_hybrid.slave import RGBlimpHybrid
from fmu_src.rgblimp_rkgp.native import PHYSICS_SOURCES, check_physics_parameters, physics_config_lines
from validation.models.rgblimp_hybrid_step import FEATURE_SCALE, INPUT_FEATURES, STATE_FEATURES
from validation.vehicles.rgblimp_equations import INPUT_NAMES, STATE_NAMES

#: The model's C files, compiled with the FMI layer.
MODEL_SOURCE = (Path(__file__).with_name("rgblimp_hybrid_model.c"), *PHYSICS_SOURCES)

_DATA_MAGIC = b"FGPRGBH1"


def build_native_rgblimp_hybrid_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the native (C, Python-free) RGBlimp hybrid FMU of a hybrid model file.

    Parameters
    ----------
    model_path : path
        As for :func:`fmu_src.rgblimp_hybrid.build.build_rgblimp_hybrid_fmu`.
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
        As :func:`fmu_src.rgblimp_hybrid.build.build_rgblimp_hybrid_fmu`; also no ``gcc`` or a
        platform other than Linux x86-64.
    RuntimeError
        gcc failed, or the RGBlimp's parameters are not those ``rgblimp_physics.c`` reads (bugs).
    """
    check_physics_parameters()
    parts = rgblimp_hybrid_parts(model_path, out_dir, name=name)
    model = RGBlimpHybridModel(parts.arrays)  # checks the arrays, as the pythonfmu FMU does at load
    slave_class = native_slave_class(parts, slave_class=RGBlimpHybrid)
    c = model.correction
    doubles = np.concatenate([np.ravel(np.asarray(a, dtype="<f8"))
                              for a in (c.inducing, c.weights, c.length_scale, c.amplitude)])
    return package_native_fmu(
        parts.target, slave_class=slave_class, model_source=MODEL_SOURCE,
        config=lambda guid: _hybrid_config(guid, parts.target.stem, slave_class.VARIABLES, model, len(doubles)),
        data=_DATA_MAGIC + struct.pack("<Q", len(doubles)) + doubles.tobytes())


def _hybrid_config(guid: str, name: str, variables: tuple, model: RGBlimpHybridModel, n_doubles: int) -> str:
    """``model_config.h``: identity, variable table, step, physics, correction and propagation."""
    n_augmented = N_STATES + N_DISTURBANCES
    return config_header(name, guid, generator="fmu_src/rgblimp_hybrid/native.py", body=[
        "/* Communication step: one RK4 sample of the source's integrator, s (fmu_src/rgblimp_hybrid/slave.py) */",
        f"#define STEP_SIZE {c_number(RGBlimpHybrid.STEP_SIZE)}", "",
        *variable_table(variables, "fmu_src/fmi/greybox.py, greybox_variables"),
        *value_reference_lines(variables=variables, state_names=STATE_NAMES, input_names=INPUT_NAMES,
                               slave="fmu_src/rgblimp_hybrid/slave.py"), "",
        "/* The correction (fmu_src/rgblimp_hybrid/model.py): inducing points, features and their scales */",
        f"#define N_INDUCING {len(model.correction.inducing)}",
        f"#define N_FEATURES {len(FEATURE_SCALE)}",
        c_array("double", "FEATURE_SCALE", FEATURE_SCALE, c_number).rstrip(),
        "/* The state and input columns of the features (validation/models/rgblimp_hybrid_step.py) */",
        c_array("int", "STATE_FEATURES", STATE_FEATURES).rstrip(),
        c_array("int", "INPUT_FEATURES", INPUT_FEATURES).rstrip(),
        *envelope_lines("FEATURE_NAMES", model.envelope), "",
        "/* Covariance propagation of the 12 states and the 6 random accelerations: central-difference",
        "   step, the accelerations' decay over one sample, their stationary variances and the process noise */",
        f"#define N_AUGMENTED {n_augmented}",
        f"#define PROPAGATION_STEP {c_number(model.propagation.step)}",
        f"#define DECAY {c_number(model.decay)}",
        c_array("double", "DISTURBANCE_VARIANCE", model.disturbance_variance, c_number).rstrip(),
        c_array("double", "PROCESS_NOISE", model.process_noise, c_number).rstrip(), "",
        "/* Hidden state: the 12 states, the augmented covariance, the envelope flag (rgblimp_hybrid_model.c) */",
        "#define MODEL_STATE_SIZE (N_STATES + N_AUGMENTED * N_AUGMENTED + 1)", "",
        f"/* The correction's arrays in resources/{DATA_FILE} (layout: rgblimp_hybrid_model.c) */",
        f"#define DATA_FILE {c_string(DATA_FILE)}",
        f"#define DATA_DOUBLES {n_doubles}", "",
        *physics_config_lines(model.params, thrust_gain=model.thrust_gain, wind=model.wind)])
