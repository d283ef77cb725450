"""The native (C, Python-free) GP-NARX rate predictor FMU (fmu_src/rate_predictor/native.py).

It passes the native FMU contract (tests/fmu_src/contract.py: the FMU contract, with the check
that the Python code inside is self-contained replaced by its native counterpart, plus the
native FMU's own checks) and the rate predictor's, with the case of the pythonfmu rate
predictor of the same model (same inputs, Python reference and tolerance).

Then what is particular to the native rate predictor: the same outputs as the pythonfmu FMU in
both modes (one step; free run by moment matching over the hyperparameter mixture, for the
paper's 400-sample model, a sparse one and ones whose output lags skip a lag), the free-run
belief in the FMU state, a corrupt belief refused as by the pythonfmu FMU, and bad start values.
"""
from __future__ import annotations

import json
import zipfile
from dataclasses import replace
from statistics import NormalDist

import numpy as np
import pytest
from fmpy import extract
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error

from fmu_src import build_native_rate_predictor_fmu, build_rate_predictor_fmu
from fmu_src.rate_predictor.native import MODEL_SOURCE
from tests.fmu_src.contract import FMI_FATAL, Host, NativeFmuContract, check_state_save_restore, run_in_fmpy
from tests.fmu_src.rate_predictor.contract import (
    RatePredictorContract,
    assert_fast_free_run_within_tolerance,
    rate_predictor_case,
)
from validation.models.narx import NarxConfig, one_step, save_trained, train_narx

OUTPUTS = [f"{axis}{suffix}" for axis in "pqr" for suffix in ("", "_lower", "_upper")]
STEP = 0.1  # the NARX step of the models here, s


@pytest.fixture(scope="module")
def case(native_rate_predictor_fmu, rate_predictor_fmu, bo105_trained, bo105_flights):
    """The case of the pythonfmu rate predictor, with the native FMU in its place: same inputs,
    same Python reference, same tolerance (1e-9 rad/s: the C code evaluates the formulas of
    NarxPredictor in another summation order; measured 1e-13)."""
    return replace(rate_predictor_case(rate_predictor_fmu, bo105_trained, bo105_flights["training"]),
                   path=native_rate_predictor_fmu, native_of=rate_predictor_fmu, model_source=MODEL_SOURCE)


class TestNativeRatePredictorFmu(NativeFmuContract, RatePredictorContract):
    """The native FMU contract and the rate predictor's, on the native rate predictor."""


def _run_fmpy(path, inputs: dict, *, free_run: bool, exact_moments: bool = True, parallel: bool = False) -> np.ndarray:
    """Every output of :data:`OUTPUTS` at every communication point of fmpy's simulate_fmu, the
    inputs (name -> (n,)) at the NARX step, in one-step or free-run mode; by default with the
    exact moments on one thread (the native FMU's fast path and its second thread are tested on
    their own)."""
    return run_in_fmpy(path, inputs, step=STEP, outputs=OUTPUTS,
                       start_values={"free_run": free_run, "exact_moments": exact_moments, "parallel": parallel})


@pytest.mark.parametrize("flight", ["training", "unseen"])
def test_outputs_equal_the_pythonfmu_fmu(case, bo105_flights, flight):
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
        native, python = (_run_fmpy(p, inputs, free_run=free_run) for p in (case.path, case.native_of))
        np.testing.assert_allclose(native, python, rtol=0, atol=1e-9)
        outputs[free_run] = native
    assert np.abs(outputs[True] - outputs[False]).max() > 1e-3  # the modes differ


@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize("flight", ["training", "unseen"])
def test_the_fast_free_run_is_within_2_percent_of_the_predicted_sd_of_the_exact_one(case, bo105_flights, flight,
                                                                                    parallel):
    """exact_moments = false (the default) takes the exponents and exponentials of the pair terms
    of eq. 6 in single precision: within 2 % of the predicted sd of the exact free run along the
    paper's 3-2-1-1 and the unseen one, on one thread and on two; measured at most 2.1e-5
    (means) and 2.8e-4 (standard deviations)."""
    assert_fast_free_run_within_tolerance(case.path, bo105_flights[flight].input("theta_1s")[::10], parallel=parallel)


