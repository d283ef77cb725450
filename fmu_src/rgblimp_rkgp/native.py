"""The native (C, Python-free) RGBlimp RKGP FMU: the identified RGBlimp model stepped by RK4 plus
GP residuals (runs in the flightgp environment, not inside an FMU; docs/fmus.md, "Native FMUs (no
Python in the host)").

:func:`build_native_rgblimp_rkgp_fmu` writes an FMI 2.0 co-simulation FMU with the interface of
the pythonfmu RGBlimp RKGP FMU (:mod:`fmu_src.rgblimp_rkgp.slave`: the same variable table, value
references, units, descriptions, start values, bounds, default experiment, sampling convention
and step, since its ``modelDescription.xml`` is written by the same class) and its numbers
(``rgblimp_model.c``: the formulas of :mod:`validation.vehicles.rgblimp_equations`,
:func:`validation.models.rgblimp_step.carry_yaw` and
:class:`fmu_src.rgblimp_rkgp.model.RGBlimpRKGPModel`, with the FMI layer's ``greybox.c`` for the
residual GPs and the covariance propagation, in the same order, so the states and the propagated
standard deviations agree to rounding), packaged by :mod:`fmu_src.fmi.native`.

``model_config.h`` holds the GUID, variable table, value references, the step, every physics
parameter, the thrust factor and the wind, the propagation step, the GP structure and the
training envelope; ``resources/model.bin`` every GP part's arrays (layout in ``greybox.h``).
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from fmu_src.fmi.greybox_build import greybox_config_lines, greybox_data, native_slave_class
from fmu_src.fmi.native import c_array, c_number, check_platform, config_header, package_native_fmu, variable_table
from fmu_src.rgblimp_rkgp.build import rgblimp_rkgp_parts
from fmu_src.rgblimp_rkgp.model import RGBlimpRKGPModel
from fmu_src.rgblimp_rkgp.slave import RGBlimpRKGP
from validation.core.errors import BadInputError
from validation.vehicles.rgblimp_equations import (
    INPUT_NAMES,
    SAMPLE_TIME,
    STATE_NAMES,
    ZERO_SPEED_GUARD,
    RGBlimpParameters,
)

#: The RGBlimp's physics in C, shared by the native RGBlimp FMUs (RKGP and hybrid).
PHYSICS_SOURCES = (Path(__file__).with_name("rgblimp_physics.c"), Path(__file__).with_name("rgblimp_physics.h"))
#: The model's C files, compiled with the FMI layer.
MODEL_SOURCE = (Path(__file__).with_name("rgblimp_model.c"), *PHYSICS_SOURCES)

_DATA_MAGIC = b"FGPRGBL1"
#: The RGBlimpParameters fields ``rgblimp_physics.c`` reads (C macros in capitals): a parameter it
#: did not read would be left out of the native FMU's physics, so the build refuses to run then.
C_PARAMETERS = ("air_density", "gravity", "buoyancy_mass", "hull_mass", "gondola_mass", "hull_cg", "propeller_arm",
                "reference_area", "inertia", "rate_damping", "c_d0", "c_d_alpha2", "c_d_beta2", "c_s0", "c_s_alpha2",
                "c_s_beta", "c_l0", "c_l_alpha", "c_l_beta2", "c_mx0", "c_mx_alpha", "c_mx_beta", "c_my0",
                "c_my_alpha", "c_my_beta4", "c_mz0", "c_mz_alpha", "c_mz_beta", "c_s_beta_abs", "c_l_alpha_abs",
                "c_my_alpha_abs", "c_mz_beta_abs", "added_mass", "added_inertia", "thrust_speed_loss",
                "thrust_line_y")
#: The RGBlimpParameters fields ``rgblimp_physics.c`` does not implement, which a native FMU's
#: model must leave at zero: the draught field that varies with position (the native covariance
#: step takes the dynamics not to read the position, ``rgblimp_physics.h``).
ZERO_IN_C = ("draught_gradient_x", "draught_gradient_y")


def build_native_rgblimp_rkgp_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the native (C, Python-free) RGBlimp RKGP FMU of a trained grey-box model file.

    Parameters
    ----------
    model_path : path
        A ``GreyBoxGP`` with ``rgblimp_rk4`` physics, as for
        :func:`fmu_src.rgblimp_rkgp.build.build_rgblimp_rkgp_fmu`.
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
        As :func:`fmu_src.rgblimp_rkgp.build.build_rgblimp_rkgp_fmu` (other physics, hyperparameter
        samples, a bad ``name`` or ``out_dir``); also no ``gcc`` or a platform other than Linux
        x86-64.
    RuntimeError
        gcc failed to compile the generated sources, or the RGBlimp's parameters are not those
        ``rgblimp_physics.c`` reads (:data:`C_PARAMETERS`; bugs: the message says which).
    """
    check_physics_parameters()
    parts = rgblimp_rkgp_parts(model_path, out_dir, name=name)
    model = RGBlimpRKGPModel(parts.arrays)  # checks the arrays' shapes, as the pythonfmu FMU does at load
    slave_class = native_slave_class(parts, slave_class=RGBlimpRKGP)
    return package_native_fmu(
        parts.target, slave_class=slave_class, model_source=MODEL_SOURCE,
        config=lambda guid: _rgblimp_config(guid, parts.target.stem, slave_class.VARIABLES, model),
        data=greybox_data(_DATA_MAGIC, model.gps))


