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
Gaussian elimination solves it stably without pivoting, every pivot >= 1 (``S = 0`` gives
``M = 0`` and the ordinary GP prediction). An input known exactly (a zero row and column of ``S``,
as the exogenous regressors of a NARX free run) gives zero rows and columns of ``T`` and ``M``,
so these are formed on the uncertain dims only.
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


#: Eq. 6's exponents are clamped to +-this before their float32 expm1 (single_precision), below
#: float32's overflow at 88.7; the native FMU's expm1_single does the same (SINGLE_BOUND).
SINGLE_PRECISION_BOUND = 87.0


#: The pair blocks (eq. 6's ``D``, float32 or float64) are computed in chunks of at most this many
#: bytes: fewer numpy calls than one chunk per pair of outputs, and less memory traffic than all
#: at once when that is larger (on the paper's model, 3-4 MB chunks measured fastest in float32
#: and float64 alike), with a bound on the memory of large models.
PAIR_CHUNK_BYTES = 4 * 2**20


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

    Notes
    -----
    GPs of different basis sizes are padded to the largest (zero-weight points): every pair of
    samples then costs the largest size squared, so one exact GP beside sparse ones makes every
    block as large as its own (5.5x slower, measured on 300 points beside three of 20).
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
        distinct, self._rows, self._index, row_counts = [], [], [], []
        for frame in self.frames:
            keep, index = _distinct_samples(frame)
            distinct.append(_frame_samples(frame, keep))
            self._rows.append(keep)
            self._index.append(index)
            row_counts.append(np.bincount(index, minlength=len(keep)).astype(float))
        n_out = len(self.frames)
        self._pairs = {(a, b): _pair_counts(self._index, (a, b))
                       for a in range(n_out) for b in range(a + 1, n_out)}
        # The distinct samples of all GPs stacked as R rows (GP 0's first), every GP padded to the
        # largest basis (its first basis point repeated, of zero weight: it adds exact zeros).
        self._stack = _stack_rows(distinct)
        gp_rows = self._stack.gp_rows
        self._row_of_sample = np.column_stack([rows.start + index for rows, index in zip(gp_rows, self._index)])
        # The blocks Q^ab (eq. 3) a call needs, as P sample pairs (row _pair_rows[0][p], row
        # _pair_rows[1][p]), each counted _pair_counts[p] times: first every row with itself (the
        # blocks Q^aa, so the first R pairs), then the distinct pairs of outputs a < b; the pairs
        # of outputs (a, b) form one segment, starting at _segment_starts, in _segment_outputs.
        segments = [(a, a, np.arange(rows.start, rows.stop), np.arange(rows.start, rows.stop), counts)
                    for a, (rows, counts) in enumerate(zip(gp_rows, row_counts))]
        segments += [(a, b, gp_rows[a].start + rows_a, gp_rows[b].start + rows_b, pair_counts)
                     for (a, b), (rows_a, rows_b, pair_counts) in self._pairs.items()]
        self._segment_outputs = tuple(np.array([s[i] for s in segments], dtype=np.intp) for i in (0, 1))
        self._segment_starts = np.cumsum([0] + [len(s[4]) for s in segments[:-1]])
        self._pair_rows = tuple(np.concatenate([s[i] for s in segments]) for i in (2, 3))  # (P,) each
        self._pair_counts = np.concatenate([s[4] for s in segments])
        # Every precision P whose M(P) (eq. 6) a call needs, as P^1/2 stacked along the last
        # axis, (d, R + P): Lambda^-1 of the R rows, then Lambda_a^-1 + Lambda_b^-1 of the P pairs.
        precision = self._stack.precision
        self._precision_roots = np.sqrt(np.concatenate(
            [precision, precision[self._pair_rows[0]] + precision[self._pair_rows[1]]]).T.copy())

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

    def __call__(self, mean, cov, *, include_noise: bool = True, single_precision: bool = False):
        """Exact mean and covariance of the m GP predictions at ``x ~ N(mean, cov)``.

        Parameters
        ----------
        mean : array_like, shape (d,)
            Input mean, raw input units.
        cov : array_like, shape (d, d)
            Input covariance, squared raw input units; symmetric positive semi-definite.
        include_noise : bool, default True
            Predict noisy observations (add each GP's noise variance) rather than latent values.
        single_precision : bool, default False
            Take the exponents of eq. 6, their ``expm1``, the sums over a block's rows and eq.
            4's ``q^T (K_inv o excess) q`` in float32, everything else in float64 (the
            exponents clamped to +-:data:`SINGLE_PRECISION_BOUND` where float32 would
            overflow): an approximation, about 1.6x faster, for the rate-predictor FMU's fast
            path. Its error grows with the cancellation in eq. 6's sums (GPs of very low noise,
            large weights): within 2 % of the predicted standard deviation along the Bo105
            paper's free runs (measured 3.9e-4), but tens of % or more on GPs of noise variance
            1e-6 (docs/fmus.md, "Free run at simulator speed").

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
        # An input dim of zero variance (a zero row and column of S, as the known regressors of
        # a NARX free run have) gives zero rows and columns of every T and M (eq. 6): the terms
        # with M need only the k uncertain dims.
        uncertain = np.flatnonzero(np.any(S != 0.0, axis=0))
        M, log_det = _woodbury_terms(self._precision_roots[uncertain], S[np.ix_(uncertain, uncertain)])
        n_rows = len(self._stack.beta)
        rows = _single_terms(self._stack, m, uncertain, M[:n_rows], log_det[:n_rows])
        # M_ab and ln|I + T_ab| - ln|I + T_a| - ln|I + T_b| (eq. 6) of the P pairs.
        log_det_change = log_det[n_rows:] - log_det[self._pair_rows[0]] - log_det[self._pair_rows[1]]
        block_bytes = self._stack.beta.shape[1] ** 2 * np.dtype(np.float32 if single_precision else float).itemsize
        cov_pairs = np.concatenate([
            self._pair_covariances(rows, M[n_rows:], log_det_change, chunk, include_noise=include_noise,
                                   single_precision=single_precision)
            for chunk in _chunks(len(log_det_change), block_bytes)])
        cov_sum = np.empty((self.n_outputs, self.n_outputs))  # sum over the samples of C_s
        cov_sum[self._segment_outputs] = np.add.reduceat(self._pair_counts * cov_pairs, self._segment_starts)
        cov_sum[self._segment_outputs[::-1]] = cov_sum[self._segment_outputs]

        mean_s = rows.weights.sum(axis=1)[self._row_of_sample]  # (S, m), eq. 1
        # Eq. 2 summed over the samples: S (S + Lambda_a)^-1 nu_i = M_a u_i, zero in the certain dims.
        row_counts = self._pair_counts[:n_rows]  # the first R pairs are the rows with themselves
        cross_rows = (rows.M @ (rows.u @ rows.weights[:, :, None]))[:, :, 0] * row_counts[:, None]
        cross_sum = np.zeros((self.n_dims, self.n_outputs))
        cross_sum[uncertain] = np.add.reduceat(cross_rows, [rows.start for rows in self._stack.gp_rows]).T

        # Back to raw units (eq. 5 scaled): y = mu_y + s_y f and x = mu_0 + s_0 z; then the
        # mixture over samples (class docstring), centred so that S = 1 adds exact zeros.
        n_samples = self.n_samples
        output_scale = np.array([gp.output_scale for gp in self.frames])
        means = np.array([gp.output_mean for gp in self.frames]) + output_scale * mean_s  # (S, m)
        out_mean = means.mean(axis=0)
        spread = means - out_mean
        out_cov = (cov_sum / n_samples * np.outer(output_scale, output_scale)
                   + spread.T @ spread / n_samples)
        cross_cov = cross_sum / n_samples * self.input_scale[:, None] * output_scale[None, :]
        return out_mean, out_cov, cross_cov

    def _pair_covariances(self, rows: _SingleTerms, M_pairs: np.ndarray, log_det_change: np.ndarray,
                          pairs: slice, *, include_noise: bool, single_precision: bool,
                          clamp: bool = False) -> np.ndarray:
        """``C_s[a, b]`` (eq. 5 without the mixture) of the sample pairs ``pairs`` (a slice of
        the P, with a step of 1), shape (len(pairs),).

        ``M_pairs`` (P, k, k) is eq. 6's ``M_ab`` of all pairs on the uncertain dims, and
        ``log_det_change`` (P,) their ``ln|I + T_ab| - ln|I + T_a| - ln|I + T_b|``;
        ``single_precision`` as :meth:`__call__`. float32's exp overflows above 88.7: where an
        exponent did (a result is not finite), the pairs are computed again with the exponents
        clamped to +-:data:`SINGLE_PRECISION_BOUND` (``clamp``), as the native FMU clamps them. A
        clamp on every call would cost a pass over the blocks, 0.3 ms a step on the paper's model.
        """
        rows_a, rows_b = (r[pairs] for r in self._pair_rows)
        M_ab = M_pairs[pairs]
        n_rows = len(rows.u)  # the first R of the P pairs are the rows with themselves (blocks Q^aa)
        own = slice(pairs.start, max(pairs.start, min(pairs.stop, n_rows)))
        n_own = own.stop - own.start
        u_a, u_b = rows.u[rows_a], rows.u[rows_b[n_own:]]  # (T, k, n), (T - n_own, k, n)
        n_pairs, k, n = u_a.shape
        # Eq. 6 as one matrix product per pair, D = left^T @ right, with z^T M_ab z expanded over
        # z_ij = u_ai + u_bj: column i of left is [M_ab u_ai, h_ai, 1] and column j of right is
        # [u_bj, 1, h_bj], where h_ai = 1/2 u_ai^T (M_ab - M_a) u_ai - 1/2 (ln|I + T_ab| -
        # ln|I + T_a| - ln|I + T_b|) and h_bj = 1/2 u_bj^T (M_ab - M_b) u_bj (h_b = h_a for Q^aa).
        dtype = np.float32 if single_precision else float
        left, right = np.empty((n_pairs, k + 2, n), dtype), np.empty((n_pairs, k + 2, n), dtype)
        M_ab_u_a = M_ab @ u_a
        left[:, :k] = M_ab_u_a
        h_a = 0.5 * (_column_dots(M_ab_u_a, u_a) - rows.uMu[rows_a])
        left[:, k] = h_a - 0.5 * log_det_change[pairs, None]
        left[:, k + 1] = 1.0
        right[:n_own, :k] = rows.u[own]
        right[n_own:, :k] = u_b
        right[:, k] = 1.0
        right[:n_own, k + 1] = h_a[:n_own]
        right[n_own:, k + 1] = 0.5 * (_column_dots(M_ab[n_own:] @ u_b, u_b) - rows.uMu[rows_b[n_own:]])
        excess = np.matmul(left.transpose(0, 2, 1), right)  # D (T, n, n), then in place:
        if clamp:
            np.clip(excess, -SINGLE_PRECISION_BOUND, SINGLE_PRECISION_BOUND, out=excess)
        # Eq. 4 with Q^aa = q q^T o (1 + excess) of eq. 3, so that (K_inv symmetric)
        # tr(K_inv Q^aa) = q^T K_inv q + q^T (K_inv o excess) q; clipped at zero as
        # GaussianProcess.predict clips its variance; eq. 5 adds it and the noise to the diagonal.
        # single_precision: the second term in float32 too, but in float64 once clamped (a
        # clamped exponential times a large K_inv entry can overflow float32).
        stack, q = self._stack, rows.q[own]
        K_inv = stack.K_inv_single[own] if single_precision and not clamp else stack.K_inv[own]
        with np.errstate(over="ignore", invalid="ignore"):  # float32 overflow: retried clamped, below
            np.expm1(excess, out=excess)  # (Q^ab - q_a q_b^T) / (q_a q_b^T), elementwise
            # sum_ij w_ai w_bj excess_ij; single: the sums over i in float32, over j in float64
            weights_a = rows.weights[rows_a].astype(dtype, copy=False)
            cov_t = ((weights_a[:, None, :] @ excess).astype(float, copy=False)
                     @ rows.weights[rows_b][:, :, None])[:, 0, 0]
            own_excess = excess[:n_own]
            excess_K_inv = np.multiply(own_excess, K_inv, out=own_excess if K_inv.dtype == dtype else None)
            trace = (_bilinear_forms(q, stack.K_inv[own], q)
                     + _bilinear_forms(q.astype(excess_K_inv.dtype, copy=False), excess_K_inv, q))
        expected_var = np.exp(stack.log_signal_variance[own]) - trace
        cov_t[:n_own] += np.maximum(expected_var, 0.0) + (stack.noise_variance[own] if include_noise else 0.0)
        # A float32 overflow in the trace would be clipped to zero variance below: retried too.
        if single_precision and not clamp and not (np.isfinite(cov_t).all() and np.isfinite(trace).all()):
            return self._pair_covariances(rows, M_pairs, log_det_change, pairs, include_noise=include_noise,
                                          single_precision=True, clamp=True)
        return cov_t

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


def _chunks(n_pairs: int, bytes_per_pair: int) -> list[slice]:
    """``range(n_pairs)`` in slices of near-equal length, each of at most
    :data:`PAIR_CHUNK_BYTES` (or of one pair, where a pair is larger)."""
    most = max(PAIR_CHUNK_BYTES // bytes_per_pair, 1)
    size = -(-n_pairs // -(-n_pairs // most))  # ceil(n / ceil(n / most)) <= most
    return [slice(start, min(start + size, n_pairs)) for start in range(0, n_pairs, size)]


def _distinct_samples(frame: FrameGP) -> tuple[np.ndarray, np.ndarray]:
    """The rows (T,) of ``frame``'s distinct samples in order of first occurrence, and which of
    them each of its S samples is (S,)."""
    n_samples = len(frame.beta)
    return first_occurrences(np.column_stack([frame.precision, frame.beta, frame.log_signal_variance,
                                              frame.noise_variance, frame.K_inv.reshape(n_samples, -1)]))


def first_occurrences(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of ``rows`` (S, p), told apart by their bytes, in order of first
    occurrence: the index of each one's first row (T,) and which of them each row is (S,).

    A dictionary of the rows' bytes, linear in the array's size: ``np.unique(axis=0)`` sorts rows
    of p fields, 5 s for three single rows of a 530-point GP's 280 000 numbers.
    """
    seen, first = {}, []
    which = np.empty(len(rows), dtype=np.intp)
    for s, row in enumerate(np.ascontiguousarray(rows)):
        which[s] = seen.setdefault(row.tobytes(), len(first))
        if which[s] == len(first):
            first.append(s)
    return np.array(first, dtype=np.intp), which


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


