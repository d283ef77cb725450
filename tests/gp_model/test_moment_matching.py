"""Moment matching at uncertain inputs: limits, Monte Carlo, invariances and argument checks."""
import numpy as np
import pytest

from gp_model import (
    GaussianProcess,
    HigdonKernel,
    PerOutputGP,
    SparseGaussianProcess,
    SquaredExponentialARD,
    alpha_from_length_scale,
    moment_matcher,
    predict_uncertain_input,
)

LENGTH_SCALES = ([0.8, 1.2, 1.5], [1.0, 0.7, 2.0])  # standardised input units, one set per output
SIGNAL_VARIANCES = (1.0, 1.5)
NOISE_VARIANCES = (1e-2, 3e-2)


def targets(X):
    """Two smooth, non-linear outputs of 3-D inputs, shape (n, 2)."""
    return np.column_stack([np.sin(1.5 * X[:, 0]) + 0.3 * X[:, 1] * X[:, 2],
                            np.cos(X[:, 1]) - 0.5 * X[:, 0] ** 2])


def training_inputs(seed=0):
    """Two different training sets, so that the two GPs standardise their inputs differently."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-2, 2, size=(40, 3)), rng.uniform(-1, 3, size=(50, 3)) * [1.0, 2.0, 0.5]


def make_kernel(kind, j):
    if kind == "se_ard":
        return SquaredExponentialARD(SIGNAL_VARIANCES[j], LENGTH_SCALES[j])
    return HigdonKernel(SIGNAL_VARIANCES[j], alpha_from_length_scale(LENGTH_SCALES[j]))


def fit_pair(kind="se_ard", *, input_scale=1.0, input_offset=0.0, output_scale=(1.0, 1.0),
             output_offset=(0.0, 0.0), n_inducing=None):
    """Two single-output GPs, data optionally expressed in other units ``x' = c x + o``; sparse
    (VFE) GPs with ``n_inducing`` inducing inputs if given."""
    gps = []
    for j, X in enumerate(training_inputs()):
        y = targets(X)[:, j] * output_scale[j] + output_offset[j]
        if n_inducing is None:
            gp = GaussianProcess(make_kernel(kind, j), noise_variance=NOISE_VARIANCES[j])
        else:
            gp = SparseGaussianProcess(make_kernel(kind, j), n_inducing=n_inducing,
                                       noise_variance=NOISE_VARIANCES[j])
        gps.append(gp.fit(X * input_scale + input_offset, y))
    return gps


def refit_at(gp, theta):
    """A GP on ``gp``'s training data with hyperparameters ``theta`` only."""
    return GaussianProcess(gp.kernel, noise_variance=gp.noise_variance).fit(
        gp.input_scaler_.inverse_transform(gp.X_train_),
        gp.output_scaler_.inverse_transform(gp.Y_train_)[:, 0], theta=theta)


def assert_moments_match_monte_carlo(x, mu, var, out_mean, out_cov, cross_cov):
    """Analytic moments against Monte Carlo: inputs ``x`` (N, d) and the GP predictions at them,
    ``mu``, ``var`` (N, m). Each moment is the sample mean of a per-sample quantity g with
    standard error std(g) / sqrt(N) (law of total variance: Cov[f] = Cov[mu(x)] + E[var(x)]);
    5 standard errors, so with ~15 compared numbers a false alarm has probability ~1e-5."""
    m = mu.shape[1]
    d_mu, d_x = mu - mu.mean(axis=0), x - x.mean(axis=0)
    per_sample = {
        "mean": (mu, out_mean),
        "cov": (d_mu[:, :, None] * d_mu[:, None, :] + var[:, :, None] * np.eye(m), out_cov),
        "cross_cov": (d_x[:, :, None] * d_mu[:, None, :], cross_cov),
    }
    for name, (g, analytic) in per_sample.items():
        estimate, standard_error = g.mean(axis=0), g.std(axis=0) / np.sqrt(len(g))
        assert np.all(np.abs(analytic - estimate) < 5 * standard_error), (
            name, analytic, estimate, standard_error)