def check_physics_parameters() -> None:
    """Raise BadInputError off Linux x86-64 (:func:`fmu_src.fmi.native.check_platform`), and
    RuntimeError (a bug) if the equations' parameters are not those ``rgblimp_physics.c`` reads."""
    check_platform()
    fields = tuple(field.name for field in dataclasses.fields(RGBlimpParameters))
    if set(fields) != set(C_PARAMETERS) | set(ZERO_IN_C):
        raise RuntimeError(f"rgblimp_physics.c reads the RGBlimp parameters {sorted(C_PARAMETERS)} and leaves out "
                           f"{sorted(ZERO_IN_C)}, the equations have {sorted(fields)}: port the change to the C file "
                           "and C_PARAMETERS")


def physics_config_lines(params, *, thrust_gain: float, wind) -> list:
    """The lines of ``model_config.h`` that ``rgblimp_physics.c`` reads: the RK4 sample, the
    airspeed guard, pi, every parameter (:data:`C_PARAMETERS`), the thrust factor and the wind.

    Raises
    ------
    validation.core.errors.BadInputError
        A parameter of :data:`ZERO_IN_C` is not zero: the native FMU would leave it out.
    """
    unsupported = [field for field in ZERO_IN_C if any(getattr(params, field))]
    if unsupported:
        raise BadInputError(f"the model has a draught field that varies across the room ({', '.join(unsupported)}), "
                            "which the native FMU does not compute; build the pythonfmu FMU instead (without "
                            "--native)")
    return [
        "/* Physics (validation/vehicles/rgblimp_equations.py, validation/models/rgblimp_identification.py;",
        "   SI units): the RK4 sample, s, the airspeed guard, m/s, pi, the RGBlimpParameters fields, the",
        "   thrust factor and the wind along earth x and y, m/s (rgblimp_physics.h) */",
        f"#define SAMPLE_TIME {c_number(SAMPLE_TIME)}",
        f"#define ZERO_SPEED_GUARD {c_number(ZERO_SPEED_GUARD)}",
        f"#define PI {c_number(math.pi)}",
        *(c_array("double", field.upper(), value, c_number).rstrip() if isinstance(value, tuple)
          else f"#define {field.upper()} {c_number(value)}"
          for field in C_PARAMETERS for value in [getattr(params, field)]),
        f"#define THRUST_GAIN {c_number(thrust_gain)}",
        c_array("double", "WIND", wind, c_number).rstrip()]


def _rgblimp_config(guid: str, name: str, variables: tuple, model: RGBlimpRKGPModel) -> str:
    """``model_config.h``: identity, variable table, step, physics and GP structure."""
    return config_header(name, guid, generator="fmu_src/rgblimp_rkgp/native.py", body=[
        "/* Communication step: one RK4 sample of the source's integrator, s (fmu_src/rgblimp_rkgp/slave.py) */",
        f"#define STEP_SIZE {c_number(RGBlimpRKGP.STEP_SIZE)}", "",
        *variable_table(variables, "fmu_src/fmi/greybox.py, greybox_variables"),
        *greybox_config_lines(variables=variables, state_names=STATE_NAMES, input_names=INPUT_NAMES,
                              state_columns=model.state_columns, gps=model.gps,
                              propagation_step=model.propagation.step, envelope=model.envelope,
                              slave="fmu_src/rgblimp_rkgp/slave.py"), "",
        "/* Hidden state: the 12 states, their covariance, the envelope flag (rgblimp_model.c) */",
        "#define MODEL_STATE_SIZE (N_STATES + N_STATES * N_STATES + 1)", "",
        *physics_config_lines(model.params, thrust_gain=model.thrust_gain, wind=model.wind)])