@dataclass(frozen=True)
class _RowStack:
    """The distinct samples of m GPs stacked as R rows, every GP's basis padded to the largest, n
    points: the padding repeats the GP's first basis point with zero weight and zero ``K_inv``
    rows and columns, so that it adds exact zeros to every sum."""

    inputs: np.ndarray  # (m, n, d) basis inputs X_a of each GP
    gp: np.ndarray  # (R,) the GP of each row
    gp_rows: tuple  # (m,) the slice of rows of each GP
    precision: np.ndarray  # (R, d) diagonal of Lambda^-1
    beta: np.ndarray  # (R, n)
    log_signal_variance: np.ndarray  # (R,)
    K_inv: np.ndarray  # (R, n, n)
    K_inv_single: np.ndarray  # (R, n, n) K_inv in float32
    noise_variance: np.ndarray  # (R,)


def _stack_rows(frames: list) -> _RowStack:
    """The :class:`_RowStack` of ``frames`` (each at its distinct samples)."""
    n = max(len(frame.inputs) for frame in frames)
    pads = [n - len(frame.inputs) for frame in frames]
    first_rows = np.cumsum([0] + [len(frame.beta) for frame in frames])
    K_inv = np.concatenate([np.pad(frame.K_inv, ((0, 0), (0, pad), (0, pad))) for frame, pad in zip(frames, pads)])
    return _RowStack(
        inputs=np.stack([np.concatenate([frame.inputs, np.repeat(frame.inputs[:1], pad, axis=0)])
                         for frame, pad in zip(frames, pads)]),
        gp=np.concatenate([np.full(len(frame.beta), a) for a, frame in enumerate(frames)]),
        gp_rows=tuple(slice(start, stop) for start, stop in zip(first_rows[:-1], first_rows[1:])),
        precision=np.concatenate([frame.precision for frame in frames]),
        beta=np.concatenate([np.pad(frame.beta, ((0, 0), (0, pad))) for frame, pad in zip(frames, pads)]),
        log_signal_variance=np.concatenate([frame.log_signal_variance for frame in frames]),
        K_inv=K_inv, K_inv_single=K_inv.astype(np.float32),
        noise_variance=np.concatenate([frame.noise_variance for frame in frames]))


