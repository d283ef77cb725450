"""Benchmarks: each measures flightgp against a peer run in the same process, as a ratio.

Speed goals live here, never in timed unit tests (see README, "Benchmarks").
"""
from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gp_model import (
    GaussianProcess,
    GPNarx,
    HigdonKernel,
    NarxStructure,
    SquaredExponentialARD,
    maximize_marginal_likelihood,
)
from validation.core.errors import BadInputError
from validation.core.progress import progress_bar


def _synthetic_regression(n: int, n_dims: int, seed: int):
    """Smooth test function plus noise on ``n`` uniform points in [-3, 3]^d (training) and 1000
    points (prediction)."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-3, 3, size=(n + 1000, n_dims))
    f = np.sin(X[:, 0]) * np.cos(0.5 * X[:, 1 % n_dims]) + 0.2 * X[:, -1]
    y = f + 0.1 * rng.standard_normal(len(X))
    return X[:n], y[:n], X[n:]


def bench_gp(*, sizes=(100, 500, 2000), n_restarts: int = 1, n_dims: int = 4, seed: int = 0,
             progress: bool = True) -> dict:
    """GP fit (type-II ML, L-BFGS-B, ``n_restarts`` random restarts) and predict (mean and
    standard deviation at 1000 points) against scikit-learn's ``GaussianProcessRegressor`` with
    the same kernel (signal variance x SE-ARD + white noise), data, standardised outputs and
    number of restarts.

    Returns
    -------
    dict
        ``{"rows": [{"n", "fit_s", "fit_s_sklearn", "fit_speedup", "lml", "lml_sklearn",
        "predict_s", "predict_s_sklearn", "predict_speedup"}, ...], "n_dims", "n_restarts"}``.
    """
    try:
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
    except ImportError:
        raise BadInputError("bench gp compares against scikit-learn: pip install scikit-learn "
                            "(or install flightgp with its [test] extra)") from None
    from tqdm.auto import tqdm

    rows = []
    for n in tqdm(sizes, desc="bench gp", unit="size", disable=not progress):
        X, y, X_test = _synthetic_regression(n, n_dims, seed)
        start = time.perf_counter()
        ours = GaussianProcess(SquaredExponentialARD(1.0, np.ones(n_dims)), noise_variance=0.1,
                               normalize_inputs=False, normalize_outputs=True).fit(X, y)
        result = maximize_marginal_likelihood(ours, n_restarts=n_restarts, seed=seed)
        fit_s = time.perf_counter() - start
        start = time.perf_counter()
        ours.predict(X_test, return_var=True)
        predict_s = time.perf_counter() - start

        kernel = ConstantKernel(1.0) * RBF(np.ones(n_dims)) + WhiteKernel(0.1)
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # sklearn's convergence chatter at the bounds
            theirs = GaussianProcessRegressor(kernel, normalize_y=True, n_restarts_optimizer=n_restarts,
                                              random_state=seed).fit(X, y)
        fit_s_sklearn = time.perf_counter() - start
        start = time.perf_counter()
        theirs.predict(X_test, return_std=True)
        predict_s_sklearn = time.perf_counter() - start
        rows.append({
            "n": n, "fit_s": fit_s, "fit_s_sklearn": fit_s_sklearn,
            "fit_speedup": fit_s_sklearn / fit_s,
            "lml": result.log_marginal_likelihood, "lml_sklearn": float(theirs.log_marginal_likelihood_value_),
            "predict_s": predict_s, "predict_s_sklearn": predict_s_sklearn,
            "predict_speedup": predict_s_sklearn / predict_s,
        })
    return {"rows": rows, "n_dims": n_dims, "n_restarts": n_restarts,
            "peer": "scikit-learn GaussianProcessRegressor"}


def format_gp_table(report: dict) -> str:
    """The ``bench gp`` report as a fixed-width table."""
    lines = [f"GP fit and predict vs {report['peer']} (d={report['n_dims']}, "
             f"restarts={report['n_restarts']}, BLAS threads={report.get('blas_threads', '?')}; "
             "speedup = sklearn time / flightgp time)",
             f"{'n':>6} {'fit s':>9} {'sklearn':>9} {'speedup':>8} {'lml':>11} {'lml sklearn':>12}"
             f" {'predict s':>10} {'sklearn':>9} {'speedup':>8}"]
    for r in report["rows"]:
        lines.append(f"{r['n']:>6} {r['fit_s']:>9.3f} {r['fit_s_sklearn']:>9.3f} {r['fit_speedup']:>7.2f}x"
                     f" {r['lml']:>11.3f} {r['lml_sklearn']:>12.3f} {r['predict_s']:>10.4f}"
                     f" {r['predict_s_sklearn']:>9.4f} {r['predict_speedup']:>7.2f}x")
    return "\n".join(lines)


# -- bench narx -----------------------------------------------------------------------------------
#: Regressors of ``bench narx``, shaped like the Bo105 case (Bo105 GP-NARX paper, AHS 74th Forum,
#: 2018): the cyclic input at lags 1 and 2 and the three body rates at lag 1.
NARX_STRUCTURE = NarxStructure(("theta_1s",), ("p", "q", "r"), input_lags=(1, 2), output_lags=(1,))
#: Training: every 25th regressor row (as the paper) of a recording long enough for 40 points.
NARX_STRIDE, NARX_TRAINING_POINTS = 25, 40
#: The issue's goal: at 1000 runs x 800 steps, the vectorised free run at least 50x faster than
#: the loop and under 2 s on the project's 2-core machine.
NARX_GOAL_RUNS, NARX_GOAL_STEPS, NARX_GOAL_SPEEDUP, NARX_GOAL_SECONDS = 1000, 800, 50.0, 2.0
#: Largest difference (output units) accepted between the loop's and the vectorised runs fed
#: the same random numbers. Rounding alone gives a few 1e-12 after 800 steps (measured; the
#: vectorised kernel expands squared distances into products); a real discrepancy (another
#: sample, draw or regressor) shows at the 0.01 noise level or above, on outputs of unit size.
NARX_AGREEMENT_TOLERANCE = 1e-8


def _rate_response(n: int, seed: int, *, noise: float = 0.01):
    """A synthetic recording with the Bo105 case's signals but not its physics, so that ``bench
    narx`` sets up in a second: a cyclic input held for 25 samples at random levels in [-1, 1]
    and three coupled, weakly non-linear, stable responses p, q, r (about unit size), plus white
    noise of standard deviation ``noise``.

    Returns
    -------
    inputs : ndarray, shape (n, 1)
    outputs : ndarray, shape (n, 3)
    """
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1.0, 1.0, n // 25 + 1), 25)[:n]
    y = np.zeros((n, 3))
    for k in range(2, n):
        p, q, r = y[k - 1]
        y[k] = [0.90 * p + 0.05 * q + 0.10 * u[k - 1] - 0.05 * u[k - 2],
                0.92 * q + 0.20 * np.tanh(u[k - 1]) - 0.08 * u[k - 2] - 0.02 * p,
                0.88 * r + 0.04 * p - 0.30 * q * q + 0.02 * u[k - 1]]
    return u[:, None], y + noise * rng.standard_normal(y.shape)


def _monte_carlo_draws(n_runs: int, n_steps: int, n_samples, seed: int):
    """The random numbers that ``GPNarx.free_run(method="monte_carlo", seed=seed)`` consumes, in
    its order: per output, the runs' hyperparameter samples (a random permutation of the runs
    modulo that output's number of samples); then step by step and output by output one
    standard-normal draw per run (one draw of all of them gives the same stream).

    Parameters
    ----------
    n_samples : sequence of int
        Hyperparameter samples of each output's GP.

    Returns
    -------
    assignment : list of ndarray, shape (n_runs,) each
        Sample used by each run, per output.
    draws : ndarray, shape (n_steps, n_outputs, n_runs)
    """
    rng = np.random.default_rng(seed)
    assignment = [rng.permutation(n_runs) % s for s in n_samples]
    return assignment, rng.standard_normal((n_steps, len(n_samples), n_runs))


def _free_run_loop(structure: NarxStructure, sample_gps, inputs, initial, assignment, draws, runs):
    """The peer of ``bench narx``: the Monte Carlo free run written the obvious way. Run by run
    and step by step, build the regressor vector, ask each output's GP for the run's
    hyperparameter sample (one :class:`GaussianProcess` per sample) for the predictive mean and
    variance of a noisy output at that single point, and draw the output from them (what
    ``free_run(..., feedback_noise=True)`` feeds back, the Bo105 paper's method).

    Parameters
    ----------
    structure : NarxStructure
    sample_gps : list (per output) of list (per hyperparameter sample) of GaussianProcess
    inputs : ndarray, shape (n, n_inputs)
    initial : ndarray, shape (max_lag, n_outputs)
    assignment, draws
        As returned by :func:`_monte_carlo_draws`.
    runs : sequence of int
        The runs to compute.

    Returns
    -------
    ndarray, shape (len(runs), n, n_outputs)
    """
    start, n = structure.max_lag, len(inputs)
    n_in, n_out = inputs.shape[1], len(sample_gps)
    result = np.zeros((len(runs), n, n_out))
    for row, r in enumerate(runs):
        history = result[row]
        history[:start] = initial
        for k in range(start, n):
            # Inputs first, then outputs, each signal lag by lag (NarxStructure.regressor_names).
            x = np.array([[inputs[k - i, c] for c in range(n_in) for i in structure.input_lags]
                          + [history[k - j, c] for c in range(n_out) for j in structure.output_lags]])
            for j, gps in enumerate(sample_gps):
                mean, var = gps[assignment[j][r]].predict(x, return_var=True, include_noise=True,
                                                          use_samples=False)
                history[k, j] = mean[0] + np.sqrt(var[0]) * draws[k - start, j, r]
    return result


def bench_narx(*, n_runs: int = 1000, n_steps: int = 800, loop_runs: int = 10, seed: int = 0,
               progress: bool = True) -> dict:
    """Monte Carlo free run of a GP-NARX (``n_runs`` runs of ``n_steps`` predicted steps, every
    run with its own annealing hyperparameter sample and its own draws) by
    :meth:`GPNarx.free_run`, vectorised over runs, against :func:`_free_run_loop`, the same
    computation run by run through :meth:`GaussianProcess.predict` at one point at a time.

    Model: :data:`NARX_STRUCTURE`, one GP per output with Higdon's kernel and simulated annealing
    at its defaults (400 samples), seed ``seed``, trained on 40 points of
    :func:`_rate_response`; the free run starts from rest under a new input of the same kind.

    Timing. The vectorised free run is timed once from cold, including the factorisation of
    every hyperparameter sample. The loop's set-up (one GP per sample and output, fitted to the
    same training points with that sample's hyperparameters) is timed once; its runs cost the
    same each, so it is timed on the first ``loop_runs`` runs and scaled linearly to
    ``n_runs`` (the full loop would take minutes).

    Agreement. The loop is fed exactly the random numbers the vectorised free run consumes
    (:func:`_monte_carlo_draws`), so on the runs it computes both must give the same
    trajectories up to rounding; the largest difference is reported, and above
    ``NARX_AGREEMENT_TOLERANCE`` the benchmark fails.

    Returns
    -------
    dict
        ``{"runs", "steps", "vectorised_s", "loop_s_estimated", "loop_runs_timed",
        "loop_setup_s", "loop_s_per_run", "speedup", "goal_speedup", "goal_seconds",
        "goal_met", "max_abs_difference", "training_points", "hyperparameter_samples",
        "peer"}``; times in seconds, speedup = loop / vectorised; ``goal_met`` is None unless
        the size is the goal's.
    """
    from tqdm.auto import tqdm

    structure, start = NARX_STRUCTURE, NARX_STRUCTURE.max_lag
    inputs, outputs = _rate_response(NARX_STRIDE * NARX_TRAINING_POINTS + start, seed)
    X, Y = structure.regressors(inputs, outputs)
    X, Y = X[::NARX_STRIDE], Y[::NARX_STRIDE]
    with progress_bar("bench narx: training", enabled=progress) as update:
        model = GPNarx.fit(structure, [(inputs, outputs)], kernel="higdon", hyperparameters="annealing",
                           stride=NARX_STRIDE, seed=seed, progress=update)
    test_inputs, _ = _rate_response(n_steps + start, seed + 1)
    initial = np.zeros((start, len(structure.output_names)))

    begin = time.perf_counter()
    vectorised = model.free_run(test_inputs, initial, method="monte_carlo", n_runs=n_runs,
                                seed=seed, feedback_noise=True, keep_runs=True)
    vectorised_s = time.perf_counter() - begin

    samples = [gp.theta_samples_ for gp in model.model.gps]
    begin = time.perf_counter()
    kernel = HigdonKernel(1.0, np.full(X.shape[1], 0.5))  # fit(theta=...) sets a clone of it
    sample_gps = [[GaussianProcess(kernel).fit(X, Y[:, j], theta=theta) for theta in thetas]
                  for j, thetas in enumerate(samples)]
    loop_setup_s = time.perf_counter() - begin
    assignment, draws = _monte_carlo_draws(n_runs, n_steps, [len(s) for s in samples], seed)
    runs = range(min(loop_runs, n_runs))
    begin = time.perf_counter()
    loop = _free_run_loop(structure, sample_gps, test_inputs, initial, assignment, draws,
                          tqdm(runs, desc="bench narx: loop", unit="run", disable=not progress))
    loop_s_per_run = (time.perf_counter() - begin) / len(runs)

    max_abs_difference = float(np.max(np.abs(loop - vectorised.runs[:len(runs)])))
    if not max_abs_difference <= NARX_AGREEMENT_TOLERANCE:
        raise RuntimeError(
            "bench narx: the vectorised free run and the loop differ by up to "
            f"{max_abs_difference:.3g} (tolerance {NARX_AGREEMENT_TOLERANCE:g}) on runs "
            f"0-{len(runs) - 1}; either "
            "GPNarx.free_run now consumes its random numbers in another order (update "
            "_monte_carlo_draws in validation/benchmarks.py) or one of the two is wrong")
    loop_s_estimated = loop_setup_s + loop_s_per_run * n_runs
    speedup = loop_s_estimated / vectorised_s
    goal_met = (speedup >= NARX_GOAL_SPEEDUP and vectorised_s <= NARX_GOAL_SECONDS
                if (n_runs, n_steps) == (NARX_GOAL_RUNS, NARX_GOAL_STEPS) else None)
    return {"runs": n_runs, "steps": n_steps, "vectorised_s": vectorised_s,
            "loop_s_estimated": loop_s_estimated, "loop_runs_timed": len(runs),
            "loop_setup_s": loop_setup_s, "loop_s_per_run": loop_s_per_run,
            "speedup": speedup, "goal_speedup": NARX_GOAL_SPEEDUP,
            "goal_seconds": NARX_GOAL_SECONDS, "goal_met": goal_met,
            "max_abs_difference": max_abs_difference, "training_points": len(X),
            "hyperparameter_samples": [len(s) for s in samples],
            "peer": "run-by-run, point-by-point loop over GaussianProcess.predict"}


def format_narx_table(report: dict) -> str:
    """The ``bench narx`` report as a fixed-width table."""
    met = {True: "yes", False: "no", None: "n/a"}[report["goal_met"]]
    goal = f">={report['goal_speedup']:g}x, <={report['goal_seconds']:g} s"
    samples = report["hyperparameter_samples"]
    lines = [f"GP-NARX Monte Carlo free run vs a {report['peer']} ({len(samples)} "
             f"outputs, {report['training_points']} training points, "
             f"{'/'.join(map(str, samples))} hyperparameter samples, "
             f"BLAS threads={report.get('blas_threads', '?')}; peer timed on "
             f"{report['loop_runs_timed']} runs, scaled to R; speedup = loop / vectorised time; "
             f"the goal applies at {NARX_GOAL_RUNS} runs x {NARX_GOAL_STEPS} steps)",
             f"{'runs':>6} {'steps':>6} {'vectorised s':>13} {'loop s (est.)':>14} {'speedup':>8}"
             f" {'goal':>18} {'met':>4} {'max |diff|':>11}",
             f"{report['runs']:>6} {report['steps']:>6} {report['vectorised_s']:>13.3f}"
             f" {report['loop_s_estimated']:>14.2f} {report['speedup']:>7.1f}x {goal:>18}"
             f" {met:>4} {report['max_abs_difference']:>11.2g}"]
    return "\n".join(lines)


#: A bare pythonfmu FMU with the rate predictor's variables that copies its inputs to its outputs:
#: the per-step overhead any pythonfmu FMU pays in fmpy, the peer of ``bench fmu``.
_BARE_FMU_SCRIPT = """
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

INPUTS = {inputs!r}
OUTPUTS = {outputs!r}


class {name}(Fmi2Slave):
    description = "bare pythonfmu FMU: outputs copy inputs (flightgp bench fmu peer)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        for name in INPUTS:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input,
                                        variability=Fmi2Variability.continuous, start=0.0))
        for name in OUTPUTS:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.output,
                                        variability=Fmi2Variability.continuous, initial="exact",
                                        start=0.0))

    def do_step(self, current_time, step_size):
        for index, name in enumerate(OUTPUTS):
            setattr(self, name, getattr(self, INPUTS[index % len(INPUTS)]))
        return True
