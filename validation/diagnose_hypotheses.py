"""Explain: named hypotheses fitted to recordings by output error, ranked by evidence.

A *hypothesis* is one effect of :mod:`validation.effects` on one target (a delay on
``theta_1s``, the derivative ``L_q``, a bias on ``q`` ...) with one free parameter, its value.
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
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.optimize import least_squares

from .bo105 import INPUT_NAMES, ROW_LETTERS, STATE_NAMES, Bo105Reference
from .effects import MAX_DELAY, MAX_LAG, TARGET_KEYS, simulate_with_effects

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
    time, inputs : list of ndarray, shapes (n_r,), (n_r, 4)
    measured : list of ndarray, shape (n_r, n_out)
        Measured outputs, in the order of ``output_names``.
    output_names : tuple of str
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
    _columns: list = field(default_factory=list)

    def __post_init__(self):
        self._columns = [STATE_NAMES.index(name) for name in self.output_names]

    @property
    def n_residuals(self) -> int:
        return int(sum(mask.sum() for mask in self.fit_mask)) * len(self.output_names)

    def simulate(self, reference: Bo105Reference, effects: list[dict]) -> list:
        """Replayed outputs per recording, shape (n_r, n_out) each."""
        return [simulate_with_effects(reference, effects, t, u)[:, self._columns]
                for t, u in zip(self.time, self.inputs)]

    def weighted_residuals(self, reference: Bo105Reference, effects: list[dict]) -> np.ndarray:
        """``(measured - replay) / noise_sd`` on the fit samples, flattened, shape (N,)."""
        parts = []
        with np.errstate(over="ignore", invalid="ignore"):
            replays = self.simulate(reference, effects)
        for replay, measured, sd, mask in zip(replays, self.measured, self.noise_sd, self.fit_mask):
            if mask.any():
                parts.append(((measured[mask] - replay[mask]) / sd).ravel())
        # A trial value that makes the model diverge gets a large, finite misfit, so the
        # optimiser steps back instead of failing on inf or NaN.
        return np.clip(np.nan_to_num(np.concatenate(parts), nan=_DIVERGED), -_DIVERGED, _DIVERGED)


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


def hypotheses_for(reference: Bo105Reference, *, excited_inputs, output_names, noise_sd) -> list:
    """Every testable hypothesis: delay and lag on each excited input, every control derivative
    of an excited input, every stability derivative (6 rows x 8 states, off-axis couplings
    included), and a bias on each measured output.

    ``noise_sd`` (dict output -> typical noise standard deviation) sets the bias screening step.
    """
    hypotheses = []
    for name in INPUT_NAMES:
        if name in excited_inputs:
            hypotheses.append(Hypothesis("time_delay", name, 0.0, 0.0, MAX_DELAY, 0.01))
            hypotheses.append(Hypothesis("input_lag", name, 0.0, 0.0, MAX_LAG, 0.01))
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
    for name in output_names:
        hypotheses.append(Hypothesis("sensor_bias", name, 0.0, -math.inf, math.inf, float(noise_sd[name])))
    return hypotheses


def _fit(data: FitData, reference: Bo105Reference, hypotheses: list, start) -> FittedModel:
    """Joint output-error least squares of ``hypotheses`` from ``start`` (module docstring)."""
    lower = np.array([h.lower for h in hypotheses])
    upper = np.array([h.upper for h in hypotheses])
    start = np.clip(np.asarray(start, dtype=float), lower, upper)

    def residuals(values):
        return data.weighted_residuals(reference, [h.as_effect(v) for h, v in zip(hypotheses, values)])

    result = least_squares(residuals, start, bounds=(lower, upper), x_scale="jac", method="trf",
                           xtol=1e-10, ftol=1e-10, max_nfev=200 * len(hypotheses))
    rss = float(result.fun @ result.fun)
    n, p = len(result.fun), len(hypotheses)
    scale = max(1.0, rss / max(n - p, 1))
    covariance = scale * np.linalg.pinv(result.jac.T @ result.jac)
    return FittedModel(list(hypotheses), result.x, rss, covariance)


def _screen(data: FitData, reference: Bo105Reference, model: FittedModel, candidates: list,
            progress) -> list:
    """One Gauss-Newton step per candidate on top of ``model``: (score, one-step value) each."""
    base_effects = model.effects()
    r0 = data.weighted_residuals(reference, base_effects)
    scores = []
    for h in candidates:
        perturbed = data.weighted_residuals(reference, base_effects + [h.as_effect(h.null + h.step)])
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


def select_effects(data: FitData, reference: Bo105Reference, hypotheses: list, *,
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
        fits = []
        for i in chosen:
            fits.append(_fit(data, reference, model.hypotheses + [candidates[i]],
                             list(model.values) + [scores[i][1]]))
            if progress:
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
    for index, h in enumerate(model.hypotheses):
        others = [i for i in range(len(model.hypotheses)) if i != index]
        if others:
            reduced = _fit(data, reference, [model.hypotheses[i] for i in others],
                           model.values[others])
            reduced_rss = reduced.rss
        else:
            reduced_rss = null_rss
        drop_lr[h.key] = float(reduced_rss - model.rss)
    return Selection(model, null_rss, steps, drop_lr, rejected, len(hypotheses))
