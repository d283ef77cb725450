"""The contract every flightgp FMU passes, written once (docs/fmus.md, "How the FMUs are tested").

As GPyTorch's shared test cases: :class:`FmuContract` holds the generic tests, written against
an :class:`FmuCase` (a built FMU and how to drive it); each FMU's test module subclasses it
(``class TestXxx(FmuContract)``) and supplies only the module fixture ``case``, the FMU's
factory. :class:`NativeFmuContract` adds what every native FMU must also pass. The FMUs and the
models behind them are session fixtures (tests/fmu_src/conftest.py), with ``unzipdir`` and
``host`` built on the module's ``case``.

Hosts: fmpy's ``simulate_fmu`` and, for fine control, fmpy's ``FMU2Slave`` driven call by call
(:class:`Host`), with the FMU's log messages captured through the FMI logger callback; the
second host, libcosim (:func:`validation.cosim.hosts.simulate_in_libcosim`); and, for native
FMUs, a plain C host (:func:`validation.cosim.hosts.simulate_in_c_host`).
"""
from __future__ import annotations

import ast
import os
import re
import shutil
import subprocess
import sys
import zipfile
from collections.abc import Callable
from ctypes import byref
from dataclasses import dataclass, field
from pathlib import Path

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

from fmu_src.fmi.native import (
    CONFIG_HEADER,
    LAYER_HEADERS,
    PLATFORM_FOLDER,
    compile_shared_library,
    compiled_sources,
    model_headers,
)
from validation.cosim.hosts import simulate_in_c_host, simulate_in_libcosim

#: fmi2Fatal, which no flightgp FMU may ever return.
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
    no_libcosim_reason : str or None
        Why libcosim cannot host the FMU (None: it can, and must give fmpy's outputs).
    runtime_packages : frozenset of str
        Packages besides numpy and pythonfmu the FMU imports at run time (the host needs them).
    native_of : Path or None
        A native FMU: the pythonfmu FMU of the same model, whose interface it declares.
    model_source : Path or None
        A native FMU: its model's C file (compiled with the FMI layer's ``fmi2_slave.c``,
        ``gp_predict.c`` and ``greybox.c``).
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
    no_libcosim_reason: str | None = None
    runtime_packages: frozenset = frozenset()
    native_of: Path | None = None
    model_source: Path | None = None

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


def run_in_fmpy(path, inputs: dict, *, step: float, outputs, start_values=None) -> np.ndarray:
    """One run of fmpy's ``simulate_fmu``: the inputs set at ``t_k = k step`` and held over the
    step, the outputs at every communication point.

    Parameters
    ----------
    path : Path
        The FMU.
    inputs : dict of str -> ndarray, shape (n,)
        Real inputs by name, value ``k`` at ``t_k``; the run takes n - 1 steps.
    step : float
        Communication step, s.
    outputs : sequence of str
    start_values : dict, optional
        Parameters and start values set before initialisation.

    Returns
    -------
    ndarray, shape (n, len(outputs))
    """
    n = len(next(iter(inputs.values())))
    signal = np.zeros(n, dtype=[("time", float)] + [(name, float) for name in inputs])
    signal["time"] = np.arange(n) * step
    for name, values in inputs.items():
        signal[name] = values
    result = simulate_fmu(str(path), input=signal, start_values=start_values or {}, stop_time=(n - 1) * step,
                          step_size=step, output_interval=step, output=list(outputs))
    return np.column_stack([result[name] for name in outputs])


def standard_run(case: FmuCase, host: Host) -> np.ndarray:
    """Outputs at every communication point of the standard run, shape (n_steps + 1, n_outputs)."""
    return np.vstack([host.start(case), host.run(case)])


def check_state_save_restore(case: FmuCase, unzipdir: str, host: Host) -> None:
    """Save the state half-way through the standard run, step on, restore it and step again:
    identical outputs; the same through a serialised copy, also restored into a fresh instance;
    and no Error logged (an incomplete state logs one when saved)."""
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


