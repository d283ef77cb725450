"""Exact Gaussian-process regression (Rasmussen & Williams 2006, ch. 2 and 5).

Conventions
-----------
- Hyperparameters of a :class:`GaussianProcess` form one unconstrained vector
  ``theta = [kernel.theta..., ln sigma_n^2]``; they act on *standardised* inputs and outputs when
  ``normalize_inputs`` / ``normalize_outputs`` are on (the default), so the same priors and
  starting points suit any units.
- Several outputs (``y`` of shape (n, m)) share one set of hyperparameters and one Cholesky
  factor, as Ko et al. (ICRA 2007) did; :class:`PerOutputGP` gives each output its own GP.
- Learned state carries a trailing underscore (``theta_``, ``L_``, ``alpha_``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, stats
from scipy.linalg import lapack

from ._errors import GPNumericalError
from ._kernels import KERNELS, StationaryKernel
from ._linalg import robust_cholesky
from ._priors import IndependentPrior
from ._scaling import Standardizer

LOG_2PI = np.log(2.0 * np.pi)


@dataclass(frozen=True)
class PredictiveForm:
    """A fitted GP's prediction at one hyperparameter vector, reduced to three arrays.

    For a standardised input ``x`` with kernel vector ``k = k(x, basis)`` (shape (m,)):

        mean(x) = k @ weights,        var(x) = k(x, x) - |variance_factor @ k|^2   (latent)

    Exact GP (Rasmussen & Williams, Alg. 2.1): ``basis`` = training inputs, ``weights`` =
    ``alpha``, ``variance_factor = L^-1``. A sparse GP fills the same slots with its inducing
    points, so free runs (and generated code) need one prediction routine for both.

    Attributes
    ----------
    theta : ndarray, shape (p,)
        Hyperparameters ``[kernel.theta..., ln sigma_n^2]``.
    basis : ndarray, shape (m, d)
        Standardised basis inputs.
    weights : ndarray, shape (m,), or (m, q) for a GP with q outputs sharing hyperparameters
    variance_factor : ndarray, shape (m, m)
    """

    theta: np.ndarray
    basis: np.ndarray
    weights: np.ndarray
    variance_factor: np.ndarray


@dataclass(frozen=True)
class _LikelihoodTerms:
    """The log marginal likelihood at one hyperparameter vector and the two parts of its gradient
    (Rasmussen & Williams eq. 5.9, summed over the m outputs ``y_k``, ``alpha_k = K^-1 y_k``):

        d lml / d theta_j = 1/2 (data_j - m trace_j),
        data_j = sum_k alpha_k^T (dK/dtheta_j) alpha_k,     trace_j = tr(K^-1 dK/dtheta_j).
    """

    lml: float
    fit: float  # sum_k y_k^T alpha_k, the data-fit term
    data: np.ndarray | None  # (p,), None when the gradient was not asked for
    trace: np.ndarray | None  # (p,)


@dataclass(frozen=True)
class _Posterior:
    """Everything prediction needs for one hyperparameter vector."""

    theta: np.ndarray  # (p,)
    L: np.ndarray  # (n, n) lower Cholesky factor of K + (sigma_n^2 + jitter) I
    alpha: np.ndarray  # (n, m) = (K + sigma_n^2 I)^-1 Y
    jitter: float


def mixture_moments(means: np.ndarray, variances: np.ndarray):
    """Mean and variance of an equal-weight mixture of Gaussians (law of total variance):
    ``E_s[mu_s]`` and ``E_s[var_s + mu_s^2] - E_s[mu_s]^2``, over the first axis.

    Parameters
    ----------
    means, variances : ndarray, shape (S, ...)
        Per-component moments (broadcastable against each other).

    Returns
    -------
    mean, var : ndarray, shape (...)
    """
    mean = means.mean(axis=0)
    var = (variances + means**2).mean(axis=0) - mean**2
    return mean, np.maximum(var, 0.0)


class BaseGaussianProcess:
    """What exact and sparse GP regression share: the hyperparameter vector and its prior, the
    data checks and standardisation of :meth:`fit`, :meth:`set_hyperparameters`, the mixture
    prediction of :meth:`predict`, and the portable state of model files (:meth:`to_arrays`,
    :meth:`from_arrays`).

    Not used directly: :class:`GaussianProcess` and :class:`~gp_model.SparseGaussianProcess`
    derive from it. They are siblings, not parent and child, so code that needs an exact GP's
    Cholesky factor ``L_`` refuses a sparse GP instead of misreading it. A subclass provides
    ``log_marginal_likelihood``, ``predictive_forms`` and the two steps prediction takes:

    - ``_posterior_at(theta)``: what prediction needs at one hyperparameter vector (a
      *posterior*; its ``theta`` and ``jitter`` fields are read here);
    - ``_predict_one(posterior, Xs, want, include_noise)``: the standardised mean, shape (k, m),
      and for ``want`` ``"var"`` the variance, shape (k,), or for ``"cov"`` the covariance,
      shape (k, k), at standardised inputs ``Xs`` (k, d).

    Parameters
    ----------
    kernel : StationaryKernel
        Covariance function; its ``theta`` is the starting point for hyperparameter inference.
    noise_variance : float, default 1e-2
        ``sigma_n^2`` of the (standardised) outputs.
    normalize_inputs, normalize_outputs : bool, default True
        Standardise each input / output column to zero mean and unit variance before fitting.

    Attributes
    ----------
    theta_ : ndarray, shape (p,)
        Hyperparameters in use (after :meth:`fit`).
    theta_samples_ : ndarray, shape (S, p) or None
        Hyperparameter samples; when set, predictions are the mixture over them.
    X_train_, Y_train_ : ndarray, shapes (n, d), (n, m)
        Standardised training data.
    input_scaler_, output_scaler_ : Standardizer
        The standardisation of the inputs (d columns) and outputs (m columns).
    """

    def __init__(self, kernel: StationaryKernel, *, noise_variance: float = 1e-2,
                 normalize_inputs: bool = True, normalize_outputs: bool = True) -> None:
        if not noise_variance > 0:
            raise ValueError(f"noise_variance must be positive, got {noise_variance}")
        self.kernel = kernel
        self.noise_variance = float(noise_variance)
        self.normalize_inputs = normalize_inputs
        self.normalize_outputs = normalize_outputs
        self.theta_samples_ = None
        self._sample_posteriors = None

    # -- hyperparameters --------------------------------------------------------------------
    @property
    def theta(self) -> np.ndarray:
        """Configured hyperparameters ``[kernel.theta..., ln noise_variance]``, shape (p,)."""
        return np.append(self.kernel.theta, np.log(self.noise_variance))

    @property
    def theta_names(self) -> list[str]:
        return self.kernel.theta_names + ["ln_noise_variance"]

    def prior(self) -> IndependentPrior:
        """Default prior on ``theta``: the kernel's, plus log-normal noise around 1e-2 of the
        standardised output variance (a 2-sigma range of about 5e-5 to 2)."""
        noise = IndependentPrior([stats.norm(np.log(1e-2), 2.5)], ["ln_noise_variance"])
        return self.kernel.prior() + noise

    @property
    def jitter_(self) -> float:
        """Jitter added to the diagonal of the factorised kernel matrix for ``theta_``."""
        return self._posterior.jitter

    # -- fitting ------------------------------------------------------------------------------
    def fit(self, X, y, *, theta=None):
        """Condition on training data with fixed hyperparameters.

        Parameters
        ----------
        X : ndarray, shape (n, d)
            Training inputs.
        y : ndarray, shape (n,) or (n, m)
            Training targets.
        theta : ndarray, shape (p,), optional
            Hyperparameters; defaults to :attr:`theta` (the configured kernel and noise).

        Returns
        -------
        self

        Raises
        ------
        ValueError
            On mismatched shapes or non-finite data.
        GPNumericalError
            If the kernel matrix cannot be factorised even with jitter.
        """
        X = np.asarray(X, dtype=float)
        y = np.asarray(y, dtype=float)
        if X.ndim != 2 or X.shape[1] != self.kernel.n_dims:
            raise ValueError(f"X must have shape (n, {self.kernel.n_dims}), got {X.shape}")
        if y.ndim not in (1, 2) or len(y) != len(X):
            raise ValueError(f"y must have shape ({len(X)},) or ({len(X)}, m), got {y.shape}")
        if len(X) == 0:
            raise ValueError("no training data")
        if not (np.isfinite(X).all() and np.isfinite(y).all()):
            raise ValueError("training data contain NaN or inf")
        self._y_1d = y.ndim == 1
        Y = y.reshape(len(y), -1)
        self.input_scaler_ = Standardizer(enabled=self.normalize_inputs).fit(X)
        self.output_scaler_ = Standardizer(enabled=self.normalize_outputs).fit(Y)
        self.X_train_ = self.input_scaler_.transform(X)
        self.Y_train_ = self.output_scaler_.transform(Y)
        return self.set_hyperparameters(self.theta if theta is None else theta)

    def set_hyperparameters(self, theta, *, samples=None):
        """Use ``theta`` (shape (p,)) and optionally a sample set (shape (S, p)) for the mixture.

        The configured ``kernel`` and ``noise_variance`` are updated to match ``theta``.

        Returns
        -------
        self

        Raises
        ------
        ValueError
            On other shapes.
        GPNumericalError
            If the kernel matrix cannot be factorised at ``theta``; the GP is then unchanged.
        """
        theta, samples = self._checked_hyperparameters(theta, samples)
        posterior = self._posterior_at(theta)  # first: if it fails, the GP stays as it was
        self.kernel = self.kernel.clone_with_theta(theta[:-1])
        self.noise_variance = float(np.exp(theta[-1]))
        self._posterior = posterior
        self.theta_ = theta
        self.theta_samples_ = samples
        self._sample_posteriors = None
        return self

    def _checked_hyperparameters(self, theta, samples) -> tuple[np.ndarray, np.ndarray | None]:
        """``theta`` as an array of shape (p,) and ``samples`` as one of shape (S, p) or None;
        raises ValueError on other shapes."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (len(self.theta),):
            raise ValueError(f"theta must have shape ({len(self.theta)},), got {theta.shape}")
        if samples is not None:
            samples = np.atleast_2d(np.asarray(samples, dtype=float))
            if samples.shape[1] != len(theta):
                raise ValueError(f"samples must have shape (S, {len(theta)}), got {samples.shape}")
        return theta, samples

    # -- prediction ---------------------------------------------------------------------------
    def predict(self, X, *, return_var: bool = False, return_cov: bool = False,
                include_noise: bool = False, use_samples: bool = True):
        """Predictive distribution at ``X``.

        Parameters
        ----------
        X : ndarray, shape (k, d)
        return_var : bool
            Also return the marginal variances.
        return_cov : bool
            Also return the full covariance (not with ``return_var``).
        include_noise : bool, default False
            Predict a noisy observation ``y`` instead of the latent ``f``.
        use_samples : bool, default True
            When ``theta_samples_`` is set, return the mixture over the samples: mean
            ``E_s[mu_s]`` and (co)variance ``E_s[Sigma_s + mu_s mu_s^T] - mu mu^T`` (law of total
            variance), so hyperparameter uncertainty reaches the bounds.

        Returns
        -------
        mean : ndarray, shape (k,) or (k, m)
        var : ndarray, shape like ``mean``; or cov, shape (k, k) or (k, k, m)
        """
        if return_var and return_cov:
            raise ValueError("ask for return_var or return_cov, not both")
        Xs = self.input_scaler_.transform(np.atleast_2d(np.asarray(X, dtype=float)))
        posteriors = self._posteriors() if use_samples else [self._posterior]
        want = "cov" if return_cov else "var" if return_var else None
        means, spreads = zip(*(self._predict_one(p, Xs, want, include_noise) for p in posteriors))
        mean = np.mean(means, axis=0)  # (k, m)
        scale = self.output_scaler_.scale_
        out_mean = self.output_scaler_.inverse_transform(mean)
        if want is None:
            return out_mean[:, 0] if self._y_1d else out_mean
        if want == "var":
            _, spread = mixture_moments(np.array(means), np.array(spreads)[:, :, None])
            spread = spread * scale**2  # (k, m)
            return (out_mean[:, 0], spread[:, 0]) if self._y_1d else (out_mean, spread)
        second = np.mean([s[:, :, None] + mu[:, None, :] * mu[None, :, :]
                          for s, mu in zip(spreads, means)], axis=0)
        cov = (second - mean[:, None, :] * mean[None, :, :]) * scale**2  # (k, k, m)
        return (out_mean[:, 0], cov[:, :, 0]) if self._y_1d else (out_mean, cov)

    def _posteriors(self) -> list:
        """The posterior of every hyperparameter sample (factorised once), or ``theta_``'s."""
        if self.theta_samples_ is None:
            return [self._posterior]
        if self._sample_posteriors is None:
            # Annealing repeats samples (a rejected move keeps the last one): each distinct
            # sample is factorised once and its posterior shared by its repeats.
            _, first, inverse = np.unique(self.theta_samples_, axis=0, return_index=True,
                                                 return_inverse=True)
            posteriors = [self._posterior_at(self.theta_samples_[i]) for i in first]
            self._sample_posteriors = [posteriors[i] for i in inverse.ravel()]
        return self._sample_posteriors

    # -- portable state (one part of a model file, gp_model._model_file) ---------------------
    def to_arrays(self) -> tuple[dict, dict]:
        """JSON-safe metadata and named arrays that fully describe the fitted GP; the inverse
        is :meth:`from_arrays`. :func:`~gp_model.save_model` writes them.

        Returns
        -------
        meta : dict
            ``kernel`` (its kind), ``normalize_inputs``, ``normalize_outputs``, ``y_1d`` (whether
            ``y`` was one-dimensional), ``theta_names``.
        arrays : dict of ndarray
            ``X_train`` (n, d), ``Y_train`` (n, m), ``theta`` (p,), ``input_mean``,
            ``input_scale`` (d,), ``output_mean``, ``output_scale`` (m,), and ``theta_samples``
            (S, p) when set.
        """
        meta = {"kernel": self.kernel.kind, "normalize_inputs": self.normalize_inputs,
                "normalize_outputs": self.normalize_outputs, "y_1d": bool(self._y_1d),
                "theta_names": self.theta_names}
        arrays = {"X_train": self.X_train_, "Y_train": self.Y_train_, "theta": self.theta_,
                  "input_mean": self.input_scaler_.mean_, "input_scale": self.input_scaler_.scale_,
                  "output_mean": self.output_scaler_.mean_, "output_scale": self.output_scaler_.scale_}
        if self.theta_samples_ is not None:
            arrays["theta_samples"] = self.theta_samples_
        return meta, arrays

    @classmethod
    def from_arrays(cls, meta: dict, arrays: dict):
        """The fitted GP that :meth:`to_arrays` described, factorised again from the stored
        training data; :func:`~gp_model.load_model` reads them.

        Raises
        ------
        KeyError, ValueError
            On missing or inconsistent content.
        GPNumericalError
            If the stored GP cannot be factorised.
        """
        theta = np.asarray(arrays["theta"], dtype=float)
        X_train, Y_train = np.asarray(arrays["X_train"], float), np.asarray(arrays["Y_train"], float)
        if theta.ndim != 1 or X_train.ndim != 2 or Y_train.ndim != 2 or len(X_train) != len(Y_train):
            raise ValueError("inconsistent array shapes")
        if theta.size != X_train.shape[1] + 2:
            raise ValueError(f"theta has {theta.size} entries, expected {X_train.shape[1] + 2}")
        kernel = KERNELS[meta["kernel"]](1.0, np.full(X_train.shape[1], 0.5)).clone_with_theta(theta[:-1])
        gp = cls(kernel, noise_variance=float(np.exp(theta[-1])),
                 normalize_inputs=bool(meta["normalize_inputs"]),
                 normalize_outputs=bool(meta["normalize_outputs"]), **cls._settings_from_meta(meta))
        gp._restore_training_data(meta, arrays, X_train, Y_train)
        return gp.set_hyperparameters(theta, samples=arrays.get("theta_samples"))

    @classmethod
    def _settings_from_meta(cls, meta: dict) -> dict:
        """Constructor options, beyond the kernel, noise and standardisation, that
        :meth:`to_arrays` stored in ``meta``: none here."""
        return {}

    def _restore_training_data(self, meta: dict, arrays: dict, X_train: np.ndarray,
                               Y_train: np.ndarray) -> None:
        """The state :meth:`fit` learns before :meth:`set_hyperparameters`, from a model file:
        the standardised training data (checked by :meth:`from_arrays`), the scalers and whether
        ``y`` was one-dimensional."""
        self._y_1d = bool(meta["y_1d"])
        self.input_scaler_ = Standardizer.from_arrays(arrays["input_mean"], arrays["input_scale"])
        self.output_scaler_ = Standardizer.from_arrays(arrays["output_mean"], arrays["output_scale"])
        self.X_train_, self.Y_train_ = X_train, Y_train


