"""The JSBSim aircraft FMU (fmu_src/jsbsim_aircraft): the FMU contract on the c172x, then what is
particular to it: JSBSimVehicle step for step, steps that are whole multiples of JSBSim's, a host
without jsbsim, the ah1s in the hover, and the parameters (declared as diagnose reads them, no
change at their start values, each moving the response the way its physics says)."""
from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error
from fmpy.validation import validate_fmu

from fmu_src import build_jsbsim_fmu
from fmu_src.jsbsim_aircraft.slave import PARAMETERS
from tests.fmu_src.contract import FMI_FATAL, FmuCase, FmuContract, Host, standard_run
from validation.core.manoeuvres import doublet, three_two_one_one
from validation.vehicles.fmu_reference import FMUReference
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


def body_from_ned(phi: float, theta: float, psi: float) -> np.ndarray:
    """The rotation from north-east-down to body axes (ZYX Euler angles, rad), shape (3, 3)."""
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    return np.array([[ct * cp, ct * sp, -st],
                     [sf * st * cp - cf * sp, sf * st * sp + cf * cp, sf * ct],
                     [cf * st * cp + sf * sp, cf * st * sp - sf * cp, cf * ct]])


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
    # The hovering helicopter has the wind only (build.METHOD_PARAMETERS); heading south (psi about
    # pi) and holding attitude, it flies its script in the wind and drifts with the air: 2 m/s toward
    # the north makes most of 2 m/s backwards (body x points south; 1.76 m/s measured after the
    # script's 100 s), 2 m/s toward the east 2 m/s to its left.
    reference = FMUReference(path)
    assert {name: unit for name, (_, unit, _) in reference.parameters.items()} == {"wind_north": "m/s",
                                                                                 "wind_east": "m/s"}
    time, still_inputs = np.array([0.0, 0.01]), np.zeros((2, 4))
    still = reference.replay(time, still_inputs)[0]
    assert abs(still[8] - np.pi) < 0.01
    north = reference.replay(time, still_inputs, parameters={"wind_north": 2.0})[0] - still
    east = reference.replay(time, still_inputs, parameters={"wind_east": 2.0})[0] - still
    assert -2.0 < north[0] < -1.5 and -2.1 < east[1] < -1.9
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


# -- the parameters -------------------------------------------------------------------------------
C172X_PARAMETERS = {"wind_north": "m/s", "wind_east": "m/s", "aero_ref_shift_x": "m"}


@pytest.fixture(scope="module")
def c172x(jsbsim_fmu):
    """The c172x FMU as ``flightgp diagnose --reference`` sees and replays it."""
    return FMUReference(jsbsim_fmu)


def test_jsbsim_parameters_are_declared_for_diagnose_with_units_and_descriptions(jsbsim_fmu, c172x):
    declared = {v.name: v for v in read_model_description(str(jsbsim_fmu)).modelVariables
                if v.causality == "parameter"}
    assert {name: v.unit for name, v in declared.items()} == C172X_PARAMETERS
    for name, variable in declared.items():
        assert (variable.type, variable.variability, float(variable.start)) == ("Real", "fixed", 0.0)
        assert f"JSBSim {PARAMETERS[name][1]}" in variable.description  # the property it maps to
    # diagnose's candidates: every one, with its unit and the FMU's description (no <output>_start).
    assert {name: (start, unit) for name, (start, unit, _) in c172x.parameters.items()} == {
        name: (0.0, unit) for name, unit in C172X_PARAMETERS.items()}
    assert all(c172x.parameters[name][2] == declared[name].description for name in declared)


def test_jsbsim_parameters_at_their_start_values_are_jsbsimvehicle_bit_for_bit(c172x):
    """Set explicitly to their start values (as diagnose sets a candidate), the parameters write
    nothing to JSBSim: the replay is the vehicle's, bit for bit (see jsbsim_case), as without them."""
    n = 200
    controls = c172x_controls(np.arange(n + 1) * JSBSIM_STEP)
    outputs = c172x.replay(np.arange(n + 1) * JSBSIM_STEP, controls, parameters=dict.fromkeys(C172X_PARAMETERS, 0.0))
    np.testing.assert_array_equal(outputs, jsbsim_reference(JSBSIM_STEP, n, controls))


