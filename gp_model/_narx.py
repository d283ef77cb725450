"""GP-NARX models: ``y(k) = f(u(k - i) for i in input_lags, y(k - j) for j in output_lags) + e``.

One GP per output (Bo105 GP-NARX paper, AHS 74th Forum, 2018: pitch, roll and yaw rate each
from the cyclic input and the previous rates). Two kinds of prediction:

- one-step-ahead (OSAP): the regressors hold *measured* past outputs;
- free run (full-model prediction, FMP): the model's own predictions are fed back. Three ways
  to carry the uncertainty along, chosen by ``method``:

  * ``"monte_carlo"`` (the paper's): R runs, each drawing its output at every step from the
    GP's predictive distribution, each run with hyperparameters drawn from the annealing
    samples; vectorised over runs and outputs, the runs that share a sample evaluated together;
  * ``"moment_matching"``: the exact mean and covariance of the GP output at a Gaussian input
    (Girard et al., NIPS 2003), propagated as a joint Gaussian over the lagged outputs;
  * ``"mean"``: the naive rollout that feeds back the mean and reports the GP variance at it.

Arrays follow one convention: ``inputs`` has shape (n, n_inputs), ``outputs`` (n, n_outputs),
row k is sample k of an evenly sampled recording.
"""
from __future__ import annotations