class GaussianProcess(BaseGaussianProcess):
    """Exact GP regression with a stationary kernel and Gaussian noise.

    Parameters
    ----------
    kernel : StationaryKernel
        Covariance function; its ``theta`` is the starting point for hyperparameter inference.
    noise_variance : float, default 1e-2
        ``sigma_n^2`` of the (standardised) outputs.
    normalize_inputs, normalize_outputs : bool, default True
        Standardise each input / output column to zero mean and unit variance before fitting.

    Attributes
    ----------
    theta_ : ndarray, shape (p,)
        Hyperparameters in use (after :meth:`fit`).
    theta_samples_ : ndarray, shape (S, p) or None
        Hyperparameter samples; when set, predictions are the mixture over them.
    X_train_, Y_train_ : ndarray, shapes (n, d), (n, m)
        Standardised training data.
    L_, alpha_ : ndarray, shapes (n, n), (n, m)
        Cholesky factor and weights for ``theta_`` (Rasmussen & Williams, Alg. 2.1).
    jitter_ : float
        Jitter added to the diagonal of ``K + sigma_n^2 I`` for ``theta_``.
    """

    @property
    def L_(self) -> np.ndarray:
        """Lower Cholesky factor of ``K + (sigma_n^2 + jitter_) I`` for ``theta_``, shape (n, n)."""
        return self._posterior.L

    @property
    def alpha_(self) -> np.ndarray:
        """``(K + sigma_n^2 I)^-1 Y_train_`` for ``theta_``, shape (n, m)."""
        return self._posterior.alpha

    def _posterior_at(self, theta) -> _Posterior:
        return self._factorise(theta)[0]

    def _factorise(self, theta, *, quiet: bool = False) -> tuple[_Posterior, np.ndarray]:
        """The posterior at ``theta`` and the noise-free kernel matrix, shape (n, n)."""
        # Rasmussen & Williams Alg. 2.1, lines 2-3: L = chol(K + sigma_n^2 I), alpha = L^T\(L\y).
        K = self.kernel(self.X_train_, theta=theta[:-1])
        diagonal = K.diagonal().copy()
        K.flat[:: len(K) + 1] += np.exp(theta[-1])
        # K is symmetric, so K.T is the same matrix in the Fortran order LAPACK works in: the
        # factorisation copies it as it is instead of transposing it.
        L, jitter = robust_cholesky(K.T, quiet=quiet)
        K.flat[:: len(K) + 1] = diagonal
        alpha = linalg.cho_solve((L, True), self.Y_train_, check_finite=False)
        return _Posterior(np.asarray(theta, dtype=float), L, alpha, jitter), K

    # -- likelihood ---------------------------------------------------------------------------
    def log_marginal_likelihood(self, theta=None, *, return_gradient: bool = False):
        """Log marginal likelihood of the (standardised) training outputs, summed over outputs.

        ``log p(Y|X, theta) = sum_j [-1/2 y_j^T alpha_j - sum_i ln L_ii - n/2 ln 2 pi]``
        (Rasmussen & Williams eq. 2.30 / Alg. 2.1 line 7); gradient eq. 5.9:
        ``d/dtheta_k = 1/2 tr((alpha alpha^T - m K^-1) dK/dtheta_k)``.

        Parameters
        ----------
        theta : ndarray, shape (p,), optional
            Defaults to ``theta_``.
        return_gradient : bool

        Returns
        -------
        lml : float
            ``-inf`` if the kernel matrix cannot be factorised at ``theta``.
        gradient : ndarray, shape (p,)
            Only when ``return_gradient``.
        """
        theta = self.theta_ if theta is None else np.asarray(theta, dtype=float)
        terms = self._likelihood_terms(theta, gradient=return_gradient)
        if terms is None:
            return (-np.inf, np.zeros_like(theta)) if return_gradient else -np.inf
        if not return_gradient:
            return terms.lml
        return terms.lml, 0.5 * (terms.data - self.Y_train_.shape[1] * terms.trace)

    def _likelihood_terms(self, theta, *, gradient: bool = True) -> _LikelihoodTerms | None:
        """:class:`_LikelihoodTerms` at ``theta``, or None if the kernel matrix cannot be factorised.

        The gradient costs one LAPACK ``dpotri`` (``K^-1`` from the Cholesky factor) and no
        other O(n^3) work: the ``alpha alpha^T`` part contracts with the kernel through one
        matrix product (eq. 4 of :mod:`gp_model._kernels`), the ``K^-1`` part through one
        elementwise product with ``K`` and one matrix product (eq. 3 there).
        """
        try:
            post, K = self._factorise(theta, quiet=True)
        except GPNumericalError:
            return None
        n, m = self.Y_train_.shape
        fit = float(np.einsum("ij,ij->", self.Y_train_, post.alpha))
        lml = float(-0.5 * fit - m * np.log(np.diag(post.L)).sum() - 0.5 * m * n * LOG_2PI)
        if not gradient:
            return _LikelihoodTerms(lml, fit, None, None)
        # K^-1 from the Cholesky factor, overwriting it; dpotri fills the lower triangle only and
        # the upper one keeps the zeros of L.
        K_inv_lower, info = lapack.dpotri(post.L, lower=1, overwrite_c=1)
        if info != 0:
            raise GPNumericalError(f"LAPACK dpotri failed (info={info})")
        X, kernel_theta, noise = self.X_train_, theta[:-1], np.exp(theta[-1])
        # K^-1 and K are symmetric: the full sum over a, b is twice the sum over the lower
        # triangle less the diagonal, where only the signal term is non-zero (x_a - x_a = 0).
        # K.T is K in the Fortran order of K_inv_lower, so their elementwise product runs in order.
        trace = 2.0 * self.kernel.gradient_contraction(X, K.T, K_inv_lower, theta=kernel_theta)
        trace[0] -= np.diag(K_inv_lower) @ np.diag(K)
        data = self.kernel.low_rank_gradient_contraction(X, K, post.alpha, theta=kernel_theta)
        return _LikelihoodTerms(
            lml, fit,
            data=np.append(data, noise * np.einsum("ij,ij->", post.alpha, post.alpha)),
            trace=np.append(trace, noise * np.trace(K_inv_lower)),
        )

    def concentrated_log_marginal_likelihood(self, x):
        """The log marginal likelihood maximised over the signal variance in closed form (the
        "concentrated" likelihood; DiceKriging's, Roustant, Ginsbourger & Deville, J. Stat. Softw.
        51(1), 2012, with the noise as a ratio to the signal variance): what
        :func:`~gp_model.maximize_marginal_likelihood` searches over.

        With ``K = sigma_f^2 (C + r I)``, ``C`` the kernel matrix at unit signal variance and
        ``r = sigma_n^2 / sigma_f^2``, the likelihood at fixed ``x = [kernel.theta[1:]..., ln r]``
        is largest at ``sigma_f^2 = s = sum_k y_k^T (C + r I)^-1 y_k / (n m)``, where

            lml(x) = -n m / 2 (1 + ln 2 pi s) - m sum_i ln L_ii,     L L^T = C + r I.

        As ``s`` is a stationary point, the gradient is the full likelihood's at ``theta`` (below)
        with respect to ``theta[1:-1]`` and ``ln sigma_n^2``, ``sigma_f^2`` held (R&W eq. 5.9,
        with ``alpha`` scaled by ``1/s``).

        Parameters
        ----------
        x : ndarray, shape (p - 1,)
            ``[kernel.theta[1:]..., ln(sigma_n^2 / sigma_f^2)]``.

        Returns
        -------
        lml : float
            ``-inf`` where the kernel matrix cannot be factorised or every output is constant.
        gradient : ndarray, shape (p - 1,)
        theta : ndarray, shape (p,) or None
            The hyperparameters ``[ln s, kernel.theta[1:]..., ln s + ln r]`` with that likelihood
            (None with ``-inf``).
        """
        terms = self._likelihood_terms(np.concatenate(([0.0], x)))
        n, m = self.Y_train_.shape
        if terms is None or not terms.fit > 0:  # no fit term: all outputs constant
            return -np.inf, np.zeros_like(x), None
        signal = terms.fit / (n * m)
        lml = terms.lml + 0.5 * terms.fit - 0.5 * n * m * (1.0 + np.log(signal))
        gradient = 0.5 * (terms.data[1:] / signal - m * terms.trace[1:])
        theta = np.concatenate(([np.log(signal)], x[:-1], [x[-1] + np.log(signal)]))
        return float(lml), gradient, theta

    # -- prediction ---------------------------------------------------------------------------
    def _predict_one(self, post: _Posterior, Xs, want, include_noise):
        """Standardised mean (k, m) and latent/noisy variance (k,) or covariance (k, k)."""
        Ks = self.kernel(Xs, self.X_train_, theta=post.theta[:-1])
        mean = Ks @ post.alpha  # R&W Alg. 2.1 line 4
        if want is None:
            return mean, None
        v = linalg.solve_triangular(post.L, Ks.T, lower=True, check_finite=False)  # line 5
        noise = np.exp(post.theta[-1]) if include_noise else 0.0
        if want == "var":
            var = self.kernel.diag(Xs, theta=post.theta[:-1]) - np.einsum("ij,ij->j", v, v)
            return mean, np.maximum(var, 0.0) + noise  # line 6
        cov = self.kernel(Xs, theta=post.theta[:-1]) - v.T @ v
        cov[np.diag_indices_from(cov)] += noise
        return mean, cov

    def predictive_forms(self, *, use_samples: bool = True) -> list[PredictiveForm]:
        """One :class:`PredictiveForm` per hyperparameter sample (or for ``theta_`` alone).

        Weights have shape (m,) for a single-output GP and (m, q) for q outputs, which share the
        variance factor (one set of hyperparameters); means and variances are in standardised
        output units.
        """
        posteriors = self._posteriors() if use_samples else [self._posterior]
        eye = np.eye(len(self.X_train_))
        single = self.Y_train_.shape[1] == 1
        forms = {}  # one form per distinct posterior, shared by the samples that repeat it
        for p in posteriors:
            if id(p) not in forms:
                forms[id(p)] = PredictiveForm(p.theta, self.X_train_, p.alpha[:, 0] if single else p.alpha,
                                              linalg.solve_triangular(p.L, eye, lower=True, check_finite=False))
        return [forms[id(p)] for p in posteriors]

    def __repr__(self) -> str:
        return f"GaussianProcess({self.kernel!r}, noise_variance={self.noise_variance:.4g})"


