"""The native (C, Python-free) blimp RKGP FMU: RK4 blimp physics plus GP residual (Ko et al.,
ICRA 2007, sec. IV-B) in C (runs in the flightgp environment, not inside an FMU; docs/fmus.md,
"Native FMUs (no Python in the host)").

:func:`build_native_blimp_rkgp_fmu` writes an FMI 2.0 co-simulation FMU with the interface of
the pythonfmu blimp RKGP FMU (:mod:`fmu_src.blimp_rkgp.slave`: the same variable table, value
references, units, descriptions, start values, bounds, default experiment, sampling convention
and step policy, since its ``modelDescription.xml`` is written by the same class) and its
numbers (``blimp_model.c``: the formulas of :mod:`validation.vehicles.blimp_equations` and of
:class:`fmu_src.blimp_rkgp.model.RKGPModel` (the GP residual, the lagged commands and the
first-order propagation of the state covariance) in the same order, so the states and the
propagated standard deviations agree to rounding), packaged by :mod:`fmu_src.fmi.native`.

``model_config.h`` holds the GUID, variable table, value references, the step range, the
physics parameters with the mass matrix and its inverse, the command lags, the propagation
step, the GP structure and the training envelope; ``resources/model.bin`` every GP part's arrays
(layout in ``blimp_model.c``). The step
is fixed by the first ``fmi2DoStep`` and refused outside the training range of the frame
interval ``dt`` (plus the envelope margin), as the pythonfmu FMU
(:meth:`fmu_src.blimp_rkgp.model.RKGPModel.step_range`).
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from fmu_src.blimp_rkgp.build import blimp_rkgp_parts
from fmu_src.blimp_rkgp.model import RKGPModel
from fmu_src.blimp_rkgp.slave import BlimpRKGP, blimp_rkgp_variables
from fmu_src.fmi.native import (
    DATA_FILE,
    c_array,
    c_number,
    c_string,
    check_platform,
    config_header,
    envelope_lines,
    lower_triangular,
    package_native_fmu,
    packed_variance_factor,
    variable_table,
)
from validation.vehicles.blimp_equations import INPUT_NAMES, STANDARD_GRAVITY, STATE_NAMES, mass_matrix

#: The model's C file, compiled with the FMI layer.
MODEL_SOURCE = Path(__file__).with_name("blimp_model.c")

_DATA_MAGIC = b"FGPBLMP2"
#: Scalar physics parameters (the ``BlimpParameters`` fields, C macros in capitals).
_SCALARS = ("mass", "net_lift", "gondola_thrust_forward", "gondola_thrust_backward", "gondola_arm",
            "tail_thrust_positive", "tail_thrust_negative", "tail_arm", "fin_lift")
_TRIPLES = ("linear_drag", "quadratic_drag", "rotational_damping", "cg_position")


def build_native_blimp_rkgp_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the native (C, Python-free) blimp RKGP FMU of a trained grey-box model file.

    Parameters
    ----------
    model_path : path
        A ``GreyBoxGP`` with ``blimp_rk4`` physics, as for
        :func:`fmu_src.blimp_rkgp.build.build_blimp_rkgp_fmu`.
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
        As :func:`fmu_src.blimp_rkgp.build.build_blimp_rkgp_fmu` (other physics, hyperparameter samples, a
        bad ``name`` or ``out_dir``); also no ``gcc`` or a platform other than Linux x86-64.
    RuntimeError
        gcc failed to compile the generated sources (a bug: the message holds its output).
    """
    check_platform()
    parts = blimp_rkgp_parts(model_path, out_dir, name=name)
    model = RKGPModel(parts.arrays)  # checks the arrays' shapes, as the pythonfmu FMU does at load
    variables = blimp_rkgp_variables(**parts.interface)
    identifier = parts.target.stem
    slave_class = type(identifier, (BlimpRKGP,), {
        "description": parts.description + "; native C (no Python at run time)", "VARIABLES": variables,
        "DEFAULT_STEP_SIZE": parts.nominal_step})
    return package_native_fmu(parts.target, slave_class=slave_class, model_source=MODEL_SOURCE,
                              config=lambda guid: _blimp_config(guid, identifier, variables, model),
                              data=_blimp_data(model))


