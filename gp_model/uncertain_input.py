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

This module needs numpy only, so that a GP-NARX FMU can carry a copy of it (docs/fmus.md); its
free-run mode propagates its bounds with :class:`MomentMatcher` and :func:`narx_belief_step`
(a simulator host has no flightgp). :mod:`gp_model._moment_matching` builds the frames from
fitted :class:`~gp_model.GaussianProcess` objects.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

#: Relative size (to the largest eigenvalue) of the asymmetry and of the negative eigenvalues
#: tolerated in the standardised input covariance: rounding in a covariance propagated over many
#: free-run steps stays near d * machine epsilon, far below this; a real error is far above it.
COVARIANCE_TOLERANCE = 1e-10


@dataclass(frozen=True)
class FrameGP:
    """One single-output GP in the common standardised input frame (module docstring), at S
    hyperparameter vectors (S = 1 for point hyperparameters) sharing its basis inputs.

    Built by :func:`frame_gp`. The latent predictive variance at a standardised input ``z`` for
    sample ``s`` is ``exp(log_signal_variance[s]) - k_s^T K_inv[s] k_s``.
    """

    inputs: np.ndarray  # (n, d) basis inputs X_a (training inputs; inducing inputs if sparse)
    precision: np.ndarray  # (S, d) diagonal of Lambda_a^-1 = 2 w
    beta: np.ndarray  # (S, n) mean weights: alpha = (K + sigma_n^2 I)^-1 y, standardised units
    log_signal_variance: np.ndarray  # (S,) ln s2_a
    K_inv: np.ndarray  # (S, n, n) (K + (sigma_n^2 + jitter) I)^-1 if exact (K_mm^-1 - Sigma if sparse)
    noise_variance: np.ndarray  # (S,) sigma_n^2, standardised output units
    output_mean: float
    output_scale: float


def frame_gp(*, basis, weights, variance_factor, kernel_weights, log_signal_variance, noise_variance,
             input_mean, input_scale, output_mean, output_scale, frame_mean, frame_scale) -> FrameGP:
    """A GP's predictive forms (one per hyperparameter sample) as a :class:`FrameGP`.

    Parameters
    ----------
    basis : array_like, shape (n, d)
        Standardised basis inputs of the GP (its own input frame).
    weights : array_like, shape (S, n)
        Mean weights, ``mean_s(z) = k_s(z, basis) @ weights[s]``.
    variance_factor : array_like, shape (S, n, n)
        ``var_s(z) = s2_s - |variance_factor[s] @ k_s|^2`` (latent).
    kernel_weights : array_like, shape (S, d)
        ``w`` of ``k(z, z') = s2 exp(-sum_i w_i (z_i - z'_i)^2)`` (kernel (1) of
        :mod:`gp_model._kernels`).
    log_signal_variance, noise_variance : array_like, shape (S,)
        ``ln s2`` and ``sigma_n^2`` (standardised output units).
    input_mean, input_scale : array_like, shape (d,)
        The GP's own input standardisation.
    output_mean, output_scale : float
        ``y = output_mean + output_scale * f``.
    frame_mean, frame_scale : array_like, shape (d,)
        The common frame (module docstring, "Frames").
    """
    # z_0 = (s_a z_a + mu_a - mu_0) / s_0; a ratio of exactly 1 keeps equal frames bit-exact.
    ratio = np.asarray(input_scale, dtype=float) / frame_scale
    offset = (np.asarray(input_mean, dtype=float) - frame_mean) / frame_scale
    factor = np.asarray(variance_factor, dtype=float)
    return FrameGP(
        inputs=np.asarray(basis, dtype=float) * ratio + offset,
        precision=2.0 * np.asarray(kernel_weights, dtype=float) / ratio**2,  # 1 / l^2 in frame 0
        beta=np.asarray(weights, dtype=float),
        log_signal_variance=np.asarray(log_signal_variance, dtype=float),
        K_inv=np.einsum("sji,sjk->sik", factor, factor),
        noise_variance=np.asarray(noise_variance, dtype=float),
        output_mean=float(output_mean),
        output_scale=float(output_scale),
    )