"""


def _time_fmu_steps(fmu_path, inputs, outputs, *, n_steps: int, step: float, repeats: int = 3,
                    values=None, start_values: dict | None = None) -> float:
    """Best-of-``repeats`` wall time per communication step (s) of ``setReal(inputs)``,
    ``doStep``, ``getReal(outputs)`` in fmpy's FMU2Slave, with varying input values: ``values``
    (shape (n_steps, len(inputs)), row ``k`` set before step ``k``), by default small sines.
    ``start_values`` (Real name -> value) are set before initialisation in every repeat."""
    import shutil

    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    description = read_model_description(str(fmu_path))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    unzipdir = extract(str(fmu_path))
    try:
        fmu = FMU2Slave(guid=description.guid, unzipDirectory=unzipdir,
                        modelIdentifier=description.coSimulation.modelIdentifier, instanceName="bench")
        fmu.instantiate()
        in_refs, out_refs = [refs[n] for n in inputs], [refs[n] for n in outputs]
        if values is None:
            values = 0.01 * np.sin(np.arange(n_steps)[:, None] + np.arange(len(inputs)))
        starts = start_values or {}
        best = np.inf
        for _ in range(repeats):
            fmu.reset()
            if starts:
                fmu.setReal([refs[n] for n in starts], [float(v) for v in starts.values()])
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
            begin = time.perf_counter()
            for k in range(n_steps):  # time from the step counter, t = k h
                fmu.setReal(in_refs, values[k].tolist())
                fmu.doStep(currentCommunicationPoint=k * step, communicationStepSize=step)
                fmu.getReal(out_refs)
            best = min(best, (time.perf_counter() - begin) / n_steps)
        fmu.terminate()
        fmu.freeInstance()
    finally:
        shutil.rmtree(unzipdir, ignore_errors=True)
    return best


def bench_fmu(*, n_steps: int = 2000, seed: int = 0, progress: bool = True) -> dict:
    """Per-step cost in fmpy of the Bo105 GP rate-predictor FMU (the paper's model: 32
    training points, Higdon kernel, 400 annealing samples per output) against a bare pythonfmu
    FMU with the same variables, both built and timed in this run.

    Then the native FMUs (issue 8) against the pythonfmu FMU of the same model, timed in fmpy and
    in the plain C host: the rate predictor of the paper's model and of :data:`NATIVE_MODELS`
    (:func:`_native_rows`, key ``"native"``), and the blimp RKGP (:func:`blimp_rkgp_row`, key
    ``"blimp"``).

    Returns
    -------
    dict
        ``{"steps", "gp_us_per_step", "bare_us_per_step", "gp_over_bare", "goal_ratio",
        "goal_met", "training_points", "hyperparameter_samples", "real_time_factor_at_narx_step",
        "native_us_per_step", "native_over_bare", "gp_over_native", "native", "native_goal_ratio",
        "native_goal_us_at_500", "blimp"}``.
    """
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    from fmu_src.builder import build_rate_predictor_fmu
    from validation.models.narx import save_trained, train_narx
    from validation.reproduce.bo105 import PAPER_CONFIG, TRAINING_MANOEUVRE, fly_3211

    recording = fly_3211("bo105-80kt-flight", input_name="theta_1s",
                         amplitude=np.radians(TRAINING_MANOEUVRE["amplitude_deg"]),
                         step_time=TRAINING_MANOEUVRE["step_time"], start=1.0, duration=8.0, seed=seed)
    trained = train_narx([recording], PAPER_CONFIG, seed=seed, progress=progress)
    inputs = [*PAPER_CONFIG.inputs, *(f"{o}_prev" for o in PAPER_CONFIG.outputs)]
    outputs = [n for o in PAPER_CONFIG.outputs for n in (o, f"{o}_lower", f"{o}_upper")]
    with tempfile.TemporaryDirectory(prefix="flightgp-bench-fmu-") as scratch:
        scratch = Path(scratch)
        gp_fmu = build_rate_predictor_fmu(save_trained(scratch / "gp.npz", trained), scratch,
                                          name="bench_gp_rate_predictor")
        script = scratch / "bench_bare_fmu.py"
        script.write_text(_BARE_FMU_SCRIPT.format(inputs=inputs, outputs=outputs, name="bench_bare_fmu"))
        subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(script), "-d", str(scratch)],
                       check=True, capture_output=True)
        step = trained.step
        bare = _time_fmu_steps(scratch / "bench_bare_fmu.fmu", inputs, outputs, n_steps=n_steps, step=step)
        gp = _time_fmu_steps(gp_fmu, inputs, outputs, n_steps=n_steps, step=step)
        native = _native_rows(scratch, scratch / "gp.npz", gp, inputs, outputs, n_steps=n_steps, step=step,
                              seed=seed, progress=progress)
        blimp = blimp_rkgp_row(scratch, n_steps=n_steps, seed=seed)
    samples = [len(g.theta_samples_) for g in trained.model.model.gps]
    return {"steps": n_steps, "gp_us_per_step": gp * 1e6, "bare_us_per_step": bare * 1e6,
            "gp_over_bare": gp / bare, "goal_ratio": FMU_GOAL_RATIO, "goal_met": gp / bare <= FMU_GOAL_RATIO,
            "training_points": int(len(trained.model.model.gps[0].X_train_)),
            "hyperparameter_samples": samples,
            "real_time_factor_at_narx_step": step / gp,
            "native_us_per_step": native[0]["native_us_per_step"], "native_over_bare":
                native[0]["native_us_per_step"] / (bare * 1e6),
            "gp_over_native": gp * 1e6 / native[0]["native_us_per_step"], "native": native,
            "native_goal_ratio": NATIVE_GOAL_RATIO, "native_goal_us_at_500": NATIVE_GOAL_US, "blimp": blimp}


#: Goal of ``bench fmu`` (issue 5): the GP adds at most this factor to the bare FMU's step cost.
FMU_GOAL_RATIO = 3.0


#: ``bench fmu``'s native comparison besides the paper's model: label, changes to
#: ``PAPER_CONFIG``, training rows (None: the paper's 3-2-1-1 at stride 25, 32 points).
NATIVE_MODELS = (
    ("32 points, 1 sample (max. likelihood)", {"hyperparameters": "maximum_likelihood"}, None),
    ("500 points, 1 sample (max. likelihood)", {"hyperparameters": "maximum_likelihood", "stride": 1}, 500),
    ("500 points, 50 inducing (sparse)", {"hyperparameters": "maximum_likelihood", "stride": 1,
                                          "n_inducing": 50}, 500),
)
#: Goals of the native FMU (issue 8): a step, variance included, at least this many times
#: cheaper than the pythonfmu FMU's, and under this many microseconds at 500 training points.
NATIVE_GOAL_RATIO, NATIVE_GOAL_US = 10.0, 10.0


def _native_rows(scratch, paper_model, paper_gp_s: float, inputs, outputs, *, n_steps: int, step: float,
                 seed: int, progress: bool) -> list:
    """Per-step cost of native rate-predictor FMUs (:mod:`fmu_src.native`) next to the pythonfmu
    FMU of the same model: the paper's model (``paper_model``, whose pythonfmu FMU took
    ``paper_gp_s`` per step) and :data:`NATIVE_MODELS`. The native FMU is timed in fmpy (the same
    ``setReal`` + ``doStep`` + ``getReal`` through ctypes as the pythonfmu FMUs) and in the plain C
    host (:func:`validation.cosim.hosts.simulate_in_c_host`: the same three calls without Python).

    Returns
    -------
    list of dict
        ``{"model", "training_points", "basis_points", "hyperparameter_samples",
        "pythonfmu_us_per_step", "native_us_per_step", "native_c_host_us_per_step",
        "pythonfmu_over_native", "pythonfmu_over_native_c_host"}`` per model, the paper's first.
    """
    from dataclasses import replace

    from fmu_src.builder import build_rate_predictor_fmu
    from fmu_src.native import build_native_rate_predictor_fmu
    from validation.cosim.hosts import simulate_in_c_host
    from validation.models.narx import load_trained, save_trained, train_narx
    from validation.reproduce.bo105 import PAPER_CONFIG, TRAINING_MANOEUVRE, fly_3211

    values = 0.01 * np.sin(np.arange(n_steps + 1)[:, None] + np.arange(len(inputs)))
    signals = dict(zip(inputs, values.T))
    models = [("paper: 32 points, 400 samples (annealing)", paper_model, paper_gp_s)]
    for label, changes, rows in NATIVE_MODELS:
        config = replace(PAPER_CONFIG, **changes)
        # rows regressor rows at stride 1: a recording of rows + max_lag NARX steps of samples
        duration = (8.0 if rows is None else
                    (rows + config.structure().max_lag * config.decimation - 1) * 0.01)
        recording = fly_3211("bo105-80kt-flight", input_name="theta_1s",
                             amplitude=np.radians(TRAINING_MANOEUVRE["amplitude_deg"]),
                             step_time=TRAINING_MANOEUVRE["step_time"], start=1.0, duration=duration, seed=seed)
        trained = train_narx([recording], config, seed=seed, progress=progress, n_restarts=0)
        path = save_trained(scratch / f"native_{len(models)}.npz", trained)
        python_fmu = build_rate_predictor_fmu(path, scratch, name=f"bench_python_{len(models)}")
        models.append((label, path, _time_fmu_steps(python_fmu, inputs, outputs, n_steps=n_steps, step=step)))
    result = []
    for index, (label, path, python_s) in enumerate(models):
        fmu = build_native_rate_predictor_fmu(path, scratch, name=f"bench_native_{index}")
        native_s = _time_fmu_steps(fmu, inputs, outputs, n_steps=n_steps, step=step)
        c_host_us = simulate_in_c_host(fmu, step_size=step, n_steps=n_steps, inputs=signals, outputs=outputs,
                                       repeats=3)["us_per_step"]
        gps = load_trained(path).model.model.gps
        forms = gps[0].predictive_forms(use_samples=True)
        result.append({"model": label, "training_points": int(len(gps[0].X_train_)),
                       "basis_points": int(len(forms[0].basis)), "hyperparameter_samples": len(forms),
                       "pythonfmu_us_per_step": python_s * 1e6, "native_us_per_step": native_s * 1e6,
                       "native_c_host_us_per_step": c_host_us, "pythonfmu_over_native": python_s / native_s,
                       "pythonfmu_over_native_c_host": python_s * 1e6 / c_host_us})
    return result


#: ``bench fmu``'s blimp RKGP model: seconds of blimp-flight (20 Hz, true states) under random
#: piecewise-constant commands held for ``BLIMP_HOLD`` frames, as tests/test_fmu.py trains it.
BLIMP_SECONDS, BLIMP_HOLD = 10.0, 10


def blimp_rkgp_row(scratch, *, n_steps: int, seed: int = 0) -> dict:
    """Per-step cost of the native blimp RKGP FMU (:func:`fmu_src.native_blimp.build_native_blimp_rkgp_fmu`)
    against the pythonfmu blimp RKGP FMU (:func:`fmu_src.builder.build_blimp_rkgp_fmu`), both built
    in ``scratch`` from one small grey-box model trained here as tests/test_fmu.py does:
    :data:`BLIMP_SECONDS` of ``blimp-flight`` (mocap off, 20 Hz) under random commands, a shared GP
    on the RK4 physics leaving out position and yaw (200 training pairs, maximum likelihood
    without restarts: about a second). Timed by :func:`time_blimp_rkgp_fmus` on the training
    commands from the training start state (inside the envelope).

    Returns
    -------
    dict
        :func:`time_blimp_rkgp_fmus`'s, with ``"model"`` and ``"training_pairs"``.
    """
    from pathlib import Path

    from fmu_src.builder import build_blimp_rkgp_fmu
    from fmu_src.native_blimp import build_native_blimp_rkgp_fmu
    from gp_model import GreyBoxGP, save_model
    from validation.models.blimp_identification import blimp_physics_description, physics_step, recording_arrays
    from validation.vehicles.blimp import BlimpParameters
    from validation.vehicles.blimp_flight import BlimpFlightTest

    scratch = Path(scratch)
    time_ = np.arange(int(round(BLIMP_SECONDS / BlimpFlightTest.sample_time)) + 1) * BlimpFlightTest.sample_time
    rng = np.random.default_rng(seed)
    levels = lambda low, high: np.repeat(  # noqa: E731
        rng.uniform(low, high, len(time_) // BLIMP_HOLD + 1), BLIMP_HOLD)[:len(time_)]
    commands = np.column_stack([levels(0.2, 0.8), levels(-0.2, 0.4), levels(-0.6, 0.6)])
    states, step_inputs = recording_arrays(BlimpFlightTest(mocap=False).simulate(time_, commands, seed=seed))
    params = BlimpParameters()
    model = GreyBoxGP(state_columns=(3, 4, 6, 7, 8, 9, 10, 11), n_restarts=0).fit_trajectories(
        [(states, step_inputs)], physics_step(params))
    path = save_model(scratch / "blimp_rkgp.npz", model, physics=blimp_physics_description(params))
    row = time_blimp_rkgp_fmus(build_blimp_rkgp_fmu(path, scratch, name="bench_blimp_python"),
                               build_native_blimp_rkgp_fmu(path, scratch, name="bench_blimp_native"),
                               commands, states[0], n_steps=n_steps)
    pairs = int(len(states) - 1)
    return {"model": f"blimp RKGP: {pairs} pairs, shared GP, 1 sample (max. likelihood)",
            "training_pairs": pairs, **row}


def time_blimp_rkgp_fmus(python_fmu, native_fmu, commands, start, *, n_steps: int) -> dict:
    """Per-step cost of a pythonfmu and a native blimp RKGP FMU of one model flying ``commands``
    (shape (n + 1, 3), one row per 20 Hz frame) from the state ``start`` (12,), for
    ``min(n_steps, n)`` steps: ``setReal`` + ``doStep`` + ``getReal`` (3 commands in, 12 states
    and 12 sds out), best of 3, in fmpy (both FMUs) and in the plain C host
    (:func:`validation.cosim.hosts.simulate_in_c_host`, the native one).

    Returns
    -------
    dict
        ``{"steps", "pythonfmu_us_per_step", "native_us_per_step", "native_c_host_us_per_step",
        "pythonfmu_over_native", "pythonfmu_over_native_c_host"}``.
    """
    from validation.cosim.hosts import simulate_in_c_host
    from validation.vehicles.blimp import INPUT_NAMES, STATE_NAMES
    from validation.vehicles.blimp_flight import BlimpFlightTest

    h, commands = BlimpFlightTest.sample_time, np.asarray(commands, dtype=float)
    steps = min(n_steps, len(commands) - 1)
    outputs = [*STATE_NAMES, *(f"{s}_sd" for s in STATE_NAMES)]
    starts = {f"{s}_start": float(v) for s, v in zip(STATE_NAMES, start)}
    python_us, native_us = (_time_fmu_steps(fmu, INPUT_NAMES, outputs, n_steps=steps, step=h,
                                            values=commands[:steps], start_values=starts) * 1e6
                            for fmu in (python_fmu, native_fmu))
    c_host_us = simulate_in_c_host(native_fmu, step_size=h, n_steps=steps, outputs=outputs, start_values=starts,
                                   inputs=dict(zip(INPUT_NAMES, commands[:steps + 1].T)),
                                   repeats=3)["us_per_step"]
    return {"steps": steps, "pythonfmu_us_per_step": python_us, "native_us_per_step": native_us,
            "native_c_host_us_per_step": c_host_us, "pythonfmu_over_native": python_us / native_us,
            "pythonfmu_over_native_c_host": python_us / c_host_us}


def format_fmu_table(report: dict) -> str:
    """The ``bench fmu`` report as a table."""
    blimp = report.get("blimp")
    native = [
        "",
        f"Native (C) FMUs vs the pythonfmu FMU of the same model, us per step (fmpy: the same calls "
        f"through ctypes; C host: the same calls from C, no Python); goals: >= "
        f"{report['native_goal_ratio']:g}x cheaper, < {report['native_goal_us_at_500']:g} us at 500 points",
        f"{'model':<42} {'basis':>5} {'S':>4} {'pythonfmu':>10} {'native':>8} {'C host':>8} {'ratio':>7} "
        f"{'ratio C':>8}",
        *(f"{r['model']:<42} {r['basis_points']:>5} {r['hyperparameter_samples']:>4} "
          f"{r['pythonfmu_us_per_step']:>10.1f} {r['native_us_per_step']:>8.1f} "
          f"{r['native_c_host_us_per_step']:>8.2f} {r['pythonfmu_over_native']:>6.1f}x "
          f"{r['pythonfmu_over_native_c_host']:>7.1f}x" for r in report.get("native", [])),
        *([f"{'blimp RKGP (shared GP, RK4 physics)':<42} {blimp['training_pairs']:>5} {1:>4} "
           f"{blimp['pythonfmu_us_per_step']:>10.1f} {blimp['native_us_per_step']:>8.1f} "
           f"{blimp['native_c_host_us_per_step']:>8.2f} {blimp['pythonfmu_over_native']:>6.1f}x "
           f"{blimp['pythonfmu_over_native_c_host']:>7.1f}x",
           f"(blimp RKGP: 3 commands in, 12 states and 12 sds out, {blimp['steps']} steps of its training "
           "flight at 20 Hz)"] if blimp else []),
    ] if report.get("native") or blimp else []
    return "\n".join([
        f"Rate-predictor FMU step cost in fmpy (setReal + doStep + getReal, best of 3 x "
        f"{report['steps']} steps) vs a bare pythonfmu FMU with the same variables; "
        f"{report['training_points']} training points, {report['hyperparameter_samples'][0]} "
        "hyperparameter samples per output",
        f"{'GP FMU us/step':>15} {'bare us/step':>13} {'ratio':>8} {'goal':>7} {'met':>4} {'x real time':>12}",
        f"{report['gp_us_per_step']:15.1f} {report['bare_us_per_step']:13.1f} "
        f"{report['gp_over_bare']:7.1f}x {'<=' + format(report['goal_ratio'], 'g') + 'x':>7} "
        f"{'yes' if report['goal_met'] else 'no':>4} {report['real_time_factor_at_narx_step']:12.0f}",
        *native,
    ])


#: Goal of ``bench cosim`` (issue 8): the 8 s 3-2-1-1 co-simulation at least this many times
#: faster than real time.
COSIM_GOAL_REAL_TIME = 200.0


def bench_cosim(*, seed: int = 0, progress: bool = True) -> dict:
    """Wall-clock time of the 8 s 80 kt 3-2-1-1 co-simulation in fmpy (``flightgp cosim``: the GP
    rate-predictor FMU in free-run mode, moment matching, next to the Bo105 reference FMU) against
    the same co-simulation's simulated time (real time) and against the reference FMU alone in
    the same loop (the peer), for the pythonfmu and the native GP FMU of two models: the paper's
    (32 points, 400 annealing samples) and one with a single (maximum-likelihood) hyperparameter
    set.

    Returns
    -------
    dict
        ``{"simulated_s", "goal_real_time", "rows": [{"model", "fmu", "seconds",
        "real_time_factor", "over_reference_alone", "goal_met"}], "reference_alone_s"}``.
    """
    import tempfile
    from dataclasses import replace
    from pathlib import Path

    from fmu_src.builder import build_bo105_reference_fmu, build_rate_predictor_fmu
    from fmu_src.native import build_native_rate_predictor_fmu
    from validation.cosim.cosimulation import cosimulate, simulate
    from validation.models.narx import save_trained, train_narx
    from validation.reproduce.bo105 import PAPER_CONFIG, TRAINING_MANOEUVRE, fly_3211

    recording = fly_3211("bo105-80kt-flight", input_name="theta_1s",
                         amplitude=np.radians(TRAINING_MANOEUVRE["amplitude_deg"]),
                         step_time=TRAINING_MANOEUVRE["step_time"], start=1.0, duration=8.0, seed=seed)
    simulated = float(recording.time[-1] - recording.time[0])
    models = (("paper: 32 points, 400 samples", PAPER_CONFIG, {}),
              ("32 points, 1 sample (max. likelihood)",
               replace(PAPER_CONFIG, hyperparameters="maximum_likelihood"), {"n_restarts": 0}))
    rows = []
    with tempfile.TemporaryDirectory(prefix="flightgp-bench-cosim-") as scratch:
        scratch = Path(scratch)
        reference = build_bo105_reference_fmu(80, scratch, name="bench_reference")
        rows_01 = slice(None, None, 10)  # the recording (100 Hz) on the 0.1 s NARX grid
        reference_alone = _best_time(lambda: simulate(
            reference, time=recording.time[rows_01] - recording.time[0],
            inputs={c: recording.input(c)[rows_01] for c in recording.input_names}, outputs=["p", "q", "r"]))
        for index, (label, config, options) in enumerate(models):
            trained = train_narx([recording], config, seed=seed, progress=progress, **options)
            path = save_trained(scratch / f"model_{index}.npz", trained)
            for kind, build in (("pythonfmu", build_rate_predictor_fmu),
                                ("native", build_native_rate_predictor_fmu)):
                fmu = build(path, scratch, name=f"bench_{kind}_{index}")
                seconds = _best_time(lambda: cosimulate(fmu, recording, reference_fmu=reference))
                rows.append({"model": label, "fmu": kind, "seconds": seconds,
                             "real_time_factor": simulated / seconds,
                             "over_reference_alone": seconds / reference_alone,
                             "goal_met": simulated / seconds >= COSIM_GOAL_REAL_TIME})
    return {"simulated_s": simulated, "goal_real_time": COSIM_GOAL_REAL_TIME,
            "reference_alone_s": reference_alone, "rows": rows}


def _best_time(run, *, repeats: int = 3) -> float:
    """Best wall-clock seconds of ``run()`` over ``repeats`` calls."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - start)
    return best


