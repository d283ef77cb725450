"""``flightgp bench gp``: GP fitting and prediction against scikit-learn's
``GaussianProcessRegressor`` (same kernel, data, standardisation and restarts), with the log
marginal likelihood each reached (docs/benchmarks.md)."""
from __future__ import annotations

import time
import warnings

import numpy as np

from gp_model import (
    GaussianProcess,
    SquaredExponentialARD,
    maximize_marginal_likelihood,
)
from validation.bench.rows import SummaryRow
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


def run(*, sizes=(100, 500, 2000), n_restarts: int = 1, n_dims: int = 4, seed: int = 0,
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
    rows = []
    with progress_bar("bench gp", enabled=progress, total=len(sizes), unit="size") as update:
        for n in sizes:
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
            if update:
                update(1)
    return {"rows": rows, "n_dims": n_dims, "n_restarts": n_restarts,
            "peer": "scikit-learn GaussianProcessRegressor"}


def format_table(report: dict) -> str:
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


#: Goal of ``bench gp`` (docs/benchmarks.md): the fit at least this many times faster than
#: scikit-learn's at equal or better log marginal likelihood.
GP_FIT_GOAL_SPEEDUP = 6.0


def summary_rows(report: dict) -> list[SummaryRow]:
    """Headline rows: the fit's speed-up over scikit-learn at each size."""
    return [SummaryRow(f"gp.fit.speedup.n{row['n']}", f"GP fit vs scikit-learn, n = {row['n']}", row["fit_speedup"],
                       "x", GP_FIT_GOAL_SPEEDUP) for row in report["rows"]]
