"""Stationary kernels with analytic hyperparameter gradients.

Both kernels here are the same function in two parametrisations,

    k(x, x') = sigma_f^2 exp(-sum_i w_i (x_i - x'_i)^2),                      (1)

with one non-negative weight ``w_i`` per input dimension:

- squared-exponential ARD (Ko et al., ICRA 2007, eq. 13; Rasmussen & Williams, *Gaussian
  Processes for Machine Learning*, 2006, eq. 5.1): ``w_i = 1 / (2 l_i^2)``;
- Higdon's product kernel, used in the Bo105 GP-NARX paper (AHS 74th Forum, 2018):
  ``k = sigma_f^2 prod_i alpha_i^(4 (x_i - x'_i)^2)``, alpha_i in (0, 1), so
  ``w_i = -4 ln alpha_i``.

Equating the weights gives the relation between the two (tested in ``tests/gp_model/test_kernels.py``):

    alpha_i = exp(-1 / (8 l_i^2)),      l_i = 1 / sqrt(-8 ln alpha_i).                  (2)

Hyperparameters are held as an unconstrained vector ``theta`` so that optimisers and samplers
need no bounds: ``theta = [ln sigma_f^2, ln l_1 .. ln l_d]`` for the SE kernel and
``theta = [ln sigma_f^2, logit alpha_1 .. logit alpha_d]`` for Higdon's.

Gradients never form the (n, n, n_theta) tensor ``dK/dtheta``: what the likelihood needs is the
contraction ``g_j = sum_ab M_ab dK_ab/dtheta_j`` with a weighting matrix ``M``. For kernel (1)
``dK_ab/d ln sigma_f^2 = K_ab`` and ``dK_ab/dw_i = -K_ab (x_ai - y_bi)^2``, so with ``R = M∘K``

    sum_ab M_ab dK_ab/dw_i = -[ (R 1)^T x_i^2 + 1^T R y_i^2 - 2 x_i^T R y_i ],             (3)

one matrix product ``R [Y, Y^2, 1]`` instead of an n^2 n_theta tensor. When ``M = A A^T`` has
low rank r (the ``alpha alpha^T`` of the likelihood gradient), ``R`` is not needed at all: for a
symmetric ``K`` (``Y = X``)

    sum_ab M_ab dK_ab/dw_i = -2 sum_k [ (a_k∘x_i^2)^T K a_k - (a_k∘x_i)^T K (a_k∘x_i) ],   (4)

one product of ``K`` with the r (d + 1) columns ``[a_k, a_k∘x_i]``.
"""
from __future__ import annotations

import numpy as np
from scipy import stats
from scipy.spatial.distance import pdist, squareform
from scipy.special import expit, logit

from ._priors import IndependentPrior, LogitBeta


