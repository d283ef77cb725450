"""The JSBSim aircraft FMU (fmu_src/jsbsim_aircraft): the FMU contract on the c172x, then what is
particular to it: JSBSimVehicle step for step, steps that are whole multiples of JSBSim's, a host
without jsbsim, and the ah1s in the hover."""
from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from fmpy import extract
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error
from fmpy.validation import validate_fmu

from fmu_src import build_jsbsim_fmu
from tests.fmu_src.contract import FMI_FATAL, FmuCase, FmuContract, Host, standard_run
from validation.core.manoeuvres import doublet, three_two_one_one
from validation.vehicles.jsbsim import JSBSimVehicle

JSBSIM_STEP = JSBSimVehicle.sample_time
JSBSIM_NO_STATE = ("JSBSim's Python API cannot capture its complete internal state (integrator "
                   "histories, flight-control filters and actuators, engine), so the FMU does not "
                   "claim canGetAndSetFMUstate")


def c172x_controls(time: np.ndarray) -> np.ndarray:
    """elevator 3-2-1-1 (0.15: above the c172x elevator's 0.05 rad hysteresis), aileron doublet,
    rudder still; shape (len(time), 3), normalised perturbations from trim."""
    return np.column_stack([three_two_one_one(time, amplitude=0.15, step_time=0.5, start=0.5),
                            doublet(time, amplitude=0.1, step_time=0.5, start=2.5), np.zeros_like(time)])


def jsbsim_reference(h: float, n: int, controls: np.ndarray, aircraft: str = "c172x") -> np.ndarray:
    """JSBSimVehicle's states at ``k h``, k = 0..n, under ``controls`` (n + 1 rows) each held over
    ``h`` (``h / 0.01`` JSBSim steps of the same value)."""
    substeps = round(h / JSBSIM_STEP)
    fine = np.repeat(controls, substeps, axis=0)[: n * substeps + 1]
    recording = JSBSimVehicle(aircraft).simulate(np.arange(len(fine)) * JSBSIM_STEP, fine)
    return recording.outputs[::substeps]


@pytest.fixture(scope="module")
def case(jsbsim_fmu):
    h, n = 0.05, 80  # 5 JSBSim steps per communication step
    controls = c172x_controls(np.arange(n + 1) * h)
    names = JSBSimVehicle("c172x").input_names
    # tolerance 0: the same JSBSim library in the same process, the same recipe to the same trim,
    # the same commands (trim + perturbation in float64) written in the same order, the same
    # 0.01 s steps: JSBSim is deterministic, so the FMU reproduces JSBSimVehicle bit for bit.
    return FmuCase(path=jsbsim_fmu, step=h, n_steps=n, inputs=lambda k: dict(zip(names, controls[k])),
                   reference=lambda: (jsbsim_reference(h, n, controls), 0),
                   far_inputs={"aileron": 0.3}, bands=[], training_envelope=False, tolerance=0.0,
                   bad_inputs=[("elevator", float("nan")), ("aileron", -float("inf")),
                               ("rudder", 1.5)],  # trim -0.004 + 1.5: beyond the pedal's travel
                   no_state_reason=JSBSIM_NO_STATE, runtime_packages=frozenset({"jsbsim"}))


class TestJsbsimFmu(FmuContract):
    """The FMU contract on the c172x."""


def test_jsbsim_fmu_at_jsbsims_own_step_is_jsbsimvehicle_step_for_step(case, tmp_path):
    n = 300
    controls = c172x_controls(np.arange(n + 1) * JSBSIM_STEP)
    run = replace(case, step=JSBSIM_STEP, n_steps=n,
                  inputs=lambda k: dict(zip(JSBSimVehicle("c172x").input_names, controls[k])))
    host = Host(extract(str(case.path), unzipdir=str(tmp_path / "u")))
    try:
        outputs = standard_run(run, host)
    finally:
        host.close()
    # Bit for bit (see jsbsim_case): same library, recipe, trim, commands and steps.
    np.testing.assert_array_equal(outputs, jsbsim_reference(JSBSIM_STEP, n, controls))
    # The outputs' start values (initial="exact") are the starting condition's, found at build time.
    np.testing.assert_array_equal([float(host.variables[name].start) for name in host.outputs], outputs[0])
    # The starting condition is reported through the FMI logger (JSBSim's own messages go there
    # too: see test_runs_where_flightgp_is_not_importable_and_prints_nothing).
    assert any("c172x at its starting condition: elevator trim" in m for _, _, m in host.messages)


def test_jsbsim_step_must_be_a_whole_multiple_of_its_step(case, tmp_path):
    host = Host(extract(str(case.path), unzipdir=str(tmp_path / "u")))
    try:
        host.start(case)
        with pytest.raises(FMICallException) as refused:
            host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.015)
        assert refused.value.status == fmi2Discard
        assert "not a whole multiple of JSBSim's 0.01 s step" in host.messages[-1][2]
        # The refused first step fixed nothing: 0.02 s (two JSBSim steps) is now the step.
        host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.02)
        host.fmu.doStep(currentCommunicationPoint=0.02, communicationStepSize=0.02)
    finally:
        host.close()
    assert FMI_FATAL not in host.statuses()


def test_jsbsim_fmu_in_a_host_without_jsbsim_says_what_to_install(case):
    """Initialisation fails with a logged Error naming the package; the steps are refused
    (fmi2Discard, which fmpy's simulate_fmu takes as the end of the run), never fmi2Fatal."""
    script = (
        "import json, sys\n"
        "sys.modules['jsbsim'] = None\n"
        "from fmpy import simulate_fmu\n"
        "messages = []\n"
        "def logger(environment, instance, status, category, message):\n"
        "    messages.append((status, message.decode()))\n"
        f"simulate_fmu({str(case.path)!r}, stop_time=0.1, debug_logging=True, logger=logger)\n"
        "print(json.dumps(messages))\n")
    completed = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert completed.returncode == 0, completed.stderr
    messages = json.loads(completed.stdout)
    assert messages[0][0] == fmi2Error and "install the jsbsim package" in messages[0][1]
    assert "refused (fmi2Discard)" in messages[-1][1]
    assert FMI_FATAL not in {status for status, _ in messages}


def test_jsbsim_ah1s_fmu_hovers_and_responds_like_the_vehicle(tmp_path):
    path = build_jsbsim_fmu("ah1s", tmp_path)
    assert validate_fmu(str(path)) == []
    names = JSBSimVehicle("ah1s").input_names
    h, n = 0.02, 100
    controls = np.zeros((n + 1, len(names)))
    controls[:, names.index("longitudinal_cyclic")] = doublet(np.arange(n + 1) * h, amplitude=0.05,
                                                              step_time=0.3, start=0.2)
    case = FmuCase(path=path, step=h, n_steps=n, inputs=lambda k: dict(zip(names, controls[k])),
                   reference=None, far_inputs={}, bands=[], bad_inputs=[])
    host = Host(extract(str(path), unzipdir=str(tmp_path / "u")))
    try:
        np.testing.assert_array_equal(standard_run(case, host), jsbsim_reference(h, n, controls, "ah1s"))
        # The collective rests near 0.6 in the hover; +0.5 would push it past its travel (0..1).
        host.set({"collective": 0.5})
        with pytest.raises(FMICallException) as refused:
            host.fmu.doStep(currentCommunicationPoint=n * h, communicationStepSize=h)
        assert refused.value.status == fmi2Discard
        assert "outside its travel 0..1" in host.messages[-1][2]
    finally:
        host.close()
