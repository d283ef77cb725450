"""Output-error fitting of named effects to recordings (the machinery of the explain stage).

The reference, with the effects under test, is replayed on the recorded inputs from trim, or from
each recording's first state where the reference says so
(:meth:`validation.vehicles.effects.EffectModel.simulate_recordings`) and the noise-weighted
differences to the measured outputs are minimised (Jategaonkar, *Flight Vehicle System
Identification*, 2006, ch. 4). With white Gaussian sensor noise of known standard deviations the
weighted residual sum of squares ``RSS`` is ``-2 ln L`` up to a constant.

References whose replays are fast (a Bo105: one exact discretisation, milliseconds) are fitted
one problem at a time by scipy's trust-region reflective ``least_squares``; references that
batch their replays (the blimp's RK4 integration of a nonlinear ODE) fit all problems of a step
at once with :func:`_fit_batched`, a Levenberg-Marquardt iteration (Marquardt, J. SIAM 11(2),
1963) whose trial points and forward-difference Jacobian columns of every problem are one
batched replay.

Intervals are 95 % Wald intervals from the Jacobian at the joint optimum,
``cov = s^2 (J^T J)^-1`` with ``s^2 = max(1, RSS / (N - p))`` so that a misfit beyond the noise
widens them (Seber & Wild, *Nonlinear Regression*, 1989, sec. 2.2). That formula assumes white
residuals; model error is correlated in time (a misfit lasts seconds), which makes it far too
narrow, so each variance is widened to the heteroscedasticity- and autocorrelation-consistent
(Newey-West) one where that is larger (:func:`_newey_west`).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy import stats
from scipy.optimize import least_squares

from validation.vehicles.effects import EffectModel, Hypothesis

_Z95 = stats.norm.isf(0.025)
#: Family-wise false-alarm probability of each step's test over all hypotheses tested.
FAMILY_ALPHA = 0.01
#: An accepted effect must remove at least this fraction of the unexplained residual energy.
MIN_EXCESS_FRACTION = 0.05
#: Competitors listed with a finding: at most this many, with evidence ratio below the limit.
MAX_ALTERNATIVES = 3
MAX_EVIDENCE_RATIO = 1e6
#: Largest weighted residual (noise standard deviations) a diverging trial model is given.
_DIVERGED = 1e6
#: Relative change of the values and of the RSS at which scipy's trust-region fit stops (its default):
#: 1e-10 took 16 % longer on the Bo105 flight-test stand-in and moved no value by more than 1e-6 of
#: itself (docs/diagnose.md, "Several effects at once: the `bo105-80kt-flight` stand-in").
_TRF_TOLERANCE = 1e-8
#: Batched Levenberg-Marquardt: most iterations, relative RSS change that counts as converged,
#: forward-difference step as a fraction of each hypothesis' screening step.
_LM_ITERATIONS = 40
_LM_RTOL = 1e-9
_LM_DIFF = 1e-3
#: Batched Levenberg-Marquardt: an RSS below this (noise variances) is an exact fit (noise-free
#: data of the model itself), where the relative test alone would iterate on rounding.
_LM_EXACT_RSS = 1e-12


@dataclass
class FitData:
    """Recordings prepared for output-error fitting.

    Attributes
    ----------
    time, inputs : list of ndarray, shapes (n_r,), (n_r, n_inputs)
    measured : list of ndarray, shape (n_r, n_out)
        Measured outputs, in the order of ``output_names``.
    output_names : tuple of str
        Measured states of the reference (any subset of its ``state_names``).
    noise_sd : list of ndarray, shape (n_out,)
        Sensor-noise standard deviation per recording and output, output units.
    fit_mask : list of ndarray of bool, shape (n_r,)
        Samples that enter the fit (the rest are held out); may be all False for a held-out
        recording.
    starts : list of (ndarray, shape (n_states,), or None)
        The state each recording's replay starts from
        (:meth:`validation.vehicles.effects.EffectModel.start_state`; None: the reference's own).
    """

    time: list
    inputs: list
    measured: list
    output_names: tuple
    noise_sd: list
    fit_mask: list
    starts: list

    @property
    def n_residuals(self) -> int:
        """Residuals of a fit: fitted samples times outputs."""
        return int(sum(mask.sum() for mask in self.fit_mask)) * len(self.output_names)

    def simulate(self, reference: EffectModel, effects: list[dict]) -> list:
        """Replayed outputs per recording, shape (n_r, n_out) each."""
        return [replay[0] for replay in self._simulate_many(reference, [effects], fitted_only=False)]

    def fitting_only(self, recordings) -> FitData:
        """These data with only the fitted samples of ``recordings`` (indices) left fitted."""
        return dataclasses.replace(self, fit_mask=[mask if i in recordings else np.zeros_like(mask)
                                                   for i, mask in enumerate(self.fit_mask)])

    def simulate_many(self, reference: EffectModel, effect_lists) -> list:
        """Per effect list, its replayed outputs per recording, shape (n_r, n_out) each, all in
        one batch."""
        per_recording = self._simulate_many(reference, effect_lists, fitted_only=False)
        return [[replays[b] for replays in per_recording] for b in range(len(effect_lists))]

    def simulate_states(self, reference: EffectModel, effect_lists, *, fitted_only: bool = False) -> list:
        """Per recording (``None`` where ``fitted_only`` and nothing of it is fitted): the
        replayed states of each effect list, shape (B, n_r, n_states), all recordings in one
        :meth:`~validation.vehicles.effects.EffectModel.simulate_recordings` call."""
        chosen = [i for i, mask in enumerate(self.fit_mask) if mask.any() or not fitted_only]
        replays = reference.simulate_recordings(effect_lists, [self.time[i] for i in chosen],
                                                [self.inputs[i] for i in chosen], [self.starts[i] for i in chosen])
        by_index = dict(zip(chosen, replays))
        return [by_index.get(i) for i in range(len(self.time))]

    def _simulate_many(self, reference: EffectModel, effect_lists, *, fitted_only: bool) -> list:
        """Per recording (``None`` where ``fitted_only`` and nothing of it is fitted): replayed
        outputs of each effect list, shape (B, n_r, n_out)."""
        columns = [reference.state_names.index(name) for name in self.output_names]
        return [None if states is None else states[:, :, columns]
                for states in self.simulate_states(reference, effect_lists, fitted_only=fitted_only)]

    def weighted_residuals_many(self, reference: EffectModel, effect_lists) -> np.ndarray:
        """``(measured - replay) / noise_sd`` on the fit samples for each of B effect lists,
        flattened per list, shape (B, N)."""
        parts = []
        with np.errstate(over="ignore", invalid="ignore"):
            replays = self._simulate_many(reference, effect_lists, fitted_only=True)
            for replay, measured, sd, mask in zip(replays, self.measured, self.noise_sd, self.fit_mask):
                if mask.any():
                    parts.append(((measured[mask] - replay[:, mask]) / sd).reshape(len(effect_lists), -1))
        # A trial value that makes the model diverge gets a large, finite misfit, so the
        # optimiser steps back instead of failing on inf or NaN.
        return np.clip(np.nan_to_num(np.concatenate(parts, axis=1), nan=_DIVERGED), -_DIVERGED, _DIVERGED)

    def weighted_residuals(self, reference: EffectModel, effects: list[dict]) -> np.ndarray:
        """``(measured - replay) / noise_sd`` on the fit samples, flattened, shape (N,)."""
        return self.weighted_residuals_many(reference, [effects])[0]


@dataclass
class FittedModel:
    """A set of hypotheses at their joint least-squares values.

    Attributes
    ----------
    hypotheses : list of Hypothesis
    values : ndarray, shape (p,)
        Fitted values, each in its hypothesis' unit.
    rss : float
        Weighted residual sum of squares at ``values``.
    covariance : ndarray, shape (p, p)
        Wald covariance, widened where the residual is correlated in time (module docstring).
    white_covariance : ndarray, shape (p, p)
        The classical ``s^2 (J^T J)^-1``, right when the model with these values is the truth
        and only white noise remains: the null hypothesis of a specification test
        (:func:`validation.diagnose.explain.amplitude_check`).
    """

    hypotheses: list
    values: np.ndarray
    rss: float
    covariance: np.ndarray
    white_covariance: np.ndarray

    def effects(self) -> list[dict]:
        """The fitted effect dicts."""
        return [h.as_effect(v) for h, v in zip(self.hypotheses, self.values)]

    def interval(self, index: int) -> tuple[float, float]:
        """95 % Wald interval of effect ``index``'s value: of its search parameter, clipped to
        the bounds, then mapped to the value (the ends swapped where the parameter is the
        value's reciprocal, :attr:`~validation.vehicles.effects.Hypothesis.reciprocal`)."""
        h, value = self.hypotheses[index], self.values[index]
        half = _Z95 * math.sqrt(max(self.covariance[index, index], 0.0))
        ends = sorted((h.effect_value(max(value - half, h.lower)), h.effect_value(min(value + half, h.upper))))
        return ends[0], ends[1]


def null_model(data: FitData, reference: EffectModel) -> FittedModel:
    """The reference without any effect, as a FittedModel (its RSS on ``data``)."""
    rss = float(np.sum(data.weighted_residuals(reference, []) ** 2))
    return FittedModel([], np.zeros(0), rss, np.zeros((0, 0)), np.zeros((0, 0)))


def fit_many(data: FitData, reference: EffectModel, problems: list) -> list[FittedModel]:
    """Joint output-error fits of several ``(hypotheses, start values)`` problems, one
    FittedModel each (batched when the reference batches its replays, module docstring)."""
    if reference.batches_simulations:
        return _fit_batched(data, reference, problems)
    return [_fit(data, reference, hypotheses, start) for hypotheses, start in problems]


def _covariances(jacobian: np.ndarray, residual: np.ndarray, data: FitData) -> tuple[np.ndarray, np.ndarray]:
    """Wald covariances of the values at a fit's optimum (module docstring): the classical
    ``s^2 (J^T J)^-1`` with each variance widened (never narrowed) to the Newey-West one
    (:func:`_newey_west`), the correlations kept; and the classical one.  ``jacobian`` (N, p)
    and ``residual`` (N,) are weighted, recording by recording, sample-major over
    ``data.output_names``."""
    n, p = jacobian.shape
    rss = float(residual @ residual)
    bread = np.linalg.pinv(jacobian.T @ jacobian)
    classic = max(1.0, rss / max(n - p, 1)) * bread
    if p == 0:
        return classic, classic
    blocks = [int(mask.sum()) for mask in data.fit_mask if mask.any()]
    robust = bread @ _newey_west(jacobian, residual, blocks, len(data.output_names)) @ bread
    variance = np.diag(classic)
    ratio = np.where(variance > 0, np.diag(robust) / np.where(variance > 0, variance, 1.0), 1.0)
    scale = np.sqrt(np.maximum(1.0, ratio))
    return classic * np.outer(scale, scale), classic


def _newey_west(jacobian: np.ndarray, residual: np.ndarray, blocks: list, n_outputs: int) -> np.ndarray:
    """The long-run covariance ``S`` (p, p) of the score ``sum_t g_t``, ``g_t = J_t^T r_t`` per
    sample ``t`` (the outputs of a sample together), with Bartlett weights ``1 - l / (L + 1)``
    up to lag ``L`` within each recording (Newey & West, Econometrica 55(3), 1987), so that
    ``(J^T J)^-1 S (J^T J)^-1`` holds when the model error is correlated in time. ``L`` is
    Andrews' plug-in for an AR(1) score with the pooled lag-one autocorrelation ``rho`` of the
    standardised scores, ``L = 1.1447 (4 rho^2 / ((1 - rho)^2 (1 + rho)^2) T)^(1/3)`` (Andrews,
    Econometrica 59(3), 1991, sec. 6), ``T`` the longest recording's samples, at most ``T - 1``."""
    p = jacobian.shape[1]
    scores, first = [], 0
    for length in blocks:
        rows = slice(first, first + length * n_outputs)
        scores.append(np.einsum("top,to->tp", jacobian[rows].reshape(length, n_outputs, p),
                                residual[rows].reshape(length, n_outputs)))
        first += length * n_outputs
    spread = np.sqrt(np.mean(np.concatenate(scores) ** 2, axis=0))
    spread = np.where(spread > 0, spread, 1.0)
    lagged = sum(float(np.sum(g[1:] / spread * g[:-1] / spread)) for g in scores)
    total = sum(float(np.sum((g / spread) ** 2)) for g in scores)
    rho = min(max(lagged / total, 0.0), 0.999) if total > 0 else 0.0
    longest = max(blocks)
    alpha = 4 * rho**2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
    bandwidth = min(int(1.1447 * (alpha * longest) ** (1 / 3)), longest - 1)
    meat = np.zeros((p, p))
    for g in scores:
        meat += g.T @ g
        for lag in range(1, min(bandwidth, len(g) - 1) + 1):
            gamma = g[lag:].T @ g[:-lag]
            meat += (1 - lag / (bandwidth + 1)) * (gamma + gamma.T)
    return meat


def _fit(data: FitData, reference: EffectModel, hypotheses: list[Hypothesis], start) -> FittedModel:
    """Joint output-error least squares of ``hypotheses`` from ``start`` (module docstring)."""
    lower = np.array([h.lower for h in hypotheses])
    upper = np.array([h.upper for h in hypotheses])
    start = np.clip(np.asarray(start, dtype=float), lower, upper)

    def residuals(values):
        return data.weighted_residuals(reference, [h.as_effect(v) for h, v in zip(hypotheses, values)])

    result = least_squares(residuals, start, bounds=(lower, upper), x_scale="jac", method="trf",
                           xtol=_TRF_TOLERANCE, ftol=_TRF_TOLERANCE, max_nfev=200 * len(hypotheses))
    rss = float(result.fun @ result.fun)
    return FittedModel(list(hypotheses), result.x, rss, *_covariances(result.jac, result.fun, data))


@dataclass
class _Problem:
    """State of one fit inside :func:`_fit_batched`."""

    hypotheses: list
    lower: np.ndarray
    upper: np.ndarray
    trial: np.ndarray
    x: np.ndarray | None = None
    rss: float = math.inf
    residual: np.ndarray | None = None
    jacobian: np.ndarray | None = None
    damping: float = 1e-3
    done: bool = False

    def trial_points(self) -> tuple[np.ndarray, list]:
        """Forward-difference steps (``_LM_DIFF`` times each screening step, taken inward at
        an upper bound) and the points to replay: the trial, then the trial moved by each step."""
        steps = np.array([_LM_DIFF * h.step for h in self.hypotheses])
        steps = np.where(self.trial + steps > self.upper, -steps, steps)
        points = [self.trial] + [self.trial + np.eye(len(steps))[j] * steps[j] for j in range(len(steps))]
        return steps, points

    def update(self, residual: np.ndarray, neighbours: np.ndarray, steps: np.ndarray) -> None:
        """One Levenberg-Marquardt step (:func:`_fit_batched`) from the trial's weighted
        residual (N,) and its neighbours' (p, N)."""
        rss = float(residual @ residual)
        if rss < self.rss:
            converged = self.rss - rss <= _LM_RTOL * rss or rss <= _LM_EXACT_RSS
            self.x, self.rss, self.residual = self.trial, rss, residual
            self.jacobian = (neighbours - residual).T / steps
            self.damping /= 3.0
            self.done = converged
        else:
            self.damping *= 4.0
            self.done = self.damping > 1e10
        if self.done:
            return
        normal = self.jacobian.T @ self.jacobian
        gradient = self.jacobian.T @ self.residual
        damped = normal + self.damping * np.diag(np.diag(normal)) + 1e-12 * np.eye(len(steps))
        delta = -np.linalg.solve(damped, gradient)
        self.trial = np.clip(self.x + delta, self.lower, self.upper)
        self.done = bool(np.all(self.trial == self.x))


def _fit_batched(data: FitData, reference: EffectModel, problems: list) -> list[FittedModel]:
    """:func:`_fit` for many problems at once by Levenberg-Marquardt (module docstring).

    Each iteration replays, in one batch, every unfinished problem's trial point and its
    forward-difference neighbours (:meth:`_Problem.trial_points`). A trial that lowers the RSS is
    accepted and the damping ``lambda`` divided by 3, otherwise ``lambda`` is multiplied by 4;
    the next trial solves ``(J^T J + lambda diag(J^T J)) delta = -J^T r`` (``J = dr/dx``) and is
    clipped to the bounds. A problem is done when an accepted step changes the RSS by less than
    ``_LM_RTOL`` relative or leaves it below ``_LM_EXACT_RSS``, or ``lambda`` exceeds 1e10.
    """
    states = []
    for hypotheses, start in problems:
        lower = np.array([h.lower for h in hypotheses])
        upper = np.array([h.upper for h in hypotheses])
        states.append(_Problem(list(hypotheses), lower, upper, np.clip(np.asarray(start, float), lower, upper)))
    for _ in range(_LM_ITERATIONS):
        active = [state for state in states if not state.done]
        if not active:
            break
        members, layout = [], []
        for state in active:
            steps, points = state.trial_points()
            layout.append((len(members), steps))
            members += [[h.as_effect(v) for h, v in zip(state.hypotheses, point)] for point in points]
        residuals = data.weighted_residuals_many(reference, members)
        for state, (first, steps) in zip(active, layout):
            state.update(residuals[first], residuals[first + 1:first + 1 + len(steps)], steps)
    return [FittedModel(state.hypotheses, state.x, state.rss, *_covariances(state.jacobian, state.residual, data))
            for state in states]


def step_threshold(n_tested: int, *, excess: float = 0.0) -> float:
    """The likelihood ratio an effect must exceed to be accepted at a step of the search: the
    Bonferroni-corrected chi-squared quantile at :data:`FAMILY_ALPHA` over the ``n_tested``
    hypotheses (1 degree of freedom), and at least :data:`MIN_EXCESS_FRACTION` of ``excess``,
    the residual energy noise does not explain (``RSS - N``, or the filter error's excess; 0
    where only the test counts)."""
    return max(float(stats.chi2.isf(FAMILY_ALPHA / max(n_tested, 1), 1)), MIN_EXCESS_FRACTION * excess)


def akaike_weights(criteria) -> np.ndarray:
    """Akaike weights ``w_i = exp(-(AIC_i - AIC_min) / 2) / sum_j exp(-(AIC_j - AIC_min) / 2)``
    of models with information criteria ``criteria`` (K,), each up to one shared constant
    (Akaike, IEEE Trans. Automatic Control 19(6), 1974; Burnham & Anderson, *Model Selection and
    Multimodel Inference*, 2nd ed., 2002, sec. 2.9): shape (K,), summing to 1."""
    criteria = np.asarray(criteria, dtype=float)
    relative = np.exp(-(criteria - criteria.min()) / 2)
    return relative / relative.sum()


def weigh_step(data: FitData, model: FittedModel, fits: list[FittedModel], *,
               n_tested: int) -> tuple[FittedModel, dict | None, dict | None]:
    """One step of a stepwise search: the best of ``fits`` (each ``model`` plus one hypothesis)
    and whether it is accepted. Accepted when its likelihood ratio against ``model`` passes a
    Bonferroni-corrected chi-squared test at :data:`FAMILY_ALPHA` over the ``n_tested``
    hypotheses and removes at least :data:`MIN_EXCESS_FRACTION` of the residual energy noise
    does not explain (``RSS - N``); its confidence is its Akaike weight among ``fits`` and
    ``model`` (Burnham & Anderson, *Model Selection and Multimodel Inference*, 2nd ed., 2002,
    sec. 2.9), its alternatives the competitors within :data:`MAX_EVIDENCE_RATIO`.

    Parameters
    ----------
    data : FitData
        For the number of residuals ``N``.
    model : FittedModel
        The effects accepted so far.
    fits : list of FittedModel
        ``model`` plus one hypothesis each, fitted jointly.
    n_tested : int
        Hypotheses tested at this step (the Bonferroni family).

    Returns
    -------
    best : FittedModel
    step : dict or None
        ``key``, ``lr``, ``p_value``, ``confidence``, ``alternatives`` (dicts with ``effect``,
        target, ``value``, ``evidence_ratio``); None when not accepted.
    rejected : dict or None
        When not accepted: ``key``, ``value``, ``lr``, ``threshold``.
    """
    best = min(fits, key=lambda fitted: fitted.rss)
    lr = model.rss - best.rss
    threshold = step_threshold(n_tested, excess=model.rss - data.n_residuals)
    new = best.hypotheses[-1]
    if lr <= threshold:
        return best, None, {"key": new.key, "value": new.effect_value(best.values[-1]), "lr": float(lr),
                            "threshold": float(threshold)}
    weights = akaike_weights([model.rss] + [fitted.rss + 2 for fitted in fits])  # AIC = RSS + 2 p, up to a constant
    ranked = sorted(zip(fits, weights[1:]), key=lambda pair: pair[0].rss)
    alternatives = []
    for fitted, _ in ranked[1:]:
        ratio = math.exp(min((fitted.rss - best.rss) / 2, 700.0))  # exp(700) is near the float limit
        if ratio < MAX_EVIDENCE_RATIO and len(alternatives) < MAX_ALTERNATIVES:
            alternatives.append({**fitted.hypotheses[-1].as_effect(fitted.values[-1]), "evidence_ratio": ratio})
    step = {"key": new.key, "lr": float(lr), "p_value": float(stats.chi2.sf(lr, 1)),
            "confidence": float(ranked[0][1]), "alternatives": alternatives}
    return best, step, None
