"""Sparse GP (Titsias 2009 VFE): the exact GP as a limit, the bound's properties, gradients,
predictive forms, inference, GP-NARX training on every sample, and model files."""

import numpy as np
import pytest

from gp_model import (
    GaussianProcess,
    GPNarx,
    HigdonKernel,
    ModelFileError,
    NarxStructure,
    PerOutputGP,
    SparseGaussianProcess,
    SquaredExponentialARD,
    anneal_hyperparameters,
    load_model,
    maximize_marginal_likelihood,
    read_header,
    save_model,
)
from tests.gp_model.data import make_data, rewrite_header


def finite_difference_gradient(function, theta, step=1e-6):
    return np.array([(function(theta + step * e) - function(theta - step * e)) / (2 * step)
                     for e in np.eye(len(theta))])


# -- the kernel helper ---------------------------------------------------------------------------
def test_cross_gradient_contraction_matches_finite_differences(make_kernel):
    rng = np.random.default_rng(1)
    kernel = make_kernel(3)
    X, Z = rng.normal(size=(20, 3)), rng.normal(size=(7, 3))
    M = rng.normal(size=(20, 7))  # any matrix of K's shape; no symmetry needed
    analytic = kernel.cross_gradient_contraction(X, Z, kernel(X, Z), M)
    numeric = finite_difference_gradient(lambda t: np.sum(M * kernel(X, Z, theta=t)), kernel.theta)
    # Central differences with h = 1e-6 on O(10) sums: accurate to ~1e-8 relative.
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-7)


# -- the exact GP as the limit m = n -------------------------------------------------------------
@pytest.mark.parametrize("n_outputs", [1, 3])
def test_all_training_inputs_as_inducing_inputs_give_the_exact_gp(make_kernel, n_outputs):
    X, y = make_data()
    Y = np.column_stack([y * (j + 1) + j for j in range(n_outputs)]) if n_outputs > 1 else y
    exact = GaussianProcess(make_kernel(2), noise_variance=0.05).fit(X, Y)
    sparse = SparseGaussianProcess(make_kernel(2), n_inducing=len(X) + 5,
                                   noise_variance=0.05).fit(X, Y)
    np.testing.assert_array_equal(sparse.inducing_inputs_, sparse.X_train_)
    assert sparse.jitter_ == 0.0  # else the comparison below would not be of the same model
    theta = exact.theta_ + 0.1
    # Z = X makes Q_nn = K_nn: bound (1) is the exact log likelihood, eqs. (3)-(4) the exact
    # posterior. The two routes round differently (condition number of K ~1e4 here), so agree
    # to ~1e-12 relative; 1e-9 leaves room without hiding any modelling error.
    lml, gradient = exact.log_marginal_likelihood(theta, return_gradient=True)
    bound, bound_gradient = sparse.log_marginal_likelihood(theta, return_gradient=True)
    assert bound == pytest.approx(lml, rel=1e-9)
    np.testing.assert_allclose(bound_gradient, gradient, rtol=1e-7, atol=1e-8)
    Xs = np.random.default_rng(3).uniform(-3, 3, size=(15, 2))
    for options in ({"return_var": True}, {"return_cov": True},
                    {"return_var": True, "include_noise": True}):
        for a, b in zip(exact.predict(Xs, **options), sparse.predict(Xs, **options)):
            np.testing.assert_allclose(b, a, rtol=1e-8, atol=1e-10)


def test_bound_is_below_the_exact_likelihood_and_grows_with_nested_inducing_inputs(make_kernel):
    X, y = make_data()
    exact = GaussianProcess(make_kernel(2), noise_variance=0.05).fit(X, y)
    sizes = [1, 2, 4, 8, 16, 24, 29]
    gps = [SparseGaussianProcess(make_kernel(2), n_inducing=m, noise_variance=0.05).fit(X, y)
           for m in sizes]
    for small, large in zip(gps, gps[1:]):  # nested: the smaller set is a prefix of the larger
        np.testing.assert_array_equal(large.inducing_inputs_[:len(small.inducing_inputs_)],
                                      small.inducing_inputs_)
    bounds = np.array([gp.log_marginal_likelihood() for gp in gps])
    # Titsias 2009, sec. 3: adding an inducing input never lowers the bound, and it never
    # exceeds the exact log likelihood. Both up to rounding, ~1e-12 of |lml|.
    tolerance = 1e-9 * abs(exact.log_marginal_likelihood())
    assert np.all(np.diff(bounds) >= -tolerance)
    assert np.all(bounds <= exact.log_marginal_likelihood() + tolerance)
    assert bounds[0] < exact.log_marginal_likelihood() - 10  # and one point is a poor summary


