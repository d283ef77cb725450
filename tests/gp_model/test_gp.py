"""Exact GP regression: properties, gradients, and agreement with scikit-learn."""
import logging

import numpy as np
import pytest

from gp_model import GaussianProcess, GPNumericalError, HigdonKernel, PerOutputGP, SquaredExponentialARD
from tests.gp_model.data import make_data


def test_interpolates_training_points_with_tiny_noise(make_kernel):
    X, y = make_data(noise=0.0)
    gp = GaussianProcess(make_kernel(2), noise_variance=1e-10).fit(X, y)
    mean, var = gp.predict(X, return_var=True)
    # With sigma_n^2 = 1e-10 (standardised) the posterior mean reproduces the data to ~1e-4 of
    # the output spread and the latent variance collapses to roughly the noise level.
    np.testing.assert_allclose(mean, y, atol=1e-4 * y.std())
    assert var.max() < 1e-6 * y.var()


def test_matches_scikit_learn_for_the_same_fixed_kernel():
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel

    X, y = make_data(n=40, d=3)
    lengths, signal, noise = np.array([0.8, 1.3, 2.1]), 1.9, 0.02
    ours = GaussianProcess(SquaredExponentialARD(signal, lengths), noise_variance=noise,
                           normalize_inputs=False, normalize_outputs=True).fit(X, y)
    theirs = GaussianProcessRegressor(ConstantKernel(signal, "fixed") * RBF(lengths, "fixed"),
                                      alpha=noise, optimizer=None, normalize_y=True).fit(X, y)
    Xs = np.random.default_rng(4).uniform(-2.5, 2.5, size=(50, 3))
    mean, var = ours.predict(Xs, return_var=True)
    mean_sk, std_sk = theirs.predict(Xs, return_std=True)
    # Same algorithm (R&W Alg. 2.1) in float64: differences are rounding, ~1e-12 relative.
    np.testing.assert_allclose(mean, mean_sk, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.sqrt(var), std_sk, rtol=1e-7, atol=1e-10)
    # sklearn's normalize_y likelihood is that of the standardised targets, as ours.
    assert ours.log_marginal_likelihood() == pytest.approx(theirs.log_marginal_likelihood_value_, rel=1e-10)


def test_concentrated_likelihood_is_the_likelihood_at_its_best_signal_variance(make_kernel):
    X, Y = make_data(n=40, n_outputs=2)
    gp = GaussianProcess(make_kernel(2), noise_variance=0.05).fit(X, Y)
    x = np.append(gp.theta_[1:-1], gp.theta_[-1] - gp.theta_[0]) + 0.2  # [kernel scales, ln r]
    lml, gradient, theta = gp.concentrated_log_marginal_likelihood(x)
    np.testing.assert_allclose(theta[1:-1], x[:-1])
    assert theta[-1] - theta[0] == pytest.approx(x[-1], rel=1e-12)  # the noise-to-signal ratio kept
    assert gp.log_marginal_likelihood(theta) == pytest.approx(lml, rel=1e-12)
    # Scaling signal and noise variance together (the ratio fixed) only lowers the likelihood.
    for shift in (-0.05, 0.05):
        assert gp.log_marginal_likelihood(theta + shift * np.eye(len(theta))[[0, -1]].sum(0)) < lml
    step = 1e-6
    numeric = [(gp.concentrated_log_marginal_likelihood(x + step * e)[0]
                - gp.concentrated_log_marginal_likelihood(x - step * e)[0]) / (2 * step) for e in np.eye(len(x))]
    # Central differences, as the contract's likelihood-gradient test: rounding ~1e-7 here.
    np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("length_scale", [1.0, 50.0])
def test_duplicate_and_ill_conditioned_inputs_escalate_jitter_and_log(caplog, length_scale):
    X, y = make_data(n=20)
    X = np.vstack([X, X[:5], X[:5]])
    y = np.concatenate([y, y[:5] + 0.01, y[:5] - 0.01])  # duplicates with conflicting outputs
    with caplog.at_level(logging.WARNING, logger="gp_model._linalg"):
        # Length scale 50 on inputs spanning 4 units makes K nearly all ones (rank ~1).
        gp = GaussianProcess(SquaredExponentialARD(1.0, [length_scale] * 2), noise_variance=1e-300,
                             normalize_inputs=False).fit(X, y)
    assert gp.jitter_ > 0
    assert "jitter" in caplog.text
    mean, var = gp.predict(X, return_var=True)
    assert np.isfinite(mean).all() and np.isfinite(var).all()


def test_hopeless_matrix_raises_clear_error_and_leaves_the_gp_as_it_was():
    # A kernel matrix with non-finite entries (here an infinite signal variance) cannot be
    # rescued by jitter.
    gp = GaussianProcess(SquaredExponentialARD(1.0, [1.0]), noise_variance=1e-2)
    X = np.zeros((3, 1))
    gp.fit(X, np.ones(3))  # constant inputs are fine: noise keeps K + s I positive definite
    theta, mean = gp.theta_, gp.predict(X)
    hopeless = np.array([np.inf, 0.0, 0.0])
    with pytest.raises(GPNumericalError, match="non-finite"):
        gp.set_hyperparameters(hopeless)
    np.testing.assert_array_equal(gp.theta, theta)  # the configured kernel and noise too
    np.testing.assert_array_equal(gp.theta_, theta)
    np.testing.assert_array_equal(gp.predict(X), mean)
    # Optimisers probe such points: the likelihood there is -inf, not an error.
    assert gp.log_marginal_likelihood(hopeless) == -np.inf


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_training_data_rejected(bad):
    X, y = make_data()
    y[3] = bad
    with pytest.raises(ValueError, match="NaN or inf"):
        GaussianProcess(SquaredExponentialARD(1.0, [1.0, 1.0])).fit(X, y)