MEAN = np.array([0.3, 0.5, 0.2])
COV = np.array([[0.30, 0.10, -0.05],
                [0.10, 0.45, 0.12],
                [-0.05, 0.12, 0.25]])  # input spread ~0.5-0.7 against length scales ~1


@pytest.mark.parametrize("kind", ["se_ard", "higdon"])
@pytest.mark.parametrize("include_noise", [False, True])
def test_zero_input_covariance_gives_ordinary_prediction(kind, include_noise):
    gps = fit_pair(kind)
    for cov_size in (0.0, 1e-14):
        out_mean, out_cov, cross_cov = predict_uncertain_input(
            gps, MEAN, cov_size * COV, include_noise=include_noise)
        predictions = [gp.predict(MEAN[None], return_var=True, include_noise=include_noise)
                       for gp in gps]
        # Same quantities by another route (q^T K^-1 q against |L^-1 k|^2): rounding only, and the
        # O(cov) terms at cov = 1e-14 x COV are below 1e-13 for outputs and gradients of O(1).
        np.testing.assert_allclose(out_mean, [p[0][0] for p in predictions], rtol=1e-10)
        np.testing.assert_allclose(np.diag(out_cov), [p[1][0] for p in predictions], rtol=1e-10)
        np.testing.assert_allclose(out_cov[0, 1], 0.0, atol=1e-12)
        np.testing.assert_allclose(cross_cov, 0.0, atol=1e-12)
        if cov_size == 0.0:
            # Every term of eq. (6) and of M(P) is an exact zero when S = 0.
            assert out_cov[0, 1] == 0.0 and not cross_cov.any()


def test_small_input_covariance_matches_linearisation():
    # For S = eps^2 C, Cov[x, f] = S J^T + O(eps^4) and Cov[mu_a, mu_b] = J_a S J_b^T + O(eps^4)
    # (odd central moments of a Gaussian vanish), J the Jacobian of the predictive means.
    gps = fit_pair()
    eps = 1e-3
    _, out_cov, cross_cov = predict_uncertain_input(gps, MEAN, eps**2 * COV)
    h = 1e-5  # central differences: truncation ~h^2 = 1e-10, rounding ~1e-16 / h = 1e-11
    J = np.array([[(gp.predict((MEAN + h * e)[None])[0] - gp.predict((MEAN - h * e)[None])[0])
                   / (2 * h) for e in np.eye(3)] for gp in gps])  # (2, 3)
    # Relative error O(eps^2) = 1e-6 times curvature over slope (~10 for these outputs).
    np.testing.assert_allclose(cross_cov, eps**2 * COV @ J.T, rtol=1e-4)
    np.testing.assert_allclose(out_cov[0, 1], eps**2 * J[0] @ COV @ J[1], rtol=1e-4)


@pytest.mark.parametrize("n_inducing", [None, 12], ids=["exact", "sparse"])
def test_agrees_with_monte_carlo(n_inducing):
    # A sparse GP is matched on its own (VFE) predictive distribution, which with 12 of 40-50
    # points differs from the exact GP's; Monte Carlo uses the same sparse predict.
    gps = fit_pair(n_inducing=n_inducing)
    out_mean, out_cov, cross_cov = predict_uncertain_input(gps, MEAN, COV, include_noise=True)

    n_samples = 200_000
    x = np.random.default_rng(42).multivariate_normal(MEAN, COV, size=n_samples)  # (N, 3)
    mu, var = (np.column_stack(columns) for columns in zip(
        *(gp.predict(x, return_var=True, include_noise=True) for gp in gps)))  # (N, 2) each
    assert_moments_match_monte_carlo(x, mu, var, out_mean, out_cov, cross_cov)
    d_mu = mu - mu.mean(axis=0)

    # The test has power: the plug-in variance at the input mean, which ignores the input
    # uncertainty, is many standard errors away from the Monte Carlo variance.
    plug_in = np.array([gp.predict(MEAN[None], return_var=True, include_noise=True)[1][0]
                        for gp in gps])
    g = d_mu**2 + var
    assert np.all(np.abs(plug_in - g.mean(axis=0)) > 50 * g.std(axis=0) / np.sqrt(n_samples))


