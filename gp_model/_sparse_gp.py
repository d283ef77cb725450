"""Sparse GP regression by the variational free energy (VFE) of Titsias (AISTATS 2009).

An exact GP costs O(n^3) per likelihood evaluation; the Bo105 paper therefore trained on every
25th sample only. A sparse GP summarises the data through ``m << n`` inducing inputs ``Z`` and
costs O(n m^2), so a GP-NARX model can learn from every sample.

Notation (all in the GP's standardised units, see :mod:`gp_model._gp`): training inputs ``X``
(n, d), outputs ``Y`` (n, p), inducing inputs ``Z`` (m, d); ``K_mm = k(Z, Z)``, ``K_mn = k(Z, X)``,
``Q_nn = K_nm K_mm^-1 K_mn``; noise variance ``s = sigma_n^2``. Titsias (2009), eq. (9), bounds
the log marginal likelihood of each output column ``y`` from below by

    F = log N(y | 0, Q_nn + s I) - 1/(2 s) tr(K_nn - Q_nn),                              (1)

with equality when ``Z = X``. It is evaluated without any n x n matrix through the Cholesky
factors of the GPflow SGPR derivation (Hensman & Matthews, GPflow notes "Derivation of SGPR
equations", 2016):

    L L^T = K_mm,  A = L^-1 K_mn / sigma_n,  B = I + A A^T = L_B L_B^T,  c = L_B^-1 A y / sigma_n,
    F = -n/2 ln(2 pi s) - sum ln diag L_B - |y|^2/(2 s) + |c|^2/2
        - tr(K_nn)/(2 s) + tr(A A^T)/2,                                                   (2)

using ``|Q_nn + s I| = s^n |B|`` and Woodbury. Several output columns share ``Z`` and the
hyperparameters; their bounds add.

The optimal variational distribution of the inducing outputs (Titsias 2009, eq. 10, with
``Sigma = (K_mm + K_mn K_nm / s)^-1``) gives the predictive distribution at ``x``

    mean(x) = k_xm w,   w = Sigma K_mn y / s = L^-T L_B^-T c,
    var(x)  = k(x, x) - k_xm (K_mm^-1 - Sigma) k_mx,                                      (3)

and ``K_mm^-1 - Sigma = L^-T (I - B^-1) L^-1``. With the eigendecomposition
``A A^T = U diag(lambda) U^T``, ``I - B^-1 = U diag(lambda / (1 + lambda)) U^T``, so

    R = diag(sqrt(lambda / (1 + lambda))) U^T L^-1,    var(x) = k(x, x) - |R k_mx|^2,        (4)

a factor formed without cancellation (a Cholesky factor of ``I - B^-1`` itself would subtract
nearly equal numbers where ``lambda << 1``). ``(Z, w, R)`` is the GP's
:class:`~gp_model.PredictiveForm`, so free runs predict through one routine for both GP kinds.

Gradient. Differentiating (1) in the Woodbury / determinant-lemma form
``-1/2 [ln|Sigma^-1| - ln|K_mm| + n ln s] - |y|^2/(2 s) + y^T K_nm Sigma K_mn y/(2 s^2)
- tr(K_nn - K_mm^-1 K_mn K_nm)/(2 s)`` and collecting trace forms
``dF = sum G_mm∘dK_mm + sum G_mn∘dK_mn + sum g_n dK_nn,diag`` gives, with ``C = L_B^-T c`` (m, p),
``E = I - B^-1`` and p output columns (checked against finite differences in the tests),

    G_mm = L^-T [ p/2 (E - A A^T) - 1/2 C C^T ] L^-1,
    G_mn = L^-T [ p E A - C (C^T A - Y^T / sigma_n) ] / sigma_n,        g_n = -p / (2 s),    (5)

    dF/d ln s = p/2 tr(E) - n p/2 + |Y|^2/(2 s) - |c|^2 + |A^T C|^2/2
                + p/2 (tr(K_nn)/s - tr(A A^T)),                                          (6)

and the kernel contracts ``[G_mm G_mn]`` with ``d k(Z, [Z; X])/dtheta`` in one call
(:meth:`~gp_model._kernels.StationaryKernel.cross_gradient_contraction`). The inducing inputs are
not hyperparameters: they stay fixed while ``theta`` is optimised or sampled.

Inducing inputs. :meth:`SparseGaussianProcess.fit` picks ``m`` training inputs by greedy
maximum-variance selection, i.e. the pivots of a pivoted (incomplete) Cholesky factorisation of
``K_nn`` (Fine & Scheinberg, JMLR 2, 2001; Foster et al., JMLR 10, 2009; Burt, Rasmussen & van der
Wilk, JMLR 21(131), 2020, Alg. 1 "conditional variance"). Each step adds the training input whose
prior variance is least explained by the inputs chosen so far, ``argmax diag(K_nn - Q_nn)``. Why
this rule and not k-means:

- it attacks the trace term of (1) directly: ``tr(K_nn - Q_nn)`` is the sum of the residual
  variances it greedily reduces, and Burt et al. (2020) show that this term controls how far the
  bound lies below the exact log likelihood;
- the selection is nested (the first ``m`` of ``m + 1`` points are the same), so the bound cannot
  decrease as points are added (Titsias 2009, sec. 3);
- inducing inputs are actual regressor vectors, on the data's manifold (NARX regressors lie on
  the trajectories flown), and points far from the rest (the edges of the flown envelope, where
  a free run must not extrapolate blindly) are taken early;
- it is O(n m^2) and deterministic.

The selection uses the kernel at the hyperparameters passed to
:meth:`~SparseGaussianProcess.fit` (the configured ones by default). For a stationary kernel all
prior variances are equal, so the first pivot is a tie; it is drawn with ``inducing_seed``, which
makes the choice reproducible. One addition to Alg. 1: when every remaining residual variance is
below :data:`SELECTION_TOLERANCE` x the signal variance before ``m`` points are chosen, the kernel
is smooth on the scale of the chosen points and another pivot would only make ``K_mm`` singular.
The inducing inputs stay fixed during hyperparameter inference, which may still move to shorter
length scales, so the selection continues from the chosen points with all length scales halved
(repeatedly if needed). Without this, a long starting length scale (e.g. 1 in standardised
units, on 1-d data) stops the selection at a dozen points whatever ``m`` is, and the optimised
bound stays far below the exact likelihood; with it, the points added are nearly redundant at the
starting hyperparameters (``K_mm`` then takes a jitter, reported in ``jitter_``) and useful at
the optimised ones. Only exact duplicates are never selected twice, so fewer than ``m`` points are
used only when the data have fewer distinct inputs. Fitting again with ``theta=gp.theta_``
re-selects at the optimised hyperparameters (Burt et al. 2020 alternate the two).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import linalg
from scipy.linalg import lapack

from ._errors import GPNumericalError
from ._gp import LOG_2PI, BaseGaussianProcess, PredictiveForm
from ._kernels import StationaryKernel
from ._linalg import robust_cholesky

logger = logging.getLogger(__name__)

#: Greedy selection at one length scale stops once every remaining training input's residual
#: prior variance ``diag(K_nn - Q_nn)`` is below this fraction of the signal variance (and then
#: continues at half the length scales, module docstring): the next pivot's Cholesky diagonal in
#: ``K_mm`` would be below 1e-5 sigma_f, close to singular, for a gain in the trace term of (1) of
#: less than 1e-10 sigma_f^2 / sigma_n^2 per training input.
SELECTION_TOLERANCE = 1e-10


@dataclass(frozen=True)
class _SparsePosterior:
    """Prediction at one hyperparameter vector: eqs. (3)-(4)."""

    theta: np.ndarray  # (p,)
    weights: np.ndarray  # (m, n_outputs) w = L^-T L_B^-T c
    variance_factor: np.ndarray  # (m, m) R, R^T R = K_mm^-1 - Sigma
    jitter: float  # added to K_mm's diagonal


@dataclass(frozen=True)
class _Factors:
    """The O(n m^2) quantities of eq. (2) at one hyperparameter vector."""

    theta: np.ndarray  # (p,)
    K_mm: np.ndarray  # (m, m) including the jitter
    K_mn: np.ndarray  # (m, n)
    L: np.ndarray  # (m, m) lower Cholesky factor of K_mm
    A: np.ndarray  # (m, n) L^-1 K_mn / sigma_n
    AAT: np.ndarray  # (m, m) A A^T
    L_B: np.ndarray  # (m, m) lower Cholesky factor of B = I + A A^T
    c: np.ndarray  # (m, n_outputs) L_B^-1 A Y / sigma_n
    trace_K_nn: float  # tr(K_nn)
    jitter: float


class SparseGaussianProcess(BaseGaussianProcess):
    """Sparse GP regression with the variational free energy of Titsias (2009).

    Same interface as :class:`~gp_model.GaussianProcess` (hyperparameters, likelihood, prediction,
    predictive forms, model files), with :meth:`log_marginal_likelihood` returning the VFE lower
    bound, eq. (1) of this module. Inducing inputs are training inputs chosen by greedy
    maximum-variance selection (module docstring).

    Parameters
    ----------
    kernel : StationaryKernel
        Covariance function; its ``theta`` is the starting point for hyperparameter inference
        and, unless :meth:`fit` is given other hyperparameters, the kernel of the selection.
    n_inducing : int, default 50
        Number of inducing inputs m. With ``n_inducing >= n`` every training input is used, and
        the GP equals the exact one. Fewer are used only if the training inputs have fewer
        distinct values.
    noise_variance : float, default 1e-2
        ``sigma_n^2`` of the (standardised) outputs.
    normalize_inputs, normalize_outputs : bool, default True
        Standardise each input / output column to zero mean and unit variance before fitting.
    inducing_seed : int, default 0
        Seed of the first pivot of the selection.

    Attributes
    ----------
    theta_ : ndarray, shape (p,)
        Hyperparameters in use (after :meth:`fit`).
    theta_samples_ : ndarray, shape (S, p) or None
        Hyperparameter samples; when set, predictions are the mixture over them.
    X_train_, Y_train_ : ndarray, shapes (n, d), (n, n_outputs)
        Standardised training data.
    inducing_inputs_ : ndarray, shape (m, d)
        Standardised inducing inputs ``Z``, rows of ``X_train_`` in the order selected.
    weights_ : ndarray, shape (m, n_outputs)
        Predictive-mean weights ``w`` of eq. (3) for ``theta_``.
    jitter_ : float
        Jitter added to the diagonal of ``K_mm`` for ``theta_``.

    Notes
    -----
    The bound penalises, through its trace term, every hyperparameter vector that the inducing
    inputs cannot resolve, by ``tr(K_nn - Q_nn) / (2 sigma_n^2)``. From a start with short length
    scales in several dimensions and a small noise variance this term dominates, and type-II
    maximum likelihood can slide into the optimum where the signal variance vanishes, the length
    scales grow without bound and all of ``y`` is noise (the bound is then equal to the exact
    likelihood of that model, so it is no numerical failure). Seen on 2000 points in 4-d with 50
    inducing inputs from ``l = 1, sigma_n^2 = 1e-2``; starting from ``sigma_n^2 = 0.5``, or
    annealing the hyperparameters, recovered the function (noise variance fitted at its true
    value). Starting from hyperparameters of an exact GP fitted to a subset also helps.
    """

    def __init__(self, kernel: StationaryKernel, *, n_inducing: int = 50,
                 noise_variance: float = 1e-2, normalize_inputs: bool = True,
                 normalize_outputs: bool = True, inducing_seed: int = 0) -> None:
        super().__init__(kernel, noise_variance=noise_variance, normalize_inputs=normalize_inputs,
                         normalize_outputs=normalize_outputs)
        if int(n_inducing) != n_inducing or n_inducing < 1:
            raise ValueError(f"n_inducing must be a positive integer, got {n_inducing}")
        self.n_inducing = int(n_inducing)
        self.inducing_seed = int(inducing_seed)

    @property
    def weights_(self) -> np.ndarray:
        """Predictive-mean weights ``w`` of eq. (3) for ``theta_``, shape (m, n_outputs)."""
        return self._posterior.weights

    # -- fitting ------------------------------------------------------------------------------
    def fit(self, X, y, *, theta=None):
        """Select the inducing inputs and condition on training data with fixed hyperparameters.

        Parameters
        ----------
        X : ndarray, shape (n, d)
            Training inputs.
        y : ndarray, shape (n,) or (n, n_outputs)
            Training targets.
        theta : ndarray, shape (p,), optional
            Hyperparameters, also those of the inducing-input selection; defaults to
            :attr:`theta` (the configured kernel and noise).

        Returns
        -------
        self

        Raises
        ------
        ValueError
            On mismatched shapes or non-finite data.
        GPNumericalError
            If ``K_mm`` cannot be factorised even with jitter.
        """
        self.inducing_inputs_ = None  # selected by set_hyperparameters, at theta
        return super().fit(X, y, theta=theta)

    def set_hyperparameters(self, theta, *, samples=None):
        """Use ``theta`` (shape (p,)) and optionally a sample set (shape (S, p)) for the mixture.

        The configured ``kernel`` and ``noise_variance`` are updated to match ``theta``. The
        inducing inputs stay as they are (they are selected by :meth:`fit`, at its ``theta``).

        Returns
        -------
        self
        """
        theta, samples = self._checked_hyperparameters(theta, samples)
        if self.inducing_inputs_ is None:
            self.inducing_inputs_ = self.X_train_[self._select_inducing(theta)]
        return super().set_hyperparameters(theta, samples=samples)

    def _select_inducing(self, theta) -> np.ndarray:
        """Indices of the inducing inputs in ``X_train_``, shape (m,): greedy maximum-variance
        selection at ``theta``, refined at shorter length scales if it saturates (module
        docstring)."""
        n = len(self.X_train_)
        if self.n_inducing >= n:
            return np.arange(n)
        pivots = [int(np.random.default_rng(self.inducing_seed).integers(n))]
        scale = 1.0
        while len(pivots) < self.n_inducing:
            # Inputs times `scale` = every length scale divided by `scale` (kernel (1)).
            more = _greedy_variance(self.kernel, theta[:-1], scale * self.X_train_, pivots,
                                    self.n_inducing)
            if scale > 1.0 and len(more) <= len(pivots):
                logger.info("inducing-input selection found only %d distinct training inputs of "
                            "the %d requested", len(pivots), self.n_inducing)
                break
            pivots, scale = more, 2.0 * scale
        return np.array(pivots)

    def _posterior_at(self, theta) -> _SparsePosterior:
        return _posterior(self._factorise(theta))

    def _factorise(self, theta) -> _Factors:
        """Eq. (2)'s factors at ``theta``; raises GPNumericalError if K_mm cannot be factorised."""
        X, Y, Z = self.X_train_, self.Y_train_, self.inducing_inputs_
        kernel_theta = theta[:-1]
        sigma = np.exp(0.5 * theta[-1])
        K_mm = self.kernel(Z, theta=kernel_theta)
        # Not logged: jitter on K_mm is routine once the selection has refined beyond the
        # kernel's resolution (module docstring); it is reported in jitter_.
        L, jitter = robust_cholesky(K_mm, quiet=True)
        if jitter:
            K_mm.flat[:: len(K_mm) + 1] += jitter
        K_mn = self.kernel(Z, X, theta=kernel_theta)
        A = linalg.solve_triangular(L, K_mn, lower=True, check_finite=False) / sigma
        AAT = A @ A.T
        B = AAT.copy()
        B.flat[:: len(B) + 1] += 1.0
        L_B, info = lapack.dpotrf(B, lower=1, clean=1)  # B >= I: fails only on inf/nan
        if info != 0:
            raise GPNumericalError(f"I + A A^T is not positive definite (LAPACK info={info}); "
                                   "the hyperparameters are out of range")
        c = linalg.solve_triangular(L_B, A @ Y, lower=True, check_finite=False) / sigma
        trace_K_nn = float(self.kernel.diag(X, theta=kernel_theta).sum())
        return _Factors(np.asarray(theta, dtype=float), K_mm, K_mn, L, A, AAT, L_B, c,
                        trace_K_nn, jitter)

    # -- likelihood ---------------------------------------------------------------------------
    def log_marginal_likelihood(self, theta=None, *, return_gradient: bool = False):
        """VFE lower bound on the log marginal likelihood (eqs. 1-2), summed over outputs.

        Parameters
        ----------
        theta : ndarray, shape (p,), optional
            Defaults to ``theta_``. The inducing inputs stay fixed.
        return_gradient : bool

        Returns
        -------
        bound : float
            ``-inf`` if ``K_mm`` cannot be factorised at ``theta``.
        gradient : ndarray, shape (p,)
            Eqs. (5)-(6); only when ``return_gradient``.
        """
        theta = self.theta_ if theta is None else np.asarray(theta, dtype=float)
        try:
            f = self._factorise(theta)
        except GPNumericalError:
            return (-np.inf, np.zeros_like(theta)) if return_gradient else -np.inf
        Y = self.Y_train_
        n, p = Y.shape
        s = np.exp(theta[-1])
        y_squared, c_squared = float(np.sum(Y * Y)), float(np.sum(f.c * f.c))
        trace_gap = f.trace_K_nn / s - np.trace(f.AAT)  # tr(K_nn - Q_nn) / s
        bound = (-0.5 * n * p * (LOG_2PI + theta[-1]) - p * np.log(np.diag(f.L_B)).sum()
                 - 0.5 * y_squared / s + 0.5 * c_squared - 0.5 * p * trace_gap)  # eq. (2)
        if not return_gradient:
            return float(bound)
        m = len(f.L)
        sigma = np.sqrt(s)
        C = linalg.solve_triangular(f.L_B, f.c, lower=True, trans="T", check_finite=False)
        E = np.eye(m) - linalg.cho_solve((f.L_B, True), np.eye(m), check_finite=False)
        # Eq. (5): the bracketed matrices, then L^-T from the left (and L^-1 from the right).
        inner_mm = 0.5 * p * (E - f.AAT) - 0.5 * C @ C.T
        inner_mn = p * (E @ f.A) - C @ (C.T @ f.A - Y.T / sigma)
        left = linalg.solve_triangular(f.L, inner_mm, lower=True, trans="T", check_finite=False)
        G_mm = linalg.solve_triangular(f.L, left.T, lower=True, trans="T", check_finite=False).T
        G_mn = linalg.solve_triangular(f.L, inner_mn, lower=True, trans="T", check_finite=False) / sigma
        Z = self.inducing_inputs_
        kernel_gradient = self.kernel.cross_gradient_contraction(
            Z, np.vstack([Z, self.X_train_]), np.hstack([f.K_mm, f.K_mn]),
            np.hstack([G_mm, G_mn]), theta=theta[:-1])
        # g_n of eq. (5): for a stationary kernel only ln sigma_f^2 moves diag(K_nn) = sigma_f^2.
        kernel_gradient[0] -= 0.5 * p * f.trace_K_nn / s
        noise_gradient = (0.5 * p * np.trace(E) - 0.5 * n * p + 0.5 * y_squared / s - c_squared
                          + 0.5 * float(np.sum((f.A.T @ C) ** 2)) + 0.5 * p * trace_gap)  # eq. (6)
        return float(bound), np.append(kernel_gradient, noise_gradient)

    # -- prediction ---------------------------------------------------------------------------
    def _predict_one(self, post: _SparsePosterior, Xs, want, include_noise):
        """Standardised mean (k, n_outputs) and latent/noisy variance (k,) or covariance (k, k),
        eqs. (3)-(4)."""
        kernel_theta = post.theta[:-1]
        Ks = self.kernel(Xs, self.inducing_inputs_, theta=kernel_theta)
        mean = Ks @ post.weights
        if want is None:
            return mean, None
        v = post.variance_factor @ Ks.T  # (m, k)
        noise = np.exp(post.theta[-1]) if include_noise else 0.0
        if want == "var":
            var = self.kernel.diag(Xs, theta=kernel_theta) - np.einsum("ij,ij->j", v, v)
            return mean, np.maximum(var, 0.0) + noise
        cov = self.kernel(Xs, theta=kernel_theta) - v.T @ v
        cov[np.diag_indices_from(cov)] += noise
        return mean, cov

    def predictive_forms(self, *, use_samples: bool = True) -> list[PredictiveForm]:
        """One :class:`~gp_model.PredictiveForm` per hyperparameter sample (or for ``theta_``):
        basis ``Z``, weights ``w`` and variance factor ``R`` of eqs. (3)-(4); weights of shape
        (m,) for one output, (m, q) for q outputs (as :meth:`GaussianProcess.predictive_forms`).
        """
        posteriors = self._posteriors() if use_samples else [self._posterior]
        single = self.Y_train_.shape[1] == 1
        return [PredictiveForm(p.theta, self.inducing_inputs_, p.weights[:, 0] if single else p.weights,
                               p.variance_factor) for p in posteriors]

    # -- portable state (one part of a model file, gp_model._model_file) ---------------------
    def to_arrays(self) -> tuple[dict, dict]:
        """JSON-safe metadata and named arrays that fully describe the fitted sparse GP: those
        of :meth:`BaseGaussianProcess.to_arrays`, plus the selection settings ``n_inducing`` and
        ``inducing_seed`` in ``meta`` and the array ``inducing_inputs`` (m, d). The inverse is
        :meth:`from_arrays`, which uses the stored inducing inputs as they are (no re-selection).
        """
        meta, arrays = super().to_arrays()
        meta.update(n_inducing=self.n_inducing, inducing_seed=self.inducing_seed)
        arrays["inducing_inputs"] = self.inducing_inputs_
        return meta, arrays

    @classmethod
    def _settings_from_meta(cls, meta: dict) -> dict:
        return {"n_inducing": int(meta["n_inducing"]), "inducing_seed": int(meta["inducing_seed"])}

    def _restore_training_data(self, meta: dict, arrays: dict, X_train: np.ndarray,
                               Y_train: np.ndarray) -> None:
        Z = np.asarray(arrays["inducing_inputs"], dtype=float)
        if Z.ndim != 2 or Z.shape[1] != X_train.shape[1] or not 0 < len(Z) <= len(X_train):
            raise ValueError(f"inducing inputs have shape {Z.shape}, expected (m, {X_train.shape[1]}) "
                             f"with 0 < m <= {len(X_train)}")
        super()._restore_training_data(meta, arrays, X_train, Y_train)
        self.inducing_inputs_ = Z

    def __repr__(self) -> str:
        return (f"SparseGaussianProcess({self.kernel!r}, n_inducing={self.n_inducing}, "
                f"noise_variance={self.noise_variance:.4g})")