def format_cosim_table(report: dict) -> str:
    """The ``bench cosim`` report as a table."""
    return "\n".join([
        f"Co-simulation of the {report['simulated_s']:g} s 80 kt 3-2-1-1 in fmpy (GP FMU free run + "
        f"Bo105 reference FMU), best of 3; reference FMU alone {report['reference_alone_s'] * 1e3:.0f} ms; "
        f"goal >= {report['goal_real_time']:g}x real time",
        f"{'model':<40} {'GP FMU':<10} {'s':>7} {'x real time':>12} {'x ref. alone':>13} {'met':>4}",
        *(f"{r['model']:<40} {r['fmu']:<10} {r['seconds']:7.3f} {r['real_time_factor']:12.1f} "
          f"{r['over_reference_alone']:13.1f} {'yes' if r['goal_met'] else 'no':>4}" for r in report["rows"]),
    ])


#: ``bench diagnose``: the diagnose-bench cases timed (one per kind of search outcome).
DIAGNOSE_CASES = ("none", "delay-theta_1s-60ms", "M_q-40%", "pair-delay+bias", "outside-quadratic-damping")
#: Goal of ``bench diagnose`` (issue 7): seconds per case for a 20 s recording at 100 Hz.
DIAGNOSE_GOAL_S = 60.0


