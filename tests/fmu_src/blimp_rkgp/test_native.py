"""The native (C, Python-free) blimp RKGP FMU (fmu_src/blimp_rkgp/native.py).

It passes the native FMU contract (tests/fmu_src/contract.py: the FMU contract, with the check
that the Python code inside is self-contained replaced by its native counterpart, plus the
native FMU's own checks: the pythonfmu FMU's modelDescription, a plain C host given the start
state, the FMI call sequence, GUID and resources checks, pedantic C99, ``fmpy compile``) and the
blimp RKGP's, with the case of the pythonfmu blimp RKGP of the same model (the same commands,
start state, Python reference and tolerance), and the blimp RKGP's lagged contract (a model with
one GP per state whose GPs see the lagged fan commands).

Then what is particular to the native blimp: its outputs over whole command sequences (inside and
outside the training envelope) against the pythonfmu FMU's, one GP per state, a full variance
factor, the step fixed by the first fmi2DoStep inside the trained frame interval, ``flightgp
bench fmu``'s blimp timing, and an unpacked FMU whose path needs percent-encoding.
"""
from __future__ import annotations

import zipfile
from dataclasses import replace

import numpy as np
import pytest
from fmpy import extract
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error

from fmu_src import build_blimp_rkgp_fmu, build_native_blimp_rkgp_fmu
from fmu_src.blimp_rkgp.native import MODEL_SOURCE
from fmu_src.fmi import greybox_build
from gp_model import GreyBoxGP, save_model
from tests.fmu_src.blimp_rkgp.contract import (
    BLIMP_HOLD,
    BlimpRkgpContract,
    BlimpRkgpLaggedContract,
    blimp_reference,
    blimp_rkgp_case,
)
from tests.fmu_src.contract import FMI_FATAL, Host, NativeFmuContract, run_in_fmpy, standard_run
from validation.bench.fmu import time_blimp_rkgp_fmus
from validation.models.blimp_greybox import BlimpStepDescription
from validation.models.blimp_identification import physics_step
from validation.vehicles.blimp import INPUT_NAMES as BLIMP_INPUTS
from validation.vehicles.blimp import STATE_NAMES as BLIMP_STATES
from validation.vehicles.blimp import BlimpParameters
from validation.vehicles.blimp_flight import BlimpFlightTest

OUTPUTS = [*BLIMP_STATES, *(f"{s}_sd" for s in BLIMP_STATES)]
STEP = BlimpFlightTest.sample_time


@pytest.fixture(scope="module")
def case(native_blimp_rkgp_fmu, blimp_rkgp_fmu, blimp_trained):
    """The case of the pythonfmu blimp RKGP, with the native FMU in its place: the same commands,
    start state, Python reference (GreyBoxGP.rollout and propagate) and tolerance (1e-9: the same
    formulas for one state instead of a batch)."""
    return replace(blimp_rkgp_case(blimp_rkgp_fmu, blimp_trained), path=native_blimp_rkgp_fmu,
                   native_of=blimp_rkgp_fmu, model_source=MODEL_SOURCE)


@pytest.fixture(scope="module")
def lagged_case(native_blimp_lagged_fmu, blimp_lagged_fmu, blimp_lagged):
    return replace(blimp_rkgp_case(blimp_lagged_fmu, blimp_lagged, n_steps=40), path=native_blimp_lagged_fmu,
                   native_of=blimp_lagged_fmu, model_source=MODEL_SOURCE)


class TestNativeBlimpRkgpFmu(NativeFmuContract, BlimpRkgpContract):
    """The native FMU contract and the blimp RKGP's, on the native blimp RKGP."""


class TestLaggedNativeBlimpRkgpFmu(BlimpRkgpLaggedContract):
    """The blimp RKGP's lagged contract, on the native blimp RKGP."""