class MomentMatcher:
    """Eqs. (1)-(6) for a fixed list of single-output GPs in one input frame.

    With S hyperparameter samples per GP, sample ``s`` of every GP forms model ``s``, and the
    prediction is the equal-weight mixture of the S models' predictions: its exact moments are
    ``E[f] = E_s[m_s]``, ``Cov[f] = E_s[C_s] + Cov_s[m_s]`` (law of total covariance) and
    ``Cov[x, f] = E_s[Cov_s[x, f]]`` (x does not depend on s), which the matched Gaussian keeps.

    Repeated samples (annealing keeps its last sample when it rejects a move, so a chain of 400
    may hold only 100 distinct ones) are computed once and counted as often as they occur: the
    moments are the same. Terms of one output use its distinct samples; the covariances between
    outputs ``a != b`` use the distinct pairs ``(s_a, s_b)`` of the joint samples.

    Parameters
    ----------
    frames : sequence of FrameGP, length m
        The GPs, every one expressed in the common standardised input frame, all with the same
        number S of samples.
    input_mean, input_scale : ndarray, shape (d,)
        The common frame: ``z = (x - input_mean) / input_scale`` (raw input units).
    """

    def __init__(self, frames, *, input_mean, input_scale) -> None:
        self.frames = list(frames)
        self.input_mean = np.asarray(input_mean, dtype=float)
        self.input_scale = np.asarray(input_scale, dtype=float)
        counts = {len(frame.beta) for frame in self.frames}
        if len(counts) != 1:
            raise ValueError(f"the GPs have different numbers of hyperparameter samples {sorted(counts)}; "
                             "moment matching pairs sample s of every GP")
        # Per GP: its distinct samples (in order of first occurrence), which of them each joint
        # sample is, and how often each occurs.
        self._distinct, self._rows, self._index, self._counts = [], [], [], []
        for frame in self.frames:
            keep, index = _distinct_samples(frame)
            self._distinct.append(_frame_samples(frame, keep))
            self._rows.append(keep)
            self._index.append(index)
            self._counts.append(np.bincount(index, minlength=len(keep)).astype(float))
        self._pairs = {(a, b): _pair_counts(self._index, (a, b))
                       for a in range(len(self.frames)) for b in range(a + 1, len(self.frames))}

    @property
    def n_dims(self) -> int:
        return self.input_mean.size

    @property
    def n_outputs(self) -> int:
        return len(self.frames)

    @property
    def n_samples(self) -> int:
        return len(self.frames[0].beta)

    def sample_pairs(self) -> dict:
        """The sample pairs of the covariances between outputs: ``{(a, b): (rows_a, rows_b,
        counts)}`` for ``a < b``, rows into each GP's distinct samples (:meth:`distinct_samples`),
        each pair counted as often as the joint samples hold it (the counts sum to S)."""
        return self._pairs

    def distinct_samples(self) -> list:
        """Per GP: ``(rows, index)``, the rows (shape (T,)) of its distinct samples among the S,
        in order of first occurrence, and which of them each joint sample is (shape (S,))."""
        return list(zip(self._rows, self._index))

    def __call__(self, mean, cov, *, include_noise: bool = True):
        """Exact mean and covariance of the m GP predictions at ``x ~ N(mean, cov)``.

        Parameters
        ----------
        mean : array_like, shape (d,)
            Input mean, raw input units.
        cov : array_like, shape (d, d)
            Input covariance, squared raw input units; symmetric positive semi-definite.
        include_noise : bool, default True
            Predict noisy observations (add each GP's noise variance) rather than latent values.

        Returns
        -------
        out_mean : ndarray, shape (m,)
            ``E[f(x)]``, output units.
        out_cov : ndarray, shape (m, m)
            ``Cov[f(x)]`` (eq. 5), products of output units.
        cross_cov : ndarray, shape (d, m)
            ``Cov[x, f(x)]`` (eq. 2), input units times output units.

        Raises
        ------
        ValueError
            ``mean`` or ``cov`` of the wrong shape, not finite, or ``cov`` not symmetric positive
            semi-definite.
        """
        m, S = self._standardise(mean, cov)
        # Per GP and distinct sample (leading axis t): u_ai (eq. 3), M_a and ln|I + T_a| (eq. 6),
        # q_a (eq. 1 in the Woodbury form -1/2 nu^T (S + Lambda)^-1 nu = -1/2 nu^T u + 1/2 u^T M_a u).
        singles = []
        for gp in self._distinct:
            nu = gp.inputs - m  # (n, d)
            u = nu * gp.precision[:, None, :]  # (T, n, d)
            M, log_det = _woodbury_terms(gp.precision, S)  # (T, d, d), (T,)
            uMu = _quadratic_forms(u, M)
            q = np.exp(gp.log_signal_variance[:, None] - 0.5 * log_det[:, None]
                       - 0.5 * np.einsum("ij,sij->si", nu, u) + 0.5 * uMu)  # (T, n)
            singles.append((u, M, log_det, q))

        n_out, n_samples = len(self.frames), self.n_samples
        mean_s = np.column_stack([np.einsum("sn,sn->s", gp.beta, q)[index] for gp, (_, _, _, q), index
                                  in zip(self._distinct, singles, self._index)])  # (S, m), eq. 1
        # Eq. 2 with S (S + Lambda_a)^-1 nu_i = M_a u_i, summed over the samples.
        cross_sum = np.column_stack([counts @ np.einsum("sde,se->sd", M, np.einsum("snd,sn->sd", u, gp.beta * q))
                                     for gp, (u, M, _, q), counts
                                     in zip(self._distinct, singles, self._counts)])  # (d, m)
        cov_sum = np.empty((n_out, n_out))  # sum over the samples of C_s
        for a in range(n_out):
            gp_a, (u_a, M_a, log_det_a, q_a) = self._distinct[a], singles[a]
            for b in range(a, n_out):
                if b == a:
                    rows_a = rows_b = slice(None)
                    counts = self._counts[a]
                else:
                    rows_a, rows_b, counts = self._pairs[a, b]
                gp_b, (u_b, M_b, log_det_b, q_b) = self._distinct[b], singles[b]
                u_a_, M_a_, q_a_ = u_a[rows_a], M_a[rows_a], q_a[rows_a]
                u_b_, M_b_, q_b_ = u_b[rows_b], M_b[rows_b], q_b[rows_b]
                M_ab, log_det_ab = _woodbury_terms(gp_a.precision[rows_a] + gp_b.precision[rows_b], S)
                # Eq. 6: z^T M_ab z expanded over z_ij = u_ai + u_bj.
                D = (0.5 * _quadratic_forms(u_a_, M_ab - M_a_)[:, :, None]
                     + 0.5 * _quadratic_forms(u_b_, M_ab - M_b_)[:, None, :]
                     + (u_a_ @ M_ab) @ np.swapaxes(u_b_, 1, 2)
                     - 0.5 * (log_det_ab - log_det_a[rows_a] - log_det_b[rows_b])[:, None, None])
                excess = np.expm1(D)  # (Q^ab - q_a q_b^T) / (q_a q_b^T), elementwise
                weighted_a, weighted_b = gp_a.beta[rows_a] * q_a_, gp_b.beta[rows_b] * q_b_
                cov_t = ((weighted_a[:, None, :] @ excess) @ weighted_b[:, :, None])[:, 0, 0]
                if b == a:
                    # Eq. 4 with Q^aa of eq. 3, clipped at zero as GaussianProcess.predict clips
                    # its variance; eq. 5 adds it and the noise to the diagonal.
                    Q_aa = q_a[:, :, None] * q_a[:, None, :] * (1.0 + excess)
                    expected_var = (np.exp(gp_a.log_signal_variance)  # tr(K_inv Q), Q symmetric
                                    - (gp_a.K_inv * Q_aa).sum(axis=(1, 2)))
                    cov_t = cov_t + np.maximum(expected_var, 0.0) + (gp_a.noise_variance if include_noise else 0.0)
                cov_sum[a, b] = cov_sum[b, a] = counts @ cov_t

        # Back to raw units (eq. 5 scaled): y = mu_y + s_y f and x = mu_0 + s_0 z; then the
        # mixture over samples (class docstring), centred so that S = 1 adds exact zeros.
        output_scale = np.array([gp.output_scale for gp in self.frames])
        means = np.array([gp.output_mean for gp in self.frames]) + output_scale * mean_s  # (S, m)
        out_mean = means.mean(axis=0)
        spread = means - out_mean
        out_cov = (cov_sum / n_samples * np.outer(output_scale, output_scale)
                   + np.einsum("si,sj->ij", spread, spread) / n_samples)
        cross_cov = cross_sum / n_samples * self.input_scale[:, None] * output_scale[None, :]
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


