"""FMUs: a contract every flightgp FMU passes, then what is particular to each.

The contract (issue 5, DESIGN.md "FMU rules") is written once against :class:`FmuCase`; an FMU
joins it by adding a factory to ``FACTORIES`` that says how to drive it (GPyTorch-style shared
contract tests, STYLE.md). Each FMU is built once per module (a module fixture per FMU).

Hosts: fmpy's ``simulate_fmu`` and, for fine control, fmpy's ``FMU2Slave`` driven call by call
(:class:`Host`), with the FMU's log messages captured through the FMI logger callback; and the
second host, libcosim (:func:`validation.cosim.hosts.simulate_in_libcosim`).
"""
from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
import zipfile
from collections.abc import Callable
from ctypes import byref
from dataclasses import dataclass, field, replace
from pathlib import Path
from statistics import NormalDist

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2Discard,
    fmi2Error,
    fmi2Warning,
)
from fmpy.logging import addLoggerProxy
from fmpy.validation import validate_fmu
from pythonfmu.enums import Fmi2Status

from fmu_src._base import FlightgpSlave, ModelFailure, Variable
from fmu_src.builder import build_blimp_rkgp_fmu, build_bo105_reference_fmu, build_jsbsim_fmu, build_rate_predictor_fmu
from gp_model import GreyBoxGP, save_model
from validation.cli import main
from validation.core.manoeuvres import doublet, step, three_two_one_one
from validation.cosim.hosts import simulate_in_libcosim
from validation.models.blimp_identification import blimp_physics_description, physics_step, recording_arrays
from validation.models.narx import NarxConfig, one_step, save_trained, train_narx
from validation.reproduce.bo105 import PAPER_CONFIG, fly_3211
from validation.vehicles.blimp import INPUT_NAMES as BLIMP_INPUTS
from validation.vehicles.blimp import STATE_NAMES as BLIMP_STATES
from validation.vehicles.blimp import BlimpParameters
from validation.vehicles.blimp_flight import BlimpFlightTest
from validation.vehicles.bo105 import INPUT_NAMES as BO105_INPUTS
from validation.vehicles.bo105 import STATE_NAMES as BO105_STATES
from validation.vehicles.bo105 import Bo105Reference
from validation.vehicles.jsbsim import JSBSimVehicle

FMI_FATAL = 4


# -- the contract's view of an FMU ------------------------------------------------------------
@dataclass
class FmuCase:
    """A built FMU and how to exercise it.

    Attributes
    ----------
    path : Path
        The ``.fmu`` file.
    step : float
        Communication step the FMU requires, s.
    n_steps : int
        Steps of the standard run.
    inputs : callable
        ``inputs(k)`` -> {name: value} the host sets at ``t_k`` in the standard run (inside the
        training envelope).
    reference : callable
        ``reference()`` -> (expected, first): the Python model's values of every output at every
        communication point of the standard run, shape (n_steps + 1, n_outputs), and the first row
        the FMU must match (earlier rows depend on how the FMU starts).
    far_inputs : dict
        Inputs far from the standard run's (outside the training envelope, if the FMU has one)
        but inside their declared min/max.
    bands : list of (lower, upper)
        Output pairs whose width must grow outside the envelope.
    spreads : list of str
        Standard-deviation outputs that must grow outside the envelope.
    bad_inputs : list of (name, value)
        Values the FMU must refuse with a logged Error and fmi2Discard.
    parameters : dict
        Parameter values set before initialisation.
    tolerance : float
        Largest absolute difference allowed between the FMU's outputs and the Python model's
        (the factory says why).
    training_envelope : bool
        False for physics FMUs, which have no training envelope.
    no_state_reason : str or None
        Why the FMU does not claim canGetAndSetFMUstate (None: it does, and must save completely).
    runtime_packages : frozenset of str
        Packages besides numpy and pythonfmu the FMU imports at run time (the host needs them).
    """

    path: Path
    step: float
    n_steps: int
    inputs: Callable[[int], dict]
    reference: Callable[[], tuple]
    far_inputs: dict
    bands: list
    bad_inputs: list
    parameters: dict = field(default_factory=dict)
    spreads: list = field(default_factory=list)
    tolerance: float = 1e-9
    training_envelope: bool = True
    no_state_reason: str | None = None
    runtime_packages: frozenset = frozenset()

    def signal(self) -> np.ndarray:
        """The standard run's inputs as an fmpy input signal."""
        rows = [self.inputs(k) for k in range(self.n_steps + 1)]
        names = list(rows[0])
        signal = np.zeros(len(rows), dtype=[("time", float)] + [(n, float) for n in names])
        signal["time"] = np.arange(len(rows)) * self.step
        for name in names:
            signal[name] = [row[name] for row in rows]
        return signal


class Host:
    """One FMU instance driven by FMI 2.0 calls (fmpy), collecting its log messages."""

    def __init__(self, unzipdir: str, *, name: str = "instance", logging: bool = True) -> None:
        description = read_model_description(unzipdir)
        self.variables = {v.name: v for v in description.modelVariables}
        self.outputs = [v.name for v in description.modelVariables if v.causality == "output"]
        self.messages = []  # (status, category, message)
        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = fmi2CallbackLoggerTYPE(self._log)
        self.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(lambda n, size: None)
        self.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(lambda pointer: None)
        addLoggerProxy(byref(self.callbacks))  # formats the printf-style message, as simulate_fmu
        self.fmu = FMU2Slave(guid=description.guid, unzipDirectory=unzipdir, instanceName=name,
                             modelIdentifier=description.coSimulation.modelIdentifier)
        self.fmu.instantiate(callbacks=self.callbacks, loggingOn=logging)

    def _log(self, environment, instance, status, category, message):
        self.messages.append((status, (category or b"").decode(), message.decode()))

    def set(self, values: dict) -> None:
        for name, value in values.items():
            variable = self.variables[name]
            if variable.type == "Boolean":
                self.fmu.setBoolean([variable.valueReference], [bool(value)])
            else:
                self.fmu.setReal([variable.valueReference], [float(value)])

    def get(self) -> np.ndarray:
        return np.array(self.fmu.getReal([self.variables[n].valueReference for n in self.outputs]))

    def start(self, case: FmuCase, inputs: dict | None = None) -> np.ndarray:
        self.set(case.parameters)
        self.set(case.inputs(0) if inputs is None else inputs)
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        return self.get()

    def step(self, case: FmuCase, k: int, inputs: dict | None = None) -> np.ndarray:
        self.set(case.inputs(k) if inputs is None else inputs)
        self.fmu.doStep(currentCommunicationPoint=k * case.step, communicationStepSize=case.step)
        return self.get()

    def run(self, case: FmuCase, first: int = 0, last: int | None = None, inputs=None) -> np.ndarray:
        """Steps ``first .. last - 1``: outputs after each, shape (last - first, n_outputs)."""
        inputs = case.inputs if inputs is None else inputs
        last = case.n_steps if last is None else last
        return np.array([self.step(case, k, inputs(k)) for k in range(first, last)])

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()

    def statuses(self) -> set:
        return {status for status, _, _ in self.messages}


