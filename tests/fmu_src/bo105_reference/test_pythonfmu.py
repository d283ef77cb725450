"""The Bo105 physics reference FMU (fmu_src/bo105_reference): the FMU contract on Padfield's 80 kt
model, then what is particular to it: the host's step and a given start state, and changed
derivatives."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu

from fmu_src import build_bo105_reference_fmu
from tests.fmu_src.contract import FmuCase, FmuContract, Host, standard_run
from validation.core.manoeuvres import doublet, step, three_two_one_one
from validation.vehicles.bo105 import INPUT_NAMES as BO105_INPUTS
from validation.vehicles.bo105 import STATE_NAMES as BO105_STATES
from validation.vehicles.bo105 import Bo105Reference


def bo105_controls(time: np.ndarray) -> np.ndarray:
    """All four Bo105 controls moving, shape (len(time), 4), rad: a 1 deg theta_1s 3-2-1-1, then a
    theta_1c doublet, a theta_0 step and a theta_0T doublet."""
    deg = np.radians(1.0)
    columns = {"theta_0": step(time, amplitude=0.5 * deg, start=5.0),
               "theta_1s": three_two_one_one(time, amplitude=deg, step_time=0.4, start=1.0),
               "theta_1c": doublet(time, amplitude=0.5 * deg, step_time=0.5, start=4.0),
               "theta_0T": doublet(time, amplitude=deg, step_time=0.5, start=6.0)}
    return np.column_stack([columns[name] for name in BO105_INPUTS])


@pytest.fixture(scope="module")
def case(bo105_reference_fmu, bo105_speed_kt):
    h, n = 0.05, 160
    time = np.arange(n + 1) * h
    controls = bo105_controls(time)

    def reference():
        return Bo105Reference(bo105_speed_kt).simulate_states(time, controls), 0

    # tolerance 1e-9, the contract's: the FMU runs the reference's own discretisation (a copy of
    # validation.vehicles.linear_discretisation), so only the order of the step products differs.
    return FmuCase(path=bo105_reference_fmu, step=h, n_steps=n, inputs=lambda k: dict(zip(BO105_INPUTS, controls[k])),
                   reference=reference, far_inputs={"theta_1s": 0.05},  # a steady 3 deg of cyclic
                   bands=[], training_envelope=False,
                   bad_inputs=[("theta_1s", float("nan")), ("theta_0T", float("inf")),
                               ("theta_1c", 0.6)])  # beyond the declared 0.5 rad


class TestBo105ReferenceFmu(FmuContract):
    """The FMU contract on the Bo105 reference."""


def test_bo105_reference_starts_at_the_given_state_and_follows_the_hosts_step(case, bo105_speed_kt, tmp_path):
    """The host picks the step (here 0.01 s, then after a reset 0.1 s); the first step fixes it and
    the FMU discretises exactly for it: Bo105Reference.simulate_states from the same start state."""
    start = dict(zip(BO105_STATES, [1.0, -0.5, 0.02, 0.01, 0.3, -0.03, 0.02, 0.01]))
    host = Host(extract(str(case.path), unzipdir=str(tmp_path / "u")))
    try:
        for h in (0.01, 0.1):
            n = round(6.0 / h)
            time = np.arange(n + 1) * h
            controls = bo105_controls(time)
            run = replace(case, step=h, n_steps=n,
                          inputs=lambda k: dict(zip(BO105_INPUTS, controls[k])),  # noqa: B023
                          parameters={f"{name}_start": value for name, value in start.items()})
            outputs = standard_run(run, host)
            np.testing.assert_array_equal(outputs[0], list(start.values()))
            expected = Bo105Reference(bo105_speed_kt).simulate_states(time, controls,
                                                                      initial_state=list(start.values()))
            # 1e-9 as the contract: the same discretisation code, products in another order.
            np.testing.assert_allclose(outputs, expected, rtol=0, atol=1e-9)
            host.fmu.reset()
    finally:
        host.close()
    assert host.statuses() == {0}


def test_bo105_reference_with_changed_derivatives_runs_the_corrected_model(case, bo105_speed_kt, tmp_path):
    corrections = {"M_q": -2.4, "L_q": -3.35}
    path = build_bo105_reference_fmu(bo105_speed_kt, tmp_path, name="bo105_corrected",
                                     derivatives=corrections)
    assert "M_q = -2.4" in read_model_description(str(path)).description
    corrected = replace(case, path=path)
    result = simulate_fmu(str(path), input=corrected.signal(), stop_time=corrected.n_steps * corrected.step,
                          step_size=corrected.step, output_interval=corrected.step)
    time = np.arange(corrected.n_steps + 1) * corrected.step  # the grid the case's inputs are on
    np.testing.assert_allclose(result["time"], time, rtol=0, atol=1e-12)
    expected = (Bo105Reference(bo105_speed_kt).with_derivatives(corrections)
                .simulate_states(time, bo105_controls(time)))
    np.testing.assert_allclose(np.column_stack([result[name] for name in BO105_STATES]), expected,
                               rtol=0, atol=1e-9)
    assert np.abs(expected - case.reference()[0]).max() > 1e-2  # the corrections matter


def test_every_derivative_is_a_parameter_that_changes_the_model(case, bo105_speed_kt):
    """The 72 derivatives are fixed parameters named as flightgp names them, with the model's
    values, units and words; set before initialisation, they run the model with those entries
    replaced, as Bo105Reference.with_derivatives (so diagnosing through the FMU can correct what
    the built-in reference corrects)."""
    reference = Bo105Reference(bo105_speed_kt)
    variables = {v.name: v for v in read_model_description(str(case.path)).modelVariables}
    names = reference.derivative_names()
    assert len(names) == 72 and all(variables[n].causality == "parameter" for n in names)
    assert all(float(variables[n].start) == reference.derivative(n) for n in names)
    assert (variables["M_q"].unit, variables["M_theta_1s"].unit, variables["X_q"].unit) == ("1/s", "1/s2", "m/(s.rad)")
    assert variables["M_q"].description.startswith("pitch damping")
    corrections = {"M_q": -2.4, "L_theta_1c": 0.8 * reference.derivative("L_theta_1c")}
    result = simulate_fmu(str(case.path), input=case.signal(), stop_time=case.n_steps * case.step,
                          step_size=case.step, output_interval=case.step, start_values=corrections)
    time = np.arange(case.n_steps + 1) * case.step
    expected = reference.with_derivatives(corrections).simulate_states(time, bo105_controls(time))
    np.testing.assert_allclose(np.column_stack([result[name] for name in BO105_STATES]), expected,
                               rtol=0, atol=1e-9)
    assert np.abs(expected - case.reference()[0]).max() > 1e-2  # the corrections matter