# -- the contract ---------------------------------------------------------------------------------
class FmuContract:
    """The tests every flightgp FMU passes; a test class ``TestXxx(FmuContract)`` runs them on the
    ``case`` fixture of its module."""

    def test_validates_without_problems(self, case):
        assert validate_fmu(str(case.path)) == []

    def test_runtime_is_self_contained(self, case):
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

    def test_simulate_fmu_runs_with_finite_outputs(self, case, host):
        result = simulate_fmu(str(case.path), input=case.signal(), start_values=case.parameters,
                              stop_time=case.n_steps * case.step, step_size=case.step,
                              output_interval=case.step)
        outputs = host.outputs
        assert len(result) == case.n_steps + 1
        values = np.column_stack([result[name] for name in outputs])
        assert np.all(np.isfinite(values))
        # simulate_fmu follows the same sampling convention as the call-by-call host.
        np.testing.assert_array_equal(values, standard_run(case, host))

    def test_outputs_equal_the_python_model(self, case, host):
        expected, first = case.reference()
        outputs = standard_run(case, host)
        np.testing.assert_allclose(outputs[first:], expected[first:], rtol=0, atol=case.tolerance)
        assert host.statuses() <= {0, fmi2Warning}

    def test_reset_reproduces_a_run(self, case, host):
        first = standard_run(case, host)
        host.fmu.reset()
        np.testing.assert_array_equal(standard_run(case, host), first)

    def test_state_capability_is_declared_honestly(self, case, unzipdir, host):
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

    def test_state_save_step_restore_step_is_identical(self, case, unzipdir, host):
        if case.no_state_reason:
            pytest.skip(case.no_state_reason)
        check_state_save_restore(case, unzipdir, host)

    def test_two_instances_in_one_process_stay_independent(self, case, unzipdir):
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
    def test_bad_input_is_a_logged_discard_and_the_step_can_be_retried(self, case, host, bad):
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
    def test_illegal_calls_are_logged_discards(self, case, host, bad_call):
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

    def test_bad_input_is_a_discard_even_without_logging(self, case, unzipdir):
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

    def test_outside_the_training_envelope_warns_and_widens_the_bounds(self, case, host):
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

    def test_runs_where_flightgp_is_not_importable_and_prints_nothing(self, case, tmp_path):
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

    def test_second_host_libcosim_agrees_with_fmpy(self, case, host):
        """The same inputs in libcosim (Open Simulation Platform) and fmpy give the same outputs: every
        flightgp FMU is deterministic, so to 1e-12 (measured: identical). libcosim initialises inside
        its first step and observes the outputs after each step; the inputs at t0 are also given as
        start values, as fmpy's host sets them before initialisation."""
        if case.no_libcosim_reason:
            pytest.skip(case.no_libcosim_reason)
        expected = standard_run(case, host)[1:]
        rows = [case.inputs(k) for k in range(case.n_steps)]
        inputs = {name: np.array([row[name] for row in rows]) for name in rows[0]}
        result = simulate_in_libcosim(case.path, step_size=case.step, n_steps=case.n_steps, inputs=inputs,
                                      start_values={**case.parameters, **case.inputs(0)}, outputs=host.outputs)
        np.testing.assert_allclose(result["time"], np.arange(1, case.n_steps + 1) * case.step, rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.column_stack([result[name] for name in host.outputs]), expected,
                                   rtol=0, atol=1e-12)