# -- the Bo105 GP-NARX rate predictor ------------------------------------------------------------
@pytest.fixture(scope="module")
def bo105_flights():
    """The paper's 3-2-1-1 (training) and an unseen one, Bo105 80 kt flight-test stand-in."""
    fly = lambda seed, amplitude, step_time: fly_3211(  # noqa: E731
        "bo105-80kt-flight", input_name="theta_1s", amplitude=np.radians(amplitude),
        step_time=step_time, start=1.0, duration=8.0, seed=seed)
    return {"training": fly(0, 1.0, 0.4), "unseen": fly(1, 1.3, 0.3)}


@pytest.fixture(scope="module")
def bo105_trained(bo105_flights):
    """The paper's configuration: 32 training points, annealing with 400 hyperparameter samples
    (about 2 s), so the FMU's mixture over samples is exercised as in production."""
    return train_narx([bo105_flights["training"]], PAPER_CONFIG, seed=0)


@pytest.fixture(scope="module")
def bo105_model_file(tmp_path_factory, bo105_trained):
    return save_trained(tmp_path_factory.mktemp("model") / "bo105_gp_narx.npz", bo105_trained)


@pytest.fixture(scope="module")
def rate_predictor_fmu(bo105_model_file, tmp_path_factory):
    return build_rate_predictor_fmu(bo105_model_file, tmp_path_factory.mktemp("fmu"),
                                    name="bo105_rate_predictor")


def rate_predictor_case(request) -> FmuCase:
    trained = request.getfixturevalue("bo105_trained")
    recording = request.getfixturevalue("bo105_flights")["training"]  # inside the envelope
    path = request.getfixturevalue("rate_predictor_fmu")
    rows = slice(None, None, trained.config.decimation)
    controls = {n: recording.input(n)[rows] for n in trained.config.inputs}
    rates = {n: recording.output(n)[rows] for n in trained.config.outputs}
    n = len(recording.time[rows])

    def inputs(k):
        return {**{n: v[k] for n, v in controls.items()}, **{f"{n}_prev": v[k] for n, v in rates.items()}}

    def reference():
        prediction = one_step(trained, recording)
        z = NormalDist().inv_cdf(0.975)  # confidence_level 0.95
        columns = []
        for j in range(len(trained.config.outputs)):
            mean, sd = prediction.mean[:, j], np.sqrt(prediction.var[:, j])
            columns += [mean, mean - z * sd, mean + z * sd]
        return np.column_stack(columns), prediction.first

    # tolerance 1e-9 rad/s: the FMU evaluates the same formulas as GaussianProcess.predict in a
    # different order (rounding of order 1e-16 relative), far below any physical meaning.
    return FmuCase(path=path, step=trained.step, n_steps=n - 1, inputs=inputs, reference=reference,
                   far_inputs={"theta_1s": 0.3},  # 17 deg of cyclic; trained on +/-1 deg
                   bands=[(f"{a}_lower", f"{a}_upper") for a in trained.config.outputs],
                   bad_inputs=[("theta_1s", float("nan")), ("q_prev", float("inf")),
                               ("theta_1s", 0.6)])  # beyond the declared 0.5 rad


# -- the Bo105 physics reference -------------------------------------------------------------------
BO105_SPEED_KT = 80


@pytest.fixture(scope="module")
def bo105_reference_fmu(tmp_path_factory):
    return build_bo105_reference_fmu(BO105_SPEED_KT, tmp_path_factory.mktemp("fmu"))


def bo105_controls(time: np.ndarray) -> np.ndarray:
    """All four Bo105 controls moving, shape (len(time), 4), rad: a 1 deg theta_1s 3-2-1-1, then a
    theta_1c doublet, a theta_0 step and a theta_0T doublet."""
    deg = np.radians(1.0)
    columns = {"theta_0": step(time, amplitude=0.5 * deg, start=5.0),
               "theta_1s": three_two_one_one(time, amplitude=deg, step_time=0.4, start=1.0),
               "theta_1c": doublet(time, amplitude=0.5 * deg, step_time=0.5, start=4.0),
               "theta_0T": doublet(time, amplitude=deg, step_time=0.5, start=6.0)}
    return np.column_stack([columns[name] for name in BO105_INPUTS])


def bo105_reference_case(request) -> FmuCase:
    path = request.getfixturevalue("bo105_reference_fmu")
    h, n = 0.05, 160
    time = np.arange(n + 1) * h
    controls = bo105_controls(time)

    def reference():
        return Bo105Reference(BO105_SPEED_KT).simulate_states(time, controls), 0

    # tolerance 1e-9: the FMU's numpy Pade expm and scipy's differ by rounding (1e-15 relative);
    # measured 1e-16 over the run.
    return FmuCase(path=path, step=h, n_steps=n, inputs=lambda k: dict(zip(BO105_INPUTS, controls[k])),
                   reference=reference, far_inputs={"theta_1s": 0.05},  # a steady 3 deg of cyclic
                   bands=[], training_envelope=False,
                   bad_inputs=[("theta_1s", float("nan")), ("theta_0T", float("inf")),
                               ("theta_1c", 0.6)])  # beyond the declared 0.5 rad


