"""Carry-over: whether each named effect improves the held-out recordings, alone and in the final
model, and which effects the corrected model keeps.

A finding fitted to the diagnosed recordings is a claim about the vehicle only if it also makes
recordings it did not see better. Each named effect is scored on the held-out samples by the
weighted held-out cost ``C = sum_outputs sum_samples ((measured - replay) / noise_sd)^2`` (the
fit's misfit measure, :class:`validation.diagnose.fitting.FitData`) twice:

- *alone*: the reference with this effect only, against the reference;
- *in the model*: the final model (all named effects), against the final model without it.

It *carries over* when the final model without it misfits the held-out recordings more; it
*fits only the recordings it saw* when the final model is better without it; neither
(``None``) when neither score moves ``C`` by more than :data:`UNEXERCISED` of the reference's
(the held-out data do not exercise it). The alone score is reported beside it: effects that
work together (a centre of gravity and a pitch stability that trade off) may each make the
flights worse alone and better together. With white Gaussian noise,
``(C_without - C_with) / 2`` is the held-out log-likelihood gain of the effect, so
``1 / (1 + exp(-(C_without - C_with) / 2))`` is its predictive Akaike weight on recordings it
did not see (the weight of Burnham & Anderson, *Model Selection and Multimodel Inference*, 2nd
ed., 2002, sec. 2.9, evaluated out of sample); a finding's confidence is capped by that weight
when it does not carry over, so such a finding is never stated with confidence.

Where the residual of the final model looks like atmospheric turbulence
(:mod:`validation.diagnose.disturbance`), no model predicts the held-out flights' gusts, and
``C`` is the filter error's ``-2 ln L`` on the held-out samples instead, in the turbulence
estimated on the diagnosed ones (:func:`validation.diagnose.disturbance.held_out_cost`): the
same weights, each model's misfit weighed by what the air could have done.

The corrected model starts from the findings that carry over and hold for the vehicle
(:mod:`validation.diagnose.scope`, ``offered``) and removes, one at a time, the finding without
which the held-out cost falls most, until every finding it keeps lowers the held-out cost of the
kept model (backward elimination on validation data, Hastie, Tibshirani & Friedman, *Elements
of Statistical Learning*, 2nd ed., 2009, sec. 3.3.2 and 7.2), at their jointly fitted values.
The held-out recordings then *select* the corrected model: they are its validation data, and its
held-out scores are no longer an unbiased test. Keep recordings beyond the diagnosis for that
(``flightgp reproduce rgblimp-diagnose`` tests on flights the diagnosis never sees).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from validation.core.metrics import rmse
from validation.diagnose.data import PreparedData
from validation.diagnose.disturbance import held_out_cost
from validation.diagnose.explain import Explanation, NamedEffect
from validation.diagnose.fitting import akaike_weights
from validation.diagnose.locate import Location
from validation.vehicles.effects import EffectModel, effect_key

#: Relative change of the held-out cost below which an effect counts as not exercised by the
#: held-out data (0.1 %: far below any effect worth naming, far above rounding).
UNEXERCISED = 1e-3


@dataclass
class HeldOutEffect:
    """The held-out check of one named effect (module docstring).

    Attributes
    ----------
    rmse_effect_alone : float
        Held-out RMSE of its main output with the reference plus this effect alone, output units.
    gain_alone : float
        Fraction of the reference's held-out cost the effect alone removes (negative: it adds).
    gain_in_model : float
        Fraction of the held-out cost of the final model without it that adding it removes.
    carries_over : bool or None
    predictive_weight : float
        Its Akaike weight on the held-out data, 0 to 1 (0.5 when not exercised).
    """

    rmse_effect_alone: float
    gain_alone: float
    gain_in_model: float
    carries_over: bool | None
    predictive_weight: float

    def as_finding(self) -> dict:
        """The diagnosis.json keys of this check."""
        return {"rmse_effect_alone": self.rmse_effect_alone, "holdout_gain_alone": self.gain_alone,
                "holdout_gain_in_model": self.gain_in_model, "carries_over": self.carries_over,
                "predictive_weight": self.predictive_weight}


#: Why a named effect is not in the corrected model (diagnosis.json's ``left_out``).
LEFT_OUT = {"per_recording": "it differs per flight",
            "fits_only_what_it_saw": "it fits only the flights it saw",
            "not_exercised": "the held-out data do not exercise it",
            "eliminated": "the corrected model's other findings do better on the held-out flights without it"}


@dataclass
class CarryOver:
    """Result of :func:`carry_over`.

    Attributes
    ----------
    effects : list of HeldOutEffect
        Per named effect of the explanation, in the order of ``explanation.named``.
    kept : list of dict
        The effect dicts of the corrected model, in the order of ``explanation.effects``.
    left_out : list of str or None
        Per named effect, in the order of ``explanation.named``: None when kept, else the key of
        :data:`LEFT_OUT` that says why.
    """

    effects: list
    kept: list
    left_out: list


def carry_over(data: PreparedData, location: Location, explanation: Explanation, reference: EffectModel, *,
               offered, progress=None) -> CarryOver:
    """Score each named effect of ``explanation`` on the held-out samples and choose the corrected
    model (module docstring); ``offered(effect)`` says whether an effect may correct the
    vehicle's model (:meth:`validation.diagnose.scope.Scope.offered`). ``data`` always holds
    held-out samples (:func:`validation.diagnose.data.prepare`). ``progress(n, **status)``,
    optional, advances once per batched replay."""
    named, final = explanation.named, explanation.effects
    replays = data.simulate_many(reference, [[e for e in final if e != n.effect] for n in named] + [final])
    if progress:
        progress(1, fitted="carry-over")
    cost_of = _plain_held_out_cost
    if (explanation.disturbance or {}).get("looks_like_turbulence"):
        in_air = held_out_cost(data, reference, final, explanation.air)
        if in_air is not None:
            cost_of = lambda _, replay: in_air(replay)  # noqa: E731
    cost_reference = cost_of(data, location.reference_replay)
    cost_final = cost_of(data, replays[-1])
    effects = [_weigh(n, data, cost_reference, cost_of(data, n.alone), cost_of(data, replay),
                      cost_final) for n, replay in zip(named, replays)]
    reasons = {}
    for n, held in zip(named, effects):
        if not offered(n.effect):
            reasons[effect_key(n.effect)] = "per_recording"
        elif held.carries_over is None:
            reasons[effect_key(n.effect)] = "not_exercised"
        elif not held.carries_over:
            reasons[effect_key(n.effect)] = "fits_only_what_it_saw"
    kept = [e for e in final if effect_key(e) not in reasons]
    current = cost_final if kept == final else None
    while kept:  # backward elimination on the held-out cost
        trials = ([] if current is not None else [kept]) + [[e for e in kept if e != drop] for drop in kept]
        costs = [cost_of(data, replay) for replay in data.simulate_many(reference, trials)]
        if progress:
            progress(1, fitted="carry-over")
        if current is None:
            current, costs = costs[0], costs[1:]
        best = int(np.argmin(costs))
        if costs[best] >= current:
            break
        reasons[effect_key(kept[best])] = "eliminated"
        kept, current = kept[:best] + kept[best + 1:], costs[best]
    return CarryOver(effects, kept, [reasons.get(effect_key(n.effect)) for n in named])


def _weigh(named: NamedEffect, data: PreparedData, cost_reference: float, cost_alone: float,
           cost_without: float, cost_final: float) -> HeldOutEffect:
    """The :class:`HeldOutEffect` of ``named`` from the four held-out costs (module docstring)."""
    main = named.main_output
    held = [(m, a, mask) for m, a, mask in zip(data.measured, named.alone, data.holdout_mask) if mask.any()]
    alone = rmse(np.concatenate([m[mask, main] for m, _, mask in held]),
                 np.concatenate([a[mask, main] for _, a, mask in held]))
    gain_alone, gain_in_model = cost_reference - cost_alone, cost_without - cost_final
    floor = UNEXERCISED * cost_reference
    if abs(gain_alone) <= floor and abs(gain_in_model) <= floor:
        return HeldOutEffect(alone, 0.0, 0.0, None, 0.5)
    weight = akaike_weights([cost_without, cost_final])[1]  # predictive: no count of parameters
    return HeldOutEffect(alone, gain_alone / cost_reference, gain_in_model / max(cost_without, 1e-300),
                         bool(gain_in_model > 0), weight)


def _plain_held_out_cost(data: PreparedData, replay: list) -> float:
    """``C`` of ``replay`` (per recording, shape (n_r, n_out)) on the held-out samples (module docstring)."""
    return float(sum(np.sum(data.weighted_output_residual(replay, i, data.holdout_mask) ** 2)
                     for i in range(len(data.output_names))))