import os
import threading
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
            Called as ``progress(1)`` after each output's GP is trained (its hyperparameters
            inferred), and with annealing as ``progress(0, zeta=..., acceptance=...)`` after
            each of its stages (see :func:`~gp_model.simulated_annealing`; its Metropolis steps
            are not counted, as their number is not known beforehand).
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

        def stage_status(n, **status):  # the annealing's stages; its Metropolis steps are not the count
            if status:
                progress(0, **status)

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
                anneal_hyperparameters(gp, seed=seed + j, progress=None if progress is None else stage_status,
                                       **inference_options)
            else:
                maximize_marginal_likelihood(gp, seed=seed + j, **inference_options)
            gps.append(gp)
            if progress is not None:
                progress(1)
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
                 use_samples: bool = True, keep_runs: bool = False, n_threads: int | None = None,
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
        n_threads : int, optional
            Threads sharing each Monte Carlo step, by default one per core available to the
            process and per ``MIN_SLOTS_PER_THREAD`` (output, run) pairs. They meet after every
            step (each step needs all outputs of the last), so more threads than free cores
            slow the run down, and so do threads with too little work between meetings. The result does not depend on it
            beyond rounding in the last bits (none where the threads' shares end between
            hyperparameter samples).
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

    def _regressors(self, inputs, history, k, out):
        """Regressors of step ``k`` for every run, one row per regressor (the order of
        :attr:`NarxStructure.regressor_names`), into ``out``, shape (n_regressors, R).

        ``history`` has shape (n, n_outputs * R): row ``k`` holds output ``c`` of run ``r`` in
        column ``c * R + r``.
        """
        s = self.structure
        n_runs = out.shape[1]
        row = 0
        for c in range(inputs.shape[1]):
            for i in s.input_lags:
                out[row] = inputs[k - i, c]
                row += 1
        for c in range(history.shape[1] // n_runs):
            for j in s.output_lags:
                out[row] = history[k - j, c * n_runs:(c + 1) * n_runs]
                row += 1
        return out

    def _free_run_mean(self, inputs, initial, *, include_noise, use_samples):
        n, n_out, start = len(inputs), len(self.structure.output_names), self.structure.max_lag
        # One "run" per hyperparameter sample, all at the same regressors: the mixture's parts.
        predictors = [_BatchPredictor([gp], [np.arange(_n_samples(gp, use_samples))],
                                      use_samples=use_samples).parts[0] for gp in self.model.gps]
        history = np.zeros((n, n_out))
        history[:start] = initial
        var = np.zeros((n, n_out))
        x = np.empty((len(self.structure.regressor_names), 1))
        for k in range(start, n):
            self._regressors(inputs, history, k, x)
            for j, predictor in enumerate(predictors):
                # Mixture over hyperparameter samples, as GaussianProcess.predict.
                means, variances = predictor(np.repeat(x, len(predictor.runs), axis=1))
                history[k, j], var[k, j] = mixture_moments(means, variances)
                if include_noise:
                    var[k, j] += predictor.noise_variance.mean()
        return FreeRunResult(history, var, None, "mean")

    def _free_run_monte_carlo(self, inputs, initial, *, n_runs, seed, include_noise,
                              feedback_noise, use_samples, keep_runs, progress, n_threads):
        rng = np.random.default_rng(seed)
        n, n_out, start = len(inputs), len(self.structure.output_names), self.structure.max_lag
        gps = self.model.gps
        # All random numbers first, in a fixed order (hyperparameter sample of each run per
        # output, then one standard normal per step, output and run), so the result does not
        # depend on how the work is split between threads.
        assignments = [rng.permutation(n_runs) % _n_samples(gp, use_samples) for gp in gps]
        normals = rng.standard_normal((n - start, n_out * n_runs))  # column c * R + r
        if n_threads is None:
            n_threads = min(_available_cores(), max(1, n_out * n_runs // MIN_SLOTS_PER_THREAD))
        predictor = _BatchPredictor(gps, assignments, use_samples=use_samples,
                                    n_parts=max(1, min(n_threads, n_out * n_runs)))
        history = np.empty((n, n_out * n_runs))  # row k: output c of run r in column c * R + r
        history[:start] = np.repeat(initial, n_runs, axis=1)
        n_regressors = len(self.structure.regressor_names)
        # Step k needs every output of step k - 1, which other threads computed: the threads
        # meet at a barrier after every step.
        barrier = threading.Barrier(len(predictor.parts))

        def run(part, report):
            x = np.empty((n_regressors, n_runs))
            try:
                for k in range(start, n):
                    mean, var = part(self._regressors(inputs, history, k, x))
                    if feedback_noise:
                        var += part.noise_variance
                    np.sqrt(var, out=var)
                    var *= normals[k - start, part.columns]
                    history[k, part.columns] = mean + var
                    if len(predictor.parts) > 1:
                        barrier.wait()
                    if report is not None:
                        report(1)
            except BaseException:
                barrier.abort()  # the other threads stop at the barrier instead of waiting
                raise

        reports = [progress] + [None] * (len(predictor.parts) - 1)
        if len(predictor.parts) == 1:
            run(predictor.parts[0], progress)
        else:
            with ThreadPoolExecutor(len(predictor.parts)) as pool:
                futures = [pool.submit(run, part, report) for part, report in zip(predictor.parts, reports)]
            errors = [f.exception() for f in futures if f.exception() is not None]
            if errors:  # the cause, not another thread's broken barrier
                raise next((e for e in errors if not isinstance(e, threading.BrokenBarrierError)), errors[0])
        runs = history.reshape(n, n_out, n_runs).transpose(2, 0, 1)  # (R, n, n_outputs)
        var = runs.var(axis=0)
        if include_noise and not feedback_noise:
            var += [np.mean(_noise_variances(gp, use_samples)[a]) for gp, a in zip(gps, assignments)]
        var[:start] = 0.0
        return FreeRunResult(runs.mean(axis=0), var, np.ascontiguousarray(runs) if keep_runs else None,
                             "monte_carlo")

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


#: Fewest (output, run) pairs per thread of the Monte Carlo free run by default: with fewer, a
#: step's work per thread (about 0.3 us per pair with samples repeated as annealing repeats
#: them) is too short to pay for the threads' meeting after it. Measured on 2 cores, 3 outputs
#: and 200 steps, one thread against two: 1000 runs 0.18 s and 0.20 s, 4000 runs 0.67 s and
#: 0.67 s, 16000 runs 3.4 s and 3.2 s (another job held one core); on a quiet machine, before
#: items were cut at ``ITEM_RUNS``, 16000 runs took 3.2 s and 1.6 s.
MIN_SLOTS_PER_THREAD = 6000

#: Most runs in one item of the Monte Carlo free run (a sample's runs beyond it form further
#: items): the items' sizes then take at most this many values, and every group of equal-sized
#: items costs a few numpy calls per step whatever its size.
#: 8 measured fastest of 4, 8, 16, 32 and unlimited on the 1000 x 800 benchmark (0.62 s against
#: 0.68, 0.67, 0.77 and 0.92 s, one thread).
ITEM_RUNS = 8


def _available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _first_repeat(forms) -> np.ndarray:
    """Index of the first form that is the same object as each of ``forms`` (shape (S,))."""
    first = {}
    return np.array([first.setdefault(id(f), i) for i, f in enumerate(forms)], dtype=int)


class _BatchPredictor:
    """Predictive means and latent variances of several GPs (one per output) for R runs at
    once, where run ``r`` predicts output ``j`` with hyperparameter sample ``assignments[j][r]``
    (of the GP's samples, or its point estimate).

    Works on any GP that offers ``predictive_forms`` (:class:`~gp_model._gp.PredictiveForm`):
    per sample, kernel weights, signal variance, mean weights and variance factor, for kernel
    (1) of ``gp_model/_kernels.py``, ``k(x, x') = sigma_f^2 exp(-sum_i w_i (x_i - x'_i)^2)`` on
    standardised inputs.

    Layout. Every (output, run) pair is a *slot*; the slots are ordered so that the runs sharing
    an output's sample (an *item*, of at most ``ITEM_RUNS`` runs; repeats of a sample count as
    one sample) are adjacent, and items with equal numbers of runs are
    adjacent, so that one batched matrix product per group of equal-sized items evaluates the
    predictive mean and variance of all their runs, each item's arrays read once per step (the
    variance products stream every sample's factor each step and bound the cost). The slots
    are cut into ``n_parts`` contiguous :class:`_BatchPart` s, one per thread.

    Parameters
    ----------
    gps : list of GP
        One per output, all with the same regressors (d inputs).
    assignments : list of ndarray, shape (R,) each
        Hyperparameter sample of every run, per output.
    use_samples : bool
        Predict with the GPs' samples (else their point hyperparameters).
    n_parts : int, default 1
    """

    def __init__(self, gps, assignments, *, use_samples: bool, n_parts: int = 1) -> None:
        forms = [gp.predictive_forms(use_samples=use_samples) for gp in gps]
        n_runs = len(assignments[0])
        # Runs on repeats of one sample (predictive_forms shares their form) become one item:
        # each distinct sample's arrays are then read once per step, whichever repeat a run drew.
        assignments = [_first_repeat(f)[a] for f, a in zip(forms, assignments)]
        # Bases of fewer points are padded with zeros to n points: their kernel values meet
        # only zero weights.
        n = max(len(f[0].basis) for f in forms)
        # Items: (runs, output, sample), larger ones first, then by output and sample.
        items = []
        for j, a in enumerate(assignments):
            order = np.argsort(a, kind="stable")
            bounds = np.concatenate(([0], np.cumsum(np.bincount(a, minlength=len(forms[j])))))
            items += [(order[c:min(c + ITEM_RUNS, hi)], j, s)
                      for s, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:])) for c in range(lo, hi, ITEM_RUNS)]
        items.sort(key=lambda item: (-len(item[0]), item[1], item[2]))
        item_output = np.array([j for _, j, _ in items])
        item_sample = np.array([s for _, _, s in items])
        sizes = np.array([len(r) for r, _, _ in items])
        slot_item = np.repeat(np.arange(len(items)), sizes)
        slot_output = item_output[slot_item]
        runs = np.concatenate([r for r, _, _ in items])

        # Per output and sample: theta (S, p), weights w (S, d); per output: the basis.
        thetas = [np.array([f.theta for f in fs]) for fs in forms]
        weights = [np.array([gp.kernel.weights(t[:-1]) for t in th]) for gp, th in zip(gps, thetas)]
        scales = [gp.output_scaler_.scale_[0] for gp in gps]

        def per_slot(values):  # values[j][s] -> array over slots (last axis)
            return np.stack([np.asarray(values[j][s], dtype=float)
                             for j, s in zip(item_output, item_sample)], axis=-1)[..., slot_item]

        # The exponent ln k(x, X_m) = ln sigma_f^2 - sum_i w_i (x_i - X_mi)^2, expanded, is one
        # matrix product per step: a (2d + 1, slots) column [w * x; w; ln sigma_f^2 - w . x^2]
        # times G = [2 X^T; -(X^2)^T; 1] (2d + 1, n); rows d..2d - 1 of ``a`` never change.
        self.input_mean = per_slot([[gp.input_scaler_.mean_] * len(f) for gp, f in zip(gps, forms)])
        self.input_scale = per_slot([[gp.input_scaler_.scale_] * len(f) for gp, f in zip(gps, forms)])
        self.weights = per_slot(weights)  # (d, slots)
        self.log_signal = per_slot([th[:, 0] for th in thetas])  # (slots,)
        self.signal = per_slot([np.exp(th[:, 0]) * sc**2 for th, sc in zip(thetas, scales)])
        self.output_mean = per_slot([[gp.output_scaler_.mean_[0]] * len(f) for gp, f in zip(gps, forms)])
        self.noise_variance = per_slot([_noise_variances(gp, use_samples) for gp in gps])
        self.runs, self.columns = runs, slot_output * n_runs + runs
        products = []
        for fs in forms:
            X = np.zeros((n, fs[0].basis.shape[1]))
            X[:len(fs[0].basis)] = fs[0].basis
            products.append(np.vstack([2.0 * X.T, -(X**2).T, np.ones((1, n))]))
        # Outputs with equal bases (the usual case: all fitted on the same regressors) share
        # one product.
        first_equal = [next(i for i in range(j + 1) if np.array_equal(products[i], products[j]))
                       for j in range(len(products))]
        slot_product = np.array(first_equal)[slot_output]

        # Mean and variance weights, in output units, per item: mean = k . (alpha * scale),
        # latent variance = sigma_f^2 scale^2 - |scale L^-1 k|^2 (Rasmussen & Williams, Alg.
        # 2.1, lines 4-6, with V = L^-1 precomputed). When every L^-1 is lower triangular (exact
        # GPs), its rows are taken in two blocks, the first ignoring the zero upper-right
        # quarter: rows [0, h) need k[:h] only; rows [h, n) need all of k.
        alpha, factor = np.zeros((len(items), n)), np.zeros((len(items), n, n))
        for i, (_, j, s) in enumerate(items):
            m = len(forms[j][s].weights)
            alpha[i, :m] = forms[j][s].weights * scales[j]
            factor[i, :m, :m] = forms[j][s].variance_factor * scales[j]
        h = n // 2 if not np.any(np.triu(factor, 1)) else 0
        # (kernel values used, weights (I, those, block rows [+ 1 for the mean]))
        blocks = [] if h == 0 else [(h, np.ascontiguousarray(factor[:, :h, :h].transpose(0, 2, 1)))]
        last = np.concatenate([factor[:, h:, :].transpose(0, 2, 1), alpha[:, :, None]], axis=2)
        blocks.append((n, np.ascontiguousarray(last)))

        edges = np.linspace(0, len(runs), n_parts + 1).astype(int)
        item_start = np.concatenate(([0], np.cumsum(sizes)))
        self.parts = []
        for lo, hi in zip(edges[:-1], edges[1:]):
            if hi == lo:
                continue
            # Groups of adjacent items with equal numbers of slots in [lo, hi) (the items at
            # the cuts keep only their share of slots).
            groups = []
            for i in range(slot_item[lo], slot_item[hi - 1] + 1):
                a, b = max(item_start[i], lo) - lo, min(item_start[i + 1], hi) - lo
                if groups and groups[-1][2] == b - a and groups[-1][1] == a:
                    groups[-1] = (groups[-1][0], b, b - a, groups[-1][3], i + 1)
                else:
                    groups.append((a, b, b - a, i, i + 1))
            cuts = np.flatnonzero(np.diff(slot_product[lo:hi])) + 1
            segments = [(a, b, products[slot_product[lo + a]])
                        for a, b in zip(np.concatenate(([0], cuts)), np.concatenate((cuts, [hi - lo])))]
            self.parts.append(_BatchPart(self, slice(lo, hi), groups, segments, blocks, n))