class NativeFmuContract(FmuContract):
    """The contract of a native FMU (``case.native_of`` and ``case.model_source`` set): every test
    of :class:`FmuContract`, its check that the Python code inside is self-contained replaced by
    the native counterpart (no Python code at all, a binary that links only libc and libm), and
    the native FMU's own: the pythonfmu FMU's modelDescription, a plain C host, the FMI call
    sequence, GUID and resources checks, pedantic C99 and ``fmpy compile``."""

    def test_runtime_is_self_contained(self, case):
        """No Python code in the FMU, and the binary needs only the C library and libm (no
        libpython): a C or C++ host loads it as it is."""
        with zipfile.ZipFile(case.path) as archive:
            names = archive.namelist()
        assert not [n for n in names if n.endswith(".py")]
        identifier = read_model_description(str(case.path)).coSimulation.modelIdentifier
        assert f"binaries/{PLATFORM_FOLDER}/{identifier}.so" in names
        with zipfile.ZipFile(case.path) as archive:
            binary = archive.read(f"binaries/{PLATFORM_FOLDER}/{identifier}.so")
        library = case.path.parent / f"{identifier}_check.so"
        library.write_bytes(binary)
        dynamic = subprocess.run(["readelf", "-d", str(library)], capture_output=True, text=True, check=True).stdout
        needed = {line.split("[", 1)[1].split("]", 1)[0] for line in dynamic.splitlines() if "(NEEDED)" in line}
        assert needed <= {"libc.so.6", "libm.so.6"}, needed
        symbols = subprocess.run(["nm", "-D", "--defined-only", str(library)], capture_output=True, text=True,
                                 check=True).stdout
        exported = {line.split()[-1] for line in symbols.splitlines() if " T " in line}
        assert exported and all(name.startswith("fmi2") for name in exported), exported  # nothing else leaks
        library.unlink()

    def test_model_description_declares_the_pythonfmu_interface(self, case):
        """Every variable (e.g. free_run's description) as the pythonfmu FMU of the same model
        declares it, its default step and output dependencies; its description plus "native C"; no
        execution tool; the C sources listed and shipped with the headers."""
        native, python = (read_model_description(str(p)) for p in (case.path, case.native_of))
        c_sources = [path.name for path in compiled_sources(case.model_source)]
        fields = ("name", "valueReference", "causality", "variability", "initial", "type", "unit",
                  "description", "start", "min", "max")
        rows = lambda d: [tuple(getattr(v, f) for f in fields) for v in d.modelVariables]  # noqa: E731
        assert rows(native) == rows(python)
        assert native.defaultExperiment.stepSize == python.defaultExperiment.stepSize
        dependencies = [[(u.index, u.dependencies) for u in d.outputs] for d in (native, python)]
        assert dependencies[0] == dependencies[1]
        assert native.description.startswith(python.description) and "native C" in native.description
        co_simulation = native.coSimulation
        assert not co_simulation.needsExecutionTool and not co_simulation.canHandleVariableCommunicationStepSize
        assert co_simulation.canGetAndSetFMUstate and co_simulation.canSerializeFMUstate
        assert native.buildConfigurations[0].sourceFileSets[0].sourceFiles == c_sources
        with zipfile.ZipFile(case.path) as archive:
            shipped = {n.split("/", 1)[1] for n in archive.namelist() if n.startswith("sources/")}
        assert shipped == {*c_sources, *(path.name for path in (*LAYER_HEADERS, *model_headers(case.model_source))),
                           CONFIG_HEADER}

    def test_runs_in_a_plain_c_host_without_python(self, case, host):
        """validation/cosim/native_host.c: dlopen, fmi2Instantiate, the case's parameters and start values
        (e.g. the blimp's start state), fmi2SetupExperiment, fmi2Enter/ExitInitializationMode, then
        fmi2SetReal + fmi2DoStep + fmi2GetReal per step, in a subprocess with no Python; outputs
        identical to fmpy's (the same binary, parameters and inputs: bit for bit)."""
        rows = [case.inputs(k) for k in range(case.n_steps + 1)]
        inputs = {name: np.array([row[name] for row in rows]) for name in rows[0]}
        result = simulate_in_c_host(case.path, step_size=case.step, n_steps=case.n_steps, inputs=inputs,
                                    outputs=host.outputs, start_values=case.parameters)
        assert not result["python_in_process"]
        np.testing.assert_array_equal(np.column_stack([result[n] for n in host.outputs]), standard_run(case, host))

    @pytest.mark.parametrize("call", ["doStep before exitInitializationMode", "doStep before initialisation",
                                      "setupExperiment after initialisation", "getReal before initialisation",
                                      "doStep after terminate"])
    def test_illegal_call_order_is_a_logged_error_and_changes_nothing(self, case, unzipdir, call):
        host = Host(unzipdir, name="order")
        try:
            fmu = host.fmu
            with pytest.raises(FMICallException) as refused:
                if call == "doStep before initialisation":
                    fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=case.step)
                elif call == "getReal before initialisation":
                    host.get()
                else:
                    fmu.setupExperiment(startTime=0.0)
                    fmu.enterInitializationMode()
                    if call == "doStep before exitInitializationMode":
                        fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=case.step)
                    fmu.exitInitializationMode()
                    if call == "setupExperiment after initialisation":
                        fmu.setupExperiment(startTime=0.0)
                    fmu.terminate()
                    fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=case.step)
            assert refused.value.status == fmi2Error
            errors = [message for status, _, message in host.messages if status == fmi2Error]
            assert len(errors) == 1 and "illegal call" in errors[0], errors
            assert call.split()[0].lower() in errors[0].lower(), errors  # names the function
            # The instance is still usable: reset, then the standard run gives the standard outputs.
            fmu.reset()
            expected, first = case.reference()
            np.testing.assert_allclose(standard_run(case, host)[first:], expected[first:], rtol=0, atol=case.tolerance)
        finally:
            host.fmu.freeInstance()
        assert FMI_FATAL not in host.statuses()

    def test_wrong_guid_or_resources_refuse_instantiation_with_a_message(self, unzipdir, tmp_path):
        description = read_model_description(unzipdir)
        resources = (Path(unzipdir) / "resources").as_uri()
        for guid, location, phrase in (("not-the-guid", resources, "GUID"),
                                       (description.guid, tmp_path.as_uri(), "model.bin")):
            probe = Host(unzipdir, name="probe")  # its callbacks collect the log
            try:
                component = probe.fmu.fmi2Instantiate(b"refused", 1, guid.encode(), location.encode(),
                                                      byref(probe.callbacks), 0, 0)  # 1: fmi2CoSimulation
                assert not component
                assert probe.messages[-1][0] == fmi2Error and phrase in probe.messages[-1][2], probe.messages
            finally:
                probe.close()

    def test_sources_compile_without_warnings_under_pedantic_c99(self, case):
        with zipfile.ZipFile(case.path) as archive:
            sources = {n.split("/", 1)[1]: archive.read(n) for n in archive.namelist() if n.startswith("sources/")}
        assert compile_shared_library(sources, "pedantic", extra_flags=("-pedantic", "-Werror"))

    def test_fmpy_compile_rebuilds_the_binary_from_the_shipped_sources(self, case, host, tmp_path, monkeypatch):
        """`fmpy compile` (CMake) builds the binary from sources/ alone; the rebuilt FMU gives the
        same outputs (same compiler and sources, CMake's Release flags: to 1e-12)."""
        from fmpy.build import build_platform_binary

        monkeypatch.setenv("PATH", f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")  # venv cmake
        if shutil.which("cmake") is None:
            pytest.skip("fmpy compile needs cmake")
        (tmp_path / "build").mkdir()
        unzipped = extract(str(case.path), unzipdir=str(tmp_path / "u"))
        binary = next((tmp_path / "u" / "binaries" / "linux64").iterdir())
        binary.unlink()
        build_platform_binary(unzipped, build_dir=str(tmp_path / "build"))
        assert binary.is_file()
        rebuilt = Host(unzipped, name="rebuilt")
        try:
            np.testing.assert_allclose(standard_run(case, rebuilt), standard_run(case, host), rtol=0, atol=1e-12)
        finally:
            rebuilt.close()