def _run_fmpy(path, commands: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Outputs at every communication point (n + 1, 24) of fmpy's simulate_fmu, commands (n + 1, 3)
    from the start state (12,)."""
    return run_in_fmpy(path, dict(zip(BLIMP_INPUTS, commands.T)), step=STEP, outputs=OUTPUTS,
                       start_values={f"{s}_start": v for s, v in zip(BLIMP_STATES, start)})


def _python_reference(model, params, commands: np.ndarray, start: np.ndarray) -> np.ndarray:
    """GreyBoxGP.rollout (mean fed back) and GreyBoxGP.propagate's sds, as the FMU's outputs
    (n + 1, 24), of a model without command lags."""
    return blimp_reference({"model": model, "params": params}, commands, start, step=STEP)


@pytest.mark.parametrize("commands", ["training", "unseen"])
def test_outputs_equal_the_pythonfmu_fmu_and_the_python_rollout(case, blimp_trained, commands):
    """Over 10 s (200 steps) of commands, the training ones and unseen ones that leave the
    envelope (u_gondola down to -0.5, trained 0.2 .. 0.8), every state and sd equals the pythonfmu
    FMU's and GreyBoxGP.rollout's (with GreyBoxGP.propagate's sds). Tolerance 1e-9 in SI units
    on states and sds alike: the same formulas for one state, rounded differently (numpy's BLAS
    and SIMD sin/cos/exp vs libm, ~1e-16 relative per operation), divided by the central
    difference's 2 * PROPAGATION_STEP in the Jacobian and grown by the dynamics over 200 steps."""
    if commands == "training":
        u = blimp_trained["commands"]
    else:
        rng = np.random.default_rng(1)
        levels = lambda low, high: np.repeat(rng.uniform(low, high, 21), BLIMP_HOLD)[:201]  # noqa: E731
        u = np.column_stack([levels(-0.5, 0.8), levels(-0.2, 0.6), levels(-0.8, 0.8)])
    start = blimp_trained["states"][0]
    native, python = (_run_fmpy(p, u, start) for p in (case.path, case.native_of))
    reference = _python_reference(blimp_trained["model"], blimp_trained["params"], u, start)
    _assert_outputs_equal(native, python)
    _assert_outputs_equal(native, reference)
    _assert_outputs_equal(python, reference)
    assert np.ptp(native[:, :12], axis=0).max() > 0.5 and native[1:, 12:].min() > 0  # a real test


def _assert_outputs_equal(actual: np.ndarray, desired: np.ndarray) -> None:
    """States and sds to 1e-9, SI units."""
    np.testing.assert_allclose(actual, desired, rtol=0, atol=1e-9)


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
                      physics=BlimpStepDescription(params).as_dict())
    return {"model": model, "params": params, "path": path, "commands": commands, "start": states[0]}


def test_one_gp_per_state_equals_the_pythonfmu_fmu_and_the_python_rollout(per_state_model, tmp_path):
    """Twelve parts (a nearly noise-free model): states and sds to 1e-9."""
    m = per_state_model
    native = build_native_blimp_rkgp_fmu(m["path"], tmp_path, name="per_state_native")
    python = build_blimp_rkgp_fmu(m["path"], tmp_path, name="per_state_python")
    with zipfile.ZipFile(native) as archive:
        assert "#define N_PARTS 12" in archive.read("sources/model_config.h").decode()
    outputs = _run_fmpy(native, m["commands"], m["start"])
    reference = _python_reference(m["model"], m["params"], m["commands"], m["start"])
    python = _run_fmpy(python, m["commands"], m["start"])
    _assert_outputs_equal(outputs, python)
    _assert_outputs_equal(outputs, reference)
    _assert_outputs_equal(python, reference)


def test_a_full_variance_factor_gives_the_same_outputs(blimp_model_file, case, blimp_trained, tmp_path,
                                                       monkeypatch):
    """The residual GPs (greybox.c, gp_predict.c) multiply a lower triangular V = L^-1 without the
    zeros above its diagonal; stored full (as a non-triangular factor would be), it adds exact
    zeros: identical outputs."""
    monkeypatch.setattr(greybox_build, "lower_triangular", lambda factor: False)
    full = build_native_blimp_rkgp_fmu(blimp_model_file, tmp_path, name="full_factor")
    with zipfile.ZipFile(full) as archive:
        assert "LOWER_TRIANGULAR[1] = {0}" in archive.read("sources/model_config.h").decode()
    u, start = blimp_trained["commands"][:41], blimp_trained["states"][0]
    np.testing.assert_array_equal(_run_fmpy(full, u, start), _run_fmpy(case.path, u, start))


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


def test_bench_times_both_blimp_fmus(case, blimp_trained):
    """validation.bench.fmu.time_blimp_rkgp_fmus (``flightgp bench fmu``'s blimp row): the
    report's structure, finite positive times and ratios that are their quotients (no speed
    asserted: speed goals live in the benchmark, docs/fmus.md, "Cost per step")."""
    row = time_blimp_rkgp_fmus(case.native_of, case.path, blimp_trained["commands"], blimp_trained["states"][0],
                               n_steps=10)
    assert set(row) == {"steps", "pythonfmu_us_per_step", "native_us_per_step", "native_c_host_us_per_step",
                        "pythonfmu_over_native", "pythonfmu_over_native_c_host"}
    assert row["steps"] == 10
    times = [row[k] for k in ("pythonfmu_us_per_step", "native_us_per_step", "native_c_host_us_per_step")]
    assert all(np.isfinite(t) and t > 0 for t in times), row
    assert row["pythonfmu_over_native"] == pytest.approx(times[0] / times[1])
    assert row["pythonfmu_over_native_c_host"] == pytest.approx(times[0] / times[2])


def test_unpacked_fmu_runs_from_its_sources_folder_name(case, tmp_path):
    """The FMU unpacked into a folder whose path needs percent-encoding (a space) still finds
    resources/model.bin (fmi2Instantiate decodes the file: URI)."""
    unzipped = extract(str(case.path), unzipdir=str(tmp_path / "with space"))
    host = Host(unzipped, name="spaced")
    try:
        host.fmu.setupExperiment(startTime=0.0)
        host.fmu.enterInitializationMode()
        host.fmu.exitInitializationMode()
        host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=STEP)
        assert np.all(np.isfinite(host.get()))
    finally:
        host.close()

