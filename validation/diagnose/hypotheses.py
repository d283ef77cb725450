"""Explain: named hypotheses fitted to recordings by output error, ranked by evidence.

A *hypothesis* is one effect of :mod:`validation.vehicles.effects` on one target (a delay on
``theta_1s``, the derivative ``L_q``, a bias on ``q``, the blimp's ``X_UU`` ...) with one free
parameter, its value. The reference is the vehicle adapter: :func:`validation.vehicles.effects.simulate_many`
replays it with effects, :func:`hypotheses_for` lists what can be tested on it.
Every hypothesis is fitted by output-error least squares: the reference, with the effects under
test, is replayed from trim on the recorded inputs and the noise-weighted differences to the
measured outputs are minimised (Jategaonkar, *Flight Vehicle System Identification*, 2006,
ch. 4; scipy's trust-region reflective ``least_squares``). With white Gaussian sensor noise of
known standard deviations the weighted residual sum of squares ``RSS`` is ``-2 ln L`` up to a
constant, so a hypothesis' likelihood ratio against the model without it is ``LR = RSS_0 -
RSS_1``, chi-squared with one degree of freedom when the effect is absent (Wilks 1938).

Search (forward stepwise selection, e.g. Hastie, Tibshirani & Friedman, *Elements of
Statistical Learning*, 2nd ed., 2009, sec. 3.3.2):

1. *Screen* every testable hypothesis on top of the current model with one Gauss-Newton step:
   the output sensitivity ``g`` to the parameter by a finite difference gives the one-step
   estimate ``delta = g.r / g.g`` and the score statistic ``(g.r)^2 / g.g`` (Rao 1948), one
   simulation per hypothesis.
2. *Fit* the most promising (the :data:`N_FULL_FITS` best scores, plus the best of every kind,
   so that a delay is always compared with a lag) jointly with the effects already found.
3. *Accept* the best fit if its LR passes a Bonferroni-corrected chi-squared test at family-wise
   level :data:`FAMILY_ALPHA` over the hypotheses screened, and removes at least
   :data:`MIN_EXCESS_FRACTION` of the residual energy noise does not explain (``RSS - N``);
   the second rule stops the search from naming ever smaller pieces of a misfit that no named
   effect captures (that is left to the ``unexplained`` finding and the residual GP). At most
   :data:`MAX_EFFECTS` effects.

Evidence between competitors (same number of parameters) is the likelihood ratio
``exp((RSS_alt - RSS_best) / 2)``; ``confidence`` is the Akaike weight of the winner among the
fitted competitors and "no further effect" (Burnham & Anderson, *Model Selection and Multimodel
Inference*, 2nd ed., 2002, sec. 2.9). Intervals are 95 % Wald intervals from the Jacobian at the
joint optimum, ``cov = s^2 (J^T J)^-1`` with ``s^2 = max(1, RSS / (N - p))`` so that a misfit
beyond the noise widens them (Seber & Wild, *Nonlinear Regression*, 1989, sec. 2.2).

Fitting: the Bo105 (exact discretisation, milliseconds per replay) uses scipy's ``least_squares``
per fit. The blimp (a nonlinear ODE integrated by RK4) fits all of a step's candidates at once
with :func:`_fit_batched`, a Levenberg-Marquardt iteration (Marquardt, J. SIAM 11(2), 1963) whose
trial points and forward-difference Jacobian columns of every candidate are one batched replay.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats
from scipy.optimize import least_squares

from validation.vehicles import blimp_effects
from validation.vehicles.blimp import BlimpReference
from validation.vehicles.bo105 import INPUT_NAMES, ROW_LETTERS, STATE_NAMES
from validation.vehicles.effects import MAX_DELAY, MAX_LAG, TARGET_KEYS, batches_simulations, model_value, simulate_many

#: Family-wise false-alarm probability of each step's test over all hypotheses screened.
FAMILY_ALPHA = 0.01
#: An accepted effect must remove at least this fraction of the unexplained residual energy.
MIN_EXCESS_FRACTION = 0.05
#: Most named effects in one diagnosis (pairs must be found; three leaves room for one more).
MAX_EFFECTS = 3
#: Hypotheses fitted in full per step, besides the best of each kind.
N_FULL_FITS = 6
#: Competitors listed with a finding: at most this many, with evidence ratio below the limit.
MAX_ALTERNATIVES = 3
MAX_EVIDENCE_RATIO = 1e6
_Z95 = stats.norm.isf(0.025)
#: Largest weighted residual (noise standard deviations) a diverging trial model is given.
_DIVERGED = 1e6
#: Batched Levenberg-Marquardt: most iterations, relative RSS change that counts as converged,
#: forward-difference step as a fraction of each hypothesis' screening step.
_LM_ITERATIONS = 40
_LM_RTOL = 1e-9
_LM_DIFF = 1e-3


@dataclass(frozen=True)
class Hypothesis:
    """One effect on one target; ``null`` is the parameter value at which it does nothing."""

    effect: str
    target: str
    null: float
    lower: float
    upper: float
    step: float  # finite-difference step for screening, parameter units

    def as_effect(self, value: float) -> dict:
        return {"effect": self.effect, TARGET_KEYS[self.effect]: self.target, "value": float(value)}

    @property
    def key(self) -> tuple[str, str]:
        return self.effect, self.target


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
    """

    time: list
    inputs: list
    measured: list
    output_names: tuple
    noise_sd: list
    fit_mask: list

    @property
    def n_residuals(self) -> int:
        return int(sum(mask.sum() for mask in self.fit_mask)) * len(self.output_names)

    def _columns(self, reference) -> list:
        return [reference.state_names.index(name) for name in self.output_names]

    def simulate(self, reference, effects: list[dict]) -> list:
        """Replayed outputs per recording, shape (n_r, n_out) each."""
        return [replay[0] for replay in self._simulate_many(reference, [effects], fitted_only=False)]

    def _simulate_many(self, reference, effect_lists, *, fitted_only: bool) -> list:
        """Per recording (``None`` where ``fitted_only`` and nothing of it is fitted): replayed
        outputs of each effect list, shape (B, n_r, n_out)."""
        columns = self._columns(reference)
        return [simulate_many(reference, effect_lists, t, u)[:, :, columns]
                if mask.any() or not fitted_only else None
                for t, u, mask in zip(self.time, self.inputs, self.fit_mask)]

    def weighted_residuals_many(self, reference, effect_lists) -> np.ndarray:
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

    def weighted_residuals(self, reference, effects: list[dict]) -> np.ndarray:
        """``(measured - replay) / noise_sd`` on the fit samples, flattened, shape (N,)."""
        return self.weighted_residuals_many(reference, [effects])[0]


