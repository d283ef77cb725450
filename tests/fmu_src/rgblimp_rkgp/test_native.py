"""The native (C, Python-free) RGBlimp RKGP FMU (fmu_src/rgblimp_rkgp/native.py).

It passes the native FMU contract (tests/fmu_src/contract.py: the FMU contract, with the check
that the Python code inside is self-contained replaced by its native counterpart, plus the
native FMU's own checks: the pythonfmu FMU's modelDescription, a plain C host given the start
state, the FMI call sequence, GUID and resources checks, pedantic C99, ``fmpy compile``) and the
RGBlimp RKGP's, with the case of the pythonfmu RGBlimp RKGP of the same model.

Then what is particular to it: a whole test flight in fmpy and in the plain C host against the
pythonfmu FMU and the Python free run, a model without wind and with added mass (the other
branches of the physics), and the C file reading every parameter of the equations.
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import replace

import numpy as np
import pytest

from fmu_src import build_native_rgblimp_rkgp_fmu
from fmu_src.rgblimp_rkgp.native import C_PARAMETERS, MODEL_SOURCE, PHYSICS_SOURCES, ZERO_IN_C, physics_config_lines
from gp_model import save_model
from tests.fmu_src.contract import NativeFmuContract, run_in_fmpy
from tests.fmu_src.rgblimp_rkgp.contract import (
    OUTPUTS,
    RGBlimpRkgpContract,
    rgblimp_reference,
    rgblimp_rkgp_case,
    start_values,
)
from validation.core.errors import BadInputError
from validation.cosim.hosts import simulate_in_c_host
from validation.models.rgblimp_greybox import RGBlimpStepDescription, fit_rkgp
from validation.models.rgblimp_identification import RGBlimpModel
from validation.vehicles.rgblimp_equations import INPUT_NAMES, SAMPLE_TIME, RGBlimpParameters


@pytest.fixture(scope="module")
def case(native_rgblimp_rkgp_fmu, rgblimp_rkgp_fmu, rgblimp_trained):
    """The case of the pythonfmu RGBlimp RKGP, with the native FMU in its place: the same inputs,
    start state, Python reference (GreyBoxGP.propagate) and tolerance."""
    return replace(rgblimp_rkgp_case(rgblimp_rkgp_fmu, rgblimp_trained), path=native_rgblimp_rkgp_fmu,
                   native_of=rgblimp_rkgp_fmu, model_source=MODEL_SOURCE)


class TestNativeRGBlimpRkgpFmu(NativeFmuContract, RGBlimpRkgpContract):
    """The native FMU contract and the RGBlimp RKGP's, on the native RGBlimp RKGP."""


def _run(path, inputs: np.ndarray, start: np.ndarray, *, c_host: bool = False) -> np.ndarray:
    """Outputs (n + 1, 24) of the FMU at ``path`` flying ``inputs`` (n + 1, 5) from ``start``, in
    fmpy or in the plain C host."""
    signals = dict(zip(INPUT_NAMES, inputs.T))
    if not c_host:
        return run_in_fmpy(path, signals, step=SAMPLE_TIME, outputs=OUTPUTS, start_values=start_values(start))
    result = simulate_in_c_host(path, step_size=SAMPLE_TIME, n_steps=len(inputs) - 1, inputs=signals,
                                outputs=OUTPUTS, start_values=start_values(start))
    assert not result["python_in_process"]
    return np.column_stack([result[name] for name in OUTPUTS])


def test_a_whole_flight_equals_the_python_free_run_in_fmpy_and_the_c_host(case, rgblimp_trained):
    """data_119 from its first recorded state (720 steps, 12 s): the native FMU in fmpy and in the
    plain C host and the pythonfmu FMU in fmpy equal GreyBoxGP.propagate's means and standard
    deviations to 1e-9 in SI units (measured 3e-14 in the means, 8e-13 in the sds); yaw is carried
    continuously past -pi, and the sds grow along the run."""
    inputs, start = rgblimp_trained["inputs"], rgblimp_trained["start"]
    expected = rgblimp_reference(rgblimp_trained, inputs, start)
    runs = {"native, fmpy": _run(case.path, inputs, start),
            "native, C host": _run(case.path, inputs, start, c_host=True),
            "pythonfmu, fmpy": _run(case.native_of, inputs, start)}
    for host, outputs in runs.items():
        np.testing.assert_allclose(outputs, expected, rtol=0, atol=1e-9, err_msg=host)
    assert expected[:, 5].min() < -np.pi  # the yaw turned past the source's wrap, carried on
    assert np.all(expected[-1, 12:] > expected[60, 12:])  # propagated sds grow


def test_a_model_without_wind_and_with_the_optional_terms_equals_the_python_free_run(rgblimp_flights, tmp_path):
    """The other branches of the physics: no wind (no change of frame, as the source's step) and
    the optional terms of the equations (added mass and inertia, thrust loss with airspeed,
    thrust line, cross-flow coefficients), one GP per state on 30 transitions; 120 steps to
    1e-9. A draught field, which the C physics leaves out, is refused with one line."""
    params = dataclasses.replace(RGBlimpParameters(), added_mass=(0.02, 0.05, 0.08), added_inertia=(1e-3, 2e-3, 3e-3),
                                 thrust_speed_loss=0.3, thrust_line_y=0.01, c_s_beta_abs=0.5, c_l_alpha_abs=-0.4,
                                 c_my_alpha_abs=0.05, c_mz_beta_abs=-0.1)
    description = RGBlimpStepDescription(RGBlimpModel(params))
    model = fit_rkgp([rgblimp_flights[118]], description.model, n_points=30)
    path = save_model(tmp_path / "still_air.npz", model, physics=description.as_dict())
    fmu = build_native_rgblimp_rkgp_fmu(path, tmp_path, name="still_air")
    test = rgblimp_flights[119].recording
    inputs, start = test.inputs[:121], test.outputs[0]
    expected = rgblimp_reference({"model": model, "description": description}, inputs, start)
    np.testing.assert_allclose(_run(fmu, inputs, start), expected, rtol=0, atol=1e-9)
    with pytest.raises(BadInputError, match="draught field .* native FMU does not compute"):
        physics_config_lines(dataclasses.replace(params, draught_gradient_y=(0.0, 0.01, 0.0)), thrust_gain=1.0,
                             wind=(0.0, 0.0))


def test_the_c_file_reads_every_parameter_of_the_equations():
    """rgblimp_physics.c (the physics of both native RGBlimp FMUs) uses every RGBlimpParameters
    field (its macro in capitals), so no parameter of the equations is left out of the native
    FMUs' physics (the build refuses to run when the fields and C_PARAMETERS differ)."""
    fields = [field.name for field in dataclasses.fields(RGBlimpParameters) if field.name not in ZERO_IN_C]
    assert sorted(fields) == sorted(C_PARAMETERS)
    source = PHYSICS_SOURCES[0].read_text(encoding="utf-8")
    assert [f for f in fields if not re.search(rf"\b{f.upper()}\b", source)] == []