def bench_diagnose(*, seed: int = 0, progress: bool = True) -> dict:
    """Wall-clock time of ``flightgp diagnose`` on concealed-effect cases
    (:mod:`validation.diagnose.bench`; 20 s at 100 Hz plus a 20 s held-out recording) against
    the recording's duration (real time) and the goal of :data:`DIAGNOSE_GOAL_S` per case.

    Returns
    -------
    dict
        ``{"cases": [{"case", "seconds", "over_recording", "passed"}], "goal_s", "max_seconds",
        "goal_met", "recording_s"}``.
    """
    from validation.diagnose.bench import DURATION, concealed_cases, run_bench

    cases = [case for case in concealed_cases() if case.name in DIAGNOSE_CASES]
    with progress_bar("bench diagnose", enabled=progress, total=len(cases), unit="case") as update:
        report = run_bench(cases, seed=seed, progress=update)
    rows = [{"case": row["case"], "seconds": row["seconds"], "over_recording": row["seconds"] / DURATION,
             "passed": row["passed"]} for row in report["cases"]]
    worst = max(row["seconds"] for row in rows)
    return {"cases": rows, "goal_s": DIAGNOSE_GOAL_S, "max_seconds": worst,
            "goal_met": worst <= DIAGNOSE_GOAL_S, "recording_s": DURATION}