def _greedy_variance(kernel: StationaryKernel, kernel_theta, X, forced, m: int) -> list[int]:
    """Pivoted Cholesky of ``k(X, X)``: up to ``m`` pivots, the ``forced`` ones first, then each
    the row of ``X`` (n, d) with the largest residual variance ``diag(K_nn - Q_nn)`` (Burt et al.
    2020, Alg. 1); stops early when that falls below :data:`SELECTION_TOLERANCE` x the signal
    variance. O(n m^2)."""
    residual = kernel.diag(X, theta=kernel_theta).astype(float)
    floor = SELECTION_TOLERANCE * residual.max()
    rows = np.empty((m, len(X)))  # partial Cholesky factor: rows.T @ rows = K_nZ K_ZZ^-1 K_Zn
    pivots = []
    for j in range(m):
        pivot = forced[j] if j < len(forced) else int(np.argmax(residual))
        if residual[pivot] < floor:
            break
        column = kernel(X, X[pivot:pivot + 1], theta=kernel_theta)[:, 0]
        rows[j] = (column - rows[:j].T @ rows[:j, pivot]) / np.sqrt(residual[pivot])
        residual -= rows[j] ** 2
        residual[pivot] = -np.inf  # never pick a point twice
        pivots.append(pivot)
    return pivots


def _posterior(f: _Factors) -> _SparsePosterior:
    """Eqs. (3)-(4) from the factors of eq. (2)."""
    m = len(f.L)
    C = linalg.solve_triangular(f.L_B, f.c, lower=True, trans="T", check_finite=False)
    weights = linalg.solve_triangular(f.L, C, lower=True, trans="T", check_finite=False)
    eigenvalues, U = linalg.eigh(f.AAT)
    eigenvalues = np.maximum(eigenvalues, 0.0)  # A A^T is PSD; clip rounding below zero
    L_inv = linalg.solve_triangular(f.L, np.eye(m), lower=True, check_finite=False)
    R = np.sqrt(eigenvalues / (1.0 + eigenvalues))[:, None] * (U.T @ L_inv)
    return _SparsePosterior(f.theta, weights, R, f.jitter)