@dataclass(frozen=True)
class _SingleTerms:
    """The GPs' terms at one input distribution, per row of a :class:`_RowStack` (leading axis
    R), on the k uncertain input dims (the ``u`` and ``M`` of the module docstring restricted to
    them)."""

    u: np.ndarray  # (R, k, n) u_ai (eq. 3) as columns
    M: np.ndarray  # (R, k, k) M_a (eq. 6)
    uMu: np.ndarray  # (R, n) u_ai^T M_a u_ai
    q: np.ndarray  # (R, n) q_a (eq. 1)
    weights: np.ndarray  # (R, n) beta_a q_a


def _single_terms(stack: _RowStack, m: np.ndarray, uncertain: np.ndarray, M: np.ndarray,
                  log_det: np.ndarray) -> _SingleTerms:
    """:class:`_SingleTerms` of the rows of ``stack`` at the standardised input mean ``m`` (d,),
    given their ``M`` (R, k, k) and ``ln|I + T_a|`` (R,) on the ``uncertain`` dims (k,)."""
    nu = stack.inputs - m  # (m, n, d)
    u = stack.precision[:, uncertain, None] * nu[:, :, uncertain].transpose(0, 2, 1)[stack.gp]  # (R, k, n)
    uMu = _column_dots(M @ u, u)
    # Eq. 1 in the Woodbury form -1/2 nu^T (S + Lambda)^-1 nu = -1/2 nu^T Lambda^-1 nu + 1/2 u^T M_a u.
    nu_Lambda_nu = np.concatenate([stack.precision[rows] @ (x * x).T for x, rows in zip(nu, stack.gp_rows)])  # (R, n)
    q = np.exp(stack.log_signal_variance[:, None] - 0.5 * log_det[:, None] - 0.5 * nu_Lambda_nu + 0.5 * uMu)
    return _SingleTerms(u=u, M=M, uMu=uMu, q=q, weights=stack.beta * q)