class _BatchPart:
    """The slots ``rows`` of a :class:`_BatchPredictor`, evaluated together (one thread's share).

    Attributes
    ----------
    runs, columns : ndarray of int, shape (m,)
        Run of each slot, and its column ``c * R + r`` (output c, run r).
    noise_variance : ndarray, shape (m,)
        Noise variance of each slot's GP and sample, output units.
    """

    def __init__(self, batch: _BatchPredictor, rows: slice, groups, segments, blocks, n: int) -> None:
        self.runs, self.columns = batch.runs[rows], batch.columns[rows]
        self.noise_variance = batch.noise_variance[rows]
        self.input_mean, self.input_scale = batch.input_mean[:, rows], batch.input_scale[:, rows]
        self.log_signal, self.signal = batch.log_signal[rows], batch.signal[rows]
        self.output_mean = batch.output_mean[rows]
        self.groups = [(slice(a, b), size, slice(i, j)) for a, b, size, i, j in groups]
        self.segments = [(slice(a, b), G) for a, b, G in segments]
        self.blocks, self.n = blocks, n
        widths = np.cumsum([0] + [w.shape[2] for _, w in blocks])
        self.block_rows = list(zip(widths[:-1], widths[1:]))  # columns of each block's product
        m, d = len(self.runs), batch.weights.shape[0]
        self.a = np.empty((2 * d + 1, m))  # the exponent's left factor, see _BatchPredictor
        self.a[d:2 * d] = batch.weights[:, rows]
        self.weights = self.a[d:2 * d]
        self.exponent = np.empty((m, n))
        self.products = np.empty((m, n + 1))
        self.mean, self.var = np.empty(m), np.empty(m)

    def __call__(self, X):
        """Mean and latent variance of every slot, each shape (m,), in output units, for the
        regressors ``X`` (d, R) of all runs (each slot reads its run's column). The arrays are
        reused by the next call."""
        d = len(self.weights)
        x = X[:, self.runs]
        x -= self.input_mean
        x /= self.input_scale
        wx = np.multiply(x, self.weights, out=self.a[:d])
        np.subtract(self.log_signal, np.einsum("ij,ij->j", wx, x), out=self.a[2 * d])
        k = self.exponent
        for rows, G in self.segments:
            np.matmul(self.a[:, rows].T, G, out=k[rows])
        # k(x_slot, X_m), shape (m, n); where x_slot meets a basis point, rounding may lift it a
        # few ulp above sigma_f^2, which the variance's clipping at zero absorbs.
        np.exp(k, out=k)
        for rows, size, items in self.groups:
            k_group = k[rows].reshape(-1, size, self.n)  # (items, runs each, n)
            v = self.products[rows].reshape(-1, size, self.n + 1)  # [scale L^-1 k, mean]
            for (cols, factors), (first, last) in zip(self.blocks, self.block_rows):
                np.matmul(k_group[:, :, :cols], factors[items], out=v[:, :, first:last])
            np.einsum("ipm,ipm->ip", v[:, :, :self.n], v[:, :, :self.n], out=self.var[rows].reshape(-1, size))
            self.mean[rows] = v[:, :, self.n].ravel()
        np.subtract(self.signal, self.var, out=self.var)
        np.maximum(self.var, 0.0, out=self.var)
        self.mean += self.output_mean
        return self.mean, self.var