class StationaryKernel:
    """Kernel (1) in some parametrisation of its weights; subclasses define that map.

    Parameters
    ----------
    signal_variance : float
        ``sigma_f^2``, in squared output units (of the scaled outputs when used in a GP).
    """

    #: Name used in model files and messages.
    kind = "stationary"

    def __init__(self, signal_variance: float, scale_parameters) -> None:
        scale_parameters = np.atleast_1d(np.asarray(scale_parameters, dtype=float))
        if scale_parameters.ndim != 1 or scale_parameters.size == 0:
            raise ValueError("need one scale parameter per input dimension")
        if not signal_variance > 0:
            raise ValueError(f"signal_variance must be positive, got {signal_variance}")
        self.theta = np.concatenate(
            ([np.log(signal_variance)], self._scale_to_theta(scale_parameters))
        )

    # -- parametrisation (subclasses) ------------------------------------------------------
    def _scale_to_theta(self, scale_parameters: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _weights_and_derivative(self, theta_scale: np.ndarray):
        """Weights ``w`` of eq. (1) and ``dw/dtheta_scale`` (elementwise), each shape (d,)."""
        raise NotImplementedError

    def _theta_scale_from_weights(self, weights: np.ndarray) -> np.ndarray:
        """``theta[1:]`` with the weights ``w`` of eq. (1) (the inverse map), shape (d,)."""
        raise NotImplementedError

    def scale_parameters(self) -> np.ndarray:
        """The kernel's own per-dimension parameters (length scales or alphas), shape (d,)."""
        raise NotImplementedError

    def prior(self) -> IndependentPrior:
        """Default prior on ``theta`` for Bayesian inference (MCMC, annealing)."""
        raise NotImplementedError

    # -- shared maths -------------------------------------------------------------------------
    @property
    def n_dims(self) -> int:
        """Input dimension d."""
        return self.theta.size - 1

    @property
    def signal_variance(self) -> float:
        return float(np.exp(self.theta[0]))

    @property
    def theta_names(self) -> list[str]:
        return ["ln_signal_variance"] + [f"{self._scale_name}_{i}" for i in range(self.n_dims)]

    def weights(self, theta=None) -> np.ndarray:
        """Weights ``w_i`` of eq. (1), shape (d,)."""
        theta = self.theta if theta is None else theta
        return self._weights_and_derivative(theta[1:])[0]

    def theta_from_weights(self, weights) -> tuple[np.ndarray, np.ndarray]:
        """The inverse of :meth:`weights`: ``theta[1:]`` with weights ``w`` (positive) and
        ``dw/dtheta[1:]`` there (elementwise), each shape (d,)."""
        theta_scale = self._theta_scale_from_weights(np.asarray(weights, dtype=float))
        return theta_scale, self._weights_and_derivative(theta_scale)[1]

    def length_scales(self) -> np.ndarray:
        """Equivalent ARD length scales ``l_i = 1 / sqrt(2 w_i)``, shape (d,)."""
        return 1.0 / np.sqrt(2.0 * self.weights())

    def __call__(self, X, Y=None, *, theta=None) -> np.ndarray:
        """Kernel matrix.

        Parameters
        ----------
        X : ndarray, shape (n, d)
        Y : ndarray, shape (m, d), optional
            Defaults to ``X``.
        theta : ndarray, shape (d + 1,), optional
            Hyperparameters to evaluate at; defaults to ``self.theta``.

        Returns
        -------
        K : ndarray, shape (n, m)
        """
        theta = self.theta if theta is None else theta
        scale = np.sqrt(self.weights(theta))
        Xs = np.asarray(X, dtype=float) * scale
        if Y is None and len(Xs) > 1:
            # Symmetric: the n (n - 1) / 2 distinct squared distances, each computed directly as
            # sum_i (x_ai - x_bi)^2 (no cancellation), then one exp per pair.
            condensed = pdist(Xs, "sqeuclidean")
            np.subtract(theta[0], condensed, out=condensed)
            K = squareform(np.exp(condensed, out=condensed))
            np.fill_diagonal(K, np.exp(theta[0]))
            return K
        Ys = Xs if Y is None else np.asarray(Y, dtype=float) * scale
        return np.exp(theta[0] - _squared_distances(Xs, Ys))

    def diag(self, X, *, theta=None) -> np.ndarray:
        """``k(x_a, x_a)`` for each row of ``X``, shape (n,)."""
        theta = self.theta if theta is None else theta
        return np.full(len(X), np.exp(theta[0]))

    def gradient_contraction(self, X, K, M, *, theta=None) -> np.ndarray:
        """``g_j = sum_ab M_ab dK_ab/dtheta_j`` for ``K = k(X, X)`` (eq. 3 with ``Y = X``).

        Parameters
        ----------
        X : ndarray, shape (n, d)
        K : ndarray, shape (n, n)
            ``self(X, theta=theta)``, passed in because the caller already has it.
        M : ndarray, shape (n, n)
            Weighting matrix.

        Returns
        -------
        g : ndarray, shape (d + 1,)
        """
        return self.cross_gradient_contraction(X, X, K, M, theta=theta)

    def cross_gradient_contraction(self, X, Y, K, M, *, theta=None) -> np.ndarray:
        """``g_j = sum_ab M_ab dK_ab/dtheta_j`` for ``K = k(X, Y)`` and any ``M`` of its shape (eq. 3).

        Sparse GPs need it for ``K_mn`` between inducing and training inputs. ``g_0 = sum(M∘K)``;
        a jitter proportional to ``sigma_f^2`` added where ``x_a = y_b`` (the diagonal of
        ``K_mm``) is differentiated correctly too, at a fixed relative jitter, since the weight
        terms vanish there.

        Parameters
        ----------
        X : ndarray, shape (n, d)
        Y : ndarray, shape (m, d)
        K : ndarray, shape (n, m)
            ``self(X, Y, theta=theta)``, passed in because the caller already has it.
        M : ndarray, shape (n, m)
            Weighting matrix.

        Returns
        -------
        g : ndarray, shape (d + 1,)
        """
        d = X.shape[1]
        products = (M * K) @ np.column_stack([Y, Y * Y, np.ones(len(Y))])  # R [Y, Y^2, 1]
        row_sums = products[:, -1]
        distance_sums = row_sums @ (X * X) + products[:, d:2 * d].sum(axis=0) \
            - 2.0 * np.einsum("ai,ai->i", X, products[:, :d])
        return self._gradient_from_sums(row_sums.sum(), distance_sums, theta)

    def low_rank_gradient_contraction(self, X, K, A, *, theta=None) -> np.ndarray:
        """``g_j = sum_ab (A A^T)_ab dK_ab/dtheta_j`` for ``K = k(X, X)`` (eq. 4), without
        forming the n x n matrix ``A A^T``.

        Parameters
        ----------
        X : ndarray, shape (n, d)
        K : ndarray, shape (n, n)
            ``self(X, theta=theta)``, passed in because the caller already has it.
        A : ndarray, shape (n, r)

        Returns
        -------
        g : ndarray, shape (d + 1,)
        """
        n, d = X.shape
        A = A.reshape(n, -1)
        columns = np.concatenate([A[:, :, None], A[:, :, None] * X[:, None, :]], axis=2)  # (n, r, d + 1)
        products = (K @ columns.reshape(n, -1)).reshape(columns.shape)  # K [a_k, a_k∘x_i]
        quadratic = np.einsum("ak,ak->", A, products[:, :, 0])  # sum_k a_k^T K a_k
        distance_sums = 2.0 * (np.einsum("ak,ai,ak->i", A, X * X, products[:, :, 0])
                               - np.einsum("aki,aki->i", columns[:, :, 1:], products[:, :, 1:]))
        return self._gradient_from_sums(quadratic, distance_sums, theta)

    def _gradient_from_sums(self, total, distance_sums, theta) -> np.ndarray:
        """``g = [total, -distance_sums * dw/dtheta_scale]``: the contraction's gradient from
        ``total = sum_ab M_ab K_ab`` and ``distance_sums_i = sum_ab M_ab K_ab (x_ai - y_bi)^2``
        (eq. 3), shape (d + 1,)."""
        theta = self.theta if theta is None else theta
        _, dw_dtheta = self._weights_and_derivative(theta[1:])
        return np.concatenate(([total], -np.asarray(distance_sums) * dw_dtheta))

    def clone_with_theta(self, theta) -> StationaryKernel:
        """A copy with hyperparameters ``theta``."""
        new = object.__new__(type(self))
        new.theta = np.array(theta, dtype=float)
        return new

    def __repr__(self) -> str:
        params = np.array2string(self.scale_parameters(), precision=4)
        return f"{type(self).__name__}(signal_variance={self.signal_variance:.4g}, {self._parameter_name}={params})"


class SquaredExponentialARD(StationaryKernel):
    """``sigma_f^2 exp(-0.5 sum_i (x_i - x'_i)^2 / l_i^2)`` (Ko et al. 2007, eq. 13).

    Parameters
    ----------
    signal_variance : float
        ``sigma_f^2``.
    length_scales : array_like, shape (d,)
        ``l_i`` in input units, positive.
    """

    kind = "squared_exponential_ard"
    _scale_name = "ln_length_scale"
    _parameter_name = "length_scales"

    def __init__(self, signal_variance: float = 1.0, length_scales=1.0) -> None:
        if np.any(np.asarray(length_scales) <= 0):
            raise ValueError("length scales must be positive")
        super().__init__(signal_variance, length_scales)

    def _scale_to_theta(self, length_scales):
        return np.log(length_scales)

    def _weights_and_derivative(self, theta_scale):
        weights = 0.5 * np.exp(-2.0 * theta_scale)  # w = 1/(2 l^2), l = e^theta
        return weights, -2.0 * weights

    def _theta_scale_from_weights(self, weights):
        return -0.5 * np.log(2.0 * weights)

    def scale_parameters(self):
        return np.exp(self.theta[1:])

    def prior(self):
        # Inputs and outputs are standardised inside the GP, so unit scales are the natural
        # centre; a log-normal of width 1.5 covers length scales from ~0.05 to ~20 (2 sigma).
        return IndependentPrior(
            [stats.norm(0.0, 1.5)] + [stats.norm(0.0, 1.5)] * self.n_dims, self.theta_names
        )


class HigdonKernel(StationaryKernel):
    """``sigma_f^2 prod_i alpha_i^(4 (x_i - x'_i)^2)`` (Bo105 GP-NARX paper, after Higdon).

    Parameters
    ----------
    signal_variance : float
        ``sigma_f^2``.
    alphas : array_like, shape (d,)
        Correlation at a distance of half an input unit, each in the open interval (0, 1);
        alpha near 1 means the output hardly depends on that input.
    """

    kind = "higdon"
    _scale_name = "logit_alpha"
    _parameter_name = "alphas"

    def __init__(self, signal_variance: float = 1.0, alphas=0.5) -> None:
        alphas = np.asarray(alphas, dtype=float)
        if np.any((alphas <= 0) | (alphas >= 1)):
            raise ValueError("Higdon alphas must lie strictly between 0 and 1")
        super().__init__(signal_variance, alphas)

    def _scale_to_theta(self, alphas):
        return logit(alphas)

    def _weights_and_derivative(self, theta_scale):
        # w = -4 ln alpha with alpha = expit(z): ln alpha = -ln(1 + e^-z) = -logaddexp(0, -z),
        # dw/dz = -4 (1 - alpha).
        weights = 4.0 * np.logaddexp(0.0, -theta_scale)
        return weights, -4.0 * expit(-theta_scale)

    def _theta_scale_from_weights(self, weights):
        return -np.log(np.expm1(0.25 * weights))  # w = 4 ln(1 + e^-z)

    def scale_parameters(self):
        return expit(self.theta[1:])

    def prior(self):
        # alpha_i ~ Beta(1, 0.1), the default of Higdon's GPMSA code (Higdon et al., JASA 103,
        # 2008; QUESO's GPMSA port: emulator correlation strength Beta(1.0, 0.1)): most mass
        # near alpha = 1, so an input is irrelevant until the data say otherwise. A uniform
        # prior instead favours short length scales, which extrapolate badly in free run.
        return IndependentPrior(
            [stats.norm(0.0, 1.5)] + [LogitBeta(1.0, 0.1)] * self.n_dims, self.theta_names
        )


#: Kernel classes by their ``kind`` (used by model files).
KERNELS = {cls.kind: cls for cls in (SquaredExponentialARD, HigdonKernel)}


def alpha_from_length_scale(length_scale):
    """Higdon alpha with the same correlation as an SE length scale (eq. 2)."""
    return np.exp(-1.0 / (8.0 * np.asarray(length_scale, dtype=float) ** 2))


def length_scale_from_alpha(alpha):
    """SE length scale with the same correlation as a Higdon alpha (eq. 2)."""
    return 1.0 / np.sqrt(-8.0 * np.log(np.asarray(alpha, dtype=float)))


def _squared_distances(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``|a - b|^2`` for every pair of rows, shape (n, m), clipped at zero."""
    sq = (A * A).sum(1)[:, None] + (B * B).sum(1)[None, :] - 2.0 * (A @ B.T)
    if A is B:
        np.fill_diagonal(sq, 0.0)
    return np.maximum(sq, 0.0)