# -- JSBSim's c172x ---------------------------------------------------------------------------------
JSBSIM_STEP = JSBSimVehicle.sample_time
JSBSIM_NO_STATE = ("JSBSim's Python API cannot capture its complete internal state (integrator "
                   "histories, flight-control filters and actuators, engine), so the FMU does not "
                   "claim canGetAndSetFMUstate")


@pytest.fixture(scope="module")
def jsbsim_fmu(tmp_path_factory):
    return build_jsbsim_fmu("c172x", tmp_path_factory.mktemp("fmu"))


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


def jsbsim_case(request) -> FmuCase:
    path = request.getfixturevalue("jsbsim_fmu")
    h, n = 0.05, 80  # 5 JSBSim steps per communication step
    controls = c172x_controls(np.arange(n + 1) * h)
    names = JSBSimVehicle("c172x").input_names
    # tolerance 0: the same JSBSim library in the same process, the same recipe to the same trim,
    # the same commands (trim + perturbation in float64) written in the same order, the same
    # 0.01 s steps: JSBSim is deterministic, so the FMU reproduces JSBSimVehicle bit for bit.
    return FmuCase(path=path, step=h, n_steps=n, inputs=lambda k: dict(zip(names, controls[k])),
                   reference=lambda: (jsbsim_reference(h, n, controls), 0),
                   far_inputs={"aileron": 0.3}, bands=[], training_envelope=False, tolerance=0.0,
                   bad_inputs=[("elevator", float("nan")), ("aileron", -float("inf")),
                               ("rudder", 1.5)],  # trim -0.004 + 1.5: beyond the pedal's travel
                   no_state_reason=JSBSIM_NO_STATE, runtime_packages=frozenset({"jsbsim"}))


# -- the blimp RKGP (RK4 physics plus GP residual) ----------------------------------------------------
BLIMP_HOLD = 10  # frames each random command level is held (0.5 s at 20 Hz)


@pytest.fixture(scope="module")
def blimp_trained():
    """10 s of blimp-flight under random piecewise-constant commands (many levels, so maximum
    likelihood finds no degenerate length scale for a command seen at two or three values), and a
    shared-GP RKGP on the reference's RK4 physics, leaving out position and yaw (Ko et al.):
    200 training pairs, about 1 s. Motion capture is off (true states, frames every 0.05 s): on
    the differentiated, noisy mocap velocities the maximum-likelihood GP interpolates the noise
    (noise variance at its lower bound) and its variance is at the prior's along any free run,
    so there would be nothing to widen outside the envelope. The other blimp-flight effects
    (motor lag, dead band, tail asymmetry, CG offset, buoyancy drift) are the residual it learns."""
    time = np.arange(201) * BlimpFlightTest.sample_time
    rng = np.random.default_rng(0)
    levels = lambda low, high: np.repeat(rng.uniform(low, high, 21), BLIMP_HOLD)[:len(time)]  # noqa: E731
    commands = np.column_stack([levels(0.2, 0.8), levels(-0.2, 0.4), levels(-0.6, 0.6)])
    states, inputs = recording_arrays(BlimpFlightTest(mocap=False).simulate(time, commands, seed=0))
    params = BlimpParameters()
    model = GreyBoxGP(state_columns=(3, 4, 6, 7, 8, 9, 10, 11), n_restarts=0).fit_trajectories(
        [(states, inputs)], physics_step(params))
    return {"model": model, "params": params, "states": states, "commands": commands}


@pytest.fixture(scope="module")
def blimp_model_file(tmp_path_factory, blimp_trained):
    return save_model(tmp_path_factory.mktemp("model") / "blimp_rkgp.npz", blimp_trained["model"],
                      physics=blimp_physics_description(blimp_trained["params"]))


@pytest.fixture(scope="module")
def blimp_rkgp_fmu(blimp_model_file, tmp_path_factory):
    return build_blimp_rkgp_fmu(blimp_model_file, tmp_path_factory.mktemp("fmu"))


def blimp_rkgp_case(request) -> FmuCase:
    trained = request.getfixturevalue("blimp_trained")
    path = request.getfixturevalue("blimp_rkgp_fmu")
    h, n = BlimpFlightTest.sample_time, 80  # the training commands' first 4 s: inside the envelope
    commands, start = trained["commands"], trained["states"][0]

    def reference():
        physics = physics_step(trained["params"])
        steps = np.column_stack([commands[:n], np.full(n, h)])  # dt column = the FMU's step
        mean = trained["model"].rollout(start, steps, physics)
        _, var = trained["model"].predict_one_step(mean[:-1], steps, physics)
        return np.hstack([mean, np.vstack([np.zeros(12), np.sqrt(var)])]), 0

    # tolerance 1e-9: the same formulas as GreyBoxGP.rollout and GaussianProcess.predict evaluated
    # for one state instead of a batch (different rounding, ~1e-16 relative per step, grown by the
    # dynamics over 80 steps; measured 4e-11 on the states, 2e-11 on the sds).
    return FmuCase(path=path, step=h, n_steps=n, inputs=lambda k: dict(zip(BLIMP_INPUTS, commands[k])),
                   reference=reference, parameters={f"{s}_start": v for s, v in zip(BLIMP_STATES, start)},
                   far_inputs={"u_gondola": -1.0, "mu": 1.5},  # trained on 0.2 .. 0.8 and -0.2 .. 0.4
                   bands=[], spreads=[f"{s}_sd" for s in ("U", "V", "W", "P", "Q", "R")],
                   bad_inputs=[("u_gondola", float("nan")), ("mu", float("inf")),
                               ("u_tail", 1.5)])  # beyond the declared -1 .. 1