@dataclass
class FittedModel:
    """A set of hypotheses at their joint least-squares values."""

    hypotheses: list
    values: np.ndarray
    rss: float
    covariance: np.ndarray

    def effects(self) -> list[dict]:
        return [h.as_effect(v) for h, v in zip(self.hypotheses, self.values)]

    def interval(self, index: int) -> tuple[float, float]:
        """95 % Wald interval of parameter ``index``, clipped to its bounds."""
        h, value = self.hypotheses[index], self.values[index]
        half = _Z95 * math.sqrt(max(self.covariance[index, index], 0.0))
        return max(value - half, h.lower), min(value + half, h.upper)


@dataclass
class Selection:
    """Outcome of the stepwise search.

    Attributes
    ----------
    model : FittedModel
        The accepted effects, jointly fitted.
    null_rss : float
        RSS of the reference (no effect).
    steps : list of dict
        Per accepted effect: ``key``, ``lr`` (against the model before it), ``p_value``,
        ``confidence`` (Akaike weight), ``alternatives`` (list of dicts with ``effect``,
        target, ``value``, ``evidence_ratio``).
    drop_lr : dict of key -> float
        LR of each accepted effect against the final model refitted without it.
    rejected : dict or None
        The best hypothesis that failed the test at the last step (``key``, ``lr``,
        ``threshold``), for the report.
    n_screened : int
    """

    model: FittedModel
    null_rss: float
    steps: list
    drop_lr: dict
    rejected: dict | None
    n_screened: int


