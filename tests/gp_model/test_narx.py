"""GP-NARX: regressors, one-step and free-run prediction, agreement of the propagation methods."""
import copy

import numpy as np
import pytest

from gp_model import (
    GaussianProcess,
    GPNarx,
    HigdonKernel,
    NarxStructure,
    PerOutputGP,
    SparseGaussianProcess,
    SquaredExponentialARD,
)


def test_regressors_of_a_known_sequence():
    structure = NarxStructure(("u",), ("y", "z"), input_lags=(0, 2), output_lags=(1, 3))
    n = 7
    u = 100 + np.arange(n)  # u(k) = 100 + k
    y = np.column_stack([np.arange(n), -np.arange(n)])  # y(k) = k, z(k) = -k
    X, Y = structure.regressors(u[:, None], y)
    assert structure.max_lag == 3
    assert structure.regressor_names == ["u(k)", "u(k-2)", "y(k-1)", "y(k-3)", "z(k-1)", "z(k-3)"]
    k = np.arange(3, n)
    np.testing.assert_array_equal(X, np.column_stack([100 + k, 100 + k - 2, k - 1, k - 3, -(k - 1), -(k - 3)]))
    np.testing.assert_array_equal(Y, np.column_stack([k, -k]))


@pytest.mark.parametrize("kwargs, message", [
    ({"output_lags": (0,)}, "output lags >= 1"),
    ({"input_lags": (-1,)}, "input lags must be >= 0"),
    ({"output_lags": ()}, "at least one output lag"),
])
def test_structure_rejects_bad_lags(kwargs, message):
    with pytest.raises(ValueError, match=message):
        NarxStructure(("u",), ("y",), **kwargs)


def simulate_system(u, *, noise=0.0, seed=0):
    """A weakly non-linear two-output system, y(k) from u(k-1) and y(k-1)."""
    rng = np.random.default_rng(seed)
    y = np.zeros((len(u), 2))
    for k in range(1, len(u)):
        a, b = y[k - 1]
        y[k] = [0.8 * a + 0.3 * np.tanh(u[k - 1]) - 0.1 * b, 0.7 * b + 0.2 * a + 0.1 * a * a]
    return y + noise * rng.standard_normal(y.shape)


def excitation(n, seed):
    rng = np.random.default_rng(seed)
    return np.repeat(rng.uniform(-1.5, 1.5, n // 5 + 1), 5)[:n]


STRUCTURE = NarxStructure(("u",), ("y1", "y2"))


@pytest.fixture(scope="module")
def ml_model():
    """Maximum-likelihood GP-NARX on 300 samples of the test system (point hyperparameters)."""
    u = excitation(300, seed=1)
    y = simulate_system(u, noise=0.01, seed=2)
    return GPNarx.fit(STRUCTURE, [(u[:, None], y)], kernel="squared_exponential_ard",
                      hyperparameters="maximum_likelihood", stride=2, n_restarts=1)


def test_one_step_equals_gp_predictive_mean(ml_model):
    u = excitation(60, seed=3)
    y = simulate_system(u, noise=0.01, seed=4)
    mean, var = ml_model.one_step(u[:, None], y)
    X = np.column_stack([u[:-1], y[:-1]])
    for j, gp in enumerate(ml_model.model.gps):
        m, v = gp.predict(X, return_var=True, include_noise=True)
        np.testing.assert_allclose(mean[:, j], m, rtol=1e-12)
        np.testing.assert_allclose(var[:, j], v, rtol=1e-12)
    # And it predicts: one-step error close to the 0.01 measurement noise.
    assert np.sqrt(np.mean((mean - y[1:]) ** 2)) < 0.02


def test_mean_rollout_iterates_the_predictive_mean(ml_model):
    u = excitation(40, seed=5)
    y0 = np.array([[0.1, -0.05]])
    result = ml_model.free_run(u[:, None], y0, method="mean", use_samples=False)
    history = [y0[0]]
    for k in range(1, len(u)):
        x = np.concatenate([[u[k - 1]], history[-1]])[None]
        history.append([gp.predict(x)[0] for gp in ml_model.model.gps])
    # The batched predictor expands squared distances into products (rounding ~1e-12), and the
    # rollout carries that along 40 steps: 1e-9 absolute is far below any modelling effect.
    np.testing.assert_allclose(result.mean, np.array(history), rtol=0, atol=1e-9)


def test_monte_carlo_with_zero_spread_equals_mean_rollout():
    """With the predictive variance driven to ~0 (dense noise-free data, tiny fixed noise), every
    Monte Carlo run follows the mean rollout."""
    a, b = np.meshgrid(np.linspace(-1.6, 1.6, 15), np.linspace(-1.2, 1.2, 15))
    X = np.column_stack([a.ravel(), b.ravel()])  # regressors [u(k-1), y(k-1)]
    y = 0.8 * X[:, 1] + 0.3 * np.tanh(X[:, 0])
    gp = GaussianProcess(SquaredExponentialARD(1.0, [1.0, 1.0]), noise_variance=1e-10).fit(X, y)
    model = GPNarx(NarxStructure(("u",), ("y",)), PerOutputGP([gp]))
    u = 0.8 * np.sin(np.linspace(0, 6, 50))[:, None]
    mc = model.free_run(u, [[0.2]], method="monte_carlo", n_runs=50, seed=0, include_noise=False)
    mean = model.free_run(u, [[0.2]], method="mean", include_noise=False)
    assert np.sqrt(mc.var.max()) < 1e-3  # the premise: practically no spread
    np.testing.assert_allclose(mc.mean, mean.mean, atol=1e-4)


def test_monte_carlo_and_moment_matching_agree(ml_model):
    u = excitation(30, seed=6)
    y0 = np.array([[0.0, 0.0]])
    n_runs = 20000
    mc = ml_model.free_run(u[:, None], y0, method="monte_carlo", n_runs=n_runs, seed=1,
                           use_samples=False, keep_runs=True)
    mm = ml_model.free_run(u[:, None], y0, method="moment_matching")
    sd = np.sqrt(mc.var[1:])
    # Monte Carlo standard error of the mean is sd/sqrt(R) (~0.7 % of sd); moment matching is
    # exact for one step but keeps only two moments of a slightly non-Gaussian distribution
    # afterwards, so allow 5 standard errors plus 5 % of the spread.
    assert np.all(np.abs(mc.mean[1:] - mm.mean[1:]) <= 5 * sd / np.sqrt(n_runs) + 0.05 * sd)
    # Variances: the same 5 % plus sampling error of a variance (sqrt(2/R) relative, ~1 %).
    np.testing.assert_allclose(mm.var[1:], mc.var[1:], rtol=0.12)
    # The spread grows from the one-step noise level as uncertainty accumulates.
    assert mm.var[-1].min() > mm.var[1].min()


def test_monte_carlo_is_reproducible_from_seed(ml_model):
    u = excitation(20, seed=7)[:, None]
    runs = [ml_model.free_run(u, [[0.0, 0.0]], n_runs=64, seed=s, keep_runs=True).runs for s in (3, 3, 4)]
    np.testing.assert_array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])


