"""``flightgp bench narx``: the vectorised Monte Carlo free run of a GP-NARX against the same
computation run by run and step by step, fed identical random numbers (docs/benchmarks.md)."""
from __future__ import annotations

import time

import numpy as np

from gp_model import (
    GaussianProcess,
    GPNarx,
    HigdonKernel,
    NarxStructure,
)
from validation.bench.rows import SummaryRow
from validation.core.progress import progress_bar

#: Training: every 25th regressor row (as the paper) of a recording long enough for 40 points.
NARX_STRIDE, NARX_TRAINING_POINTS = 25, 40
#: The goal (docs/benchmarks.md): at 1000 runs x 800 steps, the vectorised free run at least 50x faster than
#: the loop and at most 1 s on the project's 2-core machine.
NARX_GOAL_RUNS, NARX_GOAL_STEPS, NARX_GOAL_SPEEDUP, NARX_GOAL_SECONDS = 1000, 800, 50.0, 1.0


#: Regressors of ``bench narx``, shaped like the Bo105 case (Bo105 GP-NARX paper, AHS 74th Forum,
#: 2018): the cyclic input at lags 1 and 2 and the three body rates at lag 1.
NARX_STRUCTURE = NarxStructure(("theta_1s",), ("p", "q", "r"), input_lags=(1, 2), output_lags=(1,))


#: Largest difference (output units) accepted between the loop's and the vectorised runs fed
#: the same random numbers. Rounding alone gives 1e-11 to 2e-11 after 800 steps (measured; the
#: vectorised kernel expands squared distances into products and sums in another order), so
#: 1e-9 leaves a margin of 50x; a real discrepancy (another sample, draw or regressor) shows at
#: the 0.01 noise level or above, on outputs of unit size.
NARX_AGREEMENT_TOLERANCE = 1e-9


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


def _free_run_loop(structure: NarxStructure, sample_gps, inputs, initial, assignment, draws, runs, *,
                   progress=None):
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
    progress : callable, optional
        Called as ``progress(1)`` after each run.

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
        if progress:
            progress(1)
    return result


def run(*, n_runs: int = 1000, n_steps: int = 800, loop_runs: int = 10, seed: int = 0,
               progress: bool = True) -> dict:
    """Monte Carlo free run of a GP-NARX (``n_runs`` runs of ``n_steps`` predicted steps, every
    run with its own annealing hyperparameter sample and its own draws) by
    :meth:`GPNarx.free_run`, vectorised over runs, against :func:`_free_run_loop`, the same
    computation run by run through :meth:`GaussianProcess.predict` at one point at a time.

    Model: :data:`NARX_STRUCTURE`, one GP per output with Higdon's kernel and simulated annealing
    at its defaults (400 samples), seed ``seed``, trained on 40 points of
    :func:`_rate_response`; the free run starts from rest under a new input of the same kind.

    Timing. The vectorised free run is timed once from cold, including the factorisation of
    every hyperparameter sample, with its default threads (one per available core). The loop's
    set-up (one GP per sample and output, fitted to the same training points with that
    sample's hyperparameters) is timed once; its runs cost the same each, so it is timed on the
    first ``loop_runs`` runs and scaled linearly to ``n_runs`` (the full loop would take
    minutes).

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
    structure, start = NARX_STRUCTURE, NARX_STRUCTURE.max_lag
    inputs, outputs = _rate_response(NARX_STRIDE * NARX_TRAINING_POINTS + start, seed)
    X, Y = structure.regressors(inputs, outputs)
    X, Y = X[::NARX_STRIDE], Y[::NARX_STRIDE]
    with progress_bar("bench narx: training", enabled=progress, total=len(structure.output_names),
                      unit="GP") as update:
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
    with progress_bar("bench narx: loop", enabled=progress, total=len(runs), unit="run") as update:
        loop = _free_run_loop(structure, sample_gps, test_inputs, initial, assignment, draws, runs, progress=update)
    loop_s_per_run = (time.perf_counter() - begin) / len(runs)

    max_abs_difference = float(np.max(np.abs(loop - vectorised.runs[:len(runs)])))
    if not max_abs_difference <= NARX_AGREEMENT_TOLERANCE:
        raise RuntimeError(
            "bench narx: the vectorised free run and the loop differ by up to "
            f"{max_abs_difference:.3g} (tolerance {NARX_AGREEMENT_TOLERANCE:g}) on runs "
            f"0-{len(runs) - 1}; either "
            "GPNarx.free_run now consumes its random numbers in another order (update "
            "_monte_carlo_draws in validation/bench/narx.py) or one of the two is wrong")
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


def format_table(report: dict) -> str:
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


def summary_rows(report: dict) -> list[SummaryRow]:
    """Headline rows: the vectorised free run's seconds and its speed-up over the loop peer."""
    size = f"{report['runs']} runs x {report['steps']} steps"
    at_goal_size = report["goal_met"] is not None  # the goals are set at 1000 x 800 only
    return [SummaryRow("narx.montecarlo.seconds", f"Monte Carlo free run, {size}", report["vectorised_s"], "s",
                       report["goal_seconds"] if at_goal_size else None, at_least=False),
            SummaryRow("narx.montecarlo.speedup", "Monte Carlo free run vs run-by-run loop", report["speedup"], "x",
                       report["goal_speedup"] if at_goal_size else None)]