def _blimp_config(guid: str, name: str, variables: tuple, model: RKGPModel) -> str:
    """``model_config.h``: identity, variable table, step range, physics and GP structure."""
    reference = {v.name: vr for vr, v in enumerate(variables)}
    P = model.params
    matrix, inverse = mass_matrix(P.mass, P.added_mass, P.inertia, P.added_inertia, P.cg_position)
    low, high = model.step_range()
    parts = model.parts
    return config_header(name, guid, generator="fmu_src/blimp_rkgp/native.py", body=[
        "/* Communication step: fixed by the first fmi2DoStep (STEP_SIZE 0), inside the training range",
        "   of dt plus the envelope margin (fmu_src/blimp_rkgp/model.py, RKGPModel.step_range), s */",
        "#define STEP_SIZE 0.0",
        f"#define MIN_STEP_SIZE {c_number(low)}",
        f"#define MAX_STEP_SIZE {c_number(high)}",
        '#define STEP_RANGE_REASON "the frame intervals the GP residual was trained on (plus 10 %); step '
        'with the default experiment\'s step size"', "",
        *variable_table(variables, "fmu_src/blimp_rkgp/slave.py, blimp_rkgp_variables"),
        f"#define N_STATES {len(STATE_NAMES)}",
        "/* Lagged commands: N_COMMAND_LAGS time constants (s) of N_LAG_FANS commands each (columns of",
        "   u_gondola, mu, u_tail) (fmu_src/blimp_rkgp/model.py, RKGPModel.advance_lags) */",
        f"#define N_COMMAND_LAGS {len(model.command_lags)}",
        f"#define N_LAG_FANS {len(model.lag_command_columns)}",
        "#define N_LAGS (N_COMMAND_LAGS * N_LAG_FANS)",
        c_array("double", "LAG_TIME_CONSTANTS", model.command_lags, c_number).rstrip(),
        c_array("int", "LAG_COMMAND_COLUMNS", model.lag_command_columns).rstrip(),
        "/* Hidden state: the 12 states, their covariance, the lagged commands, the envelope flag (blimp_model.c) */",
        "#define MODEL_STATE_SIZE (N_STATES + N_STATES * N_STATES + N_LAGS + 1)",
        "/* Central-difference step of the covariance propagation, state units (GreyBoxGP.propagate) */",
        f"#define PROPAGATION_STEP {c_number(model.propagation_step)}",
        "/* Value references: commands, states, their sds, their start parameters */",
        c_array("unsigned", "COMMAND_VR", [reference[n] for n in INPUT_NAMES]).rstrip(),
        c_array("unsigned", "STATE_VR", [reference[n] for n in STATE_NAMES]).rstrip(),
        c_array("unsigned", "SD_VR", [reference[f"{n}_sd"] for n in STATE_NAMES]).rstrip(),
        c_array("unsigned", "START_VR", [reference[f"{n}_start"] for n in STATE_NAMES]).rstrip(), "",
        "/* Physics (validation/vehicles/blimp_equations.py; SI units) and the longest RK4 substep, s */",
        f"#define MAX_STEP {c_number(model.max_step)}",
        f"#define STANDARD_GRAVITY {c_number(STANDARD_GRAVITY)}",
        *(f"#define {field.upper()} {c_number(getattr(P, field))}" for field in _SCALARS),
        *(c_array("double", field.upper(), getattr(P, field), c_number).rstrip() for field in _TRIPLES),
        "/* M = M_RB + M_A about the centre of buoyancy (Fossen 2011, eq. 3.44) and M^-1, by rows",
        "   (validation/vehicles/blimp_equations.py, mass_matrix) */",
        c_array("double", "MASS_MATRIX", matrix.ravel(), c_number).rstrip(),
        c_array("double", "INVERSE_MASS_MATRIX", inverse.ravel(), c_number).rstrip(), "",
        "/* GP: inputs [states[STATE_COLUMNS], u_gondola, mu, u_tail, dt, lagged commands]; parts (one",
        "   shared, or one per state); GP_INPUT_OF_STATE: each state's GP input, -1 if the GP does not see it */",
        f"#define N_STATE_COLUMNS {len(model.state_columns)}",
        f"#define N_GP_INPUTS {len(model.input_names)}",
        c_array("int", "STATE_COLUMNS", model.state_columns).rstrip(),
        c_array("int", "GP_INPUT_OF_STATE", [list(model.state_columns).index(i) if i in model.state_columns else -1
                                             for i in range(len(STATE_NAMES))]).rstrip(),
        f"#define N_PARTS {len(parts)}",
        c_array("int", "BASIS_POINTS", [len(p["basis"]) for p in parts]).rstrip(),
        c_array("int", "PART_OUTPUTS", [p["weights"].shape[1] for p in parts]).rstrip(),
        c_array("int", "LOWER_TRIANGULAR", [int(lower_triangular(p["variance_factor"])) for p in parts]).rstrip(),
        *envelope_lines("GP_INPUT_NAMES", model.envelope), "",
        f"/* GP arrays in resources/{DATA_FILE} (layout: blimp_model.c) */",
        f"#define DATA_FILE {c_string(DATA_FILE)}",
        f"#define DATA_DOUBLES {len(_blimp_doubles(model))}"])


def _blimp_doubles(model: RKGPModel) -> np.ndarray:
    """The doubles of ``model.bin`` in the layout of ``blimp_model.c``."""
    chunks = []
    for p in model.parts:
        factor = p["variance_factor"]
        chunks += [p["input_mean"], p["input_scale"], p["output_mean"], p["output_scale"], p["kernel_weights"],
                   [p["log_signal_variance"]], [p["log_noise_variance"]], p["basis"].ravel(), p["weights"].ravel(),
                   packed_variance_factor(factor, triangular=lower_triangular(factor))]
    return np.concatenate([np.ravel(np.asarray(c, dtype="<f8")) for c in chunks])


def _blimp_data(model: RKGPModel) -> bytes:
    """``model.bin``: magic, count and the doubles (little-endian)."""
    data = _blimp_doubles(model)
    return _DATA_MAGIC + struct.pack("<Q", len(data)) + data.tobytes()