def test_the_exact_free_run_on_two_threads_equals_the_one_on_one(case, bo105_flights):
    """parallel = true splits each step's samples and pair blocks between the FMU's thread and a
    second one: the same terms, each thread summing its share, the two partial sums added. Along
    the unseen 3-2-1-1, with the exact moments, every output equals the one-thread run's to 1e-9
    rad/s, the tolerance against the pythonfmu FMU: only the order of the sums differs, and eq. 4
    subtracts tr(A Q), whose terms are up to the inverse of K's smallest eigenvalue, from s2
    (measured 2.2e-10). (On the fast path a change in the last bit can round an exponent to
    another float, so two threads are held to the fast path's own tolerance against the exact
    run, in the test below.)"""
    u = bo105_flights["unseen"].input("theta_1s")[::10]
    one, two = (_run_fmpy(case.path, {"theta_1s": u}, free_run=True, parallel=p) for p in (False, True))
    np.testing.assert_allclose(two, one, rtol=0, atol=1e-9)
    assert np.ptp(two[:, OUTPUTS.index("q_upper")]) > 1e-3


def _threads_of_this_process() -> int:
    import os

    return len(os.listdir("/proc/self/task"))


def test_the_second_thread_starts_with_the_first_parallel_free_run_step_and_stops_with_the_instance(
        case, unzipdir, bo105_flights):
    """The second thread is the FMU's own: none before the first free-run step with parallel =
    true, one while the instance lives (across steps and a reset), none after fmi2FreeInstance.
    A one-step (not free-run) instance never starts it."""
    u = bo105_flights["unseen"].input("theta_1s")[::10]
    before = _threads_of_this_process()
    for free_run, started in ((True, 1), (False, 0)):
        host = Host(unzipdir, name=f"threads_{free_run}")
        try:
            host.set({"free_run": free_run, "parallel": True})
            host.start(case, case.inputs(0) if not free_run else {"theta_1s": u[0]})
            assert _threads_of_this_process() == before
            host.run(case, 0, 5, inputs=(lambda k: {"theta_1s": u[k]}) if free_run else None)
            assert _threads_of_this_process() == before + started
            host.fmu.reset()
            host.set({"free_run": free_run, "parallel": True})
            host.start(case, case.inputs(0) if not free_run else {"theta_1s": u[0]})
            host.run(case, 0, 3, inputs=(lambda k: {"theta_1s": u[k]}) if free_run else None)
            assert _threads_of_this_process() == before + started
        finally:
            host.close()
        assert _threads_of_this_process() == before


def test_free_run_belief_is_part_of_the_fmu_state(case, unzipdir, host):
    """The contract's save / step / restore / serialise check, in free-run mode: the belief (mean
    vector and covariance matrix over the lagged outputs) is saved, restored and serialised with
    the lag histories, also into a fresh instance."""
    check_state_save_restore(replace(case, parameters={**case.parameters, "free_run": True}), unzipdir, host)


def test_a_sparse_model_with_a_full_variance_factor_equals_the_python_model(bo105_flights, tmp_path):
    """A sparse GP's variance factor is not triangular: the native FMU then multiplies the full
    matrix (gp_predict.c, full_product), and its free run uses A = V^T V (K_mm^-1 - Sigma).
    One-step outputs equal GPNarx's, free-run outputs GPNarx's moment-matching free run, to
    1e-9 rad/s (measured 1e-13 and 5e-11; the free run's eq. 4 cancels as in the test above)."""
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
    # padded start of RatePredictorContract.test_free_run_mode_equals_the_python_moment_matching_free_run).
    u = recording.input("theta_1s")[::10, None]
    free = _run_fmpy(path, {"theta_1s": u[:, 0]}, free_run=True)
    means, upper = free[:, [OUTPUTS.index(a) for a in "pqr"]], free[:, [OUTPUTS.index(f"{a}_upper") for a in "pqr"]]
    lag = trained.model.structure.max_lag
    padded = np.vstack([np.repeat(u[:1], lag - 1, axis=0), u])
    python = trained.model.free_run(padded, np.tile(means[0], (lag, 1)), method="moment_matching", use_samples=True)
    np.testing.assert_allclose(means[1:], python.mean[lag:], rtol=0, atol=1e-9)
    np.testing.assert_allclose((upper - means)[1:] / z, np.sqrt(python.var[lag:]), rtol=0, atol=1e-9)
    # The free run moves, so the equality tests something (with one BLAS thread the fit makes the
    # roll rate's GP flat, so not every output moves).
    assert np.ptp(means[1:], axis=0).max() > 1e-1


