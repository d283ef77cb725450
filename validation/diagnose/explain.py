"""Explain: named hypotheses fitted to the recordings by output error, accepted stepwise by
likelihood-ratio tests, ranked by evidence.

A *hypothesis* (:class:`validation.vehicles.effects.Hypothesis`) is one effect on one target (a
delay on ``theta_1s``, the derivative ``L_q``, a bias on ``q``, the blimp's ``X_UU`` ...) with one
free parameter, its value. :func:`hypotheses_for` lists what can be tested: a delay and a lag on
every excited input and a bias on every output, on any reference, plus the reference's own term
hypotheses (:meth:`validation.vehicles.effects.EffectModel.term_hypotheses`). Every hypothesis is
fitted by output error (:mod:`validation.diagnose.fitting`); with white Gaussian sensor noise of
known standard deviations a hypothesis' likelihood ratio against the model without it is
``LR = RSS_0 - RSS_1``, chi-squared with one degree of freedom when the effect is absent
(Wilks 1938).

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
Inference*, 2nd ed., 2002, sec. 2.9). Each accepted effect is finally ranked by its drop-one
likelihood ratio (against the final model refitted without it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from validation.diagnose.data import PreparedData
from validation.diagnose.fitting import FitData, FittedModel, fit_many, null_model
from validation.diagnose.locate import Location
from validation.vehicles.effects import MAX_DELAY, MAX_LAG, TARGET_KEYS, EffectModel, Hypothesis, effect_unit

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
#: Screening step of delays and lags, s: a fraction of the shortest actuator and rotor time
#: constants (the Bo105's flap, 0.07 s, Padfield 2007, ch. 3), so that one Gauss-Newton step
#: stays in the range where the response is nearly linear in the value.
_TIMING_STEP = 0.01
#: Screening step of a dead band, a fraction of the input's largest excursion from its start in
#: the fitted data: small enough that one Gauss-Newton step stays near linear.
_DEAD_BAND_STEP = 0.05
#: Screening step of an input gain: 5 %, as an FMU parameter's.
_GAIN_STEP = 0.05


@dataclass
class Selection:
    """Outcome of the stepwise search (:func:`select_effects`).

    Attributes
    ----------
    model : FittedModel
        The accepted effects, jointly fitted, in the order they were accepted.
    null_rss : float
        RSS of the reference (no effect).
    steps : list of dict
        Per accepted effect: ``key``, ``lr`` (against the model before it), ``p_value``,
        ``confidence`` (Akaike weight), ``alternatives`` (list of dicts with ``effect``,
        target, ``value``, ``evidence_ratio``).
    drop_lr : dict of key -> float
        LR of each accepted effect against the final model refitted without it.
    rejected : dict or None
        The best hypothesis that failed the test at the last step (``key``, ``value``, ``lr``,
        ``threshold``), for the report.
    n_screened : int
    """

    model: FittedModel
    null_rss: float
    steps: list
    drop_lr: dict
    rejected: dict | None
    n_screened: int


@dataclass
class NamedEffect:
    """One accepted effect with its evidence (the explain part of a diagnosis.json finding).

    Attributes
    ----------
    effect : dict
        ``{"effect", target key, "value"}``.
    unit : str
        Unit of the value (:func:`validation.vehicles.effects.effect_unit`).
    interval : list of float
        95 % Wald interval ``[lower, upper]`` (:meth:`FittedModel.interval`).
    model_value : float or None
        The reference's own value of a term; None for delays, lags and biases.
    confidence : float
        Akaike weight of the effect among the competitors at its step.
    likelihood_ratio : float
        Drop-one LR against the final model refitted without it.
    p_value : float
        ``P(chi2(1) > likelihood_ratio)``.
    alternatives : list of dict
        Competitors at its step (:class:`Selection`).
    main_output : int
        Index in ``data.output_names`` of the output it moves most, relative to the noise, on
        the fitted samples.
    alone : list of ndarray, shape (n_r, n_out)
        Per recording: the reference's replay with this effect alone.
    """

    effect: dict
    unit: str
    interval: list
    model_value: float | None
    confidence: float
    likelihood_ratio: float
    p_value: float
    alternatives: list
    main_output: int
    alone: list

    @property
    def target(self) -> str:
        """The input, term or output the effect acts on."""
        return self.effect[TARGET_KEYS[self.effect["effect"]]]


@dataclass
class Explanation:
    """Result of :func:`explain`.

    Attributes
    ----------
    effects : list of dict
        The accepted effects in the order accepted (the corrected model's).
    named : list of NamedEffect
        The same effects with their evidence, most important (largest drop-one LR) first.
    search : dict
        diagnosis.json's ``search``: ``hypotheses_tested``, ``null_rss``, ``final_rss``,
        ``n_residuals``, ``rejected`` (``effect``, target, ``value``, ``likelihood_ratio``,
        ``threshold``, or None).
    """

    effects: list
    named: list
    search: dict


def explain(data: PreparedData, location: Location, reference: EffectModel, *, progress=None) -> Explanation:
    """Search the effects the data support (module docstring) and weigh each one.

    ``progress(n, **status)``, optional, advances once per simulation batch.
    """
    hypotheses = hypotheses_for(reference, excited_inputs=data.excited, output_names=data.output_names,
                                noise_sd=data.typical_noise_sd, excursions=_excursions(data))
    selection = select_effects(data, reference, hypotheses, progress=progress)
    fitted, steps = selection.model, {step["key"]: step for step in selection.steps}
    named = []
    for index, (h, effect) in enumerate(zip(fitted.hypotheses, fitted.effects())):
        lr, step = selection.drop_lr[h.key], steps[h.key]
        alone = data.simulate(reference, [effect])
        named.append(NamedEffect(
            effect=effect, unit=effect_unit(effect, reference), interval=[float(v) for v in fitted.interval(index)],
            model_value=reference.model_value(h.target) if "term" in effect else None,
            confidence=step["confidence"], likelihood_ratio=lr, p_value=float(stats.chi2.sf(lr, 1)),
            alternatives=step["alternatives"], main_output=_main_output(data, alone, location.reference_replay),
            alone=alone))
    search = {"hypotheses_tested": selection.n_screened, "null_rss": selection.null_rss,
              "final_rss": fitted.rss, "n_residuals": data.n_residuals,
              "rejected": _describe_rejected(selection.rejected)}
    return Explanation(fitted.effects(), sorted(named, key=lambda n: -n.likelihood_ratio), search)


def _excursions(data: PreparedData) -> dict:
    """Per excited input, its largest distance from its value at the start of a recording, over
    the fitted samples of all recordings (the input's unit)."""
    return {name: max(float(np.max(np.abs(u[mask, j] - u[0, j]), initial=0.0))
                      for u, mask in zip(data.inputs, data.fit_mask))
            for j, name in enumerate(data.input_names) if name in data.excited}


def _main_output(data: PreparedData, alone: list, reference_replay: list) -> int:
    """Index of the output an effect moves most, relative to the noise, on the fitted samples
    (``alone``: the replays with the effect alone)."""
    energy = [sum(float(np.sum(((a[:, i] - r[:, i])[m] / sd[i]) ** 2))
                  for a, r, m, sd in zip(alone, reference_replay, data.fit_mask, data.noise_sd))
              for i in range(len(data.output_names))]
    return int(np.argmax(energy))


def _describe_rejected(rejected: dict | None) -> dict | None:
    if rejected is None:
        return None
    kind, target = rejected["key"]
    return {"effect": kind, TARGET_KEYS[kind]: target, "value": rejected["value"],
            "likelihood_ratio": rejected["lr"], "threshold": rejected["threshold"]}


def hypotheses_for(reference: EffectModel, *, excited_inputs, output_names, noise_sd,
                   excursions=None) -> list[Hypothesis]:
    """Every testable hypothesis on ``reference``: a delay (up to ``MAX_DELAY``), a lag (up to
    ``MAX_LAG``), a dead band (up to the input's largest excursion), a gain (null 1, at least
    0, screened at :data:`_GAIN_STEP`) and a saturation (null: the largest excursion, where it
    does nothing; screened inward) on each excited input, the
    reference's term hypotheses, a bias on each measured output (each kind where the reference
    takes it, :attr:`EffectModel.kinds`).

    ``noise_sd`` (dict output -> typical noise standard deviation) sets the bias screening step;
    ``excursions`` (dict input -> largest ``|u - u[0]|`` in the fitted data, the input's unit)
    the dead band's step and bound (no dead band hypothesis without it).
    """
    hypotheses = []
    for name in reference.input_names:
        if name in excited_inputs:
            hypotheses.append(Hypothesis("time_delay", name, 0.0, 0.0, MAX_DELAY, _TIMING_STEP))
            hypotheses.append(Hypothesis("input_lag", name, 0.0, 0.0, MAX_LAG, _TIMING_STEP))
            hypotheses.append(Hypothesis("input_gain", name, 1.0, 0.0, math.inf, _GAIN_STEP))
            excursion = (excursions or {}).get(name, 0.0)
            if excursion > 0:  # a dead band grows from 0; a limit does nothing at the excursion: screened inward
                hypotheses.append(Hypothesis("dead_band", name, 0.0, 0.0, excursion, _DEAD_BAND_STEP * excursion))
                hypotheses.append(Hypothesis("saturation", name, excursion, 0.0, excursion,
                                             -_DEAD_BAND_STEP * excursion))
    hypotheses += reference.term_hypotheses(excited_inputs)
    for name in output_names:
        hypotheses.append(Hypothesis("sensor_bias", name, 0.0, -math.inf, math.inf, float(noise_sd[name])))
    return [h for h in hypotheses if h.effect in reference.kinds]


def select_effects(data: FitData, reference: EffectModel, hypotheses: list[Hypothesis], *,
                   progress=None) -> Selection:
    """Forward stepwise search for the effects the data support (module docstring)."""
    model = null_model(data, reference)
    null_rss = model.rss
    steps, rejected = [], None
    for _ in range(MAX_EFFECTS):
        taken = {h.key for h in model.hypotheses}
        candidates = [h for h in hypotheses if h.key not in taken]
        if not candidates:
            break
        fits = _fit_promising(data, reference, model, candidates, progress)
        best = min(fits, key=lambda fitted: fitted.rss)
        lr = model.rss - best.rss
        threshold = max(stats.chi2.isf(FAMILY_ALPHA / len(candidates), 1),
                        MIN_EXCESS_FRACTION * (model.rss - data.n_residuals))
        new = best.hypotheses[-1]
        if lr <= threshold:
            rejected = {"key": new.key, "value": float(best.values[-1]), "lr": float(lr),
                        "threshold": float(threshold)}
            break
        weights = _akaike_weights([model.rss] + [fitted.rss for fitted in fits], [0] + [1] * len(fits))
        ranked = sorted(zip(fits, weights[1:]), key=lambda pair: pair[0].rss)
        steps.append({"key": new.key, "lr": float(lr), "p_value": float(stats.chi2.sf(lr, 1)),
                      "confidence": float(ranked[0][1]),
                      "alternatives": _alternatives([fitted for fitted, _ in ranked[1:]], best)})
        model = best
    return Selection(model, null_rss, steps, _drop_one_lr(data, reference, model, null_rss), rejected,
                     len(hypotheses))


def _fit_promising(data: FitData, reference: EffectModel, model: FittedModel, candidates: list,
                   progress) -> list[FittedModel]:
    """Screen ``candidates`` on top of ``model`` and fit the most promising jointly with it
    (steps 1 and 2 of the module docstring)."""
    scores = _screen(data, reference, model, candidates, progress)
    order = np.argsort([-score for score, _ in scores])
    chosen = list(order[:N_FULL_FITS])
    for kind in TARGET_KEYS:  # the best of every kind, so competitors are always compared
        best_of_kind = next((i for i in order if candidates[i].effect == kind), None)
        if best_of_kind is not None and best_of_kind not in chosen:
            chosen.append(best_of_kind)
    fits = fit_many(data, reference, [(model.hypotheses + [candidates[i]], list(model.values) + [scores[i][1]])
                                      for i in chosen])
    if progress:
        for i in chosen:
            progress(1, fitted=f"{candidates[i].effect}:{candidates[i].target}")
    return fits


def _alternatives(competitors: list[FittedModel], best: FittedModel) -> list[dict]:
    """The competitors of ``best`` (ranked by RSS) that the data disfavour by less than
    :data:`MAX_EVIDENCE_RATIO`, at most :data:`MAX_ALTERNATIVES`."""
    alternatives = []
    for fitted in competitors:
        ratio = math.exp(min((fitted.rss - best.rss) / 2, 700.0))  # exp(700) is near the float limit
        if ratio < MAX_EVIDENCE_RATIO and len(alternatives) < MAX_ALTERNATIVES:
            alternatives.append({**fitted.hypotheses[-1].as_effect(fitted.values[-1]), "evidence_ratio": ratio})
    return alternatives


def _drop_one_lr(data: FitData, reference: EffectModel, model: FittedModel, null_rss: float) -> dict:
    """LR of each effect of ``model`` against ``model`` refitted without it."""
    n_accepted = len(model.hypotheses)
    reduced = fit_many(data, reference, [([model.hypotheses[i] for i in range(n_accepted) if i != index],
                                          model.values[[i for i in range(n_accepted) if i != index]])
                                         for index in range(n_accepted)]) if n_accepted > 1 else []
    return {h.key: float((reduced[index].rss if reduced else null_rss) - model.rss)
            for index, h in enumerate(model.hypotheses)}


def _screen(data: FitData, reference: EffectModel, model: FittedModel, candidates: list, progress) -> list:
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
        if h.upper == h.null and delta > 0:  # one-sided (a limit at the largest excursion)
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