def format_diagnose_table(report: dict) -> str:
    """The ``bench diagnose`` report as a table."""
    return "\n".join([
        f"flightgp diagnose per case ({report['recording_s']:g} s at 100 Hz + a held-out recording); "
        f"goal <= {report['goal_s']:g} s per case",
        f"{'case':<28} {'s':>6} {'x recording':>12} {'scored':>7}",
        *(f"{r['case']:<28} {r['seconds']:6.1f} {r['over_recording']:12.2f} "
          f"{'pass' if r['passed'] else 'fail':>7}" for r in report["cases"]),
    ])


@dataclass(frozen=True)
class Benchmark:
    """One entry of :data:`BENCHMARKS`.

    Attributes
    ----------
    run : callable
        ``run(progress=..., **options) -> dict``, the JSON report.
    format_table : callable
        ``format_table(report) -> str``.
    options : dict
        Command-line option of ``flightgp bench`` (argparse dest) -> keyword of ``run``.
    summary : callable
        ``summary(report) -> [(measure, value, goal, met)]``: the headline rows of the combined
        ``flightgp bench`` table (``value`` and ``goal`` as text, ``met`` True/False/None).
    """

    run: Callable[..., dict]
    format_table: Callable[[dict], str]
    options: dict
    summary: Callable[[dict], list]