# -- prediction ----------------------------------------------------------------------------------
# -- inducing-input selection --------------------------------------------------------------------
def test_selection_is_deterministic_for_a_seed():
    X, y = make_data(n=200, d=3)
    def inducing(seed):
        return SparseGaussianProcess(SquaredExponentialARD(1.0, [0.5] * 3), n_inducing=20,
                                     inducing_seed=seed).fit(X, y).inducing_inputs_
    np.testing.assert_array_equal(inducing(7), inducing(7))
    assert not np.array_equal(inducing(7), inducing(8))  # the seed picks the first pivot
    gp = SparseGaussianProcess(SquaredExponentialARD(1.0, [0.5] * 3), n_inducing=20,
                               inducing_seed=7).fit(X, y)
    # Distinct standardised training inputs.
    assert len(np.unique(gp.inducing_inputs_, axis=0)) == 20
    assert all((gp.X_train_ == z).all(axis=1).any() for z in gp.inducing_inputs_)


def test_selection_refines_beyond_a_long_length_scale_and_skips_duplicates():
    x = np.linspace(-3, 3, 400)
    # At length scale 1 (standardised) about a dozen points explain the prior at every input to
    # 1e-10; the selection must still deliver the 40 points asked for.
    gp = SparseGaussianProcess(SquaredExponentialARD(1.0, [1.0]), n_inducing=40).fit(x[:, None], np.sin(x))
    assert len(np.unique(gp.inducing_inputs_)) == 40
    # Only 5 distinct inputs: never the same one twice.
    X = np.repeat(np.arange(5.0), 10)[:, None]
    gp = SparseGaussianProcess(SquaredExponentialARD(1.0, [1.0]), n_inducing=8).fit(X, X[:, 0] ** 2)
    assert sorted(gp.inducing_inputs_[:, 0]) == sorted(np.unique(gp.X_train_[:, 0]))


# -- inference -----------------------------------------------------------------------------------
def test_maximum_likelihood_on_2000_points_recovers_a_smooth_function():
    rng = np.random.default_rng(0)
    noise = 0.1
    X = rng.uniform(-3, 3, size=(2000, 1))
    truth = lambda X: np.sin(2 * X[:, 0]) + 0.5 * np.cos(5 * X[:, 0])  # noqa: E731
    y = truth(X) + noise * rng.standard_normal(len(X))
    gp = SparseGaussianProcess(SquaredExponentialARD(1.0, [1.0]), n_inducing=40).fit(X, y)
    result = maximize_marginal_likelihood(gp)
    Xs = np.linspace(-3, 3, 300)[:, None]
    rmse = np.sqrt(np.mean((gp.predict(Xs) - truth(Xs)) ** 2))
    # The posterior mean averages many noisy samples per length scale: its error against the
    # true function is far below the noise (the exact GP reaches 0.008 on these data).
    assert rmse < 0.2 * noise
    fitted_noise = np.sqrt(gp.noise_variance) * gp.output_scaler_.scale_[0]
    assert fitted_noise == pytest.approx(noise, rel=0.1)  # 2000 residuals: ~2 % standard error
    # 40 well-placed inducing inputs summarise this 1-d function completely: the bound at the
    # optimum is the exact log likelihood there to a small fraction of a nat.
    exact = GaussianProcess(SquaredExponentialARD(1.0, [1.0])).fit(X, y)
    assert result.log_marginal_likelihood == pytest.approx(exact.log_marginal_likelihood(gp.theta_), abs=0.1)


def test_annealing_samples_a_sparse_gp():
    X, y = make_data(n=300, d=2)
    gp = SparseGaussianProcess(HigdonKernel(1.0, [0.5, 0.5]), n_inducing=15).fit(X, y)
    result = anneal_hyperparameters(gp, n_samples=32, n_chains=4, steps_per_stage=10, seed=1)
    assert gp.theta_samples_.shape == (32, 4)
    np.testing.assert_array_equal(gp.theta_, result.map_sample)
    mean, var = gp.predict(X[:20], return_var=True)
    assert np.all(np.isfinite(mean)) and np.all(var > 0)
    assert np.sqrt(np.mean((mean - y[:20]) ** 2)) < 0.15  # noise 0.05 plus model error
    assert len(gp.predictive_forms()) == 32


# -- GP-NARX on every sample ---------------------------------------------------------------------
def simulate(u, *, noise, seed):
    """y(k) = 0.8 y(k-1) + 0.3 tanh(u(k-1)) - 0.1 y(k-1) |y(k-1)|, measured with noise; u (n, 1)."""
    y = np.zeros(len(u))
    for k in range(1, len(u)):
        y[k] = 0.8 * y[k - 1] + 0.3 * np.tanh(u[k - 1, 0]) - 0.1 * y[k - 1] * abs(y[k - 1])
    return (y + noise * np.random.default_rng(seed).standard_normal(len(u)))[:, None]