def test_higdon_and_se_kernels_with_equal_weights_agree():
    se = predict_uncertain_input(fit_pair("se_ard"), MEAN, COV)
    higdon = predict_uncertain_input(fit_pair("higdon"), MEAN, COV)
    for a, b in zip(se, higdon):
        # Weights equal to ~1e-15 after logit/expit; K + sigma_n^2 I (condition ~1e3 here)
        # amplifies that to ~1e-12 in beta: 1e-9 leaves a wide margin for other BLAS builds.
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_results_follow_a_change_of_units():
    c_x, o_x = 10.0, np.array([5.0, -3.0, 100.0])  # x' = 10 x + o_x
    c_y, o_y = np.array([3.0, 0.5]), np.array([-2.0, 40.0])  # y'_a = c_a y_a + o_a
    base = predict_uncertain_input(fit_pair(), MEAN, COV)
    other_units = fit_pair(input_scale=c_x, input_offset=o_x, output_scale=c_y,
                           output_offset=o_y)
    out_mean, out_cov, cross_cov = predict_uncertain_input(other_units, c_x * MEAN + o_x,
                                                           c_x**2 * COV)
    # Standardisation removes the units up to rounding of the scalers (~1e-15), amplified by
    # K + sigma_n^2 I (condition ~1e3 here) to ~1e-12: 1e-9 leaves a wide margin.
    np.testing.assert_allclose(out_mean, c_y * base[0] + o_y, rtol=1e-9)
    np.testing.assert_allclose(out_cov, np.outer(c_y, c_y) * base[1], rtol=1e-9)
    np.testing.assert_allclose(cross_cov, c_x * base[2] * c_y, rtol=1e-9, atol=1e-12)


def test_output_order_does_not_matter():
    # The common frame is that of gps[0]; the two GPs standardise differently, so reversing
    # them changes the frame but must only permute the results.
    gps = fit_pair()
    out_mean, out_cov, cross_cov = predict_uncertain_input(gps, MEAN, COV)
    rev_mean, rev_cov, rev_cross = predict_uncertain_input(gps[::-1], MEAN, COV)
    # Frame changes are affine maps of O(1) numbers: rounding only.
    np.testing.assert_allclose(rev_mean, out_mean[::-1], rtol=1e-12)
    np.testing.assert_allclose(rev_cov, out_cov[::-1, ::-1], rtol=1e-12)
    np.testing.assert_allclose(rev_cross, cross_cov[:, ::-1], rtol=1e-12)


def test_output_and_joint_covariances_are_symmetric_positive_semidefinite():
    cov = 4.0 * COV
    _, out_cov, cross_cov = predict_uncertain_input(fit_pair(), MEAN, cov, include_noise=False)
    assert np.array_equal(out_cov, out_cov.T)
    # The joint covariance of (x, f) is what a free run propagates. Eigenvalues of a PSD matrix
    # are >= 0 up to rounding of order eps * max|entry| (5 x 5 here), far below 1e-12.
    joint = np.block([[cov, cross_cov], [cross_cov.T, out_cov]])
    assert np.linalg.eigvalsh(joint).min() > -1e-12 * np.abs(joint).max()


@pytest.mark.parametrize("mean, cov, message", [
    (MEAN[:2], COV, r"mean must have shape \(3,\)"),
    (MEAN, COV[:2, :2], r"cov must have shape \(3, 3\)"),
    (MEAN, COV + np.triu(np.full((3, 3), 0.01), 1), "not symmetric"),
    (MEAN, np.diag([0.3, -0.1, 0.2]), "not positive semi-definite"),
    (np.array([0.3, np.nan, 0.2]), COV, "NaN or inf"),
])
def test_bad_input_distribution_is_refused(mean, cov, message):
    with pytest.raises(ValueError, match=message):
        predict_uncertain_input(fit_pair(), mean, cov)


