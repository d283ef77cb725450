"""Exact moments of GP predictions at a Gaussian-distributed input (moment matching).

In a free run of a GP-NARX model the regressor ``x`` holds earlier predictions, so it is uncertain:
``x ~ N(m, S)``. The predictive distribution of ``f(x)`` is then no longer Gaussian, but for
kernel (1) of :mod:`gp_model._kernels` its mean, its covariance and its covariance with ``x`` have
closed forms: Girard, Rasmussen, Quinonero-Candela & Murray-Smith, "Gaussian process priors with
uncertain inputs -- application to multiple-step ahead time series forecasting", NIPS 2003 (one
output); Deisenroth & Rasmussen, "PILCO", ICML 2011, sec. 2.2, and Deisenroth, *Efficient
reinforcement learning using Gaussian processes*, 2010, sec. 2.3 (several outputs, the covariances
between them and the input-output cross-covariance). Matching a Gaussian to these moments is what
propagates the state distribution from one step to the next.

Notation, for GP ``a`` of m independent single-output GPs, all in one standardised input frame
(below) and in standardised output units: training inputs ``X_a`` (n_a, d); weights
``beta_a = (K_a + sigma_n,a^2 I)^-1 y_a`` (the GP's ``alpha_``); signal variance ``s2_a``;
``Lambda_a = diag(l_a^2)`` with the equivalent length scales ``l_ai^2 = 1 / (2 w_ai)``, so that
``k_a(x, x') = s2_a exp(-1/2 (x - x')^T Lambda_a^-1 (x - x'))``; ``nu_ai = X_ai - m`` and
``u_ai = Lambda_a^-1 nu_ai``. Integrating products of Gaussians over ``N(x | m, S)`` gives

    E[f_a] = beta_a^T q_a,
    q_ai = s2_a |S Lambda_a^-1 + I|^-1/2 exp(-1/2 nu_ai^T (S + Lambda_a)^-1 nu_ai),        (1)

    Cov[x, f_a] = S (S + Lambda_a)^-1 sum_i beta_ai q_ai nu_ai,                          (2)

    E[mu_a(x) mu_b(x)] = beta_a^T Q^ab beta_b,     R = S (Lambda_a^-1 + Lambda_b^-1) + I,
    Q^ab_ij = k_a(X_ai, m) k_b(X_bj, m) |R|^-1/2 exp(1/2 z_ij^T R^-1 S z_ij),
    z_ij = u_ai + u_bj,                                                                     (3)

    E[var_a(x)] = s2_a - tr((K_a + sigma_n,a^2 I)^-1 Q^aa),                                  (4)

    Cov[f_a, f_b] = E[mu_a mu_b] - E[f_a] E[f_b] + delta_ab (E[var_a] + sigma_n,a^2),       (5)

where ``mu_a(x)``, ``var_a(x)`` are the ordinary GP predictive mean and variance at ``x`` and the
noise term of (5) is there only for a noisy prediction. Outputs ``a != b`` are independent given
``x``; they covary only through the shared uncertain input.

Numerics. With ``M(P) = (P + S^-1)^-1`` for a positive diagonal precision ``P``, the Woodbury
identity turns (1)-(3) into expressions that stay finite for a singular ``S``:
``(S + Lambda_a)^-1 = Lambda_a^-1 - Lambda_a^-1 M_a Lambda_a^-1`` and
``S (S + Lambda_a)^-1 = M_a Lambda_a^-1`` with ``M_a = M(Lambda_a^-1)``, and
``R^-1 S = M_ab = M(Lambda_a^-1 + Lambda_b^-1)``. Each ``M(P)`` is computed as
``P^-1/2 (I + T)^-1 T P^-1/2`` with ``T = P^1/2 S P^1/2``: ``I + T`` has all eigenvalues >= 1, so
its Cholesky factor always exists (``S = 0`` gives ``M = 0`` and the ordinary GP prediction).
The centred second moment is formed without subtracting two nearly equal numbers,

    Q^ab_ij - q_ai q_bj = q_ai q_bj expm1(D_ij),
    D_ij = 1/2 (z_ij^T M_ab z_ij - u_ai^T M_a u_ai - u_bj^T M_b u_bj)
           - 1/2 (ln|I + T_ab| - ln|I + T_a| - ln|I + T_b|),                                  (6)

whose every term vanishes with ``S``, so the output covariance stays accurate however small the
input uncertainty.

Frames. Each GP standardises its own inputs, ``z = (x - mu_x) / s_x``. All GPs are expressed in
the frame of ``gps[0]``, where GP ``a`` has training inputs ``(s_a X_a + mu_a - mu_0) / s_0`` and
length scales ``l_a s_a / s_0``; for a :class:`~gp_model.PerOutputGP` all scalers are equal and
this is every GP's own frame, bit for bit. Outputs map back as ``y = mu_y + s_y f``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from ._gp import GaussianProcess
from ._kernels import StationaryKernel

#: Relative size (to the largest eigenvalue) of the asymmetry and of the negative eigenvalues
#: tolerated in the standardised input covariance: rounding in a covariance propagated over many
#: free-run steps stays near d * machine epsilon, far below this; a real error is far above it.
COVARIANCE_TOLERANCE = 1e-10


def predict_uncertain_input(gps, mean, cov, *, include_noise: bool = True):
    """Exact mean and covariance of m GP predictions at a Gaussian input (moment matching).

    Implements eqs. (1)-(6) of this module (Girard et al. 2003; Deisenroth & Rasmussen 2011).

    Parameters
    ----------
    gps : list of GaussianProcess, length m
        Fitted single-output GPs on the same d inputs (for example ``PerOutputGP.gps``), each
        with kernel (1) of :mod:`gp_model._kernels`. The point hyperparameters ``theta_`` are used;
        ``theta_samples_`` is ignored.
    mean : array_like, shape (d,)
        Mean of the input distribution, in the raw input units of the GPs' training data.
    cov : array_like, shape (d, d)
        Covariance of the input distribution, in squared raw input units; symmetric positive
        semi-definite (zero gives the ordinary GP prediction at ``mean``).
    include_noise : bool, default True
        Predict noisy observations ``y`` (add each GP's noise variance ``exp(theta_[-1])``, in
        its standardised units, to the diagonal of ``out_cov``) instead of the latent ``f``.

    Returns
    -------
    out_mean : ndarray, shape (m,)
        ``E[f(x)]``, in output units.
    out_cov : ndarray, shape (m, m)
        ``Cov[f(x)]``, in products of output units: expected GP variances (plus noise) on the
        diagonal, and the covariances that the shared uncertain input induces between outputs.
    cross_cov : ndarray, shape (d, m)
        ``Cov[x, f(x)]``, in input units times output units.

    Raises
    ------
    TypeError
        If ``gps`` is not a list of GaussianProcess objects.
    ValueError
        If a GP is unfitted, has several outputs or another input dimension, or if ``mean`` or
        ``cov`` has the wrong shape, is not finite, or ``cov`` is not symmetric positive
        semi-definite.

    Notes
    -----
    The cost is O(m n^3) to prepare the GPs and O(m^2 n^2 d) per input distribution. A free run
    predicting from many input distributions can prepare once with ``_MomentMatcher(gps)`` and
    call it at every step.
    """
    return _MomentMatcher(gps)(mean, cov, include_noise=include_noise)


@dataclass(frozen=True)
class _FrameGP:
    """One single-output GP in the common standardised input frame (module docstring)."""

    inputs: np.ndarray  # (n, d) training inputs X_a
    precision: np.ndarray  # (d,) diagonal of Lambda_a^-1 = 2 w
    beta: np.ndarray  # (n,) the GP's alpha_, (K + sigma_n^2 I)^-1 y in standardised units
    log_signal_variance: float  # ln s2_a
    K_inv: np.ndarray  # (n, n) (K + (sigma_n^2 + jitter) I)^-1 from L_, as predict uses
    noise_variance: float  # sigma_n^2, standardised output units
    output_mean: float
    output_scale: float


class _MomentMatcher:
    """Eqs. (1)-(6) for a fixed list of GPs: the per-GP factorisations are done once here.

    Parameters
    ----------
    gps : list of GaussianProcess
        As in :func:`predict_uncertain_input`.
    """

    def __init__(self, gps) -> None:
        if not isinstance(gps, (list, tuple)) or not all(
                isinstance(gp, GaussianProcess) for gp in gps):
            raise TypeError("gps must be a list of fitted single-output GaussianProcess objects "
                            "(for a PerOutputGP pass its .gps)")
        if not gps:
            raise ValueError("gps is empty; pass one fitted GaussianProcess per output")
        for a, gp in enumerate(gps):
            if not hasattr(gp, "theta_"):
                raise ValueError(f"gps[{a}] is not fitted; call fit() first")
            if gp.Y_train_.shape[1] != 1:
                raise ValueError(f"gps[{a}] has {gp.Y_train_.shape[1]} outputs; moment matching "
                                 "needs one single-output GP per output (use PerOutputGP)")
            if not isinstance(gp.kernel, StationaryKernel):
                raise ValueError(f"gps[{a}] has kernel {type(gp.kernel).__name__}; moment "
                                 "matching needs the squared-exponential form (1) of "
                                 "gp_model._kernels")
            if gp.X_train_.shape[1] != gps[0].X_train_.shape[1]:
                raise ValueError(f"gps[{a}] has input dimension {gp.X_train_.shape[1]} but gps[0] "
                                 f"has {gps[0].X_train_.shape[1]}; all GPs must share the input")
        self.input_mean = gps[0].input_scaler_.mean_  # (d,) mu_0 of the common frame
        self.input_scale = gps[0].input_scaler_.scale_  # (d,) s_0
        self.gps = [self._to_frame(gp) for gp in gps]

    @property
    def n_dims(self) -> int:
        return self.input_mean.size

    def _to_frame(self, gp: GaussianProcess) -> _FrameGP:
        # z_0 = (s_a z_a + mu_a - mu_0) / s_0; a ratio of exactly 1 keeps equal frames bit-exact.
        ratio = gp.input_scaler_.scale_ / self.input_scale
        offset = (gp.input_scaler_.mean_ - self.input_mean) / self.input_scale
        kernel_theta = gp.theta_[:-1]
        n = len(gp.X_train_)
        return _FrameGP(
            inputs=gp.X_train_ * ratio + offset,
            precision=2.0 * gp.kernel.weights(kernel_theta) / ratio**2,  # 1 / l^2 in frame 0
            beta=gp.alpha_[:, 0],
            log_signal_variance=float(kernel_theta[0]),
            K_inv=linalg.cho_solve((gp.L_, True), np.eye(n), check_finite=False),
            noise_variance=float(np.exp(gp.theta_[-1])),
            output_mean=float(gp.output_scaler_.mean_[0]),
            output_scale=float(gp.output_scaler_.scale_[0]),
        )

    def __call__(self, mean, cov, *, include_noise: bool = True):
        """Moments at ``x ~ N(mean, cov)``; as :func:`predict_uncertain_input`."""
        m, S = self._standardise(mean, cov)
        # Per GP: u_ai (eq. 3), M_a and ln|I + T_a| (eq. 6), q_a (eq. 1 in the Woodbury form
        # -1/2 nu^T (S + Lambda)^-1 nu = -1/2 nu^T u + 1/2 u^T M_a u).
        singles = []
        for gp in self.gps:
            nu = gp.inputs - m  # (n, d)
            u = nu * gp.precision
            M, log_det = _woodbury_terms(gp.precision, S)
            uMu = np.einsum("ij,jk,ik->i", u, M, u)
            q = np.exp(gp.log_signal_variance - 0.5 * log_det
                       - 0.5 * np.einsum("ij,ij->i", nu, u) + 0.5 * uMu)
            singles.append((u, M, log_det, q))

        n_out = len(self.gps)
        mean_s = np.array([gp.beta @ q for gp, (_, _, _, q) in zip(self.gps, singles)])  # eq. 1
        # Eq. 2 with S (S + Lambda_a)^-1 nu_i = M_a u_i.
        cross_s = np.column_stack([M @ (u.T @ (gp.beta * q))
                                   for gp, (u, M, _, q) in zip(self.gps, singles)])  # (d, m)
        cov_s = np.empty((n_out, n_out))
        for a in range(n_out):
            gp_a, (u_a, M_a, log_det_a, q_a) = self.gps[a], singles[a]
            for b in range(a, n_out):
                gp_b, (u_b, M_b, log_det_b, q_b) = self.gps[b], singles[b]
                M_ab, log_det_ab = _woodbury_terms(gp_a.precision + gp_b.precision, S)
                # Eq. 6: z^T M_ab z expanded over z_ij = u_ai + u_bj.
                D = (0.5 * np.einsum("ij,jk,ik->i", u_a, M_ab - M_a, u_a)[:, None]
                     + 0.5 * np.einsum("ij,jk,ik->i", u_b, M_ab - M_b, u_b)[None, :]
                     + u_a @ M_ab @ u_b.T
                     - 0.5 * (log_det_ab - log_det_a - log_det_b))
                excess = np.expm1(D)  # (Q^ab - q_a q_b^T) / (q_a q_b^T), elementwise
                cov_s[a, b] = cov_s[b, a] = (gp_a.beta * q_a) @ excess @ (gp_b.beta * q_b)
                if b == a:
                    # Eq. 4 with Q^aa of eq. 3, clipped at zero as GaussianProcess.predict clips
                    # its variance; eq. 5 adds it and the noise to the diagonal.
                    Q_aa = np.outer(q_a, q_a) * (1.0 + excess)
                    expected_var = (np.exp(gp_a.log_signal_variance)
                                    - np.einsum("ij,ji->", gp_a.K_inv, Q_aa))
                    cov_s[a, a] += (max(expected_var, 0.0)
                                    + (gp_a.noise_variance if include_noise else 0.0))

        # Back to raw units (eq. 5 scaled): y = mu_y + s_y f and x = mu_0 + s_0 z.
        output_scale = np.array([gp.output_scale for gp in self.gps])
        out_mean = np.array([gp.output_mean for gp in self.gps]) + output_scale * mean_s
        out_cov = cov_s * np.outer(output_scale, output_scale)
        cross_cov = cross_s * self.input_scale[:, None] * output_scale[None, :]
        return out_mean, out_cov, cross_cov

    def _standardise(self, mean, cov) -> tuple[np.ndarray, np.ndarray]:
        """Check ``mean`` (d,) and ``cov`` (d, d); return them in the common frame."""
        d = self.n_dims
        mean = np.asarray(mean, dtype=float)
        cov = np.asarray(cov, dtype=float)
        if mean.shape != (d,):
            raise ValueError(f"mean must have shape ({d},) like the GP inputs, got {mean.shape}")
        if cov.shape != (d, d):
            raise ValueError(f"cov must have shape ({d}, {d}) like the GP inputs, got {cov.shape}")
        if not (np.isfinite(mean).all() and np.isfinite(cov).all()):
            raise ValueError("mean or cov contains NaN or inf")
        m = (mean - self.input_mean) / self.input_scale
        S = cov / np.outer(self.input_scale, self.input_scale)
        # Judged in the standardised frame, so that inputs in very different units (altitude in
        # m, angles in rad) weigh alike.
        size = np.abs(S).max()
        asymmetry = np.abs(S - S.T).max()
        if asymmetry > COVARIANCE_TOLERANCE * size:
            raise ValueError(
                f"cov is not symmetric: max |S - S^T| = {asymmetry:.3g} against max |S| = "
                f"{size:.3g} (S = cov standardised by the GP input scales); if the asymmetry is "
                "rounding, pass (cov + cov.T) / 2")
        S = 0.5 * (S + S.T)
        eigenvalues = np.linalg.eigvalsh(S)
        if eigenvalues[0] < -COVARIANCE_TOLERANCE * max(eigenvalues[-1], 0.0):
            raise ValueError(
                f"cov is not positive semi-definite: the standardised covariance has eigenvalue "
                f"{eigenvalues[0]:.3g} (largest {eigenvalues[-1]:.3g}); check how it was formed")
        return m, S


def _woodbury_terms(precision: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, float]:
    """``M(P) = (P + S^-1)^-1`` and ``ln|I + T|``, ``T = P^1/2 S P^1/2`` (eq. 6).

    Parameters
    ----------
    precision : ndarray, shape (d,)
        Positive diagonal of ``P``.
    S : ndarray, shape (d, d)
        Symmetric positive semi-definite; may be singular.

    Returns
    -------
    M : ndarray, shape (d, d)
        Symmetric; zero when ``S`` is zero.
    log_det : float
        ``ln|I + T| = ln|S P + I|`` (Sylvester's determinant identity).
    """
    root = np.sqrt(precision)
    T = S * np.outer(root, root)
    factor = linalg.cho_factor(np.eye(len(T)) + T, lower=True, check_finite=False)
    M = linalg.cho_solve(factor, T, check_finite=False) / np.outer(root, root)
    return 0.5 * (M + M.T), 2.0 * float(np.log(np.diag(factor[0])).sum())