def _gp_summary(report: dict) -> list:
    rows = []
    for row in report["rows"]:
        rows.append((f"GP fit vs scikit-learn, n = {row['n']}", f"{row['fit_speedup']:.1f}x faster",
                     ">= 3x", row["fit_speedup"] >= 3.0))
    return rows


def _narx_summary(report: dict) -> list:
    return [("Monte Carlo free run vs run-by-run loop", f"{report['speedup']:.0f}x faster, "
             f"{report['vectorised_s']:.2f} s", f">= {report['goal_speedup']:g}x, "
             f"<= {report['goal_seconds']:g} s", report["goal_met"])]


def _fmu_summary(report: dict) -> list:
    rows = [("pythonfmu GP FMU step vs bare pythonfmu FMU", f"{report['gp_over_bare']:.1f}x the cost",
             f"<= {report['goal_ratio']:g}x", report["goal_met"])]
    for row in report.get("native", []):
        rows.append((f"native vs pythonfmu FMU step, {row['model']}",
                     f"{row['pythonfmu_over_native_c_host']:.1f}x cheaper, "
                     f"{row['native_c_host_us_per_step']:.1f} us (C host)",
                     f">= {report['native_goal_ratio']:g}x" + (
                         f", < {report['native_goal_us_at_500']:g} us" if row["training_points"] >= 500 else ""),
                     row["pythonfmu_over_native_c_host"] >= report["native_goal_ratio"]
                     and (row["training_points"] < 500
                          or row["native_c_host_us_per_step"] < report["native_goal_us_at_500"])))
    blimp = report.get("blimp")
    if blimp:
        rows.append((f"native vs pythonfmu FMU step, blimp RKGP, {blimp['training_pairs']} pairs",
                     f"{blimp['pythonfmu_over_native_c_host']:.1f}x cheaper, "
                     f"{blimp['native_c_host_us_per_step']:.1f} us (C host)",
                     f">= {report['native_goal_ratio']:g}x",
                     blimp["pythonfmu_over_native_c_host"] >= report["native_goal_ratio"]))
    return rows


