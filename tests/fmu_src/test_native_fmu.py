"""The native (C, Python-free) GP-NARX rate predictor FMU (fmu_src/native.py).

It passes the FMU contract of tests/test_fmu.py: the contract's test functions are imported
here and run with this module's ``case`` fixture, the native FMU of the same model the
pythonfmu rate predictor there is built from (GPyTorch-style shared contract tests, STYLE.md).
The contract's check that the Python code inside an FMU is self-contained is replaced by its
native counterpart: no Python code at all, and a binary that links only libc and libm.

Then what is particular to the native FMU: the same modelDescription as the pythonfmu FMU, the
same outputs in both modes (one step; free run by moment matching over the hyperparameter
mixture, for the paper's 400-sample model, a sparse one and ones whose output lags skip a lag),
the free-run belief in the FMU state, a corrupt belief refused as by the pythonfmu FMU, a plain
C host with no Python in the process, the FMI call-sequence state machine, ``fmpy compile`` from
the shipped sources, and ``flightgp build-fmu --native``.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from dataclasses import replace
from pathlib import Path
from statistics import NormalDist

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error

from fmu_src.builder import build_rate_predictor_fmu
from fmu_src.native import C_HEADERS, C_SOURCES, CONFIG_HEADER, build_native_rate_predictor_fmu, compile_shared_library
from tests.fmu_src.test_fmu import (  # noqa: F401
    FMI_FATAL,
    Host,
    bo105_flights,
    bo105_model_file,
    bo105_trained,
    host,
    rate_predictor_case,
    rate_predictor_fmu,
    standard_run,
    test_bad_input_is_a_discard_even_without_logging,
    test_bad_input_is_a_logged_discard_and_the_step_can_be_retried,
    test_confidence_level_sets_the_band,
    test_free_run_mode_equals_the_python_moment_matching_free_run,
    test_illegal_calls_are_logged_discards,
    test_outputs_equal_the_python_model,
    test_outside_the_training_envelope_warns_and_widens_the_bounds,
    test_rate_predictor_starts_at_the_given_rates,
    test_reset_reproduces_a_run,
    test_runs_where_flightgp_is_not_importable_and_prints_nothing,
    test_second_host_libcosim_agrees_with_fmpy,
    test_simulate_fmu_runs_with_finite_outputs,
    test_state_capability_is_declared_honestly,
    test_state_save_step_restore_step_is_identical,
    test_two_instances_in_one_process_stay_independent,
    test_validates_without_problems,
    unzipdir,
)
from validation.cli import main
from validation.cosim.hosts import simulate_in_c_host

OUTPUTS = [f"{axis}{suffix}" for axis in "pqr" for suffix in ("", "_lower", "_upper")]


@pytest.fixture(scope="module")
def native_fmu(bo105_model_file, tmp_path_factory):
    return build_native_rate_predictor_fmu(bo105_model_file, tmp_path_factory.mktemp("native"),
                                           name="bo105_native_rate_predictor")


@pytest.fixture(scope="module")
def case(request, native_fmu):
    """The contract's case of the pythonfmu rate predictor, with the native FMU in its place:
    same inputs, same Python reference, same tolerance (1e-9 rad/s: the C code evaluates the
    formulas of _runtime.NarxPredictor in another summation order; measured 1e-13)."""
    return replace(rate_predictor_case(request), path=native_fmu)


@pytest.fixture(scope="module")
def rate_predictor(case):
    return case


@pytest.fixture(scope="module")
def pythonfmu_fmu(rate_predictor_fmu):
    """The pythonfmu FMU of the same model, whose interface the native FMU declares."""
    return rate_predictor_fmu


@pytest.fixture(scope="module")
def c_sources():
    """The C sources the native FMU lists in its modelDescription and compiles."""
    return C_SOURCES


# -- the contract's check of self-containment, for a binary ------------------------------------
def test_runtime_is_self_contained(case):
    """No Python code in the FMU, and the binary needs only the C library and libm (no
    libpython): a C or C++ host loads it as it is."""
    with zipfile.ZipFile(case.path) as archive:
        names = archive.namelist()
    assert not [n for n in names if n.endswith(".py")]
    identifier = read_model_description(str(case.path)).coSimulation.modelIdentifier
    assert f"binaries/linux64/{identifier}.so" in names
    with zipfile.ZipFile(case.path) as archive:
        binary = archive.read(f"binaries/linux64/{identifier}.so")
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


# -- the same interface and numbers as the pythonfmu FMU -----------------------------------------
def test_model_description_declares_the_pythonfmu_interface(native_fmu, pythonfmu_fmu, c_sources):
    """Every variable (e.g. free_run's description) as the pythonfmu FMU of the same model
    declares it, its default step and output dependencies; its description plus "native C"; no
    execution tool; the C sources listed and shipped with the headers."""
    native, python = (read_model_description(str(p)) for p in (native_fmu, pythonfmu_fmu))
    fields = ("name", "valueReference", "causality", "variability", "initial", "type", "unit",
              "description", "start", "min", "max")
    rows = lambda d: [tuple(getattr(v, f) for f in fields) for v in d.modelVariables]  # noqa: E731
    assert rows(native) == rows(python)
    assert native.defaultExperiment.stepSize == python.defaultExperiment.stepSize
    assert [(u.index, u.dependencies) for u in native.outputs] == [(u.index, u.dependencies) for u in python.outputs]
    assert native.description.startswith(python.description) and "native C" in native.description
    co_simulation = native.coSimulation
    assert not co_simulation.needsExecutionTool and not co_simulation.canHandleVariableCommunicationStepSize
    assert co_simulation.canGetAndSetFMUstate and co_simulation.canSerializeFMUstate
    assert native.buildConfigurations[0].sourceFileSets[0].sourceFiles == list(c_sources)
    with zipfile.ZipFile(native_fmu) as archive:
        shipped = {n.split("/", 1)[1] for n in archive.namelist() if n.startswith("sources/")}
    assert shipped == {*c_sources, *C_HEADERS, CONFIG_HEADER}


def _run_fmpy(path, recording_inputs, *, free_run: bool):
    n = len(next(iter(recording_inputs.values())))
    signal = np.zeros(n, dtype=[("time", float)] + [(name, float) for name in recording_inputs])
    signal["time"] = np.arange(n) * 0.1
    for name, values in recording_inputs.items():
        signal[name] = values
    result = simulate_fmu(str(path), input=signal, start_values={"free_run": free_run}, stop_time=(n - 1) * 0.1,
                          step_size=0.1, output_interval=0.1)
    return np.column_stack([result[name] for name in OUTPUTS])


@pytest.mark.parametrize("flight", ["training", "unseen"])
def test_outputs_equal_the_pythonfmu_fmu(native_fmu, rate_predictor_fmu, bo105_flights, flight):
    """Over a whole 3-2-1-1 (the training one, and an unseen one that leaves the envelope), in
    both modes, every output (means and bounds) equals the pythonfmu FMU's. Free run: both
    propagate the belief by moment matching over the 400-sample mixture (the contract's
    test_free_run_mode_equals_the_python_moment_matching_free_run compares the native FMU with
    GPNarx's moment-matching free run). Tolerance 1e-9 rad/s as the contract: one step measured
    1e-13; free run 2e-11, since eq. 4 subtracts tr(A Q) from s2 with A = V^T V summed in another
    order, and the entries of A are up to the inverse of K's smallest eigenvalue."""
    recording = bo105_flights[flight]
    u = recording.input("theta_1s")[::10]
    inputs = {"theta_1s": u, **{f"{a}_prev": recording.output(a)[::10] for a in "pqr"}}
    outputs = {}
    for free_run in (False, True):
        native, python = (_run_fmpy(p, inputs, free_run=free_run) for p in (native_fmu, rate_predictor_fmu))
        np.testing.assert_allclose(native, python, rtol=0, atol=1e-9)
        outputs[free_run] = native
    assert np.abs(outputs[True] - outputs[False]).max() > 1e-3  # the modes differ


def test_free_run_belief_is_part_of_the_fmu_state(case, unzipdir, host):
    """The contract's save / step / restore / serialise check, in free-run mode: the belief (mean
    vector and covariance matrix over the lagged outputs) is saved, restored and serialised with
    the lag histories, also into a fresh instance."""
    test_state_save_step_restore_step_is_identical(replace(case, parameters={**case.parameters, "free_run": True}),
                                                   unzipdir, host)


def test_a_sparse_model_with_a_full_variance_factor_equals_the_python_model(bo105_flights, tmp_path):
    """A sparse GP's variance factor is not triangular: the native FMU then multiplies the full
    matrix (narx_model.c, full_product), and its free run uses A = V^T V (K_mm^-1 - Sigma).
    One-step outputs equal GPNarx's, free-run outputs GPNarx's moment-matching free run, to
    1e-9 rad/s (measured 1e-13 and 5e-11; the free run's eq. 4 cancels as in the test above)."""
    from validation.models.narx import NarxConfig, one_step, save_trained, train_narx

    recording = bo105_flights["training"]
    # Two restarts: from the first start alone, maximum likelihood ends at a constant model
    # (signal variance e^-15) whose free run would test nothing.
    trained = train_narx([recording], NarxConfig(hyperparameters="maximum_likelihood", stride=5, n_inducing=20),
                         seed=0, n_restarts=2)
    path = build_native_rate_predictor_fmu(save_trained(tmp_path / "sparse.npz", trained), tmp_path)
    with zipfile.ZipFile(path) as archive:
        assert "LOWER_TRIANGULAR[3] = {0, 0, 0}" in archive.read("sources/model_config.h").decode()
    inputs = {"theta_1s": recording.input("theta_1s")[::10], **{f"{a}_prev": recording.output(a)[::10] for a in "pqr"}}
    outputs = _run_fmpy(path, inputs, free_run=False)
    prediction = one_step(trained, recording)
    first = prediction.first
    np.testing.assert_allclose(outputs[first:, [OUTPUTS.index(a) for a in "pqr"]], prediction.mean[first:],
                               rtol=0, atol=1e-9)
    z = NormalDist().inv_cdf(0.975)
    np.testing.assert_allclose(outputs[first:, [OUTPUTS.index(f"{a}_upper") for a in "pqr"]],
                               prediction.mean[first:] + z * np.sqrt(prediction.var[first:]), rtol=0, atol=1e-9)
    # Free run from rest, against GPNarx's moment-matching free run from the same rest (the
    # padded start of test_fmu.py::test_free_run_mode_equals_the_python_moment_matching_free_run).
    u = recording.input("theta_1s")[::10, None]
    free = _run_fmpy(path, {"theta_1s": u[:, 0]}, free_run=True)
    means, upper = free[:, [OUTPUTS.index(a) for a in "pqr"]], free[:, [OUTPUTS.index(f"{a}_upper") for a in "pqr"]]
    lag = trained.model.structure.max_lag
    padded = np.vstack([np.repeat(u[:1], lag - 1, axis=0), u])
    python = trained.model.free_run(padded, np.tile(means[0], (lag, 1)), method="moment_matching", use_samples=True)
    np.testing.assert_allclose(means[1:], python.mean[lag:], rtol=0, atol=1e-9)
    np.testing.assert_allclose((upper - means)[1:] / z, np.sqrt(python.var[lag:]), rtol=0, atol=1e-9)
    assert np.ptp(means[1:], axis=0).min() > 1e-3  # the free run moves: a real test


@pytest.fixture(scope="module", params=[(2,), (1, 3)], ids=["output_lags_2", "output_lags_1_3"])
def skipped_lags(request, bo105_flights, tmp_path_factory):
    """A model whose output lags skip a lag (maximum likelihood, no restarts: a few seconds), its
    native and its pythonfmu FMU."""
    from validation.models.narx import NarxConfig, save_trained, train_narx

    lags = request.param
    trained = train_narx([bo105_flights["training"]],
                         NarxConfig(hyperparameters="maximum_likelihood", output_lags=lags), seed=0, n_restarts=0)
    folder = tmp_path_factory.mktemp("skipped_lags")
    path = save_trained(folder / "skip.npz", trained)
    name = "skip_" + "_".join(map(str, lags))
    return (trained, build_native_rate_predictor_fmu(path, folder, name=f"{name}_native"),
            build_rate_predictor_fmu(path, folder, name=f"{name}_python"))


def test_output_lags_that_skip_a_lag_equal_the_pythonfmu_fmu_and_the_python_model(skipped_lags, bo105_flights):
    """Output lags (2,) or (1, 3): a lagged output that is not a regressor (y(k-1), resp. y(k-2))
    gets its covariance with the prediction from the linear-Gaussian projection of
    _cross_covariance_of_lagged_outputs (pinv by cyclic Jacobi in C). Over a 3-2-1-1, in both
    modes, the native FMU's outputs equal the pythonfmu FMU's, the one-step means GPNarx's and
    the free run GPNarx's moment-matching free run, to 1e-9 rad/s (measured: one step 2e-14,
    free run 2e-12 for (2,) and 5e-11 for (1, 3), where leaving the projection out would move
    the free-run means by 2e-3 and the sds by 2e-2 rad/s; with (2,) the even and odd samples
    are independent chains, so the projection is exactly zero)."""
    from validation.models.narx import one_step

    trained, native_path, python_path = skipped_lags
    recording = bo105_flights["training"]
    inputs = {"theta_1s": recording.input("theta_1s")[::10], **{f"{a}_prev": recording.output(a)[::10] for a in "pqr"}}
    means, uppers = [OUTPUTS.index(a) for a in "pqr"], [OUTPUTS.index(f"{a}_upper") for a in "pqr"]
    for free_run in (False, True):
        native, python = (_run_fmpy(p, inputs, free_run=free_run) for p in (native_path, python_path))
        np.testing.assert_allclose(native, python, rtol=0, atol=1e-9)
    prediction = one_step(trained, recording)
    first = prediction.first
    np.testing.assert_allclose(_run_fmpy(native_path, inputs, free_run=False)[first:, means], prediction.mean[first:],
                               rtol=0, atol=1e-9)
    # Free run from rest against GPNarx's from the same rest (as the sparse model's test above).
    u = recording.input("theta_1s")[::10, None]
    free = _run_fmpy(native_path, {"theta_1s": u[:, 0]}, free_run=True)
    lag = trained.model.structure.max_lag
    padded = np.vstack([np.repeat(u[:1], lag - 1, axis=0), u])
    python = trained.model.free_run(padded, np.tile(free[0, means], (lag, 1)), method="moment_matching")
    np.testing.assert_allclose(free[1:, means], python.mean[lag:], rtol=0, atol=1e-9)
    z = NormalDist().inv_cdf(0.975)
    np.testing.assert_allclose((free[:, uppers] - free[:, means])[1:] / z, np.sqrt(python.var[lag:]), rtol=0,
                               atol=1e-9)
    assert np.ptp(free[1:, means], axis=0).min() > 1e-2  # the free run moves: a real test
    # The projection's code, compiled in only here (narx_model.c: N_Z < BELIEF_SIZE), is
    # warning-free too.
    with zipfile.ZipFile(native_path) as archive:
        sources = {n.split("/", 1)[1]: archive.read(n) for n in archive.namelist() if n.startswith("sources/")}
    assert compile_shared_library(sources, "pedantic_skip", extra_flags=("-pedantic", "-Werror"))


def _corrupt_belief_covariance(serialised: bytes, belief_size: int, corrupt, *, native: bool) -> bytes:
    """A serialised FMU state with ``corrupt(cov)`` applied (in place) to its free-run belief
    covariance. Native: the covariance is the last block of the model state, which ends the
    serialised SlaveState, followed only by the refused message's length (0 here:
    fmi2_slave.c, serialised layout). pythonfmu: the JSON of fmu_src/_base.py, attribute _belief."""
    if native:
        data = bytearray(serialised)
        assert data[-8:] == bytes(8)  # no refused message follows
        block = slice(len(data) - 8 - 8 * belief_size**2, len(data) - 8)
        cov = np.frombuffer(bytes(data[block]), dtype=float).reshape(belief_size, belief_size).copy()
        corrupt(cov)
        data[block] = cov.tobytes()
        return bytes(data)
    state = json.loads(serialised.decode())
    entry = state["hidden"]["_belief"][1]
    cov = np.array(entry["ndarray"], dtype=float)
    assert cov.shape == (belief_size, belief_size)
    corrupt(cov)
    entry["ndarray"] = cov.tolist()
    return json.dumps(state).encode()


def _break_symmetry(cov):
    cov[0, 1] += 1e-3 * np.abs(cov).max()


def _break_definiteness(cov):
    cov[0, 0] = -cov[0, 0]


@pytest.mark.parametrize("corrupt, phrase", [(_break_symmetry, "not symmetric"),
                                             (_break_definiteness, "not positive semi-definite")])
@pytest.mark.parametrize("fmu", ["native", "pythonfmu"])
def test_a_corrupt_free_run_belief_is_a_logged_discard_as_in_the_pythonfmu_fmu(
        fmu, corrupt, phrase, case, native_fmu, rate_predictor_fmu, bo105_trained, bo105_flights, tmp_path):
    """The free run checks the regressor covariance as MomentMatcher._standardise does (finite,
    symmetric and positive semi-definite to COVARIANCE_TOLERANCE = 1e-10 relative, in the
    standardised frame; narx_model.c: covariance_problem, eigenvalues by cyclic Jacobi). A belief
    covariance that fails (set from outside through a deserialised FMU state) makes the step a
    logged Error and fmi2Discard in both FMUs (the pythonfmu FMU: MomentMatcher raises, the base
    refuses the step), and changes nothing: the state is the corrupt one still, and restoring the
    good state, the run goes on as if the step had never been tried."""
    path = native_fmu if fmu == "native" else rate_predictor_fmu
    host = Host(extract(str(path), unzipdir=str(tmp_path / "u")))
    u = bo105_flights["training"].input("theta_1s")[::10]
    free = lambda k: {"theta_1s": u[k]}  # noqa: E731
    step, k = case.step, 5
    belief_size = max(bo105_trained.model.structure.output_lags) * 3
    try:
        host.set({"free_run": True})
        host.start(case, free(0))
        expected = host.run(case, 0, k + 3, inputs=free)
        host.fmu.reset()
        host.set({"free_run": True})
        host.start(case, free(0))
        host.run(case, 0, k, inputs=free)
        good = host.fmu.getFMUstate()
        corrupted = _corrupt_belief_covariance(host.fmu.serializeFMUstate(good), belief_size, corrupt,
                                               native=fmu == "native")
        bad = host.fmu.deSerializeFMUstate(corrupted)
        host.fmu.setFMUstate(bad)
        before = host.get()
        for _ in range(2):  # refused, and refused again on retry: the corrupt state was kept
            host.set(free(k))
            with pytest.raises(FMICallException) as refused:
                host.fmu.doStep(currentCommunicationPoint=k * step, communicationStepSize=step)
            assert refused.value.status == fmi2Discard
            errors = [message for status, _, message in host.messages if status == fmi2Error]
            assert errors and phrase in errors[-1] and "Discard" in errors[-1], host.messages[-3:]
            np.testing.assert_array_equal(host.get(), before)
        host.fmu.setFMUstate(good)
        np.testing.assert_array_equal(host.run(case, k, k + 3, inputs=free), expected[k:])
        host.fmu.freeFMUstate(good)
        host.fmu.freeFMUstate(bad)
    finally:
        host.close()
    assert FMI_FATAL not in host.statuses()


# -- no Python in the process -------------------------------------------------------------------
def test_runs_in_a_plain_c_host_without_python(case, host):
    """validation/native_host.c: dlopen, fmi2Instantiate, the case's parameters and start values
    (e.g. the blimp's start state), fmi2SetupExperiment, fmi2Enter/ExitInitializationMode, then
    fmi2SetReal + fmi2DoStep + fmi2GetReal per step, in a subprocess with no Python; outputs
    identical to fmpy's (the same binary, parameters and inputs: bit for bit)."""
    rows = [case.inputs(k) for k in range(case.n_steps + 1)]
    inputs = {name: np.array([row[name] for row in rows]) for name in rows[0]}
    result = simulate_in_c_host(case.path, step_size=case.step, n_steps=case.n_steps, inputs=inputs,
                                outputs=host.outputs, start_values=case.parameters)
    assert not result["python_in_process"]
    np.testing.assert_array_equal(np.column_stack([result[n] for n in host.outputs]), standard_run(case, host))


# -- the FMI 2.0 call sequence ----------------------------------------------------------------
@pytest.mark.parametrize("call", ["doStep before exitInitializationMode", "doStep before initialisation",
                                  "setupExperiment after initialisation", "getReal before initialisation",
                                  "doStep after terminate"])
def test_illegal_call_order_is_a_logged_error_and_changes_nothing(case, unzipdir, call):
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


def test_bad_start_value_fails_initialisation_with_an_error_until_reset(case, unzipdir):
    host = Host(unzipdir, name="bad_start")
    try:
        with pytest.raises(FMICallException) as refused:
            host.start(case, {**case.inputs(0), "q_prev": float("nan")})
        assert refused.value.status == fmi2Error
        assert "initialisation refused" in host.messages[-1][2] and "q_prev" in host.messages[-1][2]
        with pytest.raises(FMICallException):  # in the error state only reset helps
            host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=case.step)
        host.fmu.reset()
        host.start(case)
        host.run(case, 0, 3)
    finally:
        host.close()
    assert FMI_FATAL not in host.statuses()


def test_wrong_guid_or_resources_refuse_instantiation_with_a_message(unzipdir, tmp_path):
    from ctypes import byref

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


# -- building --------------------------------------------------------------------------------------
def test_sources_compile_without_warnings_under_pedantic_c99(native_fmu):
    with zipfile.ZipFile(native_fmu) as archive:
        sources = {n.split("/", 1)[1]: archive.read(n) for n in archive.namelist() if n.startswith("sources/")}
    assert compile_shared_library(sources, "pedantic", extra_flags=("-pedantic", "-Werror"))


def test_fmpy_compile_rebuilds_the_binary_from_the_shipped_sources(case, host, tmp_path, monkeypatch):
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


def test_build_fmu_command_native(bo105_model_file, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["build-fmu", str(bo105_model_file), "--native", "--out", str(out), "--name", "rates"]) == 0
    assert [p.name for p in out.iterdir()] == ["rates.fmu"]
    assert "rates.fmu" in capsys.readouterr().out
    assert read_model_description(str(out / "rates.fmu")).coSimulation.needsExecutionTool is False


@pytest.mark.parametrize("arguments", [["--reference", "bo105-80kt"], ["missing.npz"]])
def test_build_fmu_native_bad_input_exits_2(arguments, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["build-fmu", *arguments, "--native", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp build-fmu: error:") and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())
