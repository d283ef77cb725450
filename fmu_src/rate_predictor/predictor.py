"""GP-NARX prediction inside the rate predictor FMU: numpy and the standard library only.

Every rate predictor FMU (pythonfmu) carries a copy of this file and of what it imports, the
shared FMU runtime (:mod:`fmu_src.fmi.runtime`) and the numpy-only moment matching of
:mod:`gp_model.uncertain_input`, under names unique to the FMU (:mod:`fmu_src.fmi.pythonfmu`):
a simulator host has no flightgp. The native rate predictor evaluates the same formulas in C
(``narx_model.c``).

Model file (``model.npz``, written by :func:`pack_model`, read without pickle)
------------------------------------------------------------------------------
Scalars and names: ``format`` (``"flightgp-fmu-narx"``), ``version``, ``step`` (NARX step, s),
``input_names``, ``output_names``, ``input_lags``, ``output_lags``, ``envelope_low`` and
``envelope_high`` (per regressor, the range of the training regressors in physical units).
Per output ``j`` (prefix ``"<j>/"``), one row per hyperparameter sample ``s`` (S rows; S = 1 for
point hyperparameters), every array in the GP's standardised units:

============================  ===========  =================================================
``basis``                     (m, d)       standardised basis inputs (training or inducing)
``weights``                   (S, m)       mean weights, ``mean_s = k_s . weights_s``
``variance_factor``           (S, m, m)    ``var_s = sigma_f,s^2 - |variance_factor_s k_s|^2``
``kernel_weights``            (S, d)       ``w`` of ``k = sigma_f^2 exp(-sum_i w_i (x_i - x'_i)^2)``
``log_signal_variance``       (S,)         ``ln sigma_f,s^2``
``noise_variance``            (S,)         ``sigma_n,s^2``
``input_mean, input_scale``   (d,)         ``x_standardised = (x - input_mean) / input_scale``
``output_mean, output_scale`` ()           ``y = y_standardised * output_scale + output_mean``
============================  ===========  =================================================

These are :class:`gp_model.PredictiveForm` s (one per sample) plus the kernel and noise
hyperparameters and the scalers. The free run (:meth:`NarxPredictor.free_run_step`) matches
the moments of the same mixture (sample ``s`` of every output forms model ``s``).
:meth:`NarxPredictor.predict` reproduces
``GaussianProcess.predict(X, return_var=True, include_noise=True)`` exactly (same mixture over
samples: mean ``E_s[mu_s]``, variance ``E_s[var_s + mu_s^2] - mean^2``, law of total variance),
up to rounding.

Regressor order (as :class:`gp_model.NarxStructure`): every input at every input lag
(input-major), then every output at every output lag.
"""
from __future__ import annotations

import json

import numpy as np

from fmu_src.fmi.runtime import (
    Envelope,
    ModelFormatError,
    check_header,
    freeze,
    kernel_rows,
    model_header,
    read_model_file,
    read_part,
)
from gp_model.uncertain_input import MomentMatcher, first_occurrences, frame_gp, narx_belief_start, narx_belief_step

FORMAT = "flightgp-fmu-narx"
VERSION = 1

#: Arrays stored per output, with their number of dimensions.
PER_OUTPUT = {"basis": 2, "weights": 2, "variance_factor": 3, "kernel_weights": 2,
              "log_signal_variance": 1, "noise_variance": 1, "input_mean": 1, "input_scale": 1,
              "output_mean": 0, "output_scale": 0}


def pack_model(*, step: float, input_names, output_names, input_lags, output_lags,
               envelope_low, envelope_high, outputs) -> dict:
    """Arrays for ``numpy.savez`` (see the module docstring).

    Parameters
    ----------
    step : float
        NARX step, s.
    input_names, output_names : sequence of str
    input_lags, output_lags : sequence of int
        Lags in NARX steps.
    envelope_low, envelope_high : array_like, shape (d,)
        Training range of each regressor, physical units.
    outputs : list of dict
        One dict per output with the arrays of :data:`PER_OUTPUT`.
    """
    arrays = {**model_header(FORMAT, VERSION), "step": np.array(float(step)),
              "input_names": np.array(list(input_names), dtype=str),
              "output_names": np.array(list(output_names), dtype=str),
              "input_lags": np.array(list(input_lags), dtype=np.int64),
              "output_lags": np.array(list(output_lags), dtype=np.int64),
              "envelope_low": np.asarray(envelope_low, dtype=float),
              "envelope_high": np.asarray(envelope_high, dtype=float)}
    for j, part in enumerate(outputs):
        for name in PER_OUTPUT:
            arrays[f"{j}/{name}"] = np.asarray(part[name], dtype=float)
    return arrays