@pytest.fixture(scope="module")
def annealed_model():
    """GP-NARX with 64 annealing samples per output on 33 points of the test system."""
    u = excitation(200, seed=8)
    y = simulate_system(u, noise=0.01, seed=9)
    return GPNarx.fit(STRUCTURE, [(u[:, None], y)], stride=6, seed=0, n_samples=64)


def test_annealed_model_draws_hyperparameters_per_run(annealed_model):
    model = annealed_model
    assert all(gp.theta_samples_.shape == (64, 5) for gp in model.model.gps)
    u_test = excitation(40, seed=10)[:, None]
    with_samples = model.free_run(u_test, [[0.0, 0.0]], n_runs=400, seed=0)
    point = model.free_run(u_test, [[0.0, 0.0]], n_runs=400, seed=0, use_samples=False)
    assert not np.allclose(with_samples.mean, point.mean)  # the samples are really used
    y_test = simulate_system(u_test[:, 0])
    assert np.sqrt(np.mean((with_samples.mean - y_test) ** 2)) < 0.05


def monte_carlo_loop(model, inputs, initial, *, n_runs, seed, runs, use_samples=True):
    """The Monte Carlo free run written the obvious way, for the runs ``runs`` only: the same
    random numbers as ``free_run`` (per output a permutation of the runs modulo the number of
    samples, then standard normals of shape (steps, outputs, runs)), and run by run, step by
    step, each output drawn from ``GaussianProcess.predict`` of a copy of its GP set to the
    run's hyperparameter sample."""
    rng = np.random.default_rng(seed)
    gps = model.model.gps
    thetas = [gp.theta_samples_ if use_samples and gp.theta_samples_ is not None else gp.theta_[None]
              for gp in gps]
    assignment = [rng.permutation(n_runs) % len(t) for t in thetas]
    start, n = model.structure.max_lag, len(inputs)
    normals = rng.standard_normal((n - start, len(gps), n_runs))
    sample_gps = [[copy.deepcopy(gp).set_hyperparameters(theta) for theta in t] for gp, t in zip(gps, thetas)]
    s = model.structure
    result = np.zeros((len(runs), n, len(gps)))
    for row, r in enumerate(runs):
        history = result[row]
        history[:start] = initial
        for k in range(start, n):
            x = np.array([[inputs[k - i, c] for c in range(inputs.shape[1]) for i in s.input_lags]
                          + [history[k - j, c] for c in range(len(gps)) for j in s.output_lags]])
            for j in range(len(gps)):
                mean, var = sample_gps[j][assignment[j][r]].predict(x, return_var=True, include_noise=True,
                                                                     use_samples=False)
                history[k, j] = mean[0] + np.sqrt(var[0]) * normals[k - start, j, r]
    return result


# The batched free run expands squared distances into products and sums in another order than
# GaussianProcess.predict; with mean weights of up to ~1e3 that rounding reaches ~1e-11 after 30
# fed-back steps (measured: 1.4e-11). Another sample, draw or regressor would differ by the 0.01
# noise level or more.
AGREEMENT = 1e-9