def _cosim_summary(report: dict) -> list:
    return [(f"co-simulation, {r['fmu']} GP FMU, {r['model']}", f"{r['real_time_factor']:.0f}x real time",
             f">= {report['goal_real_time']:g}x", r["goal_met"]) for r in report["rows"]]


def _diagnose_summary(report: dict) -> list:
    return [("diagnose per 20 s case (worst of the timed cases)", f"{report['max_seconds']:.1f} s",
             f"<= {report['goal_s']:g} s", report["goal_met"])]


#: Benchmarks by name. ``flightgp bench`` runs them all.
BENCHMARKS = {
    "gp": Benchmark(bench_gp, format_gp_table, {"sizes": "sizes", "restarts": "n_restarts"}, _gp_summary),
    "narx": Benchmark(bench_narx, format_narx_table, {"runs": "n_runs", "steps": "n_steps"}, _narx_summary),
    "fmu": Benchmark(bench_fmu, format_fmu_table, {"fmu_steps": "n_steps"}, _fmu_summary),
    "cosim": Benchmark(bench_cosim, format_cosim_table, {}, _cosim_summary),
    "diagnose": Benchmark(bench_diagnose, format_diagnose_table, {}, _diagnose_summary),
}


def format_summary(reports: dict) -> str:
    """One table of every benchmark's headline rows (``flightgp bench``)."""
    rows = [row for name, report in reports.items() for row in BENCHMARKS[name].summary(report)]
    width = max(len(row[0]) for row in rows)
    lines = [f"{'measure':<{width}}  {'measured':<34} {'goal':<16} met"]
    for measure, value, goal, met in rows:
        lines.append(f"{measure:<{width}}  {value:<34} {goal:<16} {'-' if met is None else 'yes' if met else 'no'}")
    return "\n".join(lines)
