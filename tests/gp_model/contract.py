"""The contract every GP model of gp_model passes: exact, sparse and grey-box alike.

Written once against :class:`GPModelCase` (the way GPyTorch writes its base test cases): a test
module subclasses :class:`GPModelContract` and supplies only a ``case`` fixture. What every
model must satisfy:

- the log marginal likelihood (the variational bound for a sparse GP) and its analytic gradient
  agree with central finite differences, for every GP inside the model;
- every :class:`~gp_model.PredictiveForm` (one per hyperparameter sample) reproduces the GP's own
  prediction, and the mixture mean is the average of the forms' means;
- the predictive variance is the diagonal of the predictive covariance, latent and noisy;
- a model written with :func:`~gp_model.save_model` and read back with
  :func:`~gp_model.load_model` predicts identically (not merely closely: the file holds the
  exact arrays and the factorisation is recomputed by the same code).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pytest

from gp_model import GaussianProcess, load_model, save_model

#: Central-difference step for likelihood gradients, in the unconstrained hyperparameters.
FD_STEP = 1e-6


@dataclass
class GPModelCase:
    """One fitted model and how to exercise it.

    Attributes
    ----------
    model : object
        The fitted model (GaussianProcess, SparseGaussianProcess, PerOutputGP, GreyBoxGP).
    gps : list
        The GPs inside it (each with ``log_marginal_likelihood``, ``predictive_forms``,
        ``predict``, ``theta_``, ``kernel`` and the scalers).
    X : ndarray, shape (n, d)
        Raw GP inputs at which the GPs are compared.
    predict : callable
        ``predict(model) -> tuple of ndarrays``: the model's own prediction at the case's test
        points (e.g. ``GreyBoxGP.predict_one_step`` with its physics), compared after a round
        trip through a model file.
    save_options : dict
        Keyword arguments of :func:`~gp_model.save_model` (a grey-box model needs ``physics``).
    """

    model: object
    gps: list
    X: np.ndarray
    predict: Callable
    save_options: dict = field(default_factory=dict)


def _form_prediction(gp, form, X):
    """Mean (n, q) and latent variance (n, 1) in output units from one predictive form."""
    Z = gp.input_scaler_.transform(X)
    k = gp.kernel(Z, form.basis, theta=form.theta[:-1])
    mean = (k @ form.weights).reshape(len(X), -1)
    latent = np.exp(form.theta[0]) - np.sum((k @ form.variance_factor.T) ** 2, axis=1)
    scale = gp.output_scaler_.scale_
    return mean * scale + gp.output_scaler_.mean_, latent[:, None] * scale**2


def _as_columns(array, n):
    return np.asarray(array).reshape(n, -1)


class GPModelContract:
    """Generic checks; subclasses provide a class-scoped ``case`` fixture (a :class:`GPModelCase`)."""

    def test_likelihood_gradient_matches_finite_differences(self, case):
        for gp in case.gps:
            theta = gp.theta_ + 0.1  # away from any stationary point
            value, gradient = gp.log_marginal_likelihood(theta, return_gradient=True)
            assert value == pytest.approx(gp.log_marginal_likelihood(theta), rel=1e-12)
            numeric = np.array([(gp.log_marginal_likelihood(theta + FD_STEP * e)
                                 - gp.log_marginal_likelihood(theta - FD_STEP * e)) / (2 * FD_STEP)
                                for e in np.eye(len(theta))])
            # Central differences: truncation O(h^2) ~ 1e-12, rounding O(eps |value| / h) ~ 1e-7
            # for likelihoods of a few hundred nats.
            np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-5)

    def test_predictive_forms_reproduce_the_prediction(self, case):
        for gp in case.gps:
            (point,) = gp.predictive_forms(use_samples=False)
            mean, latent = _form_prediction(gp, point, case.X)
            expected_mean, expected_var = gp.predict(case.X, return_var=True, use_samples=False)
            n = len(case.X)
            # The same arithmetic in another order: rounding only.
            np.testing.assert_allclose(mean, _as_columns(expected_mean, n), rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(np.broadcast_to(latent, mean.shape), _as_columns(expected_var, n),
                                       rtol=1e-8, atol=1e-12)
            forms = gp.predictive_forms()
            mixture = np.mean([_form_prediction(gp, form, case.X)[0] for form in forms], axis=0)
            np.testing.assert_allclose(mixture, _as_columns(gp.predict(case.X), n), rtol=1e-10, atol=1e-12)

    def test_variance_is_the_covariance_diagonal(self, case):
        for gp in case.gps:
            for include_noise in (False, True):
                mean_v, var = gp.predict(case.X, return_var=True, include_noise=include_noise)
                mean_c, cov = gp.predict(case.X, return_cov=True, include_noise=include_noise)
                np.testing.assert_allclose(mean_v, mean_c, rtol=1e-14)
                diagonal = np.diagonal(cov).T if cov.ndim == 3 else np.diag(cov)
                np.testing.assert_allclose(var, diagonal.reshape(var.shape), rtol=1e-9, atol=1e-15)
                assert np.all(var >= 0)

    def test_noise_adds_the_noise_variance(self, case):
        for gp in case.gps:
            latent = gp.predict(case.X, return_var=True, use_samples=False)[1]
            noisy = gp.predict(case.X, return_var=True, include_noise=True, use_samples=False)[1]
            noise = gp.noise_variance * gp.output_scaler_.scale_**2
            np.testing.assert_allclose(_as_columns(noisy - latent, len(case.X)),
                                       np.broadcast_to(noise, _as_columns(latent, len(case.X)).shape),
                                       rtol=1e-9)

    def test_model_file_round_trip_predicts_identically(self, case, tmp_path):
        path = save_model(tmp_path / "model", case.model, **case.save_options)
        loaded = load_model(path)
        assert type(loaded) is type(case.model)
        for before, after in zip(case.predict(case.model), case.predict(loaded), strict=True):
            np.testing.assert_array_equal(before, after)


def exact_gp_in(model):
    """Whether ``model`` is an exact GP (the covariance test needs ``return_cov``)."""
    return isinstance(model, GaussianProcess)