def test_jsbsim_wind_moves_the_ground_velocity_by_the_wind_and_leaves_the_trim(c172x):
    """A wind present from the start is trimmed in: the same flight relative to the air (heading
    east, attitude and rates as in still air) carried by the air, so the body velocities (relative
    to the ground) differ by the wind in body axes, at the start and along a pitch pulse."""
    time = np.arange(101) * 0.02
    inputs = np.zeros((len(time), 3))
    inputs[:, 0] = np.where((time >= 0.1) & (time < 0.6), 0.15, 0.0)
    still = c172x.replay(time, inputs)
    windy = c172x.replay(time, inputs, parameters={"wind_north": 3.0, "wind_east": -2.0})
    in_body = np.array([body_from_ned(*angles) @ [3.0, -2.0, 0.0] for angles in windy[:, 6:9]])
    # 0.01 m/s: JSBSim's trim stops within its tolerance (accelerations below 1e-3 ft/s^2), so the
    # trim in the wind is still air's to 0.002 m/s (measured); along the pulse the two part by at
    # most 0.006 m/s (measured) as JSBSim's wind terms (e.g. its alpha-dot from the ground-relative
    # accelerations) are not exactly those of still air.
    np.testing.assert_allclose(windy[:, :3] - still[:, :3], in_body, atol=0.01)
    assert abs(windy[0, 1] - still[0, 1] + 3.0) < 0.01 and abs(windy[0, 0] - still[0, 0] + 2.0) < 0.01  # heading east
    # 1e-3 rad/s and rad: 1 % of the pulse's peak pitch rate (0.11 rad/s), for the same reasons.
    np.testing.assert_allclose(windy[:, 3:], still[:, 3:], atol=1e-3)


def test_jsbsim_aero_ref_shift_forward_lowers_the_pitch_stability(c172x):
    """Moving the aerodynamic reference point forward is, for the aerodynamic moments, moving the
    centre of gravity aft: less static margin, so the same elevator pulse pitches the c172x further
    (the trim is found with the shift, so every run starts steady)."""
    time = np.arange(101) * 0.02
    inputs = np.zeros((len(time), 3))
    inputs[:, 0] = np.where((time >= 0.1) & (time < 0.6), 0.15, 0.0)
    peaks = []
    for shift in (-0.1, 0.0, 0.1):
        outputs = c172x.replay(time, inputs, parameters={"aero_ref_shift_x": shift})
        assert np.abs(outputs[1, 3:6]).max() < 1e-6  # steady at the start: trimmed with the shift
        peaks.append(np.abs(outputs[:, 7] - outputs[0, 7]).max())
    assert peaks[0] < peaks[1] < peaks[2]


def test_jsbsim_parameter_jsbsim_cannot_trim_with_is_a_logged_error_naming_it(jsbsim_fmu, tmp_path):
    """3 m forward puts the reference point far ahead of the neutral point: JSBSim finds no trim,
    initialisation logs an Error naming the parameter, and the steps are refused, never fatal."""
    host = Host(extract(str(jsbsim_fmu), unzipdir=str(tmp_path / "u")))
    try:
        host.set({"aero_ref_shift_x": 3.0})
        host.fmu.setupExperiment(startTime=0.0)
        host.fmu.enterInitializationMode()
        host.fmu.exitInitializationMode()
        with pytest.raises(FMICallException) as refused:
            host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=JSBSIM_STEP)
        assert refused.value.status == fmi2Discard
    finally:
        host.close()
    errors = [message for status, _, message in host.messages if status == fmi2Error]
    assert any("cannot trim c172x" in message and "aero_ref_shift_x = 3 m" in message for message in errors), errors
    assert FMI_FATAL not in host.statuses()