def _column_dots(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Dot products of the columns of ``x`` and ``y`` (T, k, n): shape (T, n). (einsum forms no
    temporary here; numpy sums over a short middle axis slowly.)"""
    return np.einsum("tkn,tkn->tn", x, y)


def _bilinear_forms(x: np.ndarray, A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``x_t^T A_t y_t`` for ``x`` (T, n), ``A`` (T, n, p) and ``y`` (T, p): shape (T,)."""
    return ((x[:, None, :] @ A) @ y[:, :, None])[:, 0, 0]


def _woodbury_terms(precision_root: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``M(P) = (P + S^-1)^-1`` and ``ln|I + T|``, ``T = P^1/2 S P^1/2`` (eq. 6), for N precisions.

    Parameters
    ----------
    precision_root : ndarray, shape (d, N)
        ``P^1/2``: square roots of the positive diagonals of the N precisions ``P``.
    S : ndarray, shape (d, d)
        Symmetric positive semi-definite; may be singular.

    Returns
    -------
    M : ndarray, shape (N, d, d)
        Symmetric; zero when ``S`` is zero.
    log_det : ndarray, shape (N,)
        ``ln|I + T| = ln|S P + I|`` (Sylvester's determinant identity).
    """
    outer = precision_root[:, None, :] * precision_root[None, :, :]  # (d, d, N), as all below
    T = S[:, :, None] * outer
    solution, log_det = _solve_positive_definite(np.eye(len(S))[:, :, None] + T, T)
    M = solution / outer
    return np.ascontiguousarray((0.5 * (M + M.transpose(1, 0, 2))).transpose(2, 0, 1)), log_det


def _solve_positive_definite(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``A^-1 B`` (k, p, N) and ``ln|A|`` (N,) for N symmetric positive definite ``A`` (k, k, N)
    and ``B`` (k, p, N), the N problems stacked along the last axis.

    Gaussian elimination without pivoting, one vectorised step per row for all N problems: stable
    for a symmetric positive definite ``A`` (for ``A = I + T`` of :func:`_woodbury_terms` every
    pivot is >= 1), and for many small matrices far cheaper than numpy.linalg, which calls LAPACK
    once per matrix.
    """
    A, X = A.copy(), B.copy()
    for p in range(len(A)):  # eliminate column p below the diagonal
        factors = A[p + 1:, p, None] / A[p, p]
        A[p + 1:, p:] -= factors * A[p, p:]
        X[p + 1:] -= factors * X[p]
    for p in reversed(range(len(A))):  # back substitution
        X[p] = (X[p] - (A[p, p + 1:, None] * X[p + 1:]).sum(axis=0)) / A[p, p]
    return X, np.log(np.diagonal(A)).sum(axis=1)  # the pivots' product is |A|


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
                     include_noise: bool = True, single_precision: bool = False):
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
    single_precision : bool, default False
        :meth:`MomentMatcher.__call__`'s approximation.

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
    y_mean, y_cov, cross = matcher(x_mean, x_cov, include_noise=include_noise, single_precision=single_precision)
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
    cov_z_y = np.empty((len(z_cov), cross_x_y.shape[1]))
    if len(z_rows) < len(z_cov):  # lags the structure skips: projected (a pseudo-inverse per step)
        x_cov = z_cov[np.ix_(z_rows, z_rows)]
        cov_z_y[:] = z_cov[:, z_rows] @ np.linalg.pinv(x_cov, rcond=1e-10, hermitian=True) @ cross_x_y
    cov_z_y[z_rows] = cross_x_y
    return cov_z_y
