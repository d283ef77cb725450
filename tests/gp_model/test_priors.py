"""Priors on unconstrained hyperparameters."""
import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import expit

from gp_model import HigdonKernel
from gp_model._priors import LogitBeta


@pytest.mark.parametrize("a, b", [(1.0, 0.1), (2.0, 3.0)])
def test_logit_beta_is_the_change_of_variables_of_beta(a, b):
    prior = LogitBeta(a, b)
    z = np.linspace(-8, 8, 9)
    alpha = expit(z)
    # p_z(z) = p_alpha(alpha) |d alpha / dz| = Beta_pdf(alpha) alpha (1 - alpha)
    expected = stats.beta(a, b).logpdf(alpha) + np.log(alpha * (1 - alpha))
    np.testing.assert_allclose(prior.logpdf(z), expected, rtol=1e-10)
    total, _ = integrate.quad(lambda t: np.exp(prior.logpdf(t)), -60, 400, limit=400)
    assert total == pytest.approx(1.0, abs=1e-6)


def test_logit_beta_samples_have_the_beta_mean():
    draws = LogitBeta(1.0, 0.1).rvs(20000, np.random.default_rng(0))
    # E[alpha] = a / (a + b) = 0.909; standard error of the mean ~0.002.
    assert expit(draws).mean() == pytest.approx(1.0 / 1.1, abs=0.01)


def test_higdon_prior_favours_irrelevant_inputs():
    prior = HigdonKernel(1.0, [0.5, 0.5]).prior()
    draws = prior.sample(4000, np.random.default_rng(1))
    # Beta(1, 0.1) puts about 79 % of its mass above alpha = 0.9 (exact value from scipy);
    # 4000 draws estimate it to within ~0.007 (one standard error).
    p_high = 1 - stats.beta(1.0, 0.1).cdf(0.9)
    assert np.mean(expit(draws[:, 1]) > 0.9) == pytest.approx(p_high, abs=0.03)
    assert p_high > 0.75