#: Every FMU the contract covers: name -> factory(request) -> FmuCase.
FACTORIES = {"bo105_rate_predictor": rate_predictor_case, "bo105_80kt_reference": bo105_reference_case,
             "jsbsim_c172x": jsbsim_case, "blimp_rkgp": blimp_rkgp_case}


@pytest.fixture(scope="module", params=list(FACTORIES))
def case(request) -> FmuCase:
    return FACTORIES[request.param](request)


@pytest.fixture(scope="module")
def unzipdir(case, tmp_path_factory):
    return extract(str(case.path), unzipdir=str(tmp_path_factory.mktemp("unzipped")))


@pytest.fixture
def host(unzipdir):
    instance = Host(unzipdir)
    yield instance
    instance.close()


def standard_run(case: FmuCase, host: Host) -> np.ndarray:
    """Outputs at every communication point of the standard run, shape (n_steps + 1, n_outputs)."""
    return np.vstack([host.start(case), host.run(case)])


# -- the contract ---------------------------------------------------------------------------------
def test_validates_without_problems(case):
    assert validate_fmu(str(case.path)) == []


def test_runtime_is_self_contained(case):
    """Inside the FMU, Python code imports only the standard library, numpy, pythonfmu and the
    FMU's own uniquely named modules: never flightgp's packages, which a host does not have."""
    allowed = set(sys.stdlib_module_names) | {"numpy", "pythonfmu"} | case.runtime_packages
    with zipfile.ZipFile(case.path) as archive:
        sources = {name: archive.read(name).decode() for name in archive.namelist()
                   if name.endswith(".py") and not name.startswith("resources/pythonfmu/")}
    own = {Path(name).parts[1].removesuffix(".py") for name in sources}
    # Module names unique to the FMU: <model identifier>_<content hash>[_lib] (a Python host
    # shares sys.modules with every FMU it loads).
    identifier = read_model_description(str(case.path)).coSimulation.modelIdentifier
    assert own and all(re.fullmatch(rf"{identifier}_[0-9a-f]{{8}}(_lib)?", module) for module in own), own
    for name, source in sources.items():
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.Import):
                roots = {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                roots = {node.module.split(".")[0]}
            else:
                continue
            assert roots <= allowed | own, f"{name} imports {roots - allowed - own}"


def test_simulate_fmu_runs_with_finite_outputs(case, host):
    result = simulate_fmu(str(case.path), input=case.signal(), start_values=case.parameters,
                          stop_time=case.n_steps * case.step, step_size=case.step,
                          output_interval=case.step)
    outputs = host.outputs
    assert len(result) == case.n_steps + 1
    values = np.column_stack([result[name] for name in outputs])
    assert np.all(np.isfinite(values))
    # simulate_fmu follows the same sampling convention as the call-by-call host.
    np.testing.assert_array_equal(values, standard_run(case, host))


def test_outputs_equal_the_python_model(case, host):
    expected, first = case.reference()
    outputs = standard_run(case, host)
    np.testing.assert_allclose(outputs[first:], expected[first:], rtol=0, atol=case.tolerance)
    assert host.statuses() <= {0, fmi2Warning}


def test_reset_reproduces_a_run(case, host):
    first = standard_run(case, host)
    host.fmu.reset()
    np.testing.assert_array_equal(standard_run(case, host), first)


def test_state_capability_is_declared_honestly(case, unzipdir, host):
    """canGetAndSetFMUstate and canSerializeFMUstate are claimed exactly when the FMU can save its
    complete state; an FMU that cannot refuses a save or restore with a logged Error, and the next
    step with fmi2Discard, never fmi2Fatal."""
    capabilities = read_model_description(unzipdir).coSimulation
    claims = case.no_state_reason is None
    assert capabilities.canGetAndSetFMUstate == capabilities.canSerializeFMUstate == claims
    if claims:
        return
    host.start(case)
    host.run(case, 0, 2)
    state = host.fmu.getFMUstate()
    host.fmu.setFMUstate(state)
    errors = [message for status, _, message in host.messages if status == fmi2Error]
    assert any("cannot save" in m for m in errors) and any("cannot restore" in m for m in errors), errors
    with pytest.raises(FMICallException) as refused:
        host.fmu.doStep(currentCommunicationPoint=2 * case.step, communicationStepSize=case.step)
    assert refused.value.status == fmi2Discard
    assert FMI_FATAL not in host.statuses()


def test_state_save_step_restore_step_is_identical(case, unzipdir, host):
    if case.no_state_reason:
        pytest.skip(case.no_state_reason)
    half = case.n_steps // 2
    host.start(case)
    host.run(case, 0, half)
    state = host.fmu.getFMUstate()
    after_save = host.run(case, half)
    host.fmu.setFMUstate(state)
    np.testing.assert_array_equal(host.run(case, half), after_save)
    # The same state, serialised and read back (canSerializeFMUstate), restores it too.
    copy = host.fmu.deSerializeFMUstate(host.fmu.serializeFMUstate(state))
    host.fmu.setFMUstate(copy)
    np.testing.assert_array_equal(host.run(case, half), after_save)
    # ... also into a fresh instance of the FMU, as a state saved to disk would be.
    fresh = Host(unzipdir, name="fresh")
    try:
        restored = fresh.fmu.deSerializeFMUstate(host.fmu.serializeFMUstate(state))
        fresh.fmu.setFMUstate(restored)
        np.testing.assert_array_equal(fresh.run(case, half), after_save)
        assert fmi2Error not in fresh.statuses()
        fresh.fmu.freeFMUstate(restored)
    finally:
        fresh.close()
    host.fmu.freeFMUstate(state)
    host.fmu.freeFMUstate(copy)
    assert fmi2Error not in host.statuses()  # an incomplete state logs an Error when saved


def test_two_instances_in_one_process_stay_independent(case, unzipdir):
    far = lambda k: {**case.inputs(k), **case.far_inputs}  # noqa: E731

    def alone(inputs, name):
        host = Host(unzipdir, name=name)
        try:
            return np.vstack([host.start(case, inputs(0)), host.run(case, inputs=inputs)])
        finally:
            host.close()

    expected = alone(case.inputs, "alone"), alone(far, "alone_far")
    a, b = Host(unzipdir, name="a"), Host(unzipdir, name="b")
    try:
        rows_a, rows_b = [a.start(case)], [b.start(case, far(0))]
        for k in range(case.n_steps):  # interleaved, with different inputs
            rows_a.append(a.step(case, k))
            rows_b.append(b.step(case, k, far(k)))
    finally:
        a.close()
        b.close()
    np.testing.assert_array_equal(np.array(rows_a), expected[0])
    np.testing.assert_array_equal(np.array(rows_b), expected[1])
    assert np.abs(expected[0] - expected[1]).max() > 1e-3  # the two runs really differ


@pytest.mark.parametrize("bad", range(3))
def test_bad_input_is_a_logged_discard_and_the_step_can_be_retried(case, host, bad):
    name, value = case.bad_inputs[bad]
    expected = standard_run(case, host)
    host.fmu.reset()
    host.start(case)
    host.run(case, 0, 3)
    host.set({name: value})
    with pytest.raises(FMICallException) as refused:
        host.fmu.doStep(currentCommunicationPoint=3 * case.step, communicationStepSize=case.step)
    assert refused.value.status == fmi2Discard
    errors = [message for status, _, message in host.messages if status == fmi2Error]
    assert errors and name in errors[-1] and "Discard" in errors[-1], host.messages
    # The refused step changed nothing: with good inputs the run goes on as if it never happened.
    np.testing.assert_array_equal(host.run(case, 3), expected[4:])
    assert FMI_FATAL not in host.statuses()


@pytest.mark.parametrize("bad_call", ["step size", "communication point", "set an output",
                                      "unknown value reference", "fixed parameter"])
def test_illegal_calls_are_logged_discards(case, host, bad_call):
    host.start(case)
    host.run(case, 0, 2)
    t, h = 2 * case.step, case.step
    if bad_call == "step size":
        h, phrase = case.step / 2, "expected communicationStepSize"
    elif bad_call == "communication point":
        t, phrase = 3 * case.step, "expected currentCommunicationPoint"
    elif bad_call == "set an output":
        host.set({host.outputs[0]: 1.0})
        phrase = f"{host.outputs[0]} is an output"
    elif bad_call == "unknown value reference":
        host.fmu.setReal([len(host.variables) + 10], [1.0])
        phrase = "is not a Real variable"
    else:
        fixed = [v for v in host.variables.values()
                 if v.causality == "parameter" and v.variability == "fixed"]
        if not fixed:
            pytest.skip("no fixed parameter")
        host.set({fixed[0].name: not fixed[0].start if fixed[0].type == "Boolean" else 1.0})
        phrase = fixed[0].name
    with pytest.raises(FMICallException) as refused:
        host.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
    assert refused.value.status == fmi2Discard
    errors = [message for status, _, message in host.messages if status == fmi2Error]
    assert any(phrase in message for message in errors), host.messages
    assert FMI_FATAL not in host.statuses()


def test_bad_input_is_a_discard_even_without_logging(case, unzipdir):
    # pythonfmu 0.7 forwards messages only while the host enables logging; the status still
    # reaches the host.
    quiet = Host(unzipdir, name="quiet", logging=False)
    try:
        quiet.start(case)
        name, value = case.bad_inputs[0]
        quiet.set({name: value})
        with pytest.raises(FMICallException) as refused:
            quiet.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=case.step)
        assert refused.value.status == fmi2Discard
    finally:
        quiet.close()