@pytest.fixture(scope="module", params=[(2,), (1, 3)], ids=["output_lags_2", "output_lags_1_3"])
def skipped_lags(request, bo105_flights, tmp_path_factory):
    """A model whose output lags skip a lag (maximum likelihood, no restarts: a few seconds), its
    native and its pythonfmu FMU. The native FMU is built with ``-pedantic -Werror`` added to its
    flags, so it exists only if its sources, the projection's code included (compiled in only
    for such models, narx_model.c: N_Z < BELIEF_SIZE), compile without warnings under pedantic
    C99 (the flags change no code, so the FMU is the one the builder's defaults give)."""
    lags = request.param
    trained = train_narx([bo105_flights["training"]],
                         NarxConfig(hyperparameters="maximum_likelihood", output_lags=lags), seed=0, n_restarts=0)
    folder = tmp_path_factory.mktemp("skipped_lags")
    path = save_trained(folder / "skip.npz", trained)
    name = "skip_" + "_".join(map(str, lags))
    return (trained, build_native_rate_predictor_fmu(path, folder, name=f"{name}_native",
                                                     extra_flags=("-pedantic", "-Werror")),
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
    # warning-free too: the fixture's build of native_path, with -pedantic -Werror, raises otherwise.


def _corrupt_belief_covariance(serialised: bytes, belief_size: int, corrupt, *, native: bool) -> bytes:
    """A serialised FMU state with ``corrupt(cov)`` applied (in place) to its free-run belief
    covariance. Native: the covariance is the last block of the model state, which ends the
    serialised SlaveState, followed only by the refused message's length (0 here:
    fmi2_slave.c, serialised layout). pythonfmu: the JSON of fmu_src/fmi/slave.py, attribute _belief."""
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
        fmu, corrupt, phrase, case, bo105_trained, bo105_flights, tmp_path):
    """The free run checks the regressor covariance as MomentMatcher._standardise does (finite,
    symmetric and positive semi-definite to COVARIANCE_TOLERANCE = 1e-10 relative, in the
    standardised frame; narx_model.c: covariance_problem, eigenvalues by cyclic Jacobi). A belief
    covariance that fails (set from outside through a deserialised FMU state) makes the step a
    logged Error and fmi2Discard in both FMUs (the pythonfmu FMU: MomentMatcher raises, the base
    refuses the step), and changes nothing: the state is the corrupt one still, and restoring the
    good state, the run goes on as if the step had never been tried."""
    path = case.path if fmu == "native" else case.native_of
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