def _read_output(arrays: dict, prefix: str, n_regressors: int) -> dict:
    """One output's arrays (:data:`PER_OUTPUT`), checked for shape and finiteness."""
    a = read_part(arrays, prefix, PER_OUTPUT)
    m, d = a["basis"].shape
    S = len(a["weights"])
    expected = {"weights": (S, m), "variance_factor": (S, m, m), "kernel_weights": (S, d),
                "log_signal_variance": (S,), "noise_variance": (S,), "input_mean": (d,),
                "input_scale": (d,)}
    for name, shape in expected.items():
        if a[name].shape != shape:
            raise ModelFormatError(f"{prefix}{name} has shape {a[name].shape}, expected {shape}")
    if d != n_regressors:
        raise ModelFormatError(f"{prefix}basis has {d} columns but the NARX structure has "
                               f"{n_regressors} regressors")
    if np.any(a["input_scale"] <= 0):
        raise ModelFormatError(f"{prefix}input_scale holds non-positive scales")
    return a


def _distinct_samples(part: dict) -> tuple[dict, np.ndarray]:
    """One output's arrays at its distinct hyperparameter samples only (annealing repeats
    samples), in order of first occurrence, and how often each occurs (T,)."""
    n = len(part["weights"])
    rows = np.column_stack([part["weights"], part["variance_factor"].reshape(n, -1), part["kernel_weights"],
                            part["log_signal_variance"], part["noise_variance"]])
    keep, which = first_occurrences(rows)
    per_sample = ("weights", "variance_factor", "kernel_weights", "log_signal_variance", "noise_variance")
    return {**part, **{name: part[name][keep] for name in per_sample}}, np.bincount(which).astype(float)


class _Block:
    """Outputs whose GPs share basis points and input scaling (every output of an exact
    GP-NARX): all their distinct hyperparameter samples are evaluated in one batch, R rows in
    all, each counted as often as its output's mixture holds it."""

    def __init__(self, parts: list) -> None:
        first = parts[0]
        self.basis = first["basis"]
        self.input_mean, self.input_scale = first["input_mean"], first["input_scale"]
        self.counts = np.array([len(p["weights"]) for p in parts], dtype=float)  # samples per output
        distinct = [_distinct_samples(p) for p in parts]
        parts = [p for p, _ in distinct]
        self.multiplicity = np.concatenate([m for _, m in distinct])  # (R,)
        stack = lambda name: np.ascontiguousarray(np.concatenate([p[name] for p in parts]))  # noqa: E731
        self.weights = stack("weights")  # (R, m)
        self.variance_factor = stack("variance_factor")  # (R, m, m)
        self.kernel_weights = stack("kernel_weights")  # (R, d)
        self.log_signal_variance = stack("log_signal_variance")  # (R,)
        self.signal_variance = np.exp(self.log_signal_variance)
        self.noise_variance = stack("noise_variance")
        rows = np.array([len(p["weights"]) for p in parts])
        self.starts = np.concatenate(([0], np.cumsum(rows)[:-1]))
        self.output_mean = np.array([float(p["output_mean"]) for p in parts])
        self.output_scale = np.array([float(p["output_scale"]) for p in parts])
        freeze(vars(self).values())

    def predict(self, x: np.ndarray) -> tuple:
        """Mean and variance (noise included) of the block's outputs at regressor ``x`` (d,), in
        output units: for each output, the mixture over its hyperparameter samples."""
        xs = (x - self.input_mean) / self.input_scale
        k = kernel_rows(xs, self.basis, self.kernel_weights, self.log_signal_variance)  # (R, m)
        means = np.einsum("rm,rm->r", k, self.weights)
        v = np.matmul(self.variance_factor, k[:, :, None])[:, :, 0]  # (R, m)
        latent = np.maximum(self.signal_variance - np.einsum("rm,rm->r", v, v), 0.0)
        variances = latent + self.noise_variance
        # Mixture per output, as GaussianProcess.predict: E_s[mu_s], E_s[var_s + mu_s^2] - mean^2.
        mean = np.add.reduceat(self.multiplicity * means, self.starts) / self.counts
        second = np.add.reduceat(self.multiplicity * (variances + means**2), self.starts) / self.counts
        spread = np.maximum(second - mean**2, 0.0)
        return mean * self.output_scale + self.output_mean, spread * self.output_scale**2


