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
   level :data:`~validation.diagnose.fitting.FAMILY_ALPHA` over the hypotheses screened, and
   removes at least :data:`~validation.diagnose.fitting.MIN_EXCESS_FRACTION` of the residual
   energy noise does not explain (``RSS - N``; :func:`~validation.diagnose.fitting.weigh_step`);
   the second rule stops the search from naming ever smaller pieces of a misfit that no named
   effect captures (that is left to the ``unexplained`` finding and the residual GP). At most
   :data:`MAX_EFFECTS` effects.

At every step the residual search (:mod:`validation.diagnose.search`) offers the terms of its
library the current model's error holds beside the named hypotheses (``search_term``, linear
references); they are screened, fitted and accepted alike, the Bonferroni family of a step being
the named hypotheses and the library together.

Evidence between competitors (same number of parameters) is the likelihood ratio
``exp((RSS_alt - RSS_best) / 2)``; ``confidence`` is the Akaike weight of the winner among the
fitted competitors and "no further effect" (Burnham & Anderson, *Model Selection and Multimodel
Inference*, 2nd ed., 2002, sec. 2.9). Each accepted effect is finally ranked by its drop-one
likelihood ratio (against the final model refitted without it), and each constant change (a
derivative, a gain, an FMU's parameter) is checked for amplitude dependence
(:func:`amplitude_check`), which caps the confidence of one the data want different on large and
small excursions; every accepted effect is checked for a change during the flights
(:mod:`validation.diagnose.over_time`), which caps the confidence of one that changes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from scipy import stats

from validation.diagnose.data import PreparedData
from validation.diagnose.disturbance import AirCompetitor, describe, gust_dynamics, trim_airspeed
from validation.diagnose.fitting import (
    MAX_ALTERNATIVES,
    MAX_EVIDENCE_RATIO,
    FitData,
    FittedModel,
    akaike_weights,
    fit_many,
    null_model,
    step_threshold,
    weigh_step,
)
from validation.diagnose.locate import Location
from validation.diagnose.over_time import refit_windows, time_check
from validation.diagnose.search import search_candidates
from validation.vehicles.effects import (
    MAX_DELAY,
    MAX_LAG,
    TARGET_KEYS,
    EffectModel,
    Hypothesis,
    cross_axis_pairs,
    cross_axis_target,
    effect_unit,
)

#: Most named effects in one diagnosis. Pairs must be found, and a vehicle with several effects at
#: once needs room beyond them: on the Bo105 flight-test stand-in (off-axis coupling, lags and
#: delays on every control) three left its pitch lag out, the fourth step names it
#: (docs/diagnose.md, "Several effects at once: the `bo105-80kt-flight` stand-in").
MAX_EFFECTS = 4
#: Most effects taken back in one search (:func:`_take_back`): each drop buys one more step, and
#: no effect taken back is offered again, so the search cannot cycle.
MAX_TAKEN_BACK = 2
#: Effects that claim a constant change (a derivative, a gain, an FMU's parameter), checked for
#: amplitude dependence (:func:`amplitude_check`).
LINEAR_KINDS = ("control_derivative", "stability_derivative", "input_gain", "fmu_parameter")
#: Level of the amplitude test of each linear finding.
AMPLITUDE_ALPHA = 0.01
#: Effects output error would accept that are weighed against "the air moved" per step, best
#: first, before the step gives up (:func:`_weigh_against_air`).
MAX_AIR_TRIALS = 4
#: Hypotheses fitted in full per step, besides the best of each kind.
N_FULL_FITS = 6
#: Screening step of delays and lags, s: a fraction of the shortest actuator and rotor time
#: constants (the Bo105's flap, 0.07 s, Padfield 2007, ch. 3), so that one Gauss-Newton step
#: stays in the range where the response is nearly linear in the value.
_TIMING_STEP = 0.01
#: Screening step of a dead band, a fraction of the input's largest excursion from its start in
#: the fitted data: small enough that one Gauss-Newton step stays near linear.
_DEAD_BAND_STEP = 0.05
#: Screening step of an input gain: 5 %, as an FMU parameter's.
_GAIN_STEP = 0.05
#: The time, s, the largest excursion takes to ramp through a rate limit at its null: a
#: microsecond, four orders below any sample interval, so the null limit never bites.
_NO_RAMP = 1e-6
#: A sensor drift is screened at one noise standard deviation per this many s (its effect is
#: linear in its value, so the step only has to move the outputs well above rounding).
_DRIFT_STEP_TIME = 10.0
#: Screening step of a cross-axis sensitivity: 1 % of the source state (linear in the value too).
_CROSS_AXIS_STEP = 0.01


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
        LR of each accepted effect against the final model refitted without it (by filter
        error where the air explains some of the final model's residual,
        :func:`_drop_one_against_air`).
    rejected : dict or None
        The best hypothesis that failed the test at the last step (``key``, ``value``, ``lr``,
        ``threshold``), for the report.
    n_screened : int
        Named hypotheses (the residual search's terms come on top, ``residual_search``).
    residual_search : dict or None
        What the residual search offered (:func:`_search_summary`).
    air : GustFit or None
        The turbulence that best explains the final model's residual
        (:meth:`validation.diagnose.disturbance.AirCompetitor.final_fit`); None where the model
        cannot carry gusts.
    taken_back : list of dict
        Effects accepted at one step and dropped at a later one (:func:`_take_back`): ``key``,
        ``lr`` (against the model without it, when dropped), ``threshold``, ``after`` (the key
        whose acceptance made it redundant).
    """

    model: FittedModel
    null_rss: float
    steps: list
    drop_lr: dict
    rejected: dict | None
    n_screened: int
    residual_search: dict | None = None
    air: object = None
    taken_back: list = field(default_factory=list)


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
    found_by : {"named hypothesis", "search"}
        Whether it is one of the named hypotheses or a term the residual search found
        (:mod:`validation.diagnose.search`).
    amplitude_check : dict or None
        For a linear change (:data:`LINEAR_KINDS`), :func:`amplitude_check`'s result.
    time_check : dict or None
        Whether it holds over the flights or changes during them
        (:func:`validation.diagnose.over_time.time_check`).
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
    found_by: str = "named hypothesis"
    amplitude_check: dict | None = None
    time_check: dict | None = None

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
    model : FittedModel
        The accepted effects' hypotheses at their joint values, in the order of ``effects``.
    disturbance : dict
        diagnosis.json's ``disturbance``: whether the final model's residual looks like
        atmospheric turbulence, and how strong (:func:`validation.diagnose.disturbance.describe`).
    air : GustFit or None
        The turbulence estimated on the final model (:attr:`Selection.air`).
    """

    effects: list
    named: list
    search: dict
    model: FittedModel
    disturbance: dict | None = None
    air: object = None


def explain(data: PreparedData, location: Location, reference: EffectModel, *, progress=None) -> Explanation:
    """Search the effects the data support (module docstring) and weigh each one.

    ``progress(n, **status)``, optional, advances once per simulation batch.
    """
    hypotheses = hypotheses_for(reference, excited_inputs=data.excited, output_names=data.output_names,
                                noise_sd=data.typical_noise_sd, excursions=_excursions(data))
    selection = select_effects(data, reference, hypotheses, progress=progress, excited=data.excited)
    fitted, steps = selection.model, {step["key"]: step for step in selection.steps}
    disturbance = describe(selection.air, airspeed=trim_airspeed(reference))
    # In turbulence, output-error refits on parts of the flights (the amplitude and time checks)
    # see different gusts and differ by them: the checks are not made.
    checked = not disturbance["looks_like_turbulence"]
    named, split_fits = [], {}
    window_fits = refit_windows(data, reference, fitted) if fitted.hypotheses and checked else []
    for index, (h, effect) in enumerate(zip(fitted.hypotheses, fitted.effects())):
        lr, step = selection.drop_lr[h.key], steps[h.key]
        alone = data.simulate(reference, [effect])
        main_output = _main_output(data, alone, location.reference_replay)
        check = (amplitude_check(data, reference, fitted, index, main_output=main_output,
                                 reference_replay=location.reference_replay, fits=split_fits)
                 if h.effect in LINEAR_KINDS and checked else None)
        over_time = time_check(fitted, index, window_fits) if checked else None
        confidence = step["confidence"]
        if check and check["amplitude_dependent"]:
            confidence = min(confidence, check["weight_linear"])
        if over_time and over_time["changes"]:
            confidence = min(confidence, over_time["weight_constant"])
        named.append(NamedEffect(
            effect=effect, unit=effect_unit(effect, reference), interval=[float(v) for v in fitted.interval(index)],
            model_value=reference.model_value(h.target) if "term" in effect else None,
            confidence=confidence, likelihood_ratio=lr, p_value=float(stats.chi2.sf(lr, 1)),
            alternatives=step["alternatives"], main_output=main_output,
            alone=alone, found_by="search" if h.effect == "search_term" else "named hypothesis",
            amplitude_check=check, time_check=over_time))
    search = {"hypotheses_tested": selection.n_screened, "null_rss": selection.null_rss,
              "final_rss": fitted.rss, "n_residuals": data.n_residuals,
              "rejected": _describe_rejected(selection.rejected), "residual_search": selection.residual_search,
              "taken_back": [_describe_taken_back(dropped) for dropped in selection.taken_back]}
    return Explanation(fitted.effects(), sorted(named, key=lambda n: -n.likelihood_ratio), search, fitted,
                       disturbance, selection.air)


def amplitude_check(data: FitData, reference: EffectModel, model: FittedModel, index: int, *, main_output: int,
                    reference_replay: list, fits: dict | None = None) -> dict | None:
    """Whether change ``index`` of ``model`` holds at every amplitude.

    ``model`` is refitted on the samples where the reference's replay of the change's main
    output is beyond its median size (the larger excursions) and on the rest (the smaller). With a
    vehicle linear in that change both refits estimate the same value, so
    ``W = (v_large - v_small)^2 / (var_large + var_small)`` (Wald's form of Chow's test for one
    coefficient, Chow, Econometrica 28(3), 1960; the variances from each refit's classical Wald
    covariance, which holds under the test's null hypothesis, a linear vehicle and white noise)
    is chi-squared with one degree of freedom; an amplitude-dependent response, such
    as a damping that grows with the rate or a stiffness that hardens, wants different values.

    Parameters
    ----------
    data : FitData
    reference : EffectModel
    model : FittedModel
        The accepted effects, jointly fitted.
    index : int
        The change tested, an index into ``model.hypotheses``.
    main_output : int
        Index in ``data.output_names`` of the output split on (the change's main output).
    reference_replay : list of ndarray, shape (n_r, n_out)
        Per recording, the reference's replay without effects.
    fits : dict, optional
        Keeps the two refits per main output, for the other changes of the same model.

    Returns
    -------
    dict or None
        ``value_small``, ``value_large`` (the change's value on each part), ``likelihood_ratio``
        (``W``), ``amplitude_dependent`` (``W`` above the chi-squared quantile at
        :data:`AMPLITUDE_ALPHA`) and ``weight_linear``: the Akaike weight of one value for all
        amplitudes against two, ``1 / (1 + exp((W - 2) / 2))``, which caps the confidence of an
        amplitude-dependent finding (at most 0.73, at W = 0, so it caps no other). None when a
        part has fewer fitted samples than the model has values (a main output the reference
        never moves).
    """
    fits = {} if fits is None else fits
    if main_output not in fits:
        sizes = np.concatenate([np.abs(replay[mask, main_output])
                                for replay, mask in zip(reference_replay, data.fit_mask)])
        median = float(np.median(sizes)) if sizes.size else 0.0
        large = [mask & (np.abs(replay[:, main_output]) > median)
                 for replay, mask in zip(reference_replay, data.fit_mask)]
        small = [mask & ~part for mask, part in zip(data.fit_mask, large)]
        if min(sum(int(m.sum()) for m in part) for part in (small, large)) <= len(model.hypotheses):
            fits[main_output] = None
        else:
            fits[main_output] = [fit_many(replace(data, fit_mask=part), reference,
                                          [(model.hypotheses, model.values)])[0] for part in (small, large)]
    parts = fits[main_output]
    if parts is None:
        return None
    h = model.hypotheses[index]
    difference = parts[1].values[index] - parts[0].values[index]
    variance = parts[0].white_covariance[index, index] + parts[1].white_covariance[index, index]
    wald = float(difference ** 2 / variance) if variance > 0 else 0.0
    return {"value_small": h.effect_value(parts[0].values[index]),
            "value_large": h.effect_value(parts[1].values[index]), "likelihood_ratio": wald,
            "amplitude_dependent": bool(wald > stats.chi2.isf(AMPLITUDE_ALPHA, 1)),
            "weight_linear": float(akaike_weights([wald + 2.0, 4.0])[0])}  # AIC of one value, of two


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
    described = {"effect": kind, TARGET_KEYS[kind]: target, "value": rejected["value"],
                 "likelihood_ratio": rejected["lr"], "threshold": rejected["threshold"]}
    if rejected.get("against_air"):  # the air explained what it takes (filter-error likelihood ratio)
        described["against_air"] = True
    return described


def _describe_taken_back(dropped: dict) -> dict:
    kind, target = dropped["key"]
    after_kind, after_target = dropped["after"]
    return {"effect": kind, TARGET_KEYS[kind]: target, "likelihood_ratio": dropped["lr"],
            "threshold": dropped["threshold"], "after": {"effect": after_kind, TARGET_KEYS[after_kind]: after_target}}


def hypotheses_for(reference: EffectModel, *, excited_inputs, output_names, noise_sd,
                   excursions=None) -> list[Hypothesis]:
    """Every testable hypothesis on ``reference``: a delay (up to ``MAX_DELAY``), a lag (up to
    ``MAX_LAG``), a dead band and free play (each up to the input's largest excursion), a gain (null 1, at least
    0, screened at :data:`_GAIN_STEP`), a saturation (null: the largest excursion, where it
    does nothing; screened inward) and a rate limit (searched as its reciprocal, the ramp time
    per unit of input, null :data:`_NO_RAMP` per excursion, screened at :data:`_TIMING_STEP`
    per excursion, at most ``MAX_LAG`` per excursion) on each excited input, the
    reference's term hypotheses, and the measurement chain of each measured output (a bias,
    screened at a noise standard deviation; a scale, null 1, at least 0, screened at
    :data:`_GAIN_STEP`; a sensor lag, as an input lag; a drift, screened at a noise standard
    deviation per :data:`_DRIFT_STEP_TIME`; a cross-axis sensitivity to every other state of the
    same unit, null 0, screened at :data:`_CROSS_AXIS_STEP`), each kind where the reference
    takes it (:attr:`EffectModel.kinds`). A sensor effect moves its own recorded output only, an
    input effect every output the input drives: that is what tells them apart.

    ``noise_sd`` (dict output -> typical noise standard deviation) sets the bias and drift
    screening steps;
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
                hypotheses.append(Hypothesis("backlash", name, 0.0, 0.0, excursion, _DEAD_BAND_STEP * excursion))
                hypotheses.append(Hypothesis("saturation", name, excursion, 0.0, excursion,
                                             -_DEAD_BAND_STEP * excursion))
                # searched as the ramp time per unit of input: null, a largest excursion ramping
                # in a microsecond; screened at one ramping in _TIMING_STEP; at most MAX_LAG.
                hypotheses.append(Hypothesis("rate_limit", name, _NO_RAMP / excursion, _NO_RAMP / excursion,
                                             MAX_LAG / excursion, _TIMING_STEP / excursion, reciprocal=True))
    hypotheses += reference.term_hypotheses(excited_inputs)
    for name in output_names:  # the measurement chain of each recorded output
        hypotheses.append(Hypothesis("sensor_bias", name, 0.0, -math.inf, math.inf, float(noise_sd[name])))
        hypotheses.append(Hypothesis("output_scale", name, 1.0, 0.0, math.inf, _GAIN_STEP))
        hypotheses.append(Hypothesis("sensor_lag", name, 0.0, 0.0, MAX_LAG, _TIMING_STEP))
        hypotheses.append(Hypothesis("sensor_drift", name, 0.0, -math.inf, math.inf,
                                     float(noise_sd[name]) / _DRIFT_STEP_TIME))
    hypotheses += [Hypothesis("sensor_cross_axis", cross_axis_target(recorded, source), 0.0, -math.inf, math.inf,
                              _CROSS_AXIS_STEP) for recorded, source in cross_axis_pairs(reference, output_names)]
    return [h for h in hypotheses if h.effect in reference.kinds]


def select_effects(data: FitData, reference: EffectModel, hypotheses: list[Hypothesis], *,
                   progress=None, excited=None) -> Selection:
    """Forward stepwise search for the effects the data support (module docstring), each step
    offered the terms the residual search finds on the model so far
    (:func:`validation.diagnose.search.search_candidates`; ``excited``: the inputs that move,
    None for no residual search)."""
    air = AirCompetitor(data, reference) if gust_dynamics(reference, []) is not None else None
    # Output error first: where its effects leave only the noise, no air is left to weigh them
    # against (gusts large enough to matter are not whitened by a few constant effects), and the
    # filter error's fits are not made; otherwise the search is made again with the air.
    steps_made = {}  # the search with the air repeats output error's steps until the air decides otherwise
    path = _stepwise(data, reference, hypotheses, None, progress, excited, steps_made)
    if air is not None and not air.at_noise(path.model):
        path = _stepwise(data, reference, hypotheses, air, progress, excited, steps_made)
    model = path.model
    in_air = air is not None and bool(model.hypotheses) and air.in_play(model)
    drop_lr = (_drop_one_against_air(air, model) if in_air
               else _drop_one_lr(data, reference, model, path.null_rss, refitted=path.refits_without))
    return Selection(model, path.null_rss, path.steps, drop_lr, path.rejected, len(hypotheses),
                     _search_summary(path.searches), air.final_fit(model) if air else None, path.taken_back)


class _Path(NamedTuple):
    """Where one stepwise search (:func:`_stepwise`) ended: the final model, the null model's
    RSS, the accepted steps, the last step's rejected effect, the residual searches and the
    effects taken back (as :class:`Selection`'s attributes); ``refits_without``: the final model
    refitted without each of its effects but the last, where :func:`_take_back` made them for
    it, else None."""

    model: FittedModel
    null_rss: float
    steps: list
    rejected: dict | None
    searches: list
    taken_back: list
    refits_without: list | None


def _stepwise(data: FitData, reference: EffectModel, hypotheses: list[Hypothesis], air: AirCompetitor | None,
              progress, excited, steps_made: dict) -> _Path:
    """The forward stepwise search of :func:`select_effects`, each step's effect weighed against
    ``air`` where given, earlier effects the new one makes redundant taken back
    (:func:`_take_back`, output error only). ``steps_made``: a step's residual search and fits by
    the model it starts from and the effects it may not offer (:func:`_step_key`), filled here
    and reused by a later search through the same model: the fits depend on nothing else."""
    model = null_model(data, reference)
    null_rss = model.rss
    steps, rejected, searches, taken_back, refits_without = [], None, [], [], None
    for _ in range(MAX_EFFECTS + MAX_TAKEN_BACK):
        if len(model.hypotheses) >= MAX_EFFECTS:
            break
        taken = {h.key for h in model.hypotheses} | {dropped["key"] for dropped in taken_back}
        key = _step_key(model, taken)
        if key not in steps_made:
            candidates, found = [h for h in hypotheses if h.key not in taken], None
            n_tested = len(candidates)
            if excited is not None:
                found = search_candidates(data, reference, model, excited=excited)
                candidates, n_tested = candidates + found.hypotheses, n_tested + found.library_terms
            fits = _fit_promising(data, reference, model, candidates, progress) if candidates else []
            steps_made[key] = (candidates, n_tested, found, fits)
        candidates, n_tested, found, fits = steps_made[key]
        if found is not None:
            searches.append(found)
        if not candidates:
            break
        best, step, rejected = weigh_step(data, model, fits, n_tested=n_tested)
        if air is not None and (step is not None or air.in_play(model)):
            best, step, rejected = _weigh_against_air(air, data, reference, model, candidates, best, step,
                                                      rejected, n_tested=n_tested)
        if step is None:
            break
        steps.append(step)
        model, refits_without = best, None
        if air is None and len(model.hypotheses) > 1 and len(taken_back) < MAX_TAKEN_BACK:
            model, dropped, reduced = _take_back(data, reference, model, n_tested=n_tested)
            if dropped is None:
                refits_without = reduced
            else:
                taken_back.append(dropped)
                steps = [s for s in steps if s["key"] != dropped["key"]]
    return _Path(model, null_rss, steps, rejected, searches, taken_back, refits_without)


def _step_key(model: FittedModel, taken: set) -> tuple:
    """What a step of :func:`_stepwise` depends on besides the data: the model it starts from
    (its effects and their values, exactly) and the effects it may not offer (the model's and
    those taken back)."""
    return (tuple((h.key, float(v)) for h, v in zip(model.hypotheses, model.values)), frozenset(taken))


def _take_back(data: FitData, reference: EffectModel, model: FittedModel, *, n_tested: int) -> tuple:
    """The drop step of Efroymson's stepwise regression (Efroymson 1960, in Ralston & Wilf,
    *Mathematical Methods for Digital Computers*; Miller, *Subset Selection in Regression*, 2nd
    ed., 2002, sec. 3.2): after ``model``'s last effect was accepted, each earlier one is refitted
    out, and the one whose likelihood ratio against ``model`` is smallest is dropped when that
    ratio no longer passes the step's Bonferroni threshold. A first effect that soaked up part of
    two true ones (a term fitted to what a pitch damping and a control power leave between them)
    is so taken back once the true ones are in.

    Returns
    -------
    model : FittedModel
        ``model``, or the refit without the dropped effect.
    dropped : dict or None
        ``key``, ``lr``, ``threshold``, ``after`` (the last accepted effect's key).
    reduced : list of FittedModel
        ``model`` refitted without each of its effects but the last (:func:`_refits_without`).
    """
    reduced = _refits_without(data, reference, model, range(len(model.hypotheses) - 1))
    ratios = np.array([fitted.rss - model.rss for fitted in reduced])
    weakest = int(np.argmin(ratios))
    threshold = step_threshold(n_tested)
    if ratios[weakest] > threshold:
        return model, None, reduced
    return reduced[weakest], {"key": model.hypotheses[weakest].key, "lr": float(max(ratios[weakest], 0.0)),
                              "threshold": threshold, "after": model.hypotheses[-1].key}, reduced


def _drop_one_against_air(air: AirCompetitor, model: FittedModel) -> dict:
    """Where the air explains some of the final ``model``'s residual: the filter-error
    likelihood ratio of each effect against ``model`` without it (the others' values kept), each
    in its own estimated turbulence (:func:`validation.diagnose.disturbance.fit_gusts`)."""
    full = air.fit(model).minus_two_log_likelihood
    result = {}
    for index, h in enumerate(model.hypotheses):
        keep = [i for i in range(len(model.hypotheses)) if i != index]
        reduced = replace(model, hypotheses=[model.hypotheses[i] for i in keep], values=model.values[keep])
        result[h.key] = float(air.fit(reduced).minus_two_log_likelihood - full)
    return result


def _weigh_against_air(air: AirCompetitor, data: FitData, reference: EffectModel, model: FittedModel,
                       candidates: list, best: FittedModel, step: dict | None, rejected: dict | None, *,
                       n_tested: int) -> tuple:
    """The effect the step would accept, against "the air moved"
    (:func:`validation.diagnose.disturbance.weigh_against_air`).

    Output error's choice (``best``, accepted: ``step``) stands as it is where with it the
    residual is the noise's (no air is left to weigh against). Otherwise, where the air explains
    some of ``model``'s residual (:meth:`~validation.diagnose.disturbance.AirCompetitor.in_play`),
    the filter error decides: the ``candidates`` screened and fitted by filter error
    (:meth:`~validation.diagnose.disturbance.AirCompetitor.screen`) are weighed against the air,
    most likely first, up to :data:`MAX_AIR_TRIALS` weighings in all with output error's
    choice; of output error's choice (when it passes) and the first screened one that passes,
    the one with the larger filter-error likelihood ratio against the air is accepted (a
    screened one that leaves only noise is refitted by output error, the right estimator
    without process noise). Its confidence is capped by its weight against the air, a screened
    one's is the smaller of that and its Akaike weight among the screened competitors and "no
    further effect" (filter-error likelihoods).

    Returns ``(best, step, rejected)`` as :func:`~validation.diagnose.fitting.weigh_step`;
    ``step`` None when none passes, and then ``rejected`` is the first weighed (with
    ``against_air`` true and the turbulence ``intensity`` estimated, m/s), or output error's
    rejection where none was.
    """
    first_rejected, trials, chosen = None, 0, None

    def note(fitted, against):
        new = fitted.hypotheses[-1]
        return first_rejected or {"key": new.key, "value": new.effect_value(fitted.values[-1]),
                                  "lr": against["likelihood_ratio"], "threshold": against["threshold"],
                                  "against_air": True, "intensity": against["intensity"]}

    if step is not None:
        trials += 1
        against, best = air.weigh(model, best, n_tested=n_tested)
        if against is None:
            step["against_air"] = None
            return best, step, rejected
        if against["passes"]:
            step["against_air"] = against
            step["confidence"] = min(step["confidence"], against["weight"])
            chosen = (best, step, rejected)
        else:
            first_rejected = note(best, against)
    model = air.refine(model)
    screened = air.screen(model, candidates) if air.in_play(model) else []
    if screened:
        null = air.fit(model).minus_two_log_likelihood
        weights = akaike_weights([null] + [value + 2 for _, value in screened])  # AIC, up to a constant
    for index, (fitted, value) in enumerate(screened):
        if trials >= MAX_AIR_TRIALS or (chosen and fitted.hypotheses[-1].key == chosen[0].hypotheses[-1].key):
            break  # output error's choice is the filter error's too
        trials += 1
        if air.at_noise(fitted):  # only the noise is left with it: output error's estimate
            fitted = fit_many(data, reference, [(fitted.hypotheses, fitted.values)])[0]
            against = {"likelihood_ratio": math.inf, "passes": True, "weight": 1.0}
        else:
            against, fitted = air.weigh(model, fitted, n_tested=n_tested)
            if against is None:  # its gust fit failed: not weighed, so not accepted
                continue
        if not against["passes"]:
            first_rejected = note(fitted, against)
            continue
        if chosen and chosen[1]["against_air"]["likelihood_ratio"] >= against["likelihood_ratio"]:
            break
        alternatives = []
        for other, other_value in screened:
            ratio = math.exp(min((other_value - value) / 2, 700.0))
            if other is not screened[index][0] and ratio < MAX_EVIDENCE_RATIO and len(alternatives) < MAX_ALTERNATIVES:
                alternatives.append({**other.hypotheses[-1].as_effect(other.values[-1]), "evidence_ratio": ratio})
        lr = max(model.rss - fitted.rss, 0.0)
        step = {"key": fitted.hypotheses[-1].key, "lr": float(lr), "p_value": float(stats.chi2.sf(lr, 1)),
                "confidence": float(min(weights[index + 1], against["weight"])), "alternatives": alternatives,
                "against_air": against if math.isfinite(against["likelihood_ratio"]) else None}
        return fitted, step, None
    if chosen:
        return chosen
    return best, None, first_rejected or rejected


def _search_summary(searches: list) -> dict | None:
    """diagnosis.json's ``search.residual_search``: ``ran``, ``reason`` (why not),
    ``library_terms`` (at the first step) and per step the regression's survivors
    (``term``, ``coefficient``, ``t``); None without a residual search."""
    if not searches:
        return None
    return {"ran": searches[0].reason is None, "reason": searches[0].reason,
            "library_terms": searches[0].library_terms, "survivors_per_step": [s.survivors for s in searches]}


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


def _drop_one_lr(data: FitData, reference: EffectModel, model: FittedModel, null_rss: float, *,
                 refitted: list | None = None) -> dict:
    """LR of each effect of ``model`` against ``model`` refitted without it; ``refitted``: the
    refits without each effect but the last, where already made (:func:`_take_back`'s), so only
    the last is refitted here."""
    if len(model.hypotheses) <= 1:
        return {h.key: float(null_rss - model.rss) for h in model.hypotheses}
    done = list(refitted or [])
    reduced = done + _refits_without(data, reference, model, range(len(done), len(model.hypotheses)))
    return {h.key: float(fitted.rss - model.rss) for h, fitted in zip(model.hypotheses, reduced)}


def _refits_without(data: FitData, reference: EffectModel, model: FittedModel, indices) -> list[FittedModel]:
    """``model`` refitted without each of its effects ``indices`` in turn, the others started at
    their values (one batch of fits)."""
    return fit_many(data, reference, [([h for i, h in enumerate(model.hypotheses) if i != k],
                                       np.delete(model.values, k)) for k in indices])


def _accepted_steps(model: FittedModel) -> list[tuple]:
    """``(hypothesis, value + step, step)`` for each accepted effect of ``model``: its finite
    difference step inside the hypothesis' bounds (backwards where forwards would leave them)."""
    steps = []
    for h, value in zip(model.hypotheses, model.values):
        step = h.step if h.lower <= value + h.step <= h.upper else -h.step
        steps.append((h, float(value + step), float(step)))
    return steps


def _screen(data: FitData, reference: EffectModel, model: FittedModel, candidates: list, progress) -> list:
    """One Gauss-Newton step per candidate on top of ``model``, the accepted effects' values
    free to move with it: (score, one-step value) each.

    The score is Rao's with the accepted values as nuisance parameters (Rao 1948; Seber & Wild,
    *Nonlinear Regression*, 1989, sec. 5.9): the candidate's output sensitivity ``g`` is first
    made orthogonal to the accepted effects' sensitivities ``J`` (``g - Q Q^T g``, ``J = Q R``),
    so it scores what the candidate explains that the accepted effects, readjusted, cannot. With
    the raw ``g`` a first effect that soaked up part of a second (a pitch damping fitted alone
    where the pitch control power is low too) hides the second behind candidates that only look
    like the first's error.
    """
    base_effects = model.effects()
    r0 = data.weighted_residuals(reference, base_effects)
    accepted = _accepted_steps(model)
    replays = data.weighted_residuals_many(
        reference, [base_effects + [h.as_effect(h.null + h.step)] for h in candidates]
        + [[*base_effects[:k], h.as_effect(value), *base_effects[k + 1:]] for k, (h, value, _) in enumerate(accepted)])
    perturbed_all = replays[:len(candidates)]
    basis = None
    if accepted:
        jacobian = np.stack([(r0 - replay) / step for replay, (_, _, step) in zip(replays[len(candidates):], accepted)],
                            axis=1)
        basis = np.linalg.qr(jacobian)[0]
    scores = []
    for h, perturbed in zip(candidates, perturbed_all):
        g = (r0 - perturbed) / h.step  # d(replay)/d(parameter), weighted
        if basis is not None:
            g = g - basis @ (basis.T @ g)
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
