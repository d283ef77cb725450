"""GP-NARX models: ``y(k) = f(u(k - i) for i in input_lags, y(k - j) for j in output_lags) + e``.

One GP per output (Bo105 GP-NARX paper, AHS 74th Forum, 2018: pitch, roll and yaw rate each
from the cyclic input and the previous rates). Two kinds of prediction:

- one-step-ahead (OSAP): the regressors hold *measured* past outputs;
- free run (full-model prediction, FMP): the model's own predictions are fed back. Three ways
  to carry the uncertainty along, chosen by ``method``:

  * ``"monte_carlo"`` (the paper's): R runs, each drawing its output at every step from the
    GP's predictive distribution, each run with hyperparameters drawn from the annealing
    samples; vectorised over runs;
  * ``"moment_matching"``: the exact mean and covariance of the GP output at a Gaussian input
    (Girard et al., NIPS 2003), propagated as a joint Gaussian over the lagged outputs;
  * ``"mean"``: the naive rollout that feeds back the mean and reports the GP variance at it.

Arrays follow one convention: ``inputs`` has shape (n, n_inputs), ``outputs`` (n, n_outputs),
row k is sample k of an evenly sampled recording.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ._gp import GaussianProcess, PerOutputGP, mixture_moments


@dataclass(frozen=True)
class NarxStructure:
    """Which signals at which lags form the regressor vector.

    Parameters
    ----------
    input_names : tuple of str
        Exogenous inputs, e.g. ``("theta_1s",)``.
    output_names : tuple of str
        Predicted outputs, fed back in free run, e.g. ``("p", "q", "r")``.
    input_lags : tuple of int, default (1,)
        Lags ``i >= 0`` of every input: ``u(k - i)`` enters the regressor of ``y(k)``.
    output_lags : tuple of int, default (1,)
        Lags ``j >= 1`` of every output.
    """

    input_names: tuple
    output_names: tuple
    input_lags: tuple = (1,)
    output_lags: tuple = (1,)

    def __post_init__(self) -> None:
        for name in ("input_names", "output_names", "input_lags", "output_lags"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        if not self.output_names:
            raise ValueError("a NARX model needs at least one output")
        if any(lag < 0 for lag in self.input_lags) or any(lag < 1 for lag in self.output_lags):
            raise ValueError("input lags must be >= 0 and output lags >= 1 "
                             f"(got {self.input_lags}, {self.output_lags})")
        if not self.output_lags:
            raise ValueError("a NARX model needs at least one output lag")

    @property
    def max_lag(self) -> int:
        """Samples of history needed before the first prediction."""
        return max((*self.input_lags, *self.output_lags))

    @property
    def regressor_names(self) -> list[str]:
        """``"theta_1s(k-1)"``, ..., ``"q(k-2)"``: inputs first, then outputs, lag by lag."""
        def lagged(name, lag):
            return f"{name}(k)" if lag == 0 else f"{name}(k-{lag})"
        return ([lagged(n, i) for n in self.input_names for i in self.input_lags]
                + [lagged(n, j) for n in self.output_names for j in self.output_lags])

    def regressors(self, inputs, outputs) -> tuple[np.ndarray, np.ndarray]:
        """Regressor matrix and targets for every ``k >= max_lag`` of one recording.

        Parameters
        ----------
        inputs : ndarray, shape (n, n_inputs)
        outputs : ndarray, shape (n, n_outputs)

        Returns
        -------
        X : ndarray, shape (n - max_lag, n_regressors)
        Y : ndarray, shape (n - max_lag, n_outputs)
            ``Y[i] = outputs[max_lag + i]``.
        """
        inputs, outputs = self._check(inputs, outputs)
        n, start = len(outputs), self.max_lag
        if n <= start:
            raise ValueError(f"need more than {start} samples for lags up to {start}, got {n}")
        columns = [inputs[start - i:n - i, c] for c in range(inputs.shape[1]) for i in self.input_lags]
        columns += [outputs[start - j:n - j, c] for c in range(outputs.shape[1]) for j in self.output_lags]
        return np.column_stack(columns), outputs[start:]

    def _check(self, inputs, outputs):
        inputs = np.asarray(inputs, dtype=float).reshape(len(outputs), -1)
        outputs = np.asarray(outputs, dtype=float)
        if outputs.ndim != 2 or outputs.shape[1] != len(self.output_names):
            raise ValueError(f"outputs must have shape (n, {len(self.output_names)}), got {outputs.shape}")
        if inputs.shape[1] != len(self.input_names):
            raise ValueError(f"inputs must have shape (n, {len(self.input_names)}), got {inputs.shape}")
        return inputs, outputs


@dataclass
class FreeRunResult:
    """A free-run prediction.

    Attributes
    ----------
    mean : ndarray, shape (n, n_outputs)
        Predicted outputs; the first ``max_lag`` rows are the given initial outputs.
    var : ndarray, shape (n, n_outputs)
        Predictive variance (zero on the initial rows).
    runs : ndarray, shape (R, n, n_outputs) or None
        The Monte Carlo runs (``method="monte_carlo"`` only).
    method : str
    """

    mean: np.ndarray
    var: np.ndarray
    runs: np.ndarray | None
    method: str


class GPNarx:
    """A GP-NARX model: a :class:`NarxStructure` and one fitted GP per output.

    Parameters
    ----------
    structure : NarxStructure
    model : PerOutputGP
        ``model.gps[j]`` predicts ``structure.output_names[j]`` from the regressor vector.
    """

    def __init__(self, structure: NarxStructure, model: PerOutputGP) -> None:
        if len(model.gps) != len(structure.output_names):
            raise ValueError("one GP per output")
        self.structure = structure
        self.model = model

    @classmethod
    def fit(cls, structure: NarxStructure, recordings, *, kernel: str = "higdon",
            hyperparameters: str = "annealing", stride: int = 1, rows=None, seed: int = 0,
            n_inducing: int | None = None, progress=None,
            **inference_options) -> GPNarx:
        """Train one GP per output on regressors built from one or more recordings.

        Parameters
        ----------
        structure : NarxStructure
        recordings : sequence of (inputs, outputs)
            Each an evenly sampled pair of arrays, shapes (n_i, n_inputs), (n_i, n_outputs);
            regressors never straddle two recordings.
        kernel : {"higdon", "squared_exponential_ard"}
        hyperparameters : {"annealing", "maximum_likelihood"}
            Simulated annealing (the Bo105 paper's; predictions then average over the
            samples) or type-II maximum likelihood.
        stride : int, default 1
            Keep every ``stride``-th regressor row of each recording (the paper: 25).
        rows : sequence of int, optional
            Instead of ``stride``: these rows of the stacked regressor matrix.
        seed : int, default 0
            Output ``j`` uses seed ``seed + j`` (for inference and, if sparse, for the first
            inducing input).
        n_inducing : int, optional
            Use a :class:`~gp_model.SparseGaussianProcess` with this many inducing inputs per
            output (variational free energy, O(n m^2)) instead of an exact GP (O(n^3)), so that
            all samples can be used (``stride=1``).
        progress : callable, optional
            Passed to the hyperparameter inference (see :func:`~gp_model.simulated_annealing`).
        **inference_options
            Passed to :func:`~gp_model.anneal_hyperparameters` or
            :func:`~gp_model.maximize_marginal_likelihood`.
        """
        from ._inference import anneal_hyperparameters, maximize_marginal_likelihood
        from ._kernels import KERNELS
        from ._sparse_gp import SparseGaussianProcess

        if kernel not in KERNELS:
            raise ValueError(f"unknown kernel {kernel!r}; use one of {', '.join(KERNELS)}")
        if hyperparameters not in ("annealing", "maximum_likelihood"):
            raise ValueError(f"unknown hyperparameter method {hyperparameters!r}")
        if stride < 1:
            raise ValueError(f"stride must be >= 1, got {stride}")
        blocks = [structure.regressors(u, y) for u, y in recordings]
        if rows is None:
            blocks = [(X[::stride], Y[::stride]) for X, Y in blocks]
        X = np.vstack([b[0] for b in blocks])
        Y = np.vstack([b[1] for b in blocks])
        if rows is not None:
            X, Y = X[np.asarray(rows)], Y[np.asarray(rows)]
        n_dims = X.shape[1]
        start = {"higdon": 0.5, "squared_exponential_ard": 1.0}[kernel]
        gps = []
        for j in range(Y.shape[1]):
            kernel_j = KERNELS[kernel](1.0, np.full(n_dims, start))
            if n_inducing is None:
                gp = GaussianProcess(kernel_j, noise_variance=1e-2)
            else:
                gp = SparseGaussianProcess(kernel_j, n_inducing=n_inducing, noise_variance=1e-2,
                                           inducing_seed=seed + j)
            gp.fit(X, Y[:, j])
            if hyperparameters == "annealing":
                anneal_hyperparameters(gp, seed=seed + j, progress=progress, **inference_options)
            else:
                maximize_marginal_likelihood(gp, seed=seed + j, **inference_options)
            gps.append(gp)
        return cls(structure, PerOutputGP(gps))

    # -- one step ---------------------------------------------------------------------------
    def one_step(self, inputs, outputs, *, include_noise: bool = True):
        """One-step-ahead prediction from measured history (OSAP).

        Returns
        -------
        mean, var : ndarray, shape (n - max_lag, n_outputs)
            Prediction of ``outputs[max_lag:]``.
        """
        X, _ = self.structure.regressors(inputs, outputs)
        return self.model.predict(X, return_var=True, include_noise=include_noise)

    # -- free run ---------------------------------------------------------------------------
    def free_run(self, inputs, initial_outputs, *, method: str = "monte_carlo", n_runs: int = 1000,
                 seed: int = 0, include_noise: bool = True, feedback_noise: bool = True,
                 use_samples: bool = True, keep_runs: bool = False, n_threads: int = 2,
                 progress=None) -> FreeRunResult:
        """Free-run (full-model) prediction over the whole input history.

        Parameters
        ----------
        inputs : ndarray, shape (n, n_inputs)
            Exogenous inputs for every sample.
        initial_outputs : ndarray, shape (max_lag, n_outputs) or longer
            Measured outputs that start the run; only the first ``max_lag`` rows are used.
        method : {"monte_carlo", "moment_matching", "mean"}
        n_runs : int, default 1000
            Monte Carlo runs R.
        seed : int, default 0
            Seed of the Monte Carlo draws (hyperparameter assignment and predictive samples).
        include_noise : bool, default True
            Report the variance of a noisy measurement (bounds for measured data) rather than
            of the latent function.
        feedback_noise : bool, default True
            Feed back draws of the noisy output, i.e. sample the full predictive distribution
            at every step (the Bo105 paper's method), so the GP noise acts as process noise
            (turbulence, unmodelled dynamics). False feeds back latent draws, treating the
            noise as pure measurement noise. Moment matching propagates the same choice.
        use_samples : bool, default True
            Draw each Monte Carlo run's hyperparameters from the GP's samples (the paper's
            method), average the mean rollout over them, or match the mixture's moments (sample
            s of every output's GP forms model s); False uses the point hyperparameters
            ``theta_``.
        keep_runs : bool
            Keep the individual Monte Carlo runs in the result.
        n_threads : int, default 2
            Threads sharing the Monte Carlo runs; the result does not depend on it (up to
            rounding in the last bits).
        progress : callable, optional
            Called as ``progress(k)`` after every ``k`` predicted steps (Monte Carlo).
        """
        inputs = np.asarray(inputs, dtype=float).reshape(len(inputs), -1)
        initial = np.asarray(initial_outputs, dtype=float)[: self.structure.max_lag]
        if initial.shape != (self.structure.max_lag, len(self.structure.output_names)):
            raise ValueError(f"initial_outputs must have at least {self.structure.max_lag} rows of "
                             f"{len(self.structure.output_names)} outputs, got {np.shape(initial_outputs)}")
        if len(inputs) <= self.structure.max_lag:
            raise ValueError(f"need more than {self.structure.max_lag} input samples")
        if method == "monte_carlo":
            return self._free_run_monte_carlo(inputs, initial, n_runs=n_runs, seed=seed,
                                              include_noise=include_noise,
                                              feedback_noise=feedback_noise, use_samples=use_samples,
                                              keep_runs=keep_runs, progress=progress,
                                              n_threads=n_threads)
        if method == "mean":
            return self._free_run_mean(inputs, initial, include_noise=include_noise,
                                       use_samples=use_samples)
        if method == "moment_matching":
            return self._free_run_moment_matching(inputs, initial, include_noise=include_noise,
                                                  feedback_noise=feedback_noise, use_samples=use_samples)
        raise ValueError(f"unknown free-run method {method!r}; use monte_carlo, moment_matching or mean")

    def _regressor_rows(self, inputs, history, k):
        """Regressors of step ``k`` for every run: ``history`` (R, n, n_outputs)."""
        s = self.structure
        u_part = [np.broadcast_to(inputs[k - i, c], (history.shape[0],))
                  for c in range(inputs.shape[1]) for i in s.input_lags]
        y_part = [history[:, k - j, c] for c in range(history.shape[2]) for j in s.output_lags]
        return np.column_stack(u_part + y_part)

    def _free_run_mean(self, inputs, initial, *, include_noise, use_samples):
        n, n_out, start = len(inputs), len(self.structure.output_names), self.structure.max_lag
        predictors = [_BatchPredictor.for_mixture(gp, use_samples=use_samples) for gp in self.model.gps]
        history = np.zeros((1, n, n_out))
        history[0, :start] = initial
        var = np.zeros((n, n_out))
        for k in range(start, n):
            x = self._regressor_rows(inputs, history, k)
            for j, predictor in enumerate(predictors):
                # Mixture over hyperparameter samples, as GaussianProcess.predict.
                means, variances = predictor(np.repeat(x, len(predictor.assignment), axis=0))
                history[0, k, j], var[k, j] = mixture_moments(means, variances)
                if include_noise:
                    var[k, j] += predictor.noise_variance.mean()
        return FreeRunResult(history[0], var, None, "mean")

    def _free_run_monte_carlo(self, inputs, initial, *, n_runs, seed, include_noise,
                              feedback_noise, use_samples, keep_runs, progress, n_threads):
        rng = np.random.default_rng(seed)
        n, n_out, start = len(inputs), len(self.structure.output_names), self.structure.max_lag
        gps = self.model.gps
        # All random numbers first, in a fixed order (hyperparameter sample of each run per
        # output, then one standard normal per step, output and run), so the result does not
        # depend on how the runs are split between threads (beyond rounding).
        assignments = [rng.permutation(n_runs) % _n_samples(gp, use_samples) for gp in gps]
        normals = rng.standard_normal((n - start, n_out, n_runs))
        bounds = np.linspace(0, n_runs, max(1, min(n_threads, n_runs)) + 1).astype(int)
        chunks = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]

        def run(rows, report):
            predictors = [_BatchPredictor(gp, a[rows], use_samples=use_samples)
                          for gp, a in zip(gps, assignments)]
            history = np.zeros((rows.stop - rows.start, n, n_out))
            history[:, :start] = initial
            for k in range(start, n):
                X = self._regressor_rows(inputs, history, k)
                for j, predictor in enumerate(predictors):
                    mean, var = predictor(X)
                    if feedback_noise:
                        var = var + predictor.noise_variance
                    history[:, k, j] = mean + np.sqrt(var) * normals[k - start, j, rows]
                if report is not None:
                    report(1)
            return history

        # Runs are independent: each thread carries a share of them through the whole horizon
        # (numpy releases the GIL in the batched products, so two threads use two cores).
        reports = [progress] + [None] * (len(chunks) - 1)
        if len(chunks) == 1:
            parts = [run(chunks[0], progress)]
        else:
            with ThreadPoolExecutor(len(chunks)) as pool:
                parts = list(pool.map(run, chunks, reports))
        history = np.concatenate(parts)
        var = history.var(axis=0)
        if include_noise and not feedback_noise:
            var += [np.mean(_noise_variances(gp, use_samples)[a]) for gp, a in zip(gps, assignments)]
        var[:start] = 0.0
        return FreeRunResult(history.mean(axis=0), var, history if keep_runs else None, "monte_carlo")

    def _free_run_moment_matching(self, inputs, initial, *, include_noise, feedback_noise, use_samples):
        from ._moment_matching import moment_matcher
        from .uncertain_input import narx_belief_start, narx_belief_step

        matcher = moment_matcher(self.model.gps, use_samples=use_samples)
        s = self.structure
        n, n_out, start = len(inputs), len(s.output_names), s.max_lag
        n_lags = max(s.output_lags)
        belief = narx_belief_start(initial[start - n_lags:][::-1])
        mean_out, var_out = np.zeros((n, n_out)), np.zeros((n, n_out))
        mean_out[:start] = initial
        for k in range(start, n):
            known = np.array([inputs[k - i, c] for c in range(inputs.shape[1]) for i in s.input_lags])
            y_mean, y_cov, *belief = narx_belief_step(matcher, known, *belief, output_lags=s.output_lags,
                                                      include_noise=feedback_noise)
            mean_out[k] = y_mean
            var_out[k] = np.diag(y_cov)
            if include_noise and not feedback_noise:
                var_out[k] += [np.mean(frame.noise_variance) * frame.output_scale**2 for frame in matcher.frames]
        return FreeRunResult(mean_out, var_out, None, "moment_matching")

    # -- interpretation ---------------------------------------------------------------------
    def relevance(self) -> dict[str, dict[str, float]]:
        """ARD relevance of each regressor for each output.

        The kernel weight ``w_i`` of a standardised regressor (``1/(2 l_i^2)``, or
        ``-4 ln alpha_i`` for Higdon's kernel) measures how fast the output changes with it;
        weights are normalised to sum to 1 per output. Uses the point hyperparameters.
        """
        names = self.structure.regressor_names
        result = {}
        for name, gp in zip(self.structure.output_names, self.model.gps):
            weights = gp.kernel.weights()
            result[name] = dict(zip(names, (weights / weights.sum()).tolist()))
        return result


def _n_samples(gp, use_samples: bool) -> int:
    """How many hyperparameter vectors a GP predicts with."""
    return len(gp.theta_samples_) if use_samples and gp.theta_samples_ is not None else 1


def _noise_variances(gp, use_samples: bool) -> np.ndarray:
    """Noise variance of each hyperparameter vector, in output units, shape (S,)."""
    thetas = gp.theta_samples_ if use_samples and gp.theta_samples_ is not None else gp.theta_[None]
    return np.exp(thetas[:, -1]) * gp.output_scaler_.scale_[0] ** 2


class _BatchPredictor:
    """Predictive mean and latent variance of one GP for many rows at once, row ``r`` with the
    hyperparameter sample ``assignment[r]`` (of the GP's samples, or its point estimate).

    Works on any GP that offers ``predictive_forms`` (:class:`~gp_model._gp.PredictiveForm`):
    per sample, kernel weights, signal variance, mean weights and variance factor. With few
    distinct samples the rows are grouped by sample and each group costs one matrix product;
    with many, the per-sample arrays are gathered per row once and a call is one batched
    (R, n, n) product (memory R n^2 doubles).
    """

    #: Up to this many distinct samples, rows are grouped by sample (a loop of matrix products);
    #: above it, a Python loop over groups costs more than the batched product.
    MAX_GROUPS = 16
    #: Largest per-row gather (R n^2 doubles) accepted, bytes.
    MAX_BYTES = 1 << 30

    def __init__(self, gp, assignment: np.ndarray, *, use_samples: bool) -> None:
        forms = gp.predictive_forms(use_samples=use_samples)
        n, n_rows = forms[0].basis.shape[0], len(assignment)
        thetas = np.array([f.theta for f in forms])
        self.weights = np.array([gp.kernel.weights(t[:-1]) for t in thetas])  # (S, d)
        self.signal = np.exp(thetas[:, 0])  # (S,)
        self.alpha = np.array([f.weights for f in forms])  # (S, n)
        self.L_inv = np.array([f.variance_factor for f in forms])  # (S, n, n)
        self.log_signal = thetas[:, 0]  # (S,)
        self.offset = self.log_signal[:, None] - self.weights @ (forms[0].basis ** 2).T  # (S, n)
        self.assignment = np.asarray(assignment)
        self.groups = None
        if len(forms) <= self.MAX_GROUPS:
            self.groups = [(s, np.flatnonzero(self.assignment == s)) for s in range(len(forms))]
        elif n_rows * n * n * 8 > self.MAX_BYTES:
            raise ValueError(f"Monte Carlo with {n_rows} runs and {len(forms)} hyperparameter "
                             f"samples on {n} basis points needs {n_rows * n * n * 8 / 2**30:.1f} "
                             "GiB; use fewer runs, use_samples=False, or fewer training points")
        else:
            self.row_weights = self.weights[self.assignment]
            self.row_signal = self.signal[self.assignment]
            self.row_log_signal = self.log_signal[self.assignment]
            self.row_offset = self.offset[self.assignment]
            self.row_alpha = self.alpha[self.assignment][:, :, None]
            self.row_L_inv = self.L_inv[self.assignment]
        self.X_train = forms[0].basis
        self.input_scaler, self.output_scaler = gp.input_scaler_, gp.output_scaler_
        self.noise_variance = _noise_variances(gp, use_samples)[self.assignment]

    @classmethod
    def for_mixture(cls, gp, *, use_samples: bool):
        """One row per hyperparameter sample (evaluate all at the same input for the mixture)."""
        return cls(gp, np.arange(_n_samples(gp, use_samples)), use_samples=use_samples)

    def _kernel_rows(self, Xs, weights, offset, log_signal):
        """``k(x_r, X_train)`` for rows ``Xs`` (R, d) with per-row (or shared) ``weights``.

        ``ln k = ln sigma_f^2 - sum_i w_i (x_i - X_ni)^2`` expanded into products, with the part
        that depends on the training points only, ``offset = ln sigma_f^2 - w . X_n^2``,
        precomputed: no (R, n, d) temporary, one (R, d) x (d, n) product per call. The cap at
        ``ln sigma_f^2`` removes rounding that would make a squared distance negative.
        """
        weighted = weights * Xs
        exponent = offset + 2.0 * (weighted @ self.X_train.T) - (weighted * Xs).sum(axis=1)[:, None]
        return np.exp(np.minimum(exponent, np.asarray(log_signal)[..., None]))

    def __call__(self, X):
        """Mean and latent variance, each shape (R,), in output units, at rows of ``X`` (R, d)."""
        Xs = self.input_scaler.transform(X)
        mean, var = np.empty(len(Xs)), np.empty(len(Xs))
        if self.groups is not None:
            for s, rows in self.groups:
                k = self._kernel_rows(Xs[rows], self.weights[s], self.offset[s], self.log_signal[s])
                mean[rows] = k @ self.alpha[s]
                v = k @ self.L_inv[s].T
                var[rows] = self.signal[s] - np.einsum("rm,rm->r", v, v)
        else:
            k = self._kernel_rows(Xs, self.row_weights, self.row_offset, self.row_log_signal)
            mean = (k[:, None, :] @ self.row_alpha)[:, 0, 0]
            v = (self.row_L_inv @ k[:, :, None])[:, :, 0]
            var = self.row_signal - np.einsum("rm,rm->r", v, v)
        scale = self.output_scaler.scale_[0]
        return mean * scale + self.output_scaler.mean_[0], np.maximum(var, 0.0) * scale**2