class PerOutputGP:
    """One independent :class:`GaussianProcess` per output column.

    Parameters
    ----------
    gps : list of GaussianProcess
        One fitted single-output GP per output, in output order.
    """

    def __init__(self, gps) -> None:
        self.gps = list(gps)

    @classmethod
    def fit(cls, make_gp, X, Y) -> PerOutputGP:
        """Fit ``make_gp()`` to each column of ``Y`` (shape (n, m)) with inputs ``X`` (n, d)."""
        Y = np.asarray(Y, dtype=float)
        if Y.ndim != 2:
            raise ValueError(f"Y must have shape (n, m), got {Y.shape}")
        return cls([make_gp().fit(X, Y[:, j]) for j in range(Y.shape[1])])

    def predict(self, X, *, return_var: bool = False, include_noise: bool = False,
                use_samples: bool = True):
        """Mean, shape (k, m), and with ``return_var`` the variances, shape (k, m).

        When the GPs share their training inputs and each predicts at one hyperparameter vector
        (the usual case: ``PerOutputGP.fit``, no hyperparameter samples in use), the m GPs are
        evaluated together (:class:`_StackedPosterior`), equal to one at a time to rounding and
        several times faster on the few points of a free-run step.
        """
        stacked = self._stacked(use_samples)
        if stacked is not None:
            return stacked.predict(X, return_var=return_var, include_noise=include_noise)
        results = [gp.predict(X, return_var=return_var, include_noise=include_noise,
                              use_samples=use_samples) for gp in self.gps]
        if not return_var:
            return np.column_stack(results)
        return np.column_stack([r[0] for r in results]), np.column_stack([r[1] for r in results])

    def _stacked(self, use_samples: bool):
        """The GPs' :class:`_StackedPosterior`, or None when they cannot be stacked (sparse GPs,
        hyperparameter samples in use, different training inputs)."""
        if any(type(gp) is not GaussianProcess or (use_samples and gp.theta_samples_ is not None)
               for gp in self.gps):
            return None
        factors = tuple(gp.L_ for gp in self.gps)  # a refit makes new factors
        cached = getattr(self, "_stacked_cache", None)
        if cached is None or any(a is not b for a, b in zip(cached[0], factors)):
            cached = (factors, _StackedPosterior.build(self.gps))
            self._stacked_cache = cached
        return cached[1]