def test_outside_the_training_envelope_warns_and_widens_the_bounds(case, host):
    if not case.training_envelope:
        pytest.skip("a physics FMU has no training envelope")
    inside = standard_run(case, host)
    host.fmu.reset()
    host.start(case)
    k = case.n_steps // 2
    host.run(case, 0, k)
    assert fmi2Warning not in host.statuses()
    outside = host.step(case, k, {**case.inputs(k), **case.far_inputs})
    warnings = [message for status, _, message in host.messages if status == fmi2Warning]
    assert warnings and "outside the training envelope" in warnings[0]
    assert all(name in warnings[0] for name in case.far_inputs)
    index = {name: i for i, name in enumerate(host.outputs)}
    for lower, upper in case.bands:
        width_inside = inside[k + 1, index[upper]] - inside[k + 1, index[lower]]
        width_outside = outside[index[upper]] - outside[index[lower]]
        assert width_outside > 1.5 * width_inside, (lower, width_inside, width_outside)
    for name in case.spreads:
        assert outside[index[name]] > 1.5 * inside[k + 1, index[name]], name
    assert FMI_FATAL not in host.statuses()


def test_runs_where_flightgp_is_not_importable_and_prints_nothing(case, tmp_path):
    """A simulator host has no flightgp: run the FMU (standard run, fmpy) in a Python where
    gp_model, validation and fmu_src cannot be imported. The FMU writes nothing to standard output
    or error (JSBSim's messages included) and no file into the working folder."""
    np.save(tmp_path / "signal.npy", case.signal())
    script = (
        "import sys\n"
        "for name in ('gp_model', 'validation', 'fmu_src'): sys.modules[name] = None\n"
        "import numpy as np\n"
        "from fmpy import simulate_fmu\n"
        f"result = simulate_fmu({str(case.path)!r}, input=np.load({str(tmp_path / 'signal.npy')!r}), "
        f"start_values={case.parameters!r}, stop_time={case.n_steps * case.step!r}, "
        f"step_size={case.step!r}, output_interval={case.step!r})\n"
        f"sys.exit(0 if len(result) == {case.n_steps + 1} and all(np.isfinite(result[n]).all() "
        "for n in result.dtype.names) else 3)\n")
    work = tmp_path / "work"
    work.mkdir()
    completed = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                               timeout=120, cwd=work)
    assert completed.returncode == 0, completed.stderr
    assert completed.stdout == "" and completed.stderr == ""
    assert list(work.iterdir()) == []


