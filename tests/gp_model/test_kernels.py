"""Contract tests every kernel passes, plus each kernel's own definition."""
import numpy as np
import pytest

from gp_model import HigdonKernel, SquaredExponentialARD, alpha_from_length_scale, length_scale_from_alpha

KERNEL_FACTORIES = {
    "se_ard": lambda: SquaredExponentialARD(1.7, [0.6, 1.4, 2.5]),
    "higdon": lambda: HigdonKernel(0.8, [0.2, 0.55, 0.9]),
}


@pytest.fixture(params=sorted(KERNEL_FACTORIES))
def kernel(request):
    return KERNEL_FACTORIES[request.param]()


@pytest.fixture
def X():
    return np.random.default_rng(1).normal(size=(25, 3))


# -- contract ---------------------------------------------------------------------------------
def test_matrix_is_symmetric_positive_semidefinite(kernel, X):
    K = kernel(X)
    np.testing.assert_allclose(K, K.T, atol=0)
    # Eigenvalues of a PSD matrix are >= 0 up to rounding of order n * eps * max|K|.
    assert np.linalg.eigvalsh(K).min() > -1e-12 * len(X) * np.abs(K).max()


def test_diag_equals_matrix_diagonal(kernel, X):
    np.testing.assert_allclose(kernel.diag(X), np.diag(kernel(X)), rtol=1e-14)


def test_cross_matrix_matches_square_matrix_blocks(kernel, X):
    np.testing.assert_allclose(kernel(X[:10], X[10:]), kernel(X)[:10, 10:], rtol=1e-12)


def test_gradient_contraction_matches_finite_differences(kernel, X):
    rng = np.random.default_rng(2)
    M = rng.normal(size=(len(X), len(X)))  # any M: the likelihood passes a triangle of K^-1
    analytic = kernel.gradient_contraction(X, kernel(X), M)
    step = 1e-6
    numeric = np.empty_like(analytic)
    for j in range(len(kernel.theta)):
        up, down = kernel.theta.copy(), kernel.theta.copy()
        up[j] += step
        down[j] -= step
        numeric[j] = (np.sum(M * kernel(X, theta=up)) - np.sum(M * kernel(X, theta=down))) / (2 * step)
    # Central differences with h = 1e-6 are accurate to ~1e-8 relative on these O(10) sums.
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-7)


def test_low_rank_contraction_equals_the_contraction_with_the_full_matrix(kernel, X):
    A = np.random.default_rng(3).normal(size=(len(X), 2))
    K = kernel(X)
    # Eq. (4) is eq. (3) with M = A A^T rearranged: equal to rounding.
    np.testing.assert_allclose(kernel.low_rank_gradient_contraction(X, K, A),
                               kernel.gradient_contraction(X, K, A @ A.T), rtol=1e-10, atol=1e-12)


def test_theta_from_weights_inverts_weights_with_their_derivative(kernel):
    theta_scale, dw_dtheta = kernel.theta_from_weights(kernel.weights())
    np.testing.assert_allclose(theta_scale, kernel.theta[1:], rtol=1e-12)
    step = 1e-6
    up, down = kernel.theta.copy(), kernel.theta.copy()
    up[1:] += step
    down[1:] -= step
    # Each weight depends on its own theta only; central differences are accurate to ~1e-10.
    np.testing.assert_allclose(dw_dtheta, (kernel.weights(up) - kernel.weights(down)) / (2 * step), rtol=1e-7)


def test_clone_with_theta_round_trips(kernel, X):
    clone = kernel.clone_with_theta(kernel.theta)
    np.testing.assert_array_equal(clone(X), kernel(X))
    assert clone is not kernel and type(clone) is type(kernel)


def test_scale_parameters_round_trip_through_constructor(kernel):
    rebuilt = type(kernel)(kernel.signal_variance, kernel.scale_parameters())
    np.testing.assert_allclose(rebuilt.theta, kernel.theta, rtol=1e-12)


# -- definitions ------------------------------------------------------------------------------
def test_squared_exponential_matches_its_formula(X):
    kernel = KERNEL_FACTORIES["se_ard"]()
    lengths = np.array([0.6, 1.4, 2.5])
    diff = (X[:, None, :] - X[None, :, :]) / lengths
    np.testing.assert_allclose(kernel(X), 1.7 * np.exp(-0.5 * (diff**2).sum(-1)), rtol=1e-12)


def test_higdon_matches_its_product_formula(X):
    kernel = KERNEL_FACTORIES["higdon"]()
    alphas = np.array([0.2, 0.55, 0.9])
    diff = X[:, None, :] - X[None, :, :]
    expected = 0.8 * np.prod(alphas ** (4 * diff**2), axis=-1)
    np.testing.assert_allclose(kernel(X), expected, rtol=1e-12)


def test_alpha_and_length_scale_describe_the_same_kernel(X):
    lengths = np.array([0.3, 1.0, 4.0])
    alphas = alpha_from_length_scale(lengths)
    np.testing.assert_allclose(
        HigdonKernel(2.0, alphas)(X), SquaredExponentialARD(2.0, lengths)(X), rtol=1e-12
    )
    np.testing.assert_allclose(length_scale_from_alpha(alphas), lengths, rtol=1e-12)
    np.testing.assert_allclose(HigdonKernel(2.0, alphas).length_scales(), lengths, rtol=1e-12)


def test_alpha_is_correlation_at_half_an_input_unit():
    # prod alpha^(4 d^2) with d = 1/2 in one dimension leaves exactly alpha.
    kernel = HigdonKernel(1.0, [0.37])
    assert kernel(np.array([[0.0]]), np.array([[0.5]]))[0, 0] == pytest.approx(0.37, rel=1e-12)


@pytest.mark.parametrize("bad", [[0.0, 0.5], [1.0, 0.5], [-0.1, 0.5]])
def test_higdon_rejects_alpha_outside_open_unit_interval(bad):
    with pytest.raises(ValueError, match="between 0 and 1"):
        HigdonKernel(1.0, bad)


def test_se_rejects_non_positive_length_scale():
    with pytest.raises(ValueError, match="positive"):
        SquaredExponentialARD(1.0, [1.0, 0.0])