def _distinct_samples(frame: FrameGP) -> tuple[np.ndarray, np.ndarray]:
    """The rows (T,) of ``frame``'s distinct samples in order of first occurrence, and which of
    them each of its S samples is (S,)."""
    n_samples = len(frame.beta)
    rows = np.column_stack([frame.precision, frame.beta, frame.log_signal_variance, frame.noise_variance,
                            frame.K_inv.reshape(n_samples, -1)])
    _, first, inverse = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)  # distinct samples by first occurrence
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return first[order], rank[inverse.ravel()]


def _frame_samples(frame: FrameGP, rows: np.ndarray) -> FrameGP:
    """``frame`` at the samples ``rows`` only."""
    return replace(frame, precision=frame.precision[rows], beta=frame.beta[rows],
                   log_signal_variance=frame.log_signal_variance[rows], K_inv=frame.K_inv[rows],
                   noise_variance=frame.noise_variance[rows])


def _pair_counts(index: list, pair: tuple) -> tuple:
    """The distinct sample pairs of GPs ``pair = (a, b)`` among the joint samples, each with how
    often it occurs: ``(rows_a, rows_b, counts)``, rows into each GP's distinct samples."""
    a, b = pair
    combos, counts = np.unique(np.column_stack([index[a], index[b]]), axis=0, return_counts=True)
    return combos[:, 0], combos[:, 1], counts.astype(float)


