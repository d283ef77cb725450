"""The native (C, Python-free) blimp RKGP FMU (fmu_src/native_blimp.py, issue 8).

It passes the FMU contract of tests/test_fmu.py with the pythonfmu blimp RKGP's case (the same
model, inputs, Python reference and tolerance), and the native FMU checks of
tests/test_native_fmu.py (the pythonfmu FMU's modelDescription, a binary that links only libc
and libm, a plain C host given the start state, the FMI call sequence, GUID and resources
checks, pedantic C99, ``fmpy compile``): the test functions are imported here and run with this
module's ``case``, ``native_fmu``, ``pythonfmu_fmu`` and ``c_sources`` fixtures (GPyTorch-style
shared contract tests, STYLE.md).

Then what is particular to the blimp: its outputs over whole command sequences (inside and
outside the training envelope) against the pythonfmu FMU's, one GP per state, the step fixed by
the first fmi2DoStep inside the trained frame interval, ``flightgp bench fmu``'s blimp timing,
and ``flightgp build-fmu --native`` with a grey-box model.
"""
from __future__ import annotations

import zipfile
from dataclasses import replace

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error
from fmpy.validation import validate_fmu

from fmu_src import native_blimp
from fmu_src.builder import build_blimp_rkgp_fmu
from fmu_src.native_blimp import C_SOURCES, build_native_blimp_rkgp_fmu
from gp_model import GreyBoxGP, save_model
from tests.fmu_src.test_fmu import (  # noqa: F401
    BLIMP_HOLD,
    FMI_FATAL,
    Host,
    blimp_model_file,
    blimp_rkgp_case,
    blimp_rkgp_fmu,
    blimp_trained,
    host,
    standard_run,
    test_bad_input_is_a_discard_even_without_logging,
    test_bad_input_is_a_logged_discard_and_the_step_can_be_retried,
    test_illegal_calls_are_logged_discards,
    test_outputs_equal_the_python_model,
    test_outside_the_training_envelope_warns_and_widens_the_bounds,
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
from tests.fmu_src.test_fmu import (
    test_blimp_rkgp_declares_the_interface_and_refuses_steps_it_was_not_trained_for as blimp_interface_checks,
)
from tests.fmu_src.test_native_fmu import (  # noqa: F401
    test_fmpy_compile_rebuilds_the_binary_from_the_shipped_sources,
    test_illegal_call_order_is_a_logged_error_and_changes_nothing,
    test_model_description_declares_the_pythonfmu_interface,
    test_runs_in_a_plain_c_host_without_python,
    test_runtime_is_self_contained,
    test_sources_compile_without_warnings_under_pedantic_c99,
    test_wrong_guid_or_resources_refuse_instantiation_with_a_message,
)
from validation.bench.fmu import time_blimp_rkgp_fmus
from validation.cli import main
from validation.models.blimp_identification import blimp_physics_description, physics_step
from validation.vehicles.blimp import INPUT_NAMES as BLIMP_INPUTS
from validation.vehicles.blimp import STATE_NAMES as BLIMP_STATES
from validation.vehicles.blimp import BlimpParameters
from validation.vehicles.blimp_flight import BlimpFlightTest

OUTPUTS = [*BLIMP_STATES, *(f"{s}_sd" for s in BLIMP_STATES)]
STEP = BlimpFlightTest.sample_time


@pytest.fixture(scope="module")
def native_fmu(blimp_model_file, tmp_path_factory):
    return build_native_blimp_rkgp_fmu(blimp_model_file, tmp_path_factory.mktemp("native"), name="blimp_native")


@pytest.fixture(scope="module")
def case(request, native_fmu):
    """The contract's case of the pythonfmu blimp RKGP, with the native FMU in its place: the same
    commands, start state, Python reference (GreyBoxGP.rollout and predict_one_step) and tolerance
    (1e-9: the same formulas for one state instead of a batch; measured 4.5e-11)."""
    return replace(blimp_rkgp_case(request), path=native_fmu)


@pytest.fixture(scope="module")
def pythonfmu_fmu(blimp_rkgp_fmu):
    """The pythonfmu FMU of the same model, whose interface the native FMU declares."""
    return blimp_rkgp_fmu


@pytest.fixture(scope="module")
def c_sources():
    """The C sources the native FMU lists in its modelDescription and compiles."""
    return C_SOURCES


def _run_fmpy(path, commands: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Outputs at every communication point (n + 1, 24) of fmpy's simulate_fmu, commands (n + 1, 3)."""
    signal = np.zeros(len(commands), dtype=[("time", float)] + [(n, float) for n in BLIMP_INPUTS])
    signal["time"] = np.arange(len(commands)) * STEP
    for i, name in enumerate(BLIMP_INPUTS):
        signal[name] = commands[:, i]
    result = simulate_fmu(str(path), input=signal, start_values={f"{s}_start": v for s, v in zip(BLIMP_STATES, start)},
                          stop_time=(len(commands) - 1) * STEP, step_size=STEP, output_interval=STEP,
                          output=OUTPUTS)
    return np.column_stack([result[name] for name in OUTPUTS])


def _python_reference(model, params, commands: np.ndarray, start: np.ndarray) -> np.ndarray:
    """GreyBoxGP.rollout (mean fed back) and its one-step sds, as the FMU's outputs (n + 1, 24)."""
    physics = physics_step(params)
    steps = np.column_stack([commands[:-1], np.full(len(commands) - 1, STEP)])
    mean = model.rollout(start, steps, physics)
    _, var = model.predict_one_step(mean[:-1], steps, physics)
    return np.hstack([mean, np.vstack([np.zeros(12), np.sqrt(var)])])


# -- the same numbers as the pythonfmu FMU ----------------------------------------------------
@pytest.mark.parametrize("commands", ["training", "unseen"])
def test_outputs_equal_the_pythonfmu_fmu_and_the_python_rollout(native_fmu, blimp_rkgp_fmu, blimp_trained, commands):
    """Over 10 s (200 steps) of commands, the training ones and unseen ones that leave the
    envelope (u_gondola down to -0.5, trained 0.2 .. 0.8), every state and sd equals the pythonfmu
    FMU's and GreyBoxGP.rollout's (with predict_one_step's sds). Tolerance 1e-9 in SI units:
    the same formulas for one state, rounded differently (numpy's BLAS and SIMD sin/cos/exp vs
    libm, ~1e-16 relative per operation), grown by the dynamics over 200 steps; measured
    2e-12 on the states and 3e-11 on the sds (native vs pythonfmu)."""
    if commands == "training":
        u = blimp_trained["commands"]
    else:
        rng = np.random.default_rng(1)
        levels = lambda low, high: np.repeat(rng.uniform(low, high, 21), BLIMP_HOLD)[:201]  # noqa: E731
        u = np.column_stack([levels(-0.5, 0.8), levels(-0.2, 0.6), levels(-0.8, 0.8)])
    start = blimp_trained["states"][0]
    native, python = (_run_fmpy(p, u, start) for p in (native_fmu, blimp_rkgp_fmu))
    reference = _python_reference(blimp_trained["model"], blimp_trained["params"], u, start)
    np.testing.assert_allclose(native, python, rtol=0, atol=1e-9)
    np.testing.assert_allclose(native, reference, rtol=0, atol=1e-9)
    assert np.ptp(native[:, :12], axis=0).max() > 0.5 and native[1:, 12:].min() > 0  # a real test


@pytest.fixture(scope="module")
def per_state_model(blimp_trained, tmp_path_factory):
    """One GP per state (GreyBoxGP(shared=False)) on the first 2 s of the training flight: 40
    pairs, twelve parts of q = 1."""
    states, commands = blimp_trained["states"][:41], blimp_trained["commands"][:41]
    inputs = np.column_stack([commands, np.full(41, STEP)])
    params = BlimpParameters()
    model = GreyBoxGP(state_columns=(3, 4, 6, 7, 8, 9, 10, 11), shared=False, n_restarts=0).fit_trajectories(
        [(states, inputs)], physics_step(params))
    path = save_model(tmp_path_factory.mktemp("per_state") / "per_state.npz", model,
                      physics=blimp_physics_description(params))
    return {"model": model, "params": params, "path": path, "commands": commands, "start": states[0]}


def test_one_gp_per_state_equals_the_pythonfmu_fmu_and_the_python_rollout(per_state_model, tmp_path):
    m = per_state_model
    native = build_native_blimp_rkgp_fmu(m["path"], tmp_path, name="per_state_native")
    python = build_blimp_rkgp_fmu(m["path"], tmp_path, name="per_state_python")
    with zipfile.ZipFile(native) as archive:
        assert "#define N_PARTS 12" in archive.read("sources/model_config.h").decode()
    outputs = _run_fmpy(native, m["commands"], m["start"])
    np.testing.assert_allclose(outputs, _run_fmpy(python, m["commands"], m["start"]), rtol=0, atol=1e-9)
    np.testing.assert_allclose(outputs, _python_reference(m["model"], m["params"], m["commands"], m["start"]),
                               rtol=0, atol=1e-9)


def test_a_full_variance_factor_gives_the_same_outputs(blimp_model_file, native_fmu, blimp_trained, tmp_path,
                                                       monkeypatch):
    """blimp_model.c multiplies a lower triangular V = L^-1 without the zeros above its diagonal;
    stored full (as a non-triangular factor would be), it adds exact zeros: identical outputs."""
    monkeypatch.setattr(native_blimp, "lower_triangular", lambda factor: False)
    full = build_native_blimp_rkgp_fmu(blimp_model_file, tmp_path, name="full_factor")
    with zipfile.ZipFile(full) as archive:
        assert "LOWER_TRIANGULAR[1] = {0}" in archive.read("sources/model_config.h").decode()
    u, start = blimp_trained["commands"][:41], blimp_trained["states"][0]
    np.testing.assert_array_equal(_run_fmpy(full, u, start), _run_fmpy(native_fmu, u, start))


# -- the step: fixed by the first fmi2DoStep, inside the trained frame interval ------------------
def test_declares_the_interface_and_refuses_steps_it_was_not_trained_for(native_fmu, tmp_path):
    """The pythonfmu blimp RKGP's own check (tests/test_fmu.py), on the native FMU."""
    blimp_interface_checks(native_fmu, tmp_path)


@pytest.mark.parametrize("step", [0.1, 0.05 * (1 - 1e-3), -0.05])
def test_a_step_outside_the_trained_dt_range_is_a_logged_discard_and_changes_nothing(case, unzipdir, step):
    """Trained on 20 Hz frames only (dt 0.05 s, no spread: the range is 0.05 s to the time
    tolerance), so twice the interval and 0.1 % less are refused, as is a negative step; then the
    run at 0.05 s is the standard run, and the first step fixes 0.05 s until reset."""
    host = Host(unzipdir, name="step")
    try:
        expected = standard_run(case, host)
        host.fmu.reset()
        host.start(case)
        with pytest.raises(FMICallException) as refused:
            host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=step)
        assert refused.value.status == fmi2Discard
        errors = [message for status, _, message in host.messages if status == fmi2Error]
        phrase = "must be positive" if step < 0 else "frame intervals the GP residual was trained on"
        assert len(errors) == 1 and phrase in errors[0] and "Discard" in errors[0], errors
        np.testing.assert_array_equal(host.get(), expected[0])  # outputs unchanged
        np.testing.assert_array_equal(host.run(case), expected[1:])  # as if it never happened
        with pytest.raises(FMICallException):
            host.fmu.doStep(currentCommunicationPoint=case.n_steps * case.step, communicationStepSize=0.05 * (1 + 1e-5))
        assert "the step of its first fmi2DoStep, until reset" in host.messages[-1][2]
        status = host.fmu.getRealStatus(2)  # fmi2LastSuccessfulTime
        assert status == pytest.approx(case.n_steps * case.step, abs=1e-12)
    finally:
        host.close()
    assert FMI_FATAL not in host.statuses()


# -- flightgp bench fmu ------------------------------------------------------------------------------
def test_bench_times_both_blimp_fmus(blimp_rkgp_fmu, native_fmu, blimp_trained):
    """validation.bench.fmu.time_blimp_rkgp_fmus (``flightgp bench fmu``'s blimp row): the
    report's structure, finite positive times and ratios that are their quotients (no speed
    asserted: speed goals live in the benchmark, README "Benchmarks")."""
    row = time_blimp_rkgp_fmus(blimp_rkgp_fmu, native_fmu, blimp_trained["commands"], blimp_trained["states"][0],
                               n_steps=10)
    assert set(row) == {"steps", "pythonfmu_us_per_step", "native_us_per_step", "native_c_host_us_per_step",
                        "pythonfmu_over_native", "pythonfmu_over_native_c_host"}
    assert row["steps"] == 10
    times = [row[k] for k in ("pythonfmu_us_per_step", "native_us_per_step", "native_c_host_us_per_step")]
    assert all(np.isfinite(t) and t > 0 for t in times), row
    assert row["pythonfmu_over_native"] == pytest.approx(times[0] / times[1])
    assert row["pythonfmu_over_native_c_host"] == pytest.approx(times[0] / times[2])


# -- the command line ------------------------------------------------------------------------------
def test_build_fmu_command_native_builds_the_blimp_rkgp(blimp_model_file, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["build-fmu", str(blimp_model_file), "--native", "--out", str(out), "--name", "blimp"]) == 0
    assert [p.name for p in out.iterdir()] == ["blimp.fmu"]
    assert "blimp.fmu" in capsys.readouterr().out
    assert validate_fmu(str(out / "blimp.fmu")) == []
    description = read_model_description(str(out / "blimp.fmu"))
    assert description.coSimulation.needsExecutionTool is False
    assert description.buildConfigurations[0].sourceFileSets[0].sourceFiles == list(C_SOURCES)


def test_build_fmu_native_refuses_a_greybox_model_of_other_physics(blimp_trained, tmp_path, capsys):
    model = save_model(tmp_path / "cart.npz", blimp_trained["model"], physics={"kind": "damped_cart"})
    assert main(["build-fmu", str(model), "--native", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp build-fmu: error:") and "blimp_rk4" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_unpacked_fmu_runs_from_its_sources_folder_name(native_fmu, tmp_path):
    """The FMU unpacked into a folder whose path needs percent-encoding (a space) still finds
    resources/model.bin (fmi2Instantiate decodes the file: URI)."""
    unzipped = extract(str(native_fmu), unzipdir=str(tmp_path / "with space"))
    host = Host(unzipped, name="spaced")
    try:
        host.fmu.setupExperiment(startTime=0.0)
        host.fmu.enterInitializationMode()
        host.fmu.exitInitializationMode()
        host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=STEP)
        assert np.all(np.isfinite(host.get()))
    finally:
        host.close()