def _moment_matcher(parts: list) -> MomentMatcher:
    """The free run's moment matcher over every output's hyperparameter samples, in the first
    output's input frame (read-only: shared by every instance of the FMU in a process)."""
    frame_mean, frame_scale = parts[0]["input_mean"], parts[0]["input_scale"]
    frames = [frame_gp(basis=p["basis"], weights=p["weights"], variance_factor=p["variance_factor"],
                       kernel_weights=p["kernel_weights"], log_signal_variance=p["log_signal_variance"],
                       noise_variance=p["noise_variance"], input_mean=p["input_mean"],
                       input_scale=p["input_scale"], output_mean=p["output_mean"],
                       output_scale=p["output_scale"], frame_mean=frame_mean, frame_scale=frame_scale)
              for p in parts]
    for frame in frames:
        freeze(vars(frame).values())
    return MomentMatcher(frames, input_mean=frame_mean, input_scale=frame_scale)


class NarxPredictor:
    """A GP-NARX model loaded from an FMU model file.

    Attributes
    ----------
    step : float
        NARX step, s.
    input_names, output_names : tuple of str
    input_lags, output_lags : tuple of int
        Lags in NARX steps; input lags >= 1 (no direct feedthrough), output lags >= 1.
    max_lag : int
    regressor_names : tuple of str
    envelope : Envelope
        Training range of each regressor.
    n_samples : int
        Hyperparameter samples of the mixture (of the first output).
    matcher : gp_model.uncertain_input.MomentMatcher
        The free run's moment matcher (its distinct samples and sample pairs are what the
        native FMU stores).
    """

    def __init__(self, arrays: dict) -> None:
        try:
            check_header(arrays, format_name=FORMAT, version=VERSION)
            self.step = float(arrays["step"])
            self.input_names = tuple(str(n) for n in arrays["input_names"])
            self.output_names = tuple(str(n) for n in arrays["output_names"])
            self.input_lags = tuple(int(i) for i in arrays["input_lags"])
            self.output_lags = tuple(int(j) for j in arrays["output_lags"])
            if not self.output_names or not self.output_lags:
                raise ModelFormatError("a NARX model needs outputs and output lags")
            if min(self.input_lags, default=1) < 1 or min(self.output_lags) < 1:
                raise ModelFormatError(f"lags must be >= 1 (inputs {self.input_lags}, outputs "
                                       f"{self.output_lags})")
            if not self.step > 0:
                raise ModelFormatError(f"NARX step must be positive, got {self.step}")
            self.max_lag = max((*self.input_lags, *self.output_lags))
            self.regressor_names = tuple(
                [f"{n}(k-{i})" for n in self.input_names for i in self.input_lags]
                + [f"{n}(k-{j})" for n in self.output_names for j in self.output_lags])
            d = len(self.regressor_names)
            self.envelope = Envelope(arrays["envelope_low"], arrays["envelope_high"], self.regressor_names)
            if self.envelope.low.shape != (d,) or self.envelope.high.shape != (d,):
                raise ModelFormatError(f"training envelope must have {d} entries")
            parts = [_read_output(arrays, f"{j}/", d) for j in range(len(self.output_names))]
        except KeyError as error:
            raise ModelFormatError(f"model file lacks the array {error}") from None
        if len({len(part["weights"]) for part in parts}) != 1:
            raise ModelFormatError("every output must have the same number of hyperparameter samples")
        self.matcher = _moment_matcher(parts)
        self.n_samples = len(parts[0]["weights"])
        # Outputs sharing basis and input scaling form one block; order[j] = (block, row).
        self._order, members = [], []
        for j, part in enumerate(parts):
            for b, group in enumerate(members):
                lead = parts[group[0]]
                if all(np.array_equal(part[n], lead[n]) for n in ("basis", "input_mean", "input_scale")):
                    self._order.append((b, len(group)))
                    group.append(j)
                    break
            else:
                self._order.append((len(members), 0))
                members.append([j])
        self._blocks = [_Block([parts[j] for j in group]) for group in members]

    @classmethod
    def load(cls, path) -> NarxPredictor:
        """Read ``path`` (an ``.npz`` written from :func:`pack_model`; never unpickles)."""
        return cls(read_model_file(path))

    def known_regressors(self, input_history: np.ndarray) -> np.ndarray:
        """The input part of the next sample's regressor (every input at every input lag).

        Parameters
        ----------
        input_history : ndarray, shape (max_lag, n_inputs)
            Row ``i`` holds the inputs ``i`` NARX steps before the current sample (row 0: current).

        Returns
        -------
        ndarray, shape (n_inputs * len(input_lags),)
            For the sample one step after the current one, so lag ``L`` is row ``L - 1``.
        """
        return np.array([input_history[i - 1, c] for c in range(len(self.input_names))
                         for i in self.input_lags], dtype=float)

    def regressor(self, input_history: np.ndarray, output_history: np.ndarray) -> np.ndarray:
        """Regressor of the next sample.

        Parameters
        ----------
        input_history : ndarray, shape (max_lag, n_inputs)
        output_history : ndarray, shape (max_lag, n_outputs)
            Row ``i`` holds the sample ``i`` NARX steps before the current one (row 0: current).

        Returns
        -------
        ndarray, shape (d,)
            For the sample one step after the current one, so lag ``L`` is row ``L - 1``.
        """
        outputs = [output_history[j - 1, c] for c in range(len(self.output_names)) for j in self.output_lags]
        return np.concatenate([self.known_regressors(input_history), outputs])

    def free_run_start(self, outputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The free-run belief (mean, covariance over the lagged outputs) of a vehicle steady at
        ``outputs`` (n_outputs,) before the first predicted sample."""
        return narx_belief_start(np.tile(outputs, (max(self.output_lags), 1)))

    def free_run_step(self, input_history: np.ndarray, belief, *, exact_moments: bool = True) -> tuple:
        """Predict the next sample of a free run by moment matching over the hyperparameter
        samples (``GPNarx.free_run(method="moment_matching")``, noisy outputs fed back).

        Parameters
        ----------
        input_history : ndarray, shape (max_lag, n_inputs)
            As :meth:`known_regressors`.
        belief : tuple of ndarray
            From :meth:`free_run_start` or the previous step.
        exact_moments : bool, default True
            False: the pair terms' exponents and exponentials in single precision
            (``MomentMatcher``'s ``single_precision``), the FMU's fast path.

        Returns
        -------
        mean, var : ndarray, shape (n_outputs,)
            Prediction of the next sample; variance with measurement noise, grown over the run.
        belief : tuple of ndarray
            For the next step.
        """
        y_mean, y_cov, *belief = narx_belief_step(self.matcher, self.known_regressors(input_history),
                                                  *belief, output_lags=self.output_lags,
                                                  include_noise=True, single_precision=not exact_moments)
        return y_mean, np.diag(y_cov).copy(), tuple(belief)

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and variance (measurement noise included) of every output, each shape
        (n_outputs,), at regressor ``x`` (d,)."""
        results = [block.predict(x) for block in self._blocks]
        mean = np.array([results[b][0][i] for b, i in self._order])
        var = np.array([results[b][1][i] for b, i in self._order])
        return mean, var

    def describe(self) -> str:
        """One line for the log."""
        return json.dumps({"outputs": list(self.output_names), "regressors": list(self.regressor_names),
                           "basis_points": int(self._blocks[0].basis.shape[0]),
                           "hyperparameter_samples": self.n_samples, "step_s": self.step})