def test_second_host_libcosim_agrees_with_fmpy(case, host):
    """The same inputs in libcosim (Open Simulation Platform) and fmpy give the same outputs: every
    flightgp FMU is deterministic, so to 1e-12 (measured: identical). libcosim initialises inside
    its first step and observes the outputs after each step; the inputs at t0 are also given as
    start values, as fmpy's host sets them before initialisation."""
    expected = standard_run(case, host)[1:]
    rows = [case.inputs(k) for k in range(case.n_steps)]
    inputs = {name: np.array([row[name] for row in rows]) for name in rows[0]}
    result = simulate_in_libcosim(case.path, step_size=case.step, n_steps=case.n_steps, inputs=inputs,
                                  start_values={**case.parameters, **case.inputs(0)}, outputs=host.outputs)
    np.testing.assert_allclose(result["time"], np.arange(1, case.n_steps + 1) * case.step, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.column_stack([result[name] for name in host.outputs]), expected,
                               rtol=0, atol=1e-12)


# -- the rate predictor in particular ---------------------------------------------------------------
@pytest.fixture(scope="module")
def rate_predictor(request):
    return rate_predictor_case(request)


@pytest.fixture(scope="module")
def bo105_reference(request):
    return bo105_reference_case(request)


@pytest.fixture(scope="module")
def jsbsim_c172x(request):
    return jsbsim_case(request)


def test_rate_predictor_starts_at_the_given_rates(rate_predictor, tmp_path):
    unzipped = extract(str(rate_predictor.path), unzipdir=str(tmp_path / "u"))
    host = Host(unzipped)
    try:
        start = {**rate_predictor.inputs(0), "p_prev": 0.01, "q_prev": -0.02, "r_prev": 0.03}
        outputs = dict(zip(host.outputs, host.start(rate_predictor, start)))
    finally:
        host.close()
    for axis, value in (("p", 0.01), ("q", -0.02), ("r", 0.03)):
        assert outputs[axis] == outputs[f"{axis}_lower"] == outputs[f"{axis}_upper"] == value


def test_free_run_mode_equals_the_python_moment_matching_free_run(rate_predictor, bo105_trained,
                                                                   bo105_flights, tmp_path):
    u = bo105_flights["unseen"].input("theta_1s")[::10, None]  # partly outside the envelope
    assert len(u) == rate_predictor.n_steps + 1
    unzipped = extract(str(rate_predictor.path), unzipdir=str(tmp_path / "u"))
    host = Host(unzipped)
    free = lambda k: {"theta_1s": u[k, 0]}  # noqa: E731 - the rates are not driven
    half = rate_predictor.n_steps // 2
    try:
        host.set({"free_run": True})
        outputs = np.vstack([host.start(rate_predictor, free(0)), host.run(rate_predictor, inputs=free)])
        # The propagated belief is state: saved mid-run and restored, the run repeats exactly.
        host.fmu.reset()
        host.set({"free_run": True})
        host.start(rate_predictor, free(0))
        host.run(rate_predictor, 0, half, inputs=free)
        state = host.fmu.getFMUstate()
        host.run(rate_predictor, half, inputs=free)
        host.fmu.setFMUstate(state)
        np.testing.assert_array_equal(host.run(rate_predictor, half, inputs=free), outputs[half + 1:])
        host.fmu.freeFMUstate(state)
    finally:
        host.close()
    columns = lambda suffix: [host.outputs.index(f"{a}{suffix}") for a in "pqr"]  # noqa: E731
    means, upper = outputs[:, columns("")], outputs[:, columns("_upper")]
    # The FMU starts from rest: every lag before t0 holds the t0 values. GPNarx's moment-matching
    # free run from the same rest (inputs held at u(t0) over the first max_lag - 1 samples) predicts
    # the same rows from its sample max_lag on.
    lag = bo105_trained.model.structure.max_lag
    padded = np.vstack([np.repeat(u[:1], lag - 1, axis=0), u])
    python = bo105_trained.model.free_run(padded, np.tile(means[0], (lag, 1)), method="moment_matching")
    np.testing.assert_allclose(means[1:], python.mean[lag:], rtol=0, atol=1e-9)
    sd = (upper - means) / NormalDist().inv_cdf(0.975)
    np.testing.assert_allclose(sd[1:], np.sqrt(python.var[lag:]), rtol=0, atol=1e-9)
    # Propagated, not one-step: the band at the end of the run is wider than one step ahead.
    assert np.all(sd[-1] > 1.5 * sd[1])


def test_confidence_level_sets_the_band(rate_predictor, tmp_path):
    unzipped = extract(str(rate_predictor.path), unzipdir=str(tmp_path / "u"))
    widths = {}
    for level in (0.6827, 0.95):
        host = Host(unzipped, name=f"level{level}")
        try:
            host.set({"confidence_level": level})
            host.start(rate_predictor)
            row = dict(zip(host.outputs, host.run(rate_predictor, 0, 5)[-1]))
        finally:
            host.close()
        widths[level] = row["q_upper"] - row["q_lower"]
    z = NormalDist().inv_cdf
    assert widths[0.95] / widths[0.6827] == pytest.approx(z(0.975) / z(0.5 + 0.6827 / 2), rel=1e-12)


def test_two_fmus_of_one_name_run_their_own_models(rate_predictor, bo105_flights, tmp_path):
    """DESIGN.md: a Python host shares sys.modules with every FMU it loads. Two FMUs with the same
    name but different models get different module names, and each runs its own model."""
    other = train_narx([bo105_flights["training"]],
                       NarxConfig(hyperparameters="maximum_likelihood", stride=10), seed=0, n_restarts=0)
    other_path = build_rate_predictor_fmu(save_trained(tmp_path / "other.npz", other), tmp_path / "fmu",
                                          name="bo105_rate_predictor")
    modules = [zipfile.ZipFile(p).read("resources/slavemodule.txt").decode().strip()
               for p in (rate_predictor.path, other_path)]
    assert modules[0] != modules[1]
    runs = []
    for i, path in enumerate((rate_predictor.path, other_path)):  # both loaded into this process
        host = Host(extract(str(path), unzipdir=str(tmp_path / f"u{i}")), name=f"fmu{i}")
        try:
            runs.append(standard_run(rate_predictor, host))
        finally:
            host.close()
    assert np.abs(runs[0] - runs[1]).max() > 1e-3
    expected, first = rate_predictor.reference()
    np.testing.assert_allclose(runs[0][first:], expected[first:], rtol=0, atol=1e-9)
    q = host.outputs.index("q")
    np.testing.assert_allclose(runs[1][first:, q], one_step(other, bo105_flights["training"]).mean[first:, 1],
                               rtol=0, atol=1e-9)


