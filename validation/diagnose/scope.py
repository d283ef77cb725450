"""Scope: whether each named effect is shared by every diagnosed recording or differs per
recording (a random effect), and its spread across them.

Real repeats differ: the buoyancy of a blimp changes with the helium's temperature, a launch or
a battery differs between flights. An effect the data name as a constant may be such a
per-flight difference, not a property of the vehicle. The final model (all named effects) is
refitted on each diagnosed recording alone, from its joint values, giving per recording ``k``
the value ``v_k`` of every effect and its Wald variance ``s_k^2`` (search-parameter units,
:mod:`validation.diagnose.fitting`). Per effect, as in a meta-analysis of ``K`` studies:

- heterogeneity: Cochran's ``Q = sum_k w_k (v_k - v_bar)^2``, ``w_k = 1 / s_k^2``, ``v_bar``
  the ``w``-weighted mean, chi-squared with ``K - 1`` degrees of freedom when every recording
  shares one value (Cochran, Biometrics 10(1), 1954);
- spread: the between-recording variance ``tau^2 = max(0, (Q - (K - 1)) / (sum w - sum w^2 / sum w))``
  (DerSimonian & Laird, Controlled Clinical Trials 7(3), 1986);
- shared part: the random-effects mean ``mu`` (weights ``1 / (s_k^2 + tau^2)``), tested against
  the model's value with the Hartung-Knapp variance and Student's t with ``K - 1`` degrees of
  freedom (Hartung & Knapp, Statistics in Medicine 20(12), 2001), which rests on the values'
  scatter rather than on the Wald variances: on real flights the model error is correlated in
  time and the Wald variances are far too small.

``kind`` is ``"shared"`` when ``Q`` is below its :data:`HETEROGENEITY_ALPHA` quantile (one value
fits every recording), ``"varies"`` when the recordings differ but share a part that is not the
model's value at level :data:`SHARED_ALPHA` (a vehicle property with a per-recording spread),
``"per_recording"`` when they differ and no shared part stands out from the spread (e.g. a
buoyancy offset of either sign).
Only ``"shared"`` and ``"varies"`` findings are offered as corrections of the vehicle's model
(:mod:`validation.diagnose.carry_over`). With a single diagnosed recording nothing can be told
(``None``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from validation.diagnose.data import PreparedData
from validation.diagnose.explain import Explanation
from validation.diagnose.fitting import fit_many
from validation.vehicles.effects import EffectModel, effect_key

#: Level of the heterogeneity test: recordings count as differing only on strong evidence.
HETEROGENEITY_ALPHA = 0.01
#: Level of the test of the shared part against the model's value.
SHARED_ALPHA = 0.05
#: The kinds that are offered as corrections of the vehicle's model.
VEHICLE_SCOPES = ("shared", "varies")


@dataclass
class Scope:
    """Result of :func:`scope`.

    Attributes
    ----------
    recordings : list of str
        The diagnosed recordings, in the order of each effect's ``values``.
    per_effect : dict of (str, str) -> dict
        By ``(effect, target)``: diagnosis.json's ``scope`` of that finding, ``kind`` (module
        docstring), ``values`` (per recording, the effect's unit), ``mean`` (the random-effects
        mean ``mu``), ``spread`` (``tau``), both in the effect's unit (mapped through the
        parameter for reciprocal searches), ``heterogeneity_p`` (``P(chi2(K-1) > Q)``) and
        ``shared_p`` (the Hartung-Knapp test of ``mu`` against the model's value). Empty with
        one diagnosed recording.
    """

    recordings: list
    per_effect: dict

    def of(self, effect: dict) -> dict | None:
        """The ``scope`` of ``effect``; None when it cannot be told."""
        return self.per_effect.get(effect_key(effect))

    def offered(self, effect: dict) -> bool:
        """Whether ``effect`` may correct the vehicle's model (module docstring)."""
        found = self.of(effect)
        return found is None or found["kind"] in VEHICLE_SCOPES


def scope(data: PreparedData, explanation: Explanation, reference: EffectModel, *, progress=None) -> Scope:
    """Refit ``explanation``'s model on each diagnosed recording alone and tell shared from
    per-recording effects (module docstring). ``progress(n, **status)``, optional, advances
    once per recording."""
    fitted = [i for i, mask in enumerate(data.fit_mask) if mask.any()]
    model = explanation.model
    names = [data.recording_names[i] for i in fitted]
    if len(fitted) < 2 or not model.hypotheses:
        return Scope(names, {})
    refits = []
    for i in fitted:
        refits.append(fit_many(data.fitting_only([i]), reference, [(model.hypotheses, model.values)])[0])
        if progress:
            progress(1, fitted=f"scope:{data.recording_names[i]}")
    per_effect = {}
    for j, h in enumerate(model.hypotheses):
        values = np.array([r.values[j] for r in refits])
        variances = np.array([r.covariance[j, j] for r in refits])
        found = _random_effects(values, variances, h.null)
        per_effect[h.key] = {**found, "values": [h.effect_value(v) for v in values],
                             "mean": h.effect_value(found["mean"]),
                             "spread": abs(h.effect_value(h.null + found["spread"]) - h.effect_value(h.null))}
    return Scope(names, per_effect)


def _random_effects(values: np.ndarray, variances: np.ndarray, null: float) -> dict:
    """``kind``, ``mean`` and ``spread`` (search-parameter units), ``heterogeneity_p`` and
    ``shared_p`` of per-recording ``values`` with Wald ``variances`` (module docstring)."""
    k = len(values)
    variances = np.maximum(variances, 1e-12 * max(float(np.max(variances)), 1e-300))  # no infinite weight
    w = 1.0 / variances
    pooled = float(np.sum(w * values) / np.sum(w))
    q = float(np.sum(w * (values - pooled) ** 2))
    heterogeneity_p = float(stats.chi2.sf(q, k - 1))
    relative = w / np.max(w)  # the denominator below, scaled to stay finite
    denominator = np.max(w) * (np.sum(relative) - np.sum(relative**2) / np.sum(relative))
    tau2 = max(0.0, (q - (k - 1)) / denominator) if denominator > 0 else 0.0
    w_random = 1.0 / (variances + tau2)
    mean = float(np.sum(w_random * values) / np.sum(w_random))
    hk_variance = float(np.sum(w_random * (values - mean) ** 2) / ((k - 1) * np.sum(w_random)))
    t = abs(mean - null) / math.sqrt(hk_variance) if hk_variance > 0 else math.inf
    shared_p = float(2 * stats.t.sf(t, k - 1))
    if heterogeneity_p >= HETEROGENEITY_ALPHA:
        kind = "shared"
    else:
        kind = "varies" if shared_p < SHARED_ALPHA else "per_recording"
    return {"kind": kind, "mean": mean, "spread": math.sqrt(tau2), "heterogeneity_p": heterogeneity_p,
            "shared_p": shared_p}