def test_the_vectorised_expm1_is_within_4_ulp_of_libm(tmp_path):
    """The pair blocks of eq. 6 use narx_model.c's branch-free expm1 of the clamped argument (so
    that they vectorise); against the C library's expm1 on 4e5 points of [-700, 700], scaled by 1,
    1e-6 and 1e-12 (the tiny arguments are where exp(x) - 1 would lose every digit). Measured: 2
    ulp."""
    import subprocess

    source = MODEL_SOURCE.read_text()
    body = source[source.index("#define LN2_HI"):source.index("/* expm1 in single precision")]
    (tmp_path / "check.c").write_text("""#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
""" + body + """
int main(void) {
    double worst = 0.0;
    for (long n = 0; n <= 400000; n++) {
        const double x = -700.0 + 1400.0 * n / 400000.0, scales[3] = {1.0, 1e-6, 1e-12};
        for (int v = 0; v < 3; v++) {
            const double exact = expm1(x * scales[v]), got = expm1_clamped(clamp_double(x * scales[v]));
            const double ulp = nextafter(fabs(exact), INFINITY) - fabs(exact);
            if (exact != 0.0 && fabs(got - exact) / ulp > worst) worst = fabs(got - exact) / ulp;
            if (exact == 0.0 && got != 0.0) worst = INFINITY;
        }
    }
    printf("%.17g\\n", worst);
    return 0;
}
""")
    for flags in ((), ("-ffp-contract=fast", "-mavx2", "-mfma")):  # the generic and the AVX2 + FMA kernels
        subprocess.run(["gcc", "-O2", "-std=c99", *flags, str(tmp_path / "check.c"), "-o", str(tmp_path / "check"),
                        "-lm"], check=True)
        worst = float(subprocess.run([str(tmp_path / "check")], capture_output=True, text=True, check=True).stdout)
        assert worst <= 4.0, f"{worst} ulp with {flags}"


def test_each_distinct_annealing_sample_is_stored_once(native_rate_predictor_fmu, bo105_trained):
    """Annealing repeats samples; the native FMU stores (and computes) each distinct one once,
    and its outputs still equal the pythonfmu FMU's over all 400 (test_outputs_equal_the_pythonfmu_fmu)."""
    with zipfile.ZipFile(native_rate_predictor_fmu) as archive:
        config = archive.read("sources/model_config.h").decode()
    distinct = [int(n) for n in config.split("DISTINCT_SAMPLES[")[1].split("{")[1].split("}")[0].split(",")]
    expected = [len(np.unique(gp.theta_samples_, axis=0)) for gp in bo105_trained.model.model.gps]
    assert distinct == expected and max(distinct) < 400
    assert "#define JOINT_SAMPLES 400" in config


def test_an_exact_model_of_more_than_512_points_free_runs_as_the_python_model(tmp_path):
    """An own block's band (8 rows of m) outgrows the 4096-term tile above m = 512, so the tile is
    sized by the band: an exact GP of 530 points (maximum likelihood on 5.5 s of the 3-2-1-1 at
    100 Hz, stride 1) free-runs in the native FMU, on one thread and on two, as GPNarx's
    moment-matching free run, to 1e-9 rad/s over 8 steps (the tolerance of the sparse model's test
    above). With a tile of 4096 terms the step wrote past it and the process aborted."""
    from dataclasses import replace as replace_config

    from validation.reproduce.bo105 import PAPER_CONFIG, TRAINING_MANOEUVRE, fly_3211

    config = replace_config(PAPER_CONFIG, hyperparameters="maximum_likelihood", stride=1)
    recording = fly_3211("bo105-80kt-flight", input_name="theta_1s", amplitude=np.radians(1.0),
                         step_time=TRAINING_MANOEUVRE["step_time"], start=1.0, duration=5.49, seed=0)
    trained = train_narx([recording], config, seed=0, n_restarts=0)
    assert len(trained.model.model.gps[0].X_train_) > 512
    native = build_native_rate_predictor_fmu(save_trained(tmp_path / "large.npz", trained), tmp_path)
    u = recording.input("theta_1s")[20:100:10, None]
    lag = trained.model.structure.max_lag
    for parallel in (False, True):
        free = _run_fmpy(native, {"theta_1s": u[:, 0]}, free_run=True, parallel=parallel)
        means = free[:, [OUTPUTS.index(a) for a in "pqr"]]
        upper = free[:, [OUTPUTS.index(f"{a}_upper") for a in "pqr"]]
        python = trained.model.free_run(np.vstack([np.repeat(u[:1], lag - 1, axis=0), u]),
                                        np.tile(means[0], (lag, 1)), method="moment_matching", use_samples=True)
        np.testing.assert_allclose(means[1:], python.mean[lag:], rtol=0, atol=1e-9)
        z = NormalDist().inv_cdf(0.975)
        np.testing.assert_allclose((upper - means)[1:] / z, np.sqrt(python.var[lag:]), rtol=0, atol=1e-9)