# -- the base slave's policies that no built FMU triggers on demand ---------------------------------
def test_a_step_the_model_cannot_undo_stops_the_fmu_until_reset():
    """A model that cannot roll back a failed step (JSBSim inside an FMU) raises ModelFailure: that
    step and every later one are refused (fmi2Discard, logged Errors), never retried on a moved
    state. The slave is driven directly in Python, as pythonfmu's native layer would."""

    class Counter(FlightgpSlave):
        VARIABLES = (Variable("y", "output", "continuous", "exact", "1", "steps taken", 0.0),)

        def start_model(self, t0):
            self.values["y"] = 0.0

        def advance_model(self, k, t, h):
            if k == 2:
                raise ModelFailure("the simulator inside has moved on")
            self.values["y"] += 1.0

    slave = Counter(instance_name="counter")
    slave.setup_experiment(0.0)
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    assert slave.do_step(0.0, 0.1) and slave.do_step(0.1, 0.1)
    assert not slave.do_step(0.2, 0.1)
    assert not slave.do_step(0.2, 0.1)  # no retry on a state that has moved
    assert slave.values["y"] == 2.0
    errors = [m.msg for m in slave.log_queue if m.status == Fmi2Status.error]
    assert "the simulator inside has moved on" in errors[0] and "reset" in errors[0]
    assert "failed earlier" in errors[1]


# -- the Bo105 reference in particular --------------------------------------------------------------
def test_bo105_reference_starts_at_the_given_state_and_follows_the_hosts_step(bo105_reference, tmp_path):
    """The host picks the step (here 0.01 s, then after a reset 0.1 s); the first step fixes it and
    the FMU discretises exactly for it: Bo105Reference.simulate_states from the same start state."""
    start = dict(zip(BO105_STATES, [1.0, -0.5, 0.02, 0.01, 0.3, -0.03, 0.02, 0.01]))
    host = Host(extract(str(bo105_reference.path), unzipdir=str(tmp_path / "u")))
    try:
        for h in (0.01, 0.1):
            n = round(6.0 / h)
            time = np.arange(n + 1) * h
            controls = bo105_controls(time)
            run = replace(bo105_reference, step=h, n_steps=n,
                          inputs=lambda k: dict(zip(BO105_INPUTS, controls[k])),  # noqa: B023
                          parameters={f"{name}_start": value for name, value in start.items()})
            outputs = standard_run(run, host)
            np.testing.assert_array_equal(outputs[0], list(start.values()))
            expected = Bo105Reference(BO105_SPEED_KT).simulate_states(time, controls,
                                                                      initial_state=list(start.values()))
            # 1e-9 as the contract: expm implementations differ by rounding only (measured 1e-13).
            np.testing.assert_allclose(outputs, expected, rtol=0, atol=1e-9)
            host.fmu.reset()
    finally:
        host.close()
    assert host.statuses() == {0}


def test_bo105_reference_with_changed_derivatives_runs_the_corrected_model(bo105_reference, tmp_path):
    corrections = {"M_q": -2.4, "L_q": -3.35}
    path = build_bo105_reference_fmu(BO105_SPEED_KT, tmp_path, name="bo105_corrected",
                                     derivatives=corrections)
    assert "M_q = -2.4" in read_model_description(str(path)).description
    corrected = replace(bo105_reference, path=path)
    result = simulate_fmu(str(path), input=corrected.signal(), stop_time=corrected.n_steps * corrected.step,
                          step_size=corrected.step, output_interval=corrected.step)
    time = np.arange(corrected.n_steps + 1) * corrected.step  # the grid the case's inputs are on
    np.testing.assert_allclose(result["time"], time, rtol=0, atol=1e-12)
    expected = (Bo105Reference(BO105_SPEED_KT).with_derivatives(corrections)
                .simulate_states(time, bo105_controls(time)))
    np.testing.assert_allclose(np.column_stack([result[name] for name in BO105_STATES]), expected,
                               rtol=0, atol=1e-9)
    assert np.abs(expected - bo105_reference.reference()[0]).max() > 1e-2  # the corrections matter


# -- the JSBSim FMU in particular --------------------------------------------------------------------
def test_jsbsim_fmu_at_jsbsims_own_step_is_jsbsimvehicle_step_for_step(jsbsim_c172x, tmp_path):
    n = 300
    controls = c172x_controls(np.arange(n + 1) * JSBSIM_STEP)
    run = replace(jsbsim_c172x, step=JSBSIM_STEP, n_steps=n,
                  inputs=lambda k: dict(zip(JSBSimVehicle("c172x").input_names, controls[k])))
    host = Host(extract(str(jsbsim_c172x.path), unzipdir=str(tmp_path / "u")))
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


def test_jsbsim_step_must_be_a_whole_multiple_of_its_step(jsbsim_c172x, tmp_path):
    host = Host(extract(str(jsbsim_c172x.path), unzipdir=str(tmp_path / "u")))
    try:
        host.start(jsbsim_c172x)
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