@pytest.mark.parametrize("n_runs, n_threads", [(150, 1), (150, 2), (150, 3), (40, 2)])
def test_monte_carlo_equals_the_run_by_run_loop(annealed_model, n_runs, n_threads):
    """64 samples: 150 runs give samples 3 or 2 runs each, 40 runs leave samples unused; 3
    threads cut through a sample's runs."""
    u = excitation(30, seed=14)[:, None]
    y0 = [[0.1, -0.1]]
    result = annealed_model.free_run(u, y0, n_runs=n_runs, seed=5, keep_runs=True, n_threads=n_threads)
    runs = [0, 1, n_runs // 2, n_runs - 1]
    loop = monte_carlo_loop(annealed_model, u, y0, n_runs=n_runs, seed=5, runs=runs)
    np.testing.assert_allclose(result.runs[runs], loop, rtol=0, atol=AGREEMENT)


def test_monte_carlo_equals_the_loop_for_mixed_gps():
    """An exact GP with samples next to a sparse GP (its variance factor is not triangular) on
    fewer basis points, and point hyperparameters (every run shares one GP)."""
    u = excitation(200, seed=15)
    y = simulate_system(u, noise=0.01, seed=16)
    X, Y = STRUCTURE.regressors(u[:, None], y)
    exact = GaussianProcess(HigdonKernel(1.0, [0.5, 0.5, 0.5])).fit(X[::5], Y[::5, 0])
    exact.set_hyperparameters(exact.theta_, samples=exact.theta_ + np.random.default_rng(0).normal(0, 0.1, (7, 5)))
    sparse = SparseGaussianProcess(SquaredExponentialARD(1.0, [1.0, 1.0, 1.0]), n_inducing=12).fit(X, Y[:, 1])
    model = GPNarx(STRUCTURE, PerOutputGP([exact, sparse]))
    u_test = excitation(25, seed=17)[:, None]
    for use_samples in (True, False):
        result = model.free_run(u_test, [[0.0, 0.0]], n_runs=30, seed=6, keep_runs=True, n_threads=2,
                                use_samples=use_samples)
        loop = monte_carlo_loop(model, u_test, [[0.0, 0.0]], n_runs=30, seed=6, runs=[0, 7, 29],
                                use_samples=use_samples)
        np.testing.assert_allclose(result.runs[[0, 7, 29]], loop, rtol=0, atol=AGREEMENT)


def test_relevance_finds_the_irrelevant_regressor():
    """y depends on u(k-1) and y(k-1) only; u(k-3) is a decoy regressor."""
    structure = NarxStructure(("u",), ("y1", "y2"), input_lags=(1, 3))
    u = excitation(300, seed=11)
    y = simulate_system(u, noise=0.005, seed=12)
    model = GPNarx.fit(structure, [(u[:, None], y)], kernel="squared_exponential_ard",
                       hyperparameters="maximum_likelihood", stride=2, n_restarts=1)
    relevance = model.relevance()["y1"]
    assert set(relevance) == set(structure.regressor_names)
    assert sum(relevance.values()) == pytest.approx(1.0)
    assert relevance["u(k-3)"] < 0.1 * relevance["u(k-1)"]


def test_free_run_rejects_short_initial_history(ml_model):
    with pytest.raises(ValueError, match="initial_outputs"):
        ml_model.free_run(np.zeros((10, 1)), np.zeros((0, 2)))
    with pytest.raises(ValueError, match="unknown free-run method"):
        ml_model.free_run(np.zeros((10, 1)), np.zeros((1, 2)), method="magic")


def test_monte_carlo_result_does_not_depend_on_the_thread_split(ml_model):
    u = excitation(25, seed=13)[:, None]
    runs = [ml_model.free_run(u, [[0.0, 0.0]], n_runs=101, seed=2, keep_runs=True, n_threads=t).runs
            for t in (1, 2, 3)]
    # Same draws for every split. A split cuts the slots' batched matrix products into other
    # shapes, which BLAS rounds differently in the last bits; the 25-step feedback carries that
    # to ~1e-11 on outputs of ~0.1 (measured).
    np.testing.assert_allclose(runs[0], runs[1], rtol=0, atol=1e-10)
    np.testing.assert_allclose(runs[0], runs[2], rtol=0, atol=1e-10)
    assert np.ptp(runs[0][:, -1], axis=0).min() > 0  # the runs spread by the last step: draws were used


def test_an_error_in_one_thread_stops_the_monte_carlo_run(ml_model):
    """The threads meet after every step: an error in one must end the others, not leave them
    waiting, and it is the error that is raised."""
    def progress(k):
        progress.calls += 1
        if progress.calls == 3:
            raise RuntimeError("stop at step 3")
    progress.calls = 0
    with pytest.raises(RuntimeError, match="stop at step 3"):
        ml_model.free_run(np.zeros((20, 1)), [[0.0, 0.0]], n_runs=50, n_threads=2, progress=progress)