def test_shape_mismatch_rejected():
    X, y = make_data()
    with pytest.raises(ValueError, match="shape"):
        GaussianProcess(SquaredExponentialARD(1.0, [1.0, 1.0, 1.0])).fit(X, y)


def test_shared_hyperparameters_equal_separate_gps_with_same_theta():
    X, y = make_data()
    Y = np.column_stack([y, np.cos(X[:, 1])])
    kernel = SquaredExponentialARD(1.0, [0.9, 1.1])
    shared = GaussianProcess(kernel, noise_variance=0.01).fit(X, Y)
    Xs = make_data(n=10, seed=9)[0]
    mean, var = shared.predict(Xs, return_var=True)
    for j in range(2):
        single = GaussianProcess(kernel, noise_variance=0.01).fit(X, Y[:, j])
        m, v = single.predict(Xs, return_var=True)
        np.testing.assert_allclose(mean[:, j], m, rtol=1e-10)
        np.testing.assert_allclose(var[:, j], v, rtol=1e-10)
    # The joint likelihood is the sum of the per-output likelihoods.
    total = sum(GaussianProcess(kernel, noise_variance=0.01).fit(X, Y[:, j]).log_marginal_likelihood()
                for j in range(2))
    assert shared.log_marginal_likelihood() == pytest.approx(total, rel=1e-12)


def test_per_output_gp_stacks_independent_models():
    X, y = make_data()
    Y = np.column_stack([y, 2 * y])
    model = PerOutputGP.fit(lambda: GaussianProcess(SquaredExponentialARD(1.0, [1.0, 1.0])), X, Y)
    mean, var = model.predict(X[:4], return_var=True)
    assert mean.shape == var.shape == (4, 2)
    # Standardisation makes the second model an exact scaled copy of the first.
    np.testing.assert_allclose(mean[:, 1], 2 * mean[:, 0], rtol=1e-10)
    np.testing.assert_allclose(var[:, 1], 4 * var[:, 0], rtol=1e-10)


def test_per_output_gp_evaluates_its_models_together_as_one_at_a_time(monkeypatch):
    X, y = make_data()
    Y = np.column_stack([y, np.sin(3 * X[:, 0]), X[:, 1] ** 2])
    kernels = iter([SquaredExponentialARD(1.0, [1.0, 1.0]), HigdonKernel(1.0, [0.5, 0.3]),
                    SquaredExponentialARD(1.0, [0.5, 2.0])])
    model = PerOutputGP.fit(lambda: GaussianProcess(next(kernels), noise_variance=0.01), X, Y)
    Xs = make_data(n=7, seed=3)[0]
    with monkeypatch.context() as patch:  # the stacked path does not call the models one by one
        patch.setattr(GaussianProcess, "predict", lambda *a, **k: pytest.fail("one model at a time"))
        mean, var = model.predict(Xs, return_var=True, include_noise=True)
        np.testing.assert_allclose(model.predict(Xs), mean, rtol=1e-12)
    for j, gp in enumerate(model.gps):
        m, v = gp.predict(Xs, return_var=True, include_noise=True)
        np.testing.assert_allclose(mean[:, j], m, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(var[:, j], v, rtol=1e-9)
    # With hyperparameter samples in use, one model at a time (the mixture of each).
    gp = model.gps[0]
    gp.set_hyperparameters(gp.theta_, samples=np.array([gp.theta_, gp.theta_ + 0.2]))
    np.testing.assert_allclose(model.predict(Xs, return_var=True)[1][:, 0], gp.predict(Xs, return_var=True)[1])


def test_mixture_over_samples_obeys_law_of_total_variance():
    X, y = make_data()
    gp = GaussianProcess(SquaredExponentialARD(1.0, [1.0, 1.0]), noise_variance=0.01).fit(X, y)
    Xs = make_data(n=8, seed=5)[0]
    samples = np.array([gp.theta_, gp.theta_ + [0.3, -0.4, 0.2, 0.5]])
    parts = []
    for theta in samples:
        parts.append(GaussianProcess(SquaredExponentialARD(1.0, [1.0, 1.0])).fit(X, y, theta=theta)
                     .predict(Xs, return_var=True))
    gp.set_hyperparameters(gp.theta_, samples=samples)
    mean, var = gp.predict(Xs, return_var=True)
    means = np.array([p[0] for p in parts])
    variances = np.array([p[1] for p in parts])
    np.testing.assert_allclose(mean, means.mean(0), rtol=1e-12)
    np.testing.assert_allclose(var, variances.mean(0) + means.var(0), rtol=1e-9)
    # Disagreement between samples can only widen the bounds.
    assert np.all(var >= variances.mean(0) - 1e-15)
    point_mean = gp.predict(Xs, use_samples=False)
    np.testing.assert_allclose(point_mean, parts[0][0], rtol=1e-12)