def test_jsbsim_fmu_in_a_host_without_jsbsim_says_what_to_install(jsbsim_c172x):
    """Initialisation fails with a logged Error naming the package; the steps are refused
    (fmi2Discard, which fmpy's simulate_fmu takes as the end of the run), never fmi2Fatal."""
    script = (
        "import json, sys\n"
        "sys.modules['jsbsim'] = None\n"
        "from fmpy import simulate_fmu\n"
        "messages = []\n"
        "def logger(environment, instance, status, category, message):\n"
        "    messages.append((status, message.decode()))\n"
        f"simulate_fmu({str(jsbsim_c172x.path)!r}, stop_time=0.1, debug_logging=True, logger=logger)\n"
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


# -- flightgp build-fmu ------------------------------------------------------------------------------
def test_build_fmu_command_writes_the_fmu(bo105_model_file, tmp_path, capsys):
    assert main(["build-fmu", str(bo105_model_file), "--out", str(tmp_path / "out"), "--name", "rates"]) == 0
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["rates.fmu"]
    assert validate_fmu(str(tmp_path / "out" / "rates.fmu")) == []
    assert "rates.fmu" in capsys.readouterr().out


@pytest.mark.parametrize("problem", ["missing", "not a model", "bad name", "out is a file", "input lag 0"])
def test_build_fmu_bad_input_exits_2_and_writes_nothing(bo105_model_file, bo105_flights, tmp_path, capsys,
                                                        problem):
    model, out, name = str(bo105_model_file), tmp_path / "out", []
    if problem == "missing":
        model = str(tmp_path / "nope.npz")
    elif problem == "not a model":
        (tmp_path / "junk.npz").write_text("not a zip")
        model = str(tmp_path / "junk.npz")
    elif problem == "bad name":
        name = ["--name", "2 fast"]
    elif problem == "out is a file":
        out.write_text("keep me")
    else:
        config = NarxConfig(input_lags=(0, 1), hyperparameters="maximum_likelihood", stride=25)
        trained = train_narx([bo105_flights["training"]], config, seed=0, n_restarts=0)
        model = str(save_trained(tmp_path / "lag0.npz", trained))
    assert main(["build-fmu", model, "--out", str(out), *name]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp build-fmu: error:") and "Traceback" not in err
    assert not out.is_dir() or not any(out.iterdir())


@pytest.mark.parametrize("reference, file_name", [("bo105-80kt", "bo105_80kt_reference.fmu"),
                                                  ("jsbsim:c172x", "jsbsim_c172x.fmu")])
def test_build_fmu_command_builds_reference_fmus(reference, file_name, tmp_path, capsys):
    assert main(["build-fmu", "--reference", reference, "--out", str(tmp_path / "out")]) == 0
    assert [p.name for p in (tmp_path / "out").iterdir()] == [file_name]
    assert validate_fmu(str(tmp_path / "out" / file_name)) == []
    assert file_name in capsys.readouterr().out


@pytest.mark.parametrize("arguments", [["--reference", "bo105-85kt"], ["--reference", "bo105-80kt-flight"],
                                       ["--reference", "blimp"], ["--reference", "jsbsim:"],
                                       ["--reference", "jsbsim:nope"], ["--reference", "jsbsim:ZLT-NT"],
                                       [], ["model.npz", "--reference", "bo105-80kt"]])
def test_build_fmu_bad_reference_exits_2_naming_the_valid_ones(arguments, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["build-fmu", *arguments, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp build-fmu: error:") and err.count("\n") == 1 and "Traceback" not in err
    assert "jsbsim:c172x" in err or "jsbsim:<aircraft>" in err
    if not any(a.startswith("jsbsim:") for a in arguments):
        assert "bo105-<V>kt" in err or "bo105-80kt, bo105-100kt" in err
    assert not out.exists()


# -- the blimp RKGP in particular -------------------------------------------------------------------
def test_blimp_rkgp_declares_the_interface_and_refuses_steps_it_was_not_trained_for(blimp_rkgp_fmu, tmp_path):
    description = read_model_description(str(blimp_rkgp_fmu))
    by_causality = lambda c: [v.name for v in description.modelVariables if v.causality == c]  # noqa: E731
    assert by_causality("input") == list(BLIMP_INPUTS)
    assert by_causality("output") == list(BLIMP_STATES) + [f"{s}_sd" for s in BLIMP_STATES]
    assert by_causality("parameter") == [f"{s}_start" for s in BLIMP_STATES]
    # The default start is the reference parameters' hanging equilibrium: CG on the z axis, level.
    assert all(float(v.start) == 0.0 for v in description.modelVariables if v.causality == "parameter")
    # Default step: the median training frame interval (20 Hz).
    assert abs(float(description.defaultExperiment.stepSize) - 0.05) < 1e-12
    host = Host(extract(str(blimp_rkgp_fmu), unzipdir=str(tmp_path / "unzipped")))
    try:
        host.fmu.setupExperiment(startTime=0.0)
        host.fmu.enterInitializationMode()
        host.fmu.exitInitializationMode()
        np.testing.assert_array_equal(host.get(), np.zeros(24))  # at rest, hanging; sd 0
        with pytest.raises(FMICallException) as refused:  # twice the frame interval
            host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.1)
        assert refused.value.status == fmi2Discard
        errors = [message for status, _, message in host.messages if status == fmi2Error]
        assert "frame intervals the GP residual was trained on" in errors[-1]
        host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.05)  # then it steps
        assert np.all(np.isfinite(host.get()))
    finally:
        host.close()


def test_build_fmu_command_builds_the_blimp_rkgp_from_a_greybox_model(blimp_model_file, tmp_path, capsys):
    assert main(["build-fmu", str(blimp_model_file), "--out", str(tmp_path / "out"), "--name", "blimp"]) == 0
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["blimp.fmu"]
    assert validate_fmu(str(tmp_path / "out" / "blimp.fmu")) == []
    names = [v.name for v in read_model_description(str(tmp_path / "out" / "blimp.fmu")).modelVariables]
    assert "u_gondola" in names and "R_sd" in names
    assert "blimp.fmu" in capsys.readouterr().out


def test_build_fmu_refuses_a_greybox_model_of_other_physics(blimp_trained, tmp_path, capsys):
    model = save_model(tmp_path / "cart.npz", blimp_trained["model"], physics={"kind": "damped_cart"})
    assert main(["build-fmu", str(model), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp build-fmu: error:") and "blimp_rk4" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()
