"""Hyperparameter inference: type-II maximum likelihood, Metropolis MCMC, simulated annealing.

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

from ._gp import GaussianProcess
from ._priors import IndependentPrior

logger = logging.getLogger(__name__)

#: Box on every unconstrained hyperparameter for the optimiser: e^±15 spans 13 decades, so it
#: never binds on standardised data but keeps L-BFGS away from overflow.
THETA_BOUND = 15.0

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


def maximize_marginal_likelihood(gp: GaussianProcess, *, n_restarts: int = 3, seed: int = 0,
                                 min_noise_variance: float | None = None) -> MaximumLikelihoodResult:
    """Type-II maximum likelihood: L-BFGS-B from ``gp.theta_`` and ``n_restarts`` prior draws.

    The fitted ``gp`` is updated to the best hyperparameters found.

    Parameters
    ----------
    gp : GaussianProcess
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
    n_evaluations = 0

    def negative_lml(theta):
        nonlocal n_evaluations
        n_evaluations += 1
        lml, gradient = gp.log_marginal_likelihood(theta, return_gradient=True)
        if not np.isfinite(lml):
            return 1e25, np.zeros_like(theta)
        return -lml, -gradient

    restarts = []
    for start in starts:
        result = optimize.minimize(negative_lml, start, jac=True, method="L-BFGS-B", bounds=bounds)
        restarts.append((result.x, -result.fun))
    best_theta, best_lml = max(restarts, key=lambda r: r[1])
    if not np.isfinite(best_lml) or best_lml <= -1e24:
        raise ValueError("no start gave a finite likelihood; check the training data")
    gp.set_hyperparameters(best_theta)
    return MaximumLikelihoodResult(best_theta, float(best_lml), restarts, n_evaluations)


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