def hypotheses_for(reference, *, excited_inputs, output_names, noise_sd) -> list:
    """Every testable hypothesis on ``reference``: delay and lag on each excited input, a bias
    on each measured output, and the reference's terms: on a Bo105 every control derivative of
    an excited input and every stability derivative (6 rows x 8 states, off-axis couplings
    included); on the blimp the thrust gains of the excited fans, the rotational damping
    ``L_P, M_Q, N_R``, the quadratic drag ``X_UU, Y_VV, Z_WW`` and the force offsets
    ``X_0, Y_0, Z_0, N_0`` (:mod:`validation.vehicles.blimp_effects`).

    ``noise_sd`` (dict output -> typical noise standard deviation) sets the bias screening step.
    """
    hypotheses = []
    for name in reference.input_names:
        if name in excited_inputs:
            hypotheses.append(Hypothesis("time_delay", name, 0.0, 0.0, MAX_DELAY, 0.01))
            hypotheses.append(Hypothesis("input_lag", name, 0.0, 0.0, MAX_LAG, 0.01))
    hypotheses += (_blimp_terms(reference, excited_inputs) if isinstance(reference, BlimpReference)
                   else _bo105_derivatives(reference, excited_inputs))
    for name in output_names:
        hypotheses.append(Hypothesis("sensor_bias", name, 0.0, -math.inf, math.inf, float(noise_sd[name])))
    return hypotheses


#: Screening steps of the blimp's force offsets: 1 mN (about 1 % of full gondola thrust, the
#: buoyancy drift of the stand-in) and 1 mN m.
_OFFSET_STEPS = {"X_0": 1e-3, "Y_0": 1e-3, "Z_0": 1e-3, "N_0": 1e-3}


def _blimp_terms(reference: BlimpReference, excited_inputs) -> list:
    """The blimp's term hypotheses (:func:`hypotheses_for`); thrust gains stay positive."""
    hypotheses = []
    for term, (column, _) in blimp_effects.CONTROL_TERMS.items():
        if column in excited_inputs:
            value = model_value(reference, term)
            hypotheses.append(Hypothesis("control_derivative", term, value, 0.0, math.inf, 0.05 * value))
    for kind, terms in (("stability_derivative", blimp_effects.STABILITY_TERMS),
                        ("quadratic_drag", blimp_effects.DRAG_TERMS)):
        for term in terms:
            value = model_value(reference, term)
            hypotheses.append(Hypothesis(kind, term, value, -math.inf, math.inf, 0.05 * abs(value)))
    for term, step in _OFFSET_STEPS.items():
        hypotheses.append(Hypothesis("force_offset", term, model_value(reference, term),
                                     -math.inf, math.inf, step))
    return hypotheses


def _bo105_derivatives(reference, excited_inputs) -> list:
    """The Bo105's derivative hypotheses (:func:`hypotheses_for`)."""
    hypotheses = []
    A, B = reference.A, reference.B
    for letter, row_state in ROW_LETTERS.items():
        row = STATE_NAMES.index(row_state)
        for columns, matrix, kind in ((STATE_NAMES, A, "stability_derivative"),
                                      (INPUT_NAMES, B, "control_derivative")):
            typical = np.max(np.abs(matrix[row]))
            for column, column_name in enumerate(columns):
                if kind == "control_derivative" and column_name not in excited_inputs:
                    continue
                value = matrix[row, column]
                step = 0.05 * max(abs(value), 0.01 * typical, 1e-6)
                hypotheses.append(Hypothesis(kind, f"{letter}_{column_name}", float(value),
                                             -math.inf, math.inf, step))
    return hypotheses


def _covariance(jacobian: np.ndarray, rss: float) -> np.ndarray:
    """Wald covariance ``s^2 (J^T J)^-1`` with ``s^2 = max(1, RSS / (N - p))`` (module docstring)."""
    n, p = jacobian.shape
    return max(1.0, rss / max(n - p, 1)) * np.linalg.pinv(jacobian.T @ jacobian)