@dataclass(frozen=True)
class _StackedPosterior:
    """m single-output GPs with the same training inputs, as stacked arrays.

    Every kernel here is ``sigma_f^2 exp(-sum_i w_i (x_i - x'_i)^2)`` (:class:`StationaryKernel`),
    so with each GP's inputs standardised and multiplied by ``sqrt(w)`` the m kernel matrices
    are m squared-distance computations against stacked training inputs (Rasmussen & Williams,
    Alg. 2.1, lines 4-6; the variance's triangular solves stay one per GP, by the LAPACK routine
    :meth:`GaussianProcess.predict` uses, so the two agree to rounding, about 1e-14 relative).
    """

    input_mean: np.ndarray  # (m, 1, d)
    input_scale: np.ndarray  # (m, 1, d)
    root_weights: np.ndarray  # (m, 1, d) sqrt(w)
    basis: np.ndarray  # (m, n, d) standardised training inputs times sqrt(w)
    basis_norm: np.ndarray  # (m, 1, n)
    log_signal: np.ndarray  # (m, 1, 1)
    noise: np.ndarray  # (m,)
    alpha: np.ndarray  # (m, n)
    factor: list  # m lower Cholesky factors L (n, n), Fortran order as LAPACK takes them
    output_mean: np.ndarray  # (m,)
    output_scale: np.ndarray  # (m,)

    @classmethod
    def build(cls, gps):
        """Stack ``gps`` (None when their training inputs differ or one has several outputs)."""
        first = gps[0].X_train_
        if any(gp.Y_train_.shape[1] != 1 or gp.X_train_.shape != first.shape for gp in gps):
            return None
        raw = [gp.input_scaler_.inverse_transform(gp.X_train_) for gp in gps]
        if any(not np.allclose(r, raw[0], rtol=1e-12, atol=1e-12) for r in raw):
            return None
        root_weights = np.array([np.sqrt(gp.kernel.weights(gp.theta_[:-1])) for gp in gps])
        basis = np.array([gp.X_train_ for gp in gps]) * root_weights[:, None, :]
        return cls(
            input_mean=np.array([gp.input_scaler_.mean_ * np.ones(first.shape[1]) for gp in gps])[:, None, :],
            input_scale=np.array([gp.input_scaler_.scale_ * np.ones(first.shape[1]) for gp in gps])[:, None, :],
            root_weights=root_weights[:, None, :],
            basis=basis, basis_norm=np.sum(basis**2, axis=2)[:, None, :],
            log_signal=np.array([gp.theta_[0] for gp in gps])[:, None, None],
            noise=np.array([np.exp(gp.theta_[-1]) for gp in gps]),
            alpha=np.array([gp.alpha_[:, 0] for gp in gps]),
            factor=[np.asfortranarray(gp.L_) for gp in gps],
            output_mean=np.array([np.ravel(gp.output_scaler_.mean_)[0] for gp in gps]),
            output_scale=np.array([np.ravel(gp.output_scaler_.scale_)[0] for gp in gps]))

    def predict(self, X, *, return_var: bool, include_noise: bool):
        """As :meth:`PerOutputGP.predict`: mean (k, m) and variance (k, m)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))[None]
        Xs = (X - self.input_mean) / self.input_scale * self.root_weights  # (m, k, d), as the kernel scales
        sq = np.sum(Xs**2, axis=2)[:, :, None] + self.basis_norm - 2.0 * (Xs @ np.swapaxes(self.basis, 1, 2))
        K = np.exp(self.log_signal - np.maximum(sq, 0.0))  # (m, k, n)
        mean = np.matmul(K, self.alpha[:, :, None])[:, :, 0].T * self.output_scale + self.output_mean
        if not return_var:
            return mean
        latent = np.empty(K.shape[:2])
        for j, (factor, kernel) in enumerate(zip(self.factor, K)):
            v, _ = lapack.dtrtrs(factor, kernel.T, lower=1)  # the triangular solve of solve_triangular
            latent[j] = np.exp(self.log_signal[j, 0, 0]) - np.einsum("ij,ij->j", v, v)
        var = np.maximum(latent, 0.0) + (self.noise[:, None] if include_noise else 0.0)
        return mean, (var * self.output_scale[:, None] ** 2).T
