"""Hyperparameter inference: type-II maximum likelihood, Metropolis MCMC, simulated annealing.

Maximum likelihood (:func:`maximize_marginal_likelihood`) runs one L-BFGS-B search per start;
its cost is the number of likelihood evaluations, each an O(n^3) Cholesky factorisation and
inverse. Three choices keep that number down:

- L-BFGS-B's first step is a unit step along the gradient when every variable is boxed (Byrd,
  Lu, Nocedal & Zhu, SIAM J. Sci. Comput. 16, 1995), and a gradient of O(n) in lml units sends
  it into a corner of the box, to be walked back over several evaluations. The search's
  variables are therefore the hyperparameters times ``sqrt(n m)``, so that the first step moves
  them by the gradient per datum. Later steps are quasi-Newton steps, which such a scaling does
  not change; the tolerances are SciPy's defaults in lml units (the function's, relative, is
  not affected; the gradient's, 1e-5, is divided by ``sqrt(n m)`` with the gradient);
- each input's variable is ``v_i = ln(1 + w_i / RELEVANCE_WEIGHT)`` for the kernel weight
  ``w_i`` of eq. (1) in :mod:`gp_model._kernels`, not its ``theta_i``. For an input the data do
  not need, the likelihood approaches its supremum as ``L_inf - c w_i`` when ``w_i -> 0``, which
  in ``ln l_i`` is ``L_inf - c' e^(-2 ln l_i)``: a Newton step there gains 1/2 in ``ln l_i``
  whatever the distance to go, and L-BFGS-B creeps towards ``l_i = e^15`` one small gain at a
  time. ``v_i`` is logarithmic in ``w_i`` above :data:`RELEVANCE_WEIGHT` and linear below it,
  where such an input is found at its bound in a step or two;
- on an exact GP the search runs over the concentrated likelihood, the signal variance
  maximised in closed form (:meth:`GaussianProcess.concentrated_log_marginal_likelihood`): one
  variable fewer and no ridge along which signal and noise variance trade off. Its last
  variable is ``ln(sigma_n^2 / sigma_f^2)``; where the search ends outside the box on ``theta``
  (the concentrated signal variance is not bounded in it, and a noise floor bounds a sum of two
  of its variables), it continues over ``[ln sigma_f^2, v..., ln sigma_n^2]`` from that end
  clipped into the box. Sparse GPs search over those variables directly.

The annealer follows the Bo105 GP-NARX paper (AHS 74th Forum, 2018): it samples the tempered
posterior

    pi_zeta(theta) ∝ p(theta) L(theta)^zeta,                                            (1)

raising the likelihood weight zeta from a small value to 1. The schedule is adaptive: each step
in zeta is chosen so that the entropy of the tempered target changes by a fixed amount. With
``H(zeta) = -E_zeta[ln pi_zeta]`` and ``d/dzeta E_zeta[f] = Cov_zeta(f, ln L)`` one finds

    dH/dzeta = -( Cov_zeta(ln p, ln L) + zeta Var_zeta(ln L) ),                          (2)

so to first order ``delta_zeta = entropy_step / |Cov(ln p, ln L) + zeta Var(ln L)|``. That
undershoots (Var(ln L) shrinks within a step), so the step is found exactly instead, by
bisection on the entropy at the candidate zeta estimated by importance-reweighting the samples
of the stage just run (eq. 3 in :func:`_next_zeta`); one step never raises zeta tenfold or more.
Between stages the chains are resampled with
weights ``L^delta_zeta`` (sequential Monte Carlo, Del Moral et al., JRSS-B 68, 2006) and the
Gaussian random-walk proposal is re-tuned: its shape to the stage's sample covariance and its
width towards the 0.234 acceptance rate (Roberts, Gelman & Gilks, Ann. Appl. Probab. 7, 1997).
The states visited at zeta = 1 after one stage of burn-in are returned as the samples.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize
from scipy.special import logsumexp

from ._gp import BaseGaussianProcess, GaussianProcess
from ._priors import IndependentPrior

logger = logging.getLogger(__name__)

#: Box on every unconstrained hyperparameter for the optimiser: e^±15 spans 13 decades, so it
#: never binds on standardised data but keeps L-BFGS away from overflow.
THETA_BOUND = 15.0

#: Kernel weight (eq. 1 of gp_model._kernels) below which the optimiser's variable for an
#: input turns from logarithmic in it to linear (module docstring). At w_i = 1e-6 the input
#: changes the kernel by a factor exp(-w_i dx^2) of at least 1 - 1e-4 over a span of dx = 10
#: standardised units, so below it the input hardly matters. In the scikit-learn comparison
#: (docs/benchmarks.md, d = 4 with one input unused) it takes a fit at n = 500 from 76
#: evaluations (variables ln l_i) to 43 and leaves one at n = 2000, where the unused input's
#: optimum is near w = 1e-6, at 44.
RELEVANCE_WEIGHT = 1e-6

#: Optimal random-walk acceptance rate in high dimension (Roberts, Gelman & Gilks 1997).
TARGET_ACCEPTANCE = 0.234


@dataclass
class MaximumLikelihoodResult:
    """Outcome of :func:`maximize_marginal_likelihood`.

    Attributes
    ----------
    theta : ndarray, shape (p,)
        Best hyperparameters found.
    log_marginal_likelihood : float
        At ``theta``.
    restarts : list of (theta, lml)
        Every local optimum, starting point first.
    n_evaluations : int
        Likelihood-and-gradient evaluations used.
    """

    theta: np.ndarray
    log_marginal_likelihood: float
    restarts: list
    n_evaluations: int


def maximize_marginal_likelihood(gp: BaseGaussianProcess, *, n_restarts: int = 3, seed: int = 0,
                                 min_noise_variance: float | None = None) -> MaximumLikelihoodResult:
    """Type-II maximum likelihood: L-BFGS-B (module docstring) from ``gp.theta_`` and from
    ``n_restarts`` prior draws.

    The fitted ``gp`` is updated to the best hyperparameters found.

    Parameters
    ----------
    gp : GaussianProcess or SparseGaussianProcess
        Already :meth:`~GaussianProcess.fit` to data; its ``theta_`` is the first start.
    n_restarts : int, default 3
        Further starts drawn from ``gp.prior()`` (clipped to the optimiser's box).
    seed : int, default 0
        Seed of the restart draws.
    min_noise_variance : float, optional
        A floor under the noise variance ``sigma_n^2`` (standardised outputs): the search keeps
        ``ln sigma_n^2 >= ln min_noise_variance``, so targets that are nearly a function of the
        inputs cannot drive the noise to zero and the fit to interpolation. Default: the box
        alone (``e^-15``).

    Returns
    -------
    MaximumLikelihoodResult
        Best hyperparameters, their log marginal likelihood, every restart's optimum and the
        number of likelihood evaluations.
    """
    rng = np.random.default_rng(seed)
    bounds = [(-THETA_BOUND, THETA_BOUND)] * len(gp.theta_)
    if min_noise_variance is not None:
        if not (np.isfinite(min_noise_variance) and 0 < min_noise_variance < np.exp(THETA_BOUND)):
            raise ValueError(f"min_noise_variance must be a positive number, got {min_noise_variance}")
        bounds[-1] = (float(np.log(min_noise_variance)), THETA_BOUND)
    low, high = np.array(bounds).T
    starts = [np.clip(gp.theta_, low, high)]
    if n_restarts > 0:
        starts += list(np.clip(gp.prior().sample(n_restarts, rng), low, high))
    search = _LocalSearch(gp, low, high)
    restarts = [search.run(start) for start in starts]
    best_theta, best_lml = max(restarts, key=lambda r: r[1])
    if not np.isfinite(best_lml):
        raise ValueError("no start gave a finite likelihood; check the training data")
    gp.set_hyperparameters(best_theta)
    return MaximumLikelihoodResult(best_theta, float(best_lml), restarts, search.n_evaluations)


class _Objective:
    """``-lml`` and its gradient at the optimiser's variables ``z = sqrt(n m) x`` (module
    docstring), from ``evaluate(x) -> (lml, gradient, theta)``; counts the evaluations and keeps
    the best theta."""

    #: What a failed evaluation (-inf likelihood) returns: far above any real value.
    FAILED = 1e25

    def __init__(self, evaluate, n_data: int) -> None:
        self.evaluate = evaluate
        self.scale = np.sqrt(n_data)
        self.n_evaluations = 0
        self.best_lml, self.best_theta = -np.inf, None

    def __call__(self, z):
        self.n_evaluations += 1
        lml, gradient, theta = self.evaluate(z / self.scale)
        if not np.isfinite(lml):
            return self.FAILED, np.zeros_like(z)
        if lml > self.best_lml:
            self.best_lml, self.best_theta = lml, np.array(theta, dtype=float)
        return -lml, -np.asarray(gradient) / self.scale


class _LocalSearch:
    """The L-BFGS-B search from one start (module docstring), counting the evaluations of all.

    Its variables are ``x = [v..., ln(sigma_n^2 / sigma_f^2)]`` over the concentrated likelihood
    of an exact GP, and ``x = [ln sigma_f^2, v..., ln sigma_n^2]`` otherwise.
    """

    def __init__(self, gp: BaseGaussianProcess, low: np.ndarray, high: np.ndarray) -> None:
        self.gp, self.low, self.high = gp, low, high
        self.n_evaluations = 0
        self.concentrated = isinstance(gp, GaussianProcess)
        # The box on theta, in the variables: v falls as theta_i rises, for both kernels.
        v_low, v_high = self._weight_variables(high), self._weight_variables(low)
        self.x_low = np.concatenate((v_low, [low[-1] - high[0]]))  # r = sigma_n^2 / sigma_f^2
        self.x_high = np.concatenate((v_high, [high[-1] - low[0]]))
        self.plain_low = np.concatenate(([low[0]], v_low, [low[-1]]))
        self.plain_high = np.concatenate(([high[0]], v_high, [high[-1]]))

    def _weight_variables(self, theta: np.ndarray) -> np.ndarray:
        """``v = ln(1 + w / RELEVANCE_WEIGHT)`` of ``theta``'s kernel weights, shape (d,)."""
        return np.log1p(self.gp.kernel.weights(theta[:-1]) / RELEVANCE_WEIGHT)

    def _kernel_scales(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``theta[1:-1]`` at the variables ``v`` (clipped into the box against rounding) and
        ``d theta[1:-1] / dv``, each shape (d,)."""
        weights = RELEVANCE_WEIGHT * np.expm1(v)
        theta_scale, dw_dtheta = self.gp.kernel.theta_from_weights(weights)
        return (np.clip(theta_scale, self.low[1:-1], self.high[1:-1]),
                (weights + RELEVANCE_WEIGHT) / dw_dtheta)

    def run(self, start: np.ndarray) -> tuple[np.ndarray, float]:
        """(theta, lml) of the best point of the search from ``start``; (start, -inf) if no
        evaluation succeeded."""
        v = self._weight_variables(start)
        if self.concentrated:
            lml, theta = self._minimize(self._concentrated, np.append(v, start[-1] - start[0]),
                                        self.x_low, self.x_high)
            if theta is not None and np.all((self.low <= theta) & (theta <= self.high)):
                return theta, lml
            if theta is not None:
                start = np.clip(theta, self.low, self.high)
                v = self._weight_variables(start)
        lml, theta = self._minimize(self._plain, np.concatenate(([start[0]], v, [start[-1]])),
                                    self.plain_low, self.plain_high)
        return (start, -np.inf) if theta is None else (theta, lml)

    def _concentrated(self, x):
        """(lml, its gradient in x, theta) of the concentrated likelihood."""
        theta_scale, jacobian = self._kernel_scales(x[:-1])
        lml, gradient, theta = self.gp.concentrated_log_marginal_likelihood(np.append(theta_scale, x[-1]))
        return lml, np.append(gradient[:-1] * jacobian, gradient[-1]), theta

    def _plain(self, x):
        """(lml, its gradient in x, theta) of the likelihood."""
        theta_scale, jacobian = self._kernel_scales(x[1:-1])
        theta = np.concatenate(([x[0]], theta_scale, [x[-1]]))
        lml, gradient = self.gp.log_marginal_likelihood(theta, return_gradient=True)
        return lml, np.concatenate(([gradient[0]], gradient[1:-1] * jacobian, [gradient[-1]])), theta

    def _minimize(self, evaluate, x0, low, high) -> tuple[float, np.ndarray | None]:
        """L-BFGS-B on ``evaluate``'s objective in the box [low, high] from ``x0``: the best
        (lml, theta) it evaluated, theta None if none succeeded."""
        objective = _Objective(evaluate, self.gp.Y_train_.size)
        scale = objective.scale
        optimize.minimize(objective, scale * np.clip(x0, low, high), jac=True, method="L-BFGS-B",
                          bounds=list(zip(scale * low, scale * high)), options={"gtol": 1e-5 / scale})
        self.n_evaluations += objective.n_evaluations
        return objective.best_lml, objective.best_theta


# -- Metropolis ------------------------------------------------------------------------------
@dataclass
class MCMCResult:
    """Samples of a Metropolis run.

    Attributes
    ----------
    samples : ndarray, shape (n_steps, n_chains, p)
        Chain states after each step (a rejected proposal repeats the state, as it must).
    log_likelihood, log_prior : ndarray, shape (n_steps, n_chains)
    acceptance_rate : float
    """

    samples: np.ndarray
    log_likelihood: np.ndarray
    log_prior: np.ndarray
    acceptance_rate: float


def _metropolis_steps(log_likelihood, log_prior, states, ll, lp, *, zeta, n_steps,
                      proposal_chol, rng, progress=None) -> MCMCResult:
    """Random-walk Metropolis on ``lp + zeta * ll`` for several chains at once.

    ``states`` (n_chains, p) with their log-likelihood ``ll`` and log-prior ``lp`` (n_chains,);
    proposals ``theta + proposal_chol @ z``, z standard normal.
    """
    n_chains, p = states.shape
    states, ll, lp = states.copy(), ll.copy(), lp.copy()
    samples = np.empty((n_steps, n_chains, p))
    lls, lps = np.empty((n_steps, n_chains)), np.empty((n_steps, n_chains))
    accepted = 0
    for step in range(n_steps):
        proposals = states + rng.standard_normal((n_chains, p)) @ proposal_chol.T
        log_u = np.log(rng.uniform(size=n_chains))
        lp_new = log_prior(proposals)
        for c in range(n_chains):
            if not np.isfinite(lp_new[c]):
                continue
            ll_new = log_likelihood(proposals[c])
            if not np.isfinite(ll_new):
                continue
            current = lp[c] + zeta * ll[c] if np.isfinite(ll[c]) else -np.inf
            if log_u[c] < lp_new[c] + zeta * ll_new - current:
                states[c], ll[c], lp[c] = proposals[c], ll_new, lp_new[c]
                accepted += 1
        samples[step], lls[step], lps[step] = states, ll, lp
        if progress is not None:
            progress(1)
    return MCMCResult(samples, lls, lps, accepted / (n_steps * n_chains))


def metropolis(log_target, initial, *, n_steps: int, proposal_scale, seed: int = 0) -> MCMCResult:
    """Random-walk Metropolis sampler (Metropolis et al., J. Chem. Phys. 21, 1953).

    Parameters
    ----------
    log_target : callable
        ``log_target(theta) -> float``, unnormalised log density; ``-inf`` outside its support.
    initial : ndarray, shape (p,) or (n_chains, p)
        Starting state(s); several rows run independent chains.
    n_steps : int
        Steps per chain.
    proposal_scale : float or ndarray, shape (p,) or (p, p)
        Standard deviation(s) of the Gaussian proposal, or its covariance's Cholesky factor.
    seed : int, default 0

    Returns
    -------
    MCMCResult
        The chain states after every step, shape (n_steps, n_chains, p), their log target
        values, and the acceptance rate.
    """
    states = np.atleast_2d(np.asarray(initial, dtype=float))
    p = states.shape[1]
    scale = np.asarray(proposal_scale, dtype=float)
    chol = scale if scale.ndim == 2 else np.diag(np.broadcast_to(scale, (p,)))
    ll = np.array([log_target(s) for s in states])
    zero_prior = lambda theta: np.zeros(len(theta))  # noqa: E731 - the target is all in ll
    return _metropolis_steps(log_target, zero_prior, states, ll, np.zeros(len(states)), zeta=1.0,
                             n_steps=n_steps, proposal_chol=chol, rng=np.random.default_rng(seed))


# -- simulated annealing ---------------------------------------------------------------------
@dataclass
class AnnealingResult:
    """Outcome of :func:`simulated_annealing`.

    Attributes
    ----------
    samples : ndarray, shape (n_samples, p)
        States visited at zeta = 1 (chains interleaved).
    log_likelihood : ndarray, shape (n_samples,)
    log_prior : ndarray, shape (n_samples,)
    zeta_schedule : list of float
        Likelihood weights of the stages, increasing, the last exactly 1.
    acceptance_rates : list of float
        Acceptance rate of each stage.
    proposal_widths : list of float
        Overall proposal width multiplier used in each stage.
    """

    samples: np.ndarray
    log_likelihood: np.ndarray
    log_prior: np.ndarray
    zeta_schedule: list = field(default_factory=list)
    acceptance_rates: list = field(default_factory=list)
    proposal_widths: list = field(default_factory=list)

    @property
    def map_sample(self) -> np.ndarray:
        """The sample with the highest posterior density, shape (p,)."""
        return self.samples[np.argmax(self.log_likelihood + self.log_prior)]


def simulated_annealing(log_likelihood, prior: IndependentPrior, *, n_samples: int = 400,
                        n_chains: int = 8, steps_per_stage: int = 40, entropy_step: float = 0.5,
                        zeta_start: float = 1e-4, max_stages: int = 200, seed: int = 0,
                        progress=None) -> AnnealingResult:
    """Sample ``p(theta) L(theta)`` by annealing ``p L^zeta`` from ``zeta_start`` to 1 (eqs. 1-2).

    Parameters
    ----------
    log_likelihood : callable
        ``log_likelihood(theta) -> float`` (``-inf`` where undefined).
    prior : IndependentPrior
        Proper prior; the chains start from its draws.
    n_samples : int, default 400
        Samples returned at zeta = 1 (rounded up to a multiple of ``n_chains``).
    n_chains : int, default 8
    steps_per_stage : int, default 40
        Metropolis steps per chain at each zeta.
    entropy_step : float, default 0.5
        Target change in entropy (nats) of the tempered target per stage.
    zeta_start : float, default 1e-4
    max_stages : int, default 200
        If reached, the next stage jumps to zeta = 1 (logged).
    seed : int, default 0
    progress : callable, optional
        Called as ``progress(1)`` after every Metropolis step and as
        ``progress(0, zeta=..., acceptance=...)`` after every stage.

    Returns
    -------
    AnnealingResult
        Samples at zeta = 1, shape (n_samples, p), their log-likelihoods and log-priors, and the
        zeta schedule, acceptance rates and proposal widths of every stage.
    """
    if not 0 < zeta_start <= 1:
        raise ValueError(f"zeta_start must be in (0, 1], got {zeta_start}")
    rng = np.random.default_rng(seed)
    p = len(prior)
    states = prior.sample(n_chains, rng)
    ll = np.array([log_likelihood(s) for s in states])
    lp = prior.log_pdf(states)
    # Initial proposal: the prior's spread, width 2.38/sqrt(p) (Roberts et al. 1997).
    shape_chol = np.linalg.cholesky(np.cov(prior.sample(2000, rng), rowvar=False).reshape(p, p)
                                    + 1e-9 * np.eye(p))
    width = 2.38 / np.sqrt(p)
    result = AnnealingResult(np.empty((0, p)), np.empty(0), np.empty(0))
    n_final = int(np.ceil(n_samples / n_chains))
    zeta = zeta_start
    while True:
        result.zeta_schedule.append(zeta)
        result.proposal_widths.append(width)
        stage = _metropolis_steps(log_likelihood, prior.log_pdf, states, ll, lp, zeta=zeta,
                                  n_steps=steps_per_stage, proposal_chol=width * shape_chol,
                                  rng=rng, progress=progress)
        result.acceptance_rates.append(stage.acceptance_rate)
        states, ll, lp = stage.samples[-1], stage.log_likelihood[-1], stage.log_prior[-1]
        shape_chol, width = _retune(stage, shape_chol, width)
        if progress is not None:
            progress(0, zeta=f"{zeta:.3g}", acceptance=f"{stage.acceptance_rate:.2f}")
        if zeta >= 1.0:
            break
        zeta_next = _next_zeta(stage, zeta, entropy_step)
        if len(result.zeta_schedule) >= max_stages and zeta_next < 1.0:
            logger.warning("annealing reached %d stages at zeta=%.3g; jumping to zeta=1 "
                           "(raise entropy_step or max_stages)", max_stages, zeta)
            zeta_next = 1.0
        states, ll, lp = _resample(states, ll, lp, (zeta_next - zeta) * ll, rng)
        zeta = zeta_next
    final = _metropolis_steps(log_likelihood, prior.log_pdf, states, ll, lp, zeta=1.0,
                              n_steps=n_final, proposal_chol=width * shape_chol, rng=rng,
                              progress=progress)
    result.samples = final.samples.reshape(-1, p)
    result.log_likelihood = final.log_likelihood.reshape(-1)
    result.log_prior = final.log_prior.reshape(-1)
    return result


def anneal_hyperparameters(gp: GaussianProcess, **options) -> AnnealingResult:
    """Run :func:`simulated_annealing` on a fitted GP's likelihood and prior, then use the
    samples for mixture predictions and the highest-posterior sample as ``theta_``.

    ``options`` are passed to :func:`simulated_annealing`.
    """
    result = simulated_annealing(gp.log_marginal_likelihood, gp.prior(), **options)
    gp.set_hyperparameters(result.map_sample, samples=result.samples)
    return result


def _next_zeta(stage: MCMCResult, zeta: float, entropy_step: float) -> float:
    """The next zeta: the one at which the tempered target's entropy is ``entropy_step`` lower.

    The entropy at a candidate ``zeta' = zeta + d`` is estimated from the stage's samples by
    importance weights ``w ∝ L^d`` (eq. 3):

        H(zeta') - H(zeta) = -(E'[ln p] + zeta' E'[ln L]) + (E[ln p] + zeta E[ln L])
                             + ln E[L^d],

    (``ln Z(zeta') - ln Z(zeta) = ln E_zeta[L^d]``), and ``d`` is found by bisection. The
    first-order rule of eq. (2) undershoots because Var(ln L) shrinks within a step.
    """
    ll, lp = stage.log_likelihood.ravel(), stage.log_prior.ravel()
    finite = np.isfinite(ll) & np.isfinite(lp)
    if finite.sum() < 2:
        return min(1.0, 10.0 * zeta)
    ll, lp = ll[finite], lp[finite]
    baseline = lp.mean() + zeta * ll.mean()

    def entropy_drop(d: float) -> float:
        log_w = d * ll
        log_mean_weight = logsumexp(log_w) - np.log(len(ll))
        w = np.exp(log_w - log_w.max())
        w /= w.sum()
        return float(w @ lp + (zeta + d) * (w @ ll) - baseline - log_mean_weight)

    # Never more than a tenfold increase in one stage: the importance weights degenerate and
    # say little about a target far ahead.
    d_max = min(1.0, 10.0 * zeta) - zeta
    if entropy_drop(d_max) <= entropy_step:
        return zeta + d_max
    low, high = 0.0, d_max
    for _ in range(60):  # relative precision 2^-60 of d_max
        middle = 0.5 * (low + high)
        low, high = (middle, high) if entropy_drop(middle) < entropy_step else (low, middle)
    return zeta + high


def _resample(states, ll, lp, log_weights, rng):
    """Multinomial resampling of the chains by importance weights (SMC step)."""
    log_weights = np.where(np.isfinite(log_weights), log_weights, -np.inf)
    if not np.isfinite(log_weights).any():
        return states, ll, lp
    weights = np.exp(log_weights - log_weights.max())
    index = rng.choice(len(states), size=len(states), p=weights / weights.sum())
    return states[index], ll[index], lp[index]


def _retune(stage: MCMCResult, shape_chol, width):
    """New proposal: shape from the stage's sample covariance, width from its acceptance rate."""
    flat = stage.samples.reshape(-1, stage.samples.shape[-1])
    p = flat.shape[1]
    cov = np.cov(flat, rowvar=False).reshape(p, p)
    try:
        # The optimal random-walk covariance is (2.38^2/p) x target covariance (Roberts et al.
        # 1997); `width` carries the 2.38/sqrt(p) factor and its acceptance-rate correction. A
        # small ridge keeps a collapsed dimension explorable.
        new_chol = np.linalg.cholesky(cov + 1e-6 * np.trace(cov) / p * np.eye(p) + 1e-12 * np.eye(p))
        shape_chol = new_chol
    except np.linalg.LinAlgError:
        pass
    width *= float(np.exp(np.clip(stage.acceptance_rate - TARGET_ACCEPTANCE, -1.0, 1.0) * 2.0))
    return shape_chol, float(np.clip(width, 1e-3, 10.0))