def _fit_many(data: FitData, reference, problems: list) -> list:
    """Joint output-error fits of several ``(hypotheses, start)`` problems, one FittedModel each."""
    if batches_simulations(reference):
        return _fit_batched(data, reference, problems)
    return [_fit(data, reference, hypotheses, start) for hypotheses, start in problems]


def _fit(data: FitData, reference, hypotheses: list, start) -> FittedModel:
    """Joint output-error least squares of ``hypotheses`` from ``start`` (module docstring)."""
    lower = np.array([h.lower for h in hypotheses])
    upper = np.array([h.upper for h in hypotheses])
    start = np.clip(np.asarray(start, dtype=float), lower, upper)

    def residuals(values):
        return data.weighted_residuals(reference, [h.as_effect(v) for h, v in zip(hypotheses, values)])

    result = least_squares(residuals, start, bounds=(lower, upper), x_scale="jac", method="trf",
                           xtol=1e-10, ftol=1e-10, max_nfev=200 * len(hypotheses))
    rss = float(result.fun @ result.fun)
    return FittedModel(list(hypotheses), result.x, rss, _covariance(result.jac, rss))


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


def _fit_batched(data: FitData, reference, problems: list) -> list:
    """:func:`_fit` for many problems at once by Levenberg-Marquardt (module docstring).

    Each iteration replays, in one batch, every unfinished problem's trial point and its
    forward-difference neighbours (step ``_LM_DIFF`` times the hypothesis' screening step, taken
    inward at a bound). A trial that lowers the RSS is accepted and the damping ``lambda`` divided
    by 3, otherwise ``lambda`` is multiplied by 4; the next trial solves
    ``(J^T J + lambda diag(J^T J)) delta = -J^T r`` (``J = dr/dx``) and is clipped to the bounds.
    A problem is done when an accepted step changes the RSS by less than ``_LM_RTOL`` relative,
    or ``lambda`` exceeds 1e10.
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
            steps = np.array([_LM_DIFF * h.step for h in state.hypotheses])
            steps = np.where(state.trial + steps > state.upper, -steps, steps)
            layout.append((len(members), steps))
            points = [state.trial] + [state.trial + np.eye(len(steps))[j] * steps[j] for j in range(len(steps))]
            members += [[h.as_effect(v) for h, v in zip(state.hypotheses, point)] for point in points]
        residuals = data.weighted_residuals_many(reference, members)
        for state, (first, steps) in zip(active, layout):
            residual = residuals[first]
            rss = float(residual @ residual)
            if rss < state.rss:
                converged = state.rss - rss <= _LM_RTOL * rss
                state.x, state.rss, state.residual = state.trial, rss, residual
                state.jacobian = (residuals[first + 1:first + 1 + len(steps)] - residual).T / steps
                state.damping /= 3.0
                state.done = converged
            else:
                state.damping *= 4.0
                state.done = state.damping > 1e10
            if state.done:
                continue
            normal = state.jacobian.T @ state.jacobian
            gradient = state.jacobian.T @ state.residual
            damped = normal + state.damping * np.diag(np.diag(normal)) + 1e-12 * np.eye(len(steps))
            delta = -np.linalg.solve(damped, gradient)
            state.trial = np.clip(state.x + delta, state.lower, state.upper)
            state.done = bool(np.all(state.trial == state.x))
    return [FittedModel(state.hypotheses, state.x, state.rss, _covariance(state.jacobian, state.rss))
            for state in states]


def _screen(data: FitData, reference, model: FittedModel, candidates: list, progress) -> list:
    """One Gauss-Newton step per candidate on top of ``model``: (score, one-step value) each."""
    base_effects = model.effects()
    r0 = data.weighted_residuals(reference, base_effects)
    perturbed_all = data.weighted_residuals_many(
        reference, [base_effects + [h.as_effect(h.null + h.step)] for h in candidates])
    scores = []
    for h, perturbed in zip(candidates, perturbed_all):
        g = (r0 - perturbed) / h.step  # d(replay)/d(parameter), weighted
        gg = float(g @ g)
        delta = float(g @ r0) / gg if gg > 0 else 0.0
        if h.lower == h.null and delta < 0:  # one-sided (delays, lags): no gain below zero
            delta = 0.0
        scores.append((gg * delta**2, h.null + delta))
        if progress:
            progress(1)
    return scores


def _akaike_weights(rss_values, n_parameters) -> np.ndarray:
    """Akaike weights ``exp(-AIC_i/2) / sum`` with ``AIC = RSS + 2 p`` (Burnham & Anderson 2002)."""
    aic = np.asarray(rss_values) + 2 * np.asarray(n_parameters)
    weights = np.exp(-(aic - aic.min()) / 2)
    return weights / weights.sum()


def select_effects(data: FitData, reference, hypotheses: list, *,
                   progress=None) -> Selection:
    """Forward stepwise search for the effects the data support (module docstring)."""
    n_residuals = data.n_residuals
    model = FittedModel([], np.zeros(0), 0.0, np.zeros((0, 0)))
    model.rss = float(np.sum(data.weighted_residuals(reference, []) ** 2))
    null_rss = model.rss
    steps, rejected = [], None
    for _ in range(MAX_EFFECTS):
        taken = {h.key for h in model.hypotheses}
        candidates = [h for h in hypotheses if h.key not in taken]
        if not candidates:
            break
        scores = _screen(data, reference, model, candidates, progress)
        order = np.argsort([-score for score, _ in scores])
        chosen = list(order[:N_FULL_FITS])
        for kind in TARGET_KEYS:  # the best of every kind, so competitors are always compared
            best_of_kind = next((i for i in order if candidates[i].effect == kind), None)
            if best_of_kind is not None and best_of_kind not in chosen:
                chosen.append(best_of_kind)
        fits = _fit_many(data, reference, [(model.hypotheses + [candidates[i]],
                                             list(model.values) + [scores[i][1]]) for i in chosen])
        if progress:
            for i in chosen:
                progress(1, fitted=f"{candidates[i].effect}:{candidates[i].target}")
        best = min(fits, key=lambda fitted: fitted.rss)
        lr = model.rss - best.rss
        threshold = max(stats.chi2.isf(FAMILY_ALPHA / len(candidates), 1),
                        MIN_EXCESS_FRACTION * (model.rss - n_residuals))
        new = best.hypotheses[-1]
        if lr <= threshold:
            rejected = {"key": new.key, "value": float(best.values[-1]), "lr": float(lr),
                        "threshold": float(threshold)}
            break
        weights = _akaike_weights([model.rss] + [fitted.rss for fitted in fits],
                                  [0] + [1] * len(fits))
        ranked = sorted(zip(fits, weights[1:]), key=lambda pair: pair[0].rss)
        alternatives = []
        for fitted, _ in ranked[1:]:
            ratio = math.exp(min((fitted.rss - best.rss) / 2, 700.0))
            if ratio < MAX_EVIDENCE_RATIO and len(alternatives) < MAX_ALTERNATIVES:
                alternatives.append({**fitted.hypotheses[-1].as_effect(fitted.values[-1]),
                                     "evidence_ratio": ratio})
        steps.append({"key": new.key, "lr": float(lr), "p_value": float(stats.chi2.sf(lr, 1)),
                      "confidence": float(ranked[0][1]), "alternatives": alternatives})
        model = best
    drop_lr = {}
    n_accepted = len(model.hypotheses)
    reduced = _fit_many(data, reference, [([model.hypotheses[i] for i in range(n_accepted) if i != index],
                                           model.values[[i for i in range(n_accepted) if i != index]])
                                          for index in range(n_accepted)]) if n_accepted > 1 else []
    for index, h in enumerate(model.hypotheses):
        drop_lr[h.key] = float((reduced[index].rss if reduced else null_rss) - model.rss)
    return Selection(model, null_rss, steps, drop_lr, rejected, len(hypotheses))
