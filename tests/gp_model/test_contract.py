"""Every GP model kind passes the contract of :mod:`tests.gp_model.contract`: exact and sparse
GPs (one output and several sharing hyperparameters, point hyperparameters and sample
mixtures, both kernels), per-output GPs and grey-box models (shared and per-state GPs)."""
from __future__ import annotations

import numpy as np
import pytest

from gp_model import GaussianProcess, GreyBoxGP, HigdonKernel, PerOutputGP, SparseGaussianProcess, SquaredExponentialARD
from tests.gp_model.cart import CART_PHYSICS, physics, trajectory
from tests.gp_model.contract import GPModelCase, GPModelContract
from tests.gp_model.data import make_data


def prediction_points(seed=7):
    return np.random.default_rng(seed).uniform(-2.5, 2.5, size=(12, 2))


def with_samples(gp, *, seed=1, spread=0.1, n_samples=4):
    """``gp`` mixing a few hyperparameter samples around its point estimate."""
    samples = gp.theta_ + np.random.default_rng(seed).normal(0.0, spread, (n_samples, len(gp.theta_)))
    gp.set_hyperparameters(gp.theta_, samples=samples)
    return gp


def gp_case(gp):
    X = prediction_points()
    return GPModelCase(model=gp, gps=[gp], X=X,
                       predict=lambda model: model.predict(X, return_var=True))


class TestExactSquaredExponential(GPModelContract):
    @pytest.fixture(scope="class")
    @classmethod
    def case(cls):
        X, y = make_data(30)
        return gp_case(GaussianProcess(SquaredExponentialARD(1.3, [0.7, 1.5]), noise_variance=0.05).fit(X, y))


class TestExactHigdonMixtureSharedOutputs(GPModelContract):
    @pytest.fixture(scope="class")
    @classmethod
    def case(cls):
        X, Y = make_data(30, n_outputs=3)
        return gp_case(with_samples(GaussianProcess(HigdonKernel(1.2, [0.3, 0.6]), noise_variance=0.03).fit(X, Y)))


class TestSparseSquaredExponentialMixture(GPModelContract):
    @pytest.fixture(scope="class")
    @classmethod
    def case(cls):
        X, y = make_data(60)
        gp = SparseGaussianProcess(SquaredExponentialARD(1.3, [0.7, 1.5]), n_inducing=12, noise_variance=0.02)
        return gp_case(with_samples(gp.fit(X, y)))


class TestSparseHigdonSharedOutputs(GPModelContract):
    @pytest.fixture(scope="class")
    @classmethod
    def case(cls):
        X, Y = make_data(60, n_outputs=3)
        return gp_case(SparseGaussianProcess(HigdonKernel(1.3, [0.3, 0.7]), n_inducing=10,
                                             noise_variance=0.05).fit(X, Y))


class TestPerOutputExactAndSparse(GPModelContract):
    @pytest.fixture(scope="class")
    @classmethod
    def case(cls):
        X, Y = make_data(40, n_outputs=2)
        factories = iter([lambda: GaussianProcess(SquaredExponentialARD(1.0, [1.0, 1.0])),
                          lambda: SparseGaussianProcess(HigdonKernel(1.0, [0.5, 0.5]), n_inducing=8)])
        model = PerOutputGP.fit(lambda: next(factories)(), X, Y)
        Xs = prediction_points()
        return GPModelCase(model=model, gps=list(model.gps), X=Xs,
                           predict=lambda m: m.predict(Xs, return_var=True))


def greybox_case(*, shared):
    training = [trajectory(60, seed, extra=True) for seed in (3, 4)]
    # Configured hyperparameters (no search): the contract holds at any hyperparameters, and
    # maximum likelihood here drives the noise to its bound, where finite differences of the
    # likelihood are ill-conditioned.
    model = GreyBoxGP(state_columns=[1], shared=shared).fit_trajectories(training, physics, optimize=False)
    states, inputs = trajectory(30, seed=5, extra=True)
    gps = [model.gp_] if shared else list(model.gp_.gps)
    return GPModelCase(
        model=model, gps=gps, X=model.gp_inputs(states, inputs),
        predict=lambda m: (*m.predict_one_step(states, inputs, physics),
                           m.rollout(states[0], inputs[:-1], physics)),
        save_options={"physics": CART_PHYSICS})


class TestGreyBoxShared(GPModelContract):
    @pytest.fixture(scope="class")
    @classmethod
    def case(cls):
        return greybox_case(shared=True)


class TestGreyBoxPerState(GPModelContract):
    @pytest.fixture(scope="class")
    @classmethod
    def case(cls):
        return greybox_case(shared=False)