def excitation(n, seed):
    return np.repeat(np.random.default_rng(seed).uniform(-1.5, 1.5, n // 5 + 1), 5)[:n, None]


@pytest.fixture(scope="module")
def sparse_narx():
    u = excitation(1500, seed=1)
    structure = NarxStructure(("u",), ("y",), input_lags=(1, 2), output_lags=(1,))
    return GPNarx.fit(structure, [(u, simulate(u, noise=0.01, seed=2))], kernel="squared_exponential_ard",
                      hyperparameters="maximum_likelihood", n_inducing=30, n_restarts=1)


def test_narx_with_inducing_inputs_trains_on_every_sample_and_free_runs(sparse_narx):
    gp = sparse_narx.model.gps[0]
    assert isinstance(gp, SparseGaussianProcess)
    assert gp.X_train_.shape == (1498, 3) and gp.inducing_inputs_.shape == (30, 3)
    u = excitation(80, seed=3)
    y_true = simulate(u, noise=0.0, seed=0)
    result = sparse_narx.free_run(u, y_true[:2], method="monte_carlo", n_runs=200, seed=0)
    assert np.all(np.isfinite(result.mean)) and np.all(np.isfinite(result.var))
    # A 3-regressor system learnt from 1500 samples follows the true response to well within
    # its spread (standard deviation ~0.4) over 80 steps.
    assert np.sqrt(np.mean((result.mean - y_true) ** 2)) < 0.03


# -- model files ---------------------------------------------------------------------------------
def test_round_trip_sparse_gp_with_samples(tmp_path):
    X, y = make_data(n=80, d=2)
    gp = SparseGaussianProcess(HigdonKernel(1.2, [0.3, 0.6]), n_inducing=12, inducing_seed=3,
                               noise_variance=0.03).fit(X, y)
    gp.set_hyperparameters(gp.theta_, samples=gp.theta_ + np.random.default_rng(1).normal(0, 0.1, (5, 4)))
    path = save_model(tmp_path / "sparse", gp)
    loaded = load_model(path)
    assert isinstance(loaded, SparseGaussianProcess)
    assert (loaded.n_inducing, loaded.inducing_seed) == (12, 3)
    np.testing.assert_array_equal(loaded.inducing_inputs_, gp.inducing_inputs_)
    assert read_header(path)["parts"][0]["gp_type"] == "sparse_vfe"
    assert loaded.log_marginal_likelihood() == gp.log_marginal_likelihood()  # predictions: the contract


def test_round_trip_per_output_gp_of_exact_and_sparse_parts(tmp_path):
    X, y = make_data(n=60, d=2)
    Y = np.column_stack([y, X[:, 0] * X[:, 1]])
    kernel = SquaredExponentialARD(1.0, [1.0, 1.0])
    model = PerOutputGP([SparseGaussianProcess(kernel, n_inducing=10).fit(X, Y[:, 0]),
                         GaussianProcess(kernel).fit(X, Y[:, 1])])
    path = save_model(tmp_path / "mixed.npz", model)
    assert [p["gp_type"] for p in read_header(path)["parts"]] == ["sparse_vfe", "exact"]
    loaded = load_model(path)
    assert [type(gp) for gp in loaded.gps] == [SparseGaussianProcess, GaussianProcess]


def test_round_trip_sparse_narx_free_runs_identically(tmp_path, sparse_narx):
    loaded = load_model(save_model(tmp_path / "narx.npz", sparse_narx))
    assert isinstance(loaded.model.gps[0], SparseGaussianProcess)
    u = excitation(30, seed=4)
    a = sparse_narx.free_run(u, [[0.0], [0.0]], n_runs=50, seed=1, keep_runs=True)
    b = loaded.free_run(u, [[0.0], [0.0]], n_runs=50, seed=1, keep_runs=True)
    np.testing.assert_array_equal(a.runs, b.runs)


def test_parts_without_gp_type_are_exact_and_unknown_types_are_refused(tmp_path):
    X, y = make_data()
    gp = GaussianProcess(SquaredExponentialARD(1.0, [1.0, 1.0])).fit(X, y)
    path = save_model(tmp_path / "old.npz", gp)
    rewrite_header(path, lambda h: h["parts"][0].pop("gp_type"))  # as written before sparse GPs
    loaded = load_model(path)
    assert type(loaded) is GaussianProcess
    np.testing.assert_array_equal(loaded.predict(X), gp.predict(X))
    rewrite_header(path, lambda h: h["parts"][0].update(gp_type="fitc"))
    with pytest.raises(ModelFileError, match="unknown type 'fitc'.*reads exact, sparse_vfe"):
        load_model(path)
