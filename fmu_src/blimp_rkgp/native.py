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
(:mod:`fmu_src.fmi.greybox_build`, layout in ``greybox.h``). The step
is fixed by the first ``fmi2DoStep`` and refused outside the training range of the frame
interval ``dt`` (plus the envelope margin), as the pythonfmu FMU
(:meth:`fmu_src.blimp_rkgp.model.RKGPModel.step_range`).
"""
from __future__ import annotations

from pathlib import Path

from fmu_src.blimp_rkgp.build import blimp_rkgp_parts
from fmu_src.blimp_rkgp.model import RKGPModel
from fmu_src.blimp_rkgp.slave import BlimpRKGP
from fmu_src.fmi.greybox_build import greybox_config_lines, greybox_data, native_slave_class
from fmu_src.fmi.native import (
    c_array,
    c_number,
    check_platform,
    config_header,
    package_native_fmu,
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
    slave_class = native_slave_class(parts, slave_class=BlimpRKGP)
    return package_native_fmu(parts.target, slave_class=slave_class, model_source=MODEL_SOURCE,
                              config=lambda guid: _blimp_config(guid, parts.target.stem, slave_class.VARIABLES, model),
                              data=greybox_data(_DATA_MAGIC, model.gps))


def _blimp_config(guid: str, name: str, variables: tuple, model: RKGPModel) -> str:
    """``model_config.h``: identity, variable table, step range, physics and GP structure."""
    P = model.params
    matrix, inverse = mass_matrix(P.mass, P.added_mass, P.inertia, P.added_inertia, P.cg_position)
    low, high = model.step_range()
    return config_header(name, guid, generator="fmu_src/blimp_rkgp/native.py", body=[
        "/* Communication step: fixed by the first fmi2DoStep (STEP_SIZE 0), inside the training range",
        "   of dt plus the envelope margin (fmu_src/blimp_rkgp/model.py, RKGPModel.step_range), s */",
        "#define STEP_SIZE 0.0",
        f"#define MIN_STEP_SIZE {c_number(low)}",
        f"#define MAX_STEP_SIZE {c_number(high)}",
        '#define STEP_RANGE_REASON "the frame intervals the GP residual was trained on (plus 10 %); step '
        'with the default experiment\'s step size"', "",
        *variable_table(variables, "fmu_src/fmi/greybox.py, greybox_variables"),
        *greybox_config_lines(variables=variables, state_names=STATE_NAMES, input_names=INPUT_NAMES,
                              state_columns=model.state_columns, gps=model.gps,
                              propagation_step=model.propagation.step, envelope=model.envelope,
                              slave="fmu_src/blimp_rkgp/slave.py"), "",
        "/* Lagged commands: N_COMMAND_LAGS time constants (s) of N_LAG_FANS commands each (columns of",
        "   u_gondola, mu, u_tail) (fmu_src/blimp_rkgp/model.py, RKGPModel.advance_lags) */",
        f"#define N_COMMAND_LAGS {len(model.command_lags)}",
        f"#define N_LAG_FANS {len(model.lag_command_columns)}",
        "#define N_LAGS (N_COMMAND_LAGS * N_LAG_FANS)",
        c_array("double", "LAG_TIME_CONSTANTS", model.command_lags, c_number).rstrip(),
        c_array("int", "LAG_COMMAND_COLUMNS", model.lag_command_columns).rstrip(),
        "/* Hidden state: the 12 states, their covariance, the lagged commands, the envelope flag (blimp_model.c) */",
        "#define MODEL_STATE_SIZE (N_STATES + N_STATES * N_STATES + N_LAGS + 1)", "",
        "/* Physics (validation/vehicles/blimp_equations.py; SI units) and the longest RK4 substep, s */",
        f"#define MAX_STEP {c_number(model.max_step)}",
        f"#define STANDARD_GRAVITY {c_number(STANDARD_GRAVITY)}",
        *(f"#define {field.upper()} {c_number(getattr(P, field))}" for field in _SCALARS),
        *(c_array("double", field.upper(), getattr(P, field), c_number).rstrip() for field in _TRIPLES),
        "/* M = M_RB + M_A about the centre of buoyancy (Fossen 2011, eq. 3.44) and M^-1, by rows",
        "   (validation/vehicles/blimp_equations.py, mass_matrix) */",
        c_array("double", "MASS_MATRIX", matrix.ravel(), c_number).rstrip(),
        c_array("double", "INVERSE_MASS_MATRIX", inverse.ravel(), c_number).rstrip()])