def test_bad_gp_lists_are_refused():
    X, _ = training_inputs()
    y = targets(X)
    se = SquaredExponentialARD(1.0, [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="empty"):
        predict_uncertain_input([], MEAN, COV)
    with pytest.raises(ValueError, match="not fitted"):
        predict_uncertain_input([GaussianProcess(se)], MEAN, COV)
    with pytest.raises(ValueError, match="2 outputs"):
        predict_uncertain_input([GaussianProcess(se).fit(X, y)], MEAN, COV)
    two_d = GaussianProcess(SquaredExponentialARD(1.0, [1.0, 1.0])).fit(X[:, :2], y[:, 0])
    with pytest.raises(ValueError, match="input dimension 2"):
        predict_uncertain_input(fit_pair() + [two_d], MEAN, COV)
    with pytest.raises(TypeError, match="pass its .gps"):
        predict_uncertain_input(PerOutputGP(fit_pair()), MEAN, COV)


def test_mixture_over_hyperparameter_samples_agrees_with_monte_carlo():
    """With S hyperparameter samples per GP, sample s of every GP forms model s; the matched
    moments are those of the equal-weight mixture of the S models at the uncertain input."""
    gps = fit_pair()
    shifts = np.array([[0.0, 0.0, 0.0, 0.0, 0.0], [0.4, -0.3, 0.2, 0.1, -0.5], [-0.3, 0.5, -0.4, 0.3, 0.6]])
    for gp in gps:  # three hyperparameter vectors around the fitted one, noise variance included
        gp.set_hyperparameters(gp.theta_, samples=gp.theta_ + shifts)
    matcher = moment_matcher(gps, use_samples=True)
    out_mean, out_cov, cross_cov = matcher(MEAN, COV)

    n_per_model = 100_000
    rng = np.random.default_rng(7)
    x = rng.multivariate_normal(MEAN, COV, size=(len(shifts), n_per_model))  # (S, N, 3)
    mu, var = np.empty((len(shifts), n_per_model, 2)), np.empty((len(shifts), n_per_model, 2))
    for s in range(len(shifts)):
        for j, gp in enumerate(gps):
            mu[s, :, j], var[s, :, j] = refit_at(gp, gp.theta_samples_[s]).predict(
                x[s], return_var=True, include_noise=True)
    mu, var, x = mu.reshape(-1, 2), var.reshape(-1, 2), x.reshape(-1, 3)
    assert_moments_match_monte_carlo(x, mu, var, out_mean, out_cov, cross_cov)
    d_mu = mu - mu.mean(axis=0)
    # Power: the mixture's moments differ from the first model's alone by many standard errors.
    alone = predict_uncertain_input([refit_at(gp, gp.theta_samples_[0]) for gp in gps], MEAN, COV)
    g = d_mu**2 + var
    assert np.any(np.abs(np.diag(alone[1]) - g.mean(axis=0)) > 20 * g.std(axis=0) / np.sqrt(len(g)))


def test_gps_with_different_sample_counts_are_refused():
    gps = fit_pair()
    gps[0].set_hyperparameters(gps[0].theta_, samples=np.vstack([gps[0].theta_] * 2))
    with pytest.raises(ValueError, match="different numbers of hyperparameter samples"):
        moment_matcher(gps, use_samples=True)


def test_repeated_samples_are_computed_once_and_counted_as_often_as_they_occur():
    """Annealing repeats samples; the matcher computes each distinct one once. Its moments must
    be the law of total covariance over the S joint samples, each model matched on its own."""
    gps = fit_pair()
    shifts = np.array([[0.0] * 5, [0.4, -0.3, 0.2, 0.1, -0.5], [0.0] * 5, [-0.3, 0.5, -0.4, 0.3, 0.6]])
    order = ([0, 1, 2, 3, 1, 1], [0, 0, 2, 3, 3, 1])  # output 1 pairs the repeats differently
    for gp, rows in zip(gps, order):
        gp.set_hyperparameters(gp.theta_, samples=gp.theta_ + shifts[rows])
    matcher = moment_matcher(gps, use_samples=True)
    assert [len(rows) for rows, _ in matcher.distinct_samples()] == [3, 3]  # shifts 0 and 2 are equal
    assert len(matcher.sample_pairs()[0, 1][0]) == 5  # of 6 joint pairs, one occurs twice
    out_mean, out_cov, cross_cov = matcher(MEAN, COV)

    models = [predict_uncertain_input([refit_at(gp, gp.theta_samples_[s]) for gp in gps], MEAN, COV)
              for s in range(len(order[0]))]
    means = np.array([m for m, _, _ in models])
    expected_cov = np.mean([c for _, c, _ in models], axis=0) + np.cov(means.T, bias=True)
    np.testing.assert_allclose(out_mean, means.mean(axis=0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(out_cov, expected_cov, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cross_cov, np.mean([x for _, _, x in models], axis=0), rtol=0, atol=1e-12)


def textbook_moments(matcher, mean, cov, include_noise=True):
    """Eqs. (1)-(5) of gp_model.uncertain_input as printed, for GPs with one hyperparameter
    vector: explicit inverses and determinants of d x d matrices over all input dims, no Woodbury
    forms and no expm1, so an independent route to the matcher's moments."""
    scale = matcher.input_scale
    m, S = (mean - matcher.input_mean) / scale, cov / np.outer(scale, scale)
    eye = np.eye(len(m))
    gps, n_out = matcher.frames, len(matcher.frames)
    nu = [gp.inputs - m for gp in gps]  # (n_a, d)
    u = [n * gp.precision[0] for gp, n in zip(gps, nu)]  # Lambda_a^-1 nu_ai
    s2 = [np.exp(gp.log_signal_variance[0]) for gp in gps]
    k = [s * np.exp(-0.5 * (n * v).sum(axis=1)) for s, n, v in zip(s2, nu, u)]  # k_a(X_ai, m)
    q, out_mean, cross = [], np.empty(n_out), np.empty((len(m), n_out))
    for a, gp in enumerate(gps):
        inverse = np.linalg.inv(S + np.diag(1.0 / gp.precision[0]))
        q.append(s2[a] / np.sqrt(np.linalg.det(S * gp.precision[0] + eye))
                 * np.exp(-0.5 * np.einsum("id,de,ie->i", nu[a], inverse, nu[a])))  # (1)
        out_mean[a] = gp.beta[0] @ q[a]
        cross[:, a] = S @ inverse @ ((gp.beta[0] * q[a]) @ nu[a])  # (2)
    out_cov = np.empty((n_out, n_out))
    for a in range(n_out):
        for b in range(n_out):
            R = S * (gps[a].precision[0] + gps[b].precision[0]) + eye
            z = u[a][:, None, :] + u[b][None, :, :]
            Q = (np.outer(k[a], k[b]) / np.sqrt(np.linalg.det(R))
                 * np.exp(0.5 * np.einsum("ijd,de,ije->ij", z, np.linalg.solve(R, S), z)))  # (3)
            out_cov[a, b] = gps[a].beta[0] @ Q @ gps[b].beta[0] - out_mean[a] * out_mean[b]
            if a == b:  # (4) and (5)
                out_cov[a, a] += (max(s2[a] - np.sum(gps[a].K_inv[0] * Q), 0.0)
                                  + (gps[a].noise_variance[0] if include_noise else 0.0))
    output_mean = np.array([gp.output_mean for gp in gps])
    output_scale = np.array([gp.output_scale for gp in gps])
    return (output_mean + output_scale * out_mean, np.outer(output_scale, output_scale) * out_cov,
            scale[:, None] * cross * output_scale)


@pytest.mark.parametrize("known", [(), (1,), (0, 2)], ids=["none", "one", "two"])
def test_inputs_known_exactly_give_the_textbook_moments(known):
    """An input known exactly (a zero row and column of the covariance, as the exogenous
    regressors of a NARX free run) is left out of the Woodbury terms (M_a = 0 there): the moments
    must still be those of eqs. (1)-(5) over all input dims, computed the textbook way. The two
    GPs have 40 and 50 training points, so the matcher pads the first with zero-weight points."""
    cov = COV.copy()
    cov[known, :] = cov[:, known] = 0.0
    matcher = moment_matcher(fit_pair())
    # The textbook route subtracts E[mu_a] E[mu_b] from E[mu_a mu_b] and forms (S + Lambda)^-1
    # explicitly; with K + sigma_n^2 I of condition ~1e3 the two routes agree to ~2e-13 relative
    # here: 1e-9 leaves a wide margin for other BLAS builds. The certain dims of cross_cov are
    # exact zeros in both.
    for got, expected in zip(matcher(MEAN, cov), textbook_moments(matcher, MEAN, cov)):
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=0)


def test_single_precision_stays_within_2_percent_of_the_predicted_sd():
    """single_precision takes eq. 6's exponents and expm1 in float32 (the FMUs' fast path): an
    approximation held to 2 % of the predicted standard deviation (the fast path's tolerance,
    docs/fmus.md; in a free run the means then move too, through the fed-back covariance); it must
    differ from the exact covariance at all, and the means and cross-covariances (eqs. 1-2, no
    pair terms) are the exact ones."""
    matcher = moment_matcher(fit_pair())
    (mean, cov, cross), (fast_mean, fast_cov, fast_cross) = (matcher(MEAN, COV, single_precision=s)
                                                            for s in (False, True))
    sd, fast_sd = np.sqrt(np.diag(cov)), np.sqrt(np.diag(fast_cov))
    assert np.max(np.abs(fast_sd - sd) / sd) <= 0.02 and np.max(np.abs(fast_cov - cov)) > 0.0
    np.testing.assert_array_equal(fast_mean, mean)
    np.testing.assert_array_equal(fast_cross, cross)


def test_single_precision_stays_finite_where_exponents_exceed_float32():
    """Just outside the data of a GP with a short length scale, eq. 6's exponents exceed float32's
    exp range (88.7): single_precision clamps them (at 87, as the native FMU) and stays finite and
    within 2 % of the exact sd, where an unclamped float32 expm1 gave inf and then NaN."""
    x = np.random.default_rng(0).uniform(-2.0, 2.0, (40, 1))
    gp = GaussianProcess(SquaredExponentialARD(1.0, [0.15]), noise_variance=1e-2).fit(x, np.sin(3.0 * x[:, 0]))
    matcher = moment_matcher([gp])
    for mean in (2.5, 3.0):
        exact, fast = (matcher(np.array([mean]), np.array([[0.01]]), single_precision=s)[1][0, 0]
                       for s in (False, True))
        assert np.isfinite(fast) and abs(np.sqrt(fast) - np.sqrt(exact)) <= 0.02 * np.sqrt(exact)


def test_single_precision_retries_a_trace_that_overflows_float32():
    """Far from the data (here 55 length scales) eq. 4's float32 product K_inv o (Q / q q^T - 1)
    can overflow where the pair sums stay finite; clipped at zero, that trace would leave only the
    noise variance (4e-6 where the exact variance is 0.015). single_precision must compute such
    blocks again clamped, with the product in float64, and stay within 2 % of the exact sd."""
    x = np.array([[-3.673274601972766], [-6.018362590405937]])
    gp = GaussianProcess(SquaredExponentialARD(1.0, [3.039103459016252]),
                         noise_variance=2.715924146370525e-4).fit(x, np.sin(x[:, 0]))
    matcher = moment_matcher([gp])
    exact, fast = (matcher(np.array([166.1282968292834]), np.array([[150.73641298017375]]),
                           single_precision=s)[1][0, 0] for s in (False, True))
    assert exact > 0.01 and abs(np.sqrt(fast) - np.sqrt(exact)) <= 0.02 * np.sqrt(exact)