def _quadratic_forms(u: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``u_si^T M_s u_si`` for ``u`` (S, n, d) and ``M`` (S, d, d): shape (S, n)."""
    return ((u @ M) * u).sum(axis=2)


def _woodbury_terms(precision: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``M(P) = (P + S^-1)^-1`` and ``ln|I + T|``, ``T = P^1/2 S P^1/2`` (eq. 6), per sample.

    Parameters
    ----------
    precision : ndarray, shape (S, d)
        Positive diagonals of ``P``, one per hyperparameter sample.
    S : ndarray, shape (d, d)
        Symmetric positive semi-definite; may be singular.

    Returns
    -------
    M : ndarray, shape (S, d, d)
        Symmetric; zero when ``S`` is zero.
    log_det : ndarray, shape (S,)
        ``ln|I + T| = ln|S P + I|`` (Sylvester's determinant identity).
    """
    root = np.sqrt(precision)
    outer = root[:, :, None] * root[:, None, :]
    T = S * outer
    factor = np.linalg.cholesky(np.eye(S.shape[0]) + T)  # lower; exists as I + T >= I
    M = np.linalg.solve(np.swapaxes(factor, 1, 2), np.linalg.solve(factor, T)) / outer
    log_det = 2.0 * np.log(np.diagonal(factor, axis1=1, axis2=2)).sum(axis=1)
    return 0.5 * (M + np.swapaxes(M, 1, 2)), log_det


# -- a NARX free run by moment matching --------------------------------------------------------
# The belief is a joint Gaussian over the lagged outputs y(k-1), ..., y(k-L), L = the largest
# output lag, ordered lag-major: entry (lag - 1) * n_outputs + output.

def narx_belief_start(initial_outputs) -> tuple[np.ndarray, np.ndarray]:
    """The belief before the first predicted sample: the given outputs, known exactly.

    Parameters
    ----------
    initial_outputs : ndarray, shape (L, n_outputs)
        Row ``i`` holds y(k - 1 - i), the output ``i + 1`` samples before the first predicted one.

    Returns
    -------
    mean : ndarray, shape (L * n_outputs,)
    cov : ndarray, shape (L * n_outputs, L * n_outputs)
        Zero.
    """
    initial = np.asarray(initial_outputs, dtype=float)
    return initial.reshape(-1).copy(), np.zeros((initial.size, initial.size))


def narx_belief_step(matcher: MomentMatcher, known_regressors, mean, cov, *, output_lags,
                     include_noise: bool = True):
    """Predict the next NARX output from the belief and shift it by one sample.

    The regressor is ``x = [known_regressors, lagged outputs]`` (the order of
    :class:`gp_model.NarxStructure`: outputs output-major, lags in ``output_lags`` order); its
    output part is Gaussian with the belief's moments, the known part is exact. Eqs. (1)-(6) give
    the prediction ``y(k)``, whose covariance with the lagged outputs comes from eq. (2) (with
    :func:`_cross_covariance_of_lagged_outputs` for lags the structure skips); the new belief is
    the joint Gaussian over ``y(k), ..., y(k-L+1)``.

    Parameters
    ----------
    matcher : MomentMatcher
        The NARX model's per-output GPs (m = n_outputs) on the d regressors; with hyperparameter
        samples, the belief is matched to the mixture's moments at every step.
    known_regressors : ndarray, shape (d - n_outputs * len(output_lags),)
        The input part of the regressor (exogenous inputs at their lags).
    mean, cov : ndarray, shapes (L * n_outputs,), (L * n_outputs, L * n_outputs)
        The belief over ``y(k-1), ..., y(k-L)``.
    output_lags : sequence of int
        The structure's output lags (each >= 1, the largest L).
    include_noise : bool, default True
        Predict (and feed back) the noisy output: the GP noise acts as process noise.

    Returns
    -------
    y_mean : ndarray, shape (n_outputs,)
    y_cov : ndarray, shape (n_outputs, n_outputs)
    mean, cov : ndarray
        The shifted belief over ``y(k), ..., y(k-L+1)``.
    """
    n_out = matcher.n_outputs
    n_lags = max(output_lags)
    known = np.asarray(known_regressors, dtype=float)
    z_rows = [(j - 1) * n_out + c for c in range(n_out) for j in output_lags]
    n_u = known.size
    x_mean = np.concatenate([known, mean[z_rows]])
    x_cov = np.zeros((x_mean.size, x_mean.size))
    x_cov[n_u:, n_u:] = cov[np.ix_(z_rows, z_rows)]
    y_mean, y_cov, cross = matcher(x_mean, x_cov, include_noise=include_noise)
    cov_z_y = _cross_covariance_of_lagged_outputs(cov, z_rows, cross[n_u:])
    keep = (n_lags - 1) * n_out
    new_mean = np.concatenate([y_mean, mean[:keep]])
    new_cov = np.zeros_like(cov)
    new_cov[:n_out, :n_out] = y_cov
    new_cov[n_out:, n_out:] = cov[:keep, :keep]
    new_cov[n_out:, :n_out] = cov_z_y[:keep]
    new_cov[:n_out, n_out:] = cov_z_y[:keep].T
    return y_mean, y_cov, new_mean, 0.5 * (new_cov + new_cov.T)


def _cross_covariance_of_lagged_outputs(z_cov, z_rows, cross_x_y):
    """``Cov(z, y)`` for all lagged outputs ``z`` given ``Cov(x_z, y)`` for the rows ``z_rows``
    of ``z`` that are regressors.

    Rows of ``z`` that are regressors take the exact cross-covariance; any other row (a lag the
    structure skips) gets its linear-Gaussian projection ``Cov(z, x_z) Cov(x_z)^+ Cov(x_z, y)``
    (Deisenroth 2010, sec. 2.3.2, uses the same approximation for non-Gaussian joints).
    """
    x_cov = z_cov[np.ix_(z_rows, z_rows)]
    cov_z_y = z_cov[:, z_rows] @ np.linalg.pinv(x_cov, rcond=1e-10, hermitian=True) @ cross_x_y
    cov_z_y[z_rows] = cross_x_y
    return cov_z_y
