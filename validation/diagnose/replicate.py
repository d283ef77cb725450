"""Replicate: the explain stage repeated on folds of the diagnosed recordings, so that only
findings the data name again and again are stated with confidence.

On recordings a reference fits to the noise, the likelihood-ratio tests of
:mod:`validation.diagnose.explain` are calibrated. On real flights the model error dwarfs the
noise and is correlated over seconds, so the likelihood ratios and Wald intervals overstate the
evidence many times over: a coefficient can win a step because it mimics something specific to
one flight. The check that needs no noise model is replication (the cross-validation idea of
Stone, J. R. Stat. Soc. B 36(2), 1974, applied to the selection itself): with ``folds = K``
the diagnosed recordings are dealt round-robin into K folds, the whole stepwise search is run on
each fold alone, and a finding is *replicated* when every fold names the same effect on the same
target and moves it the same way from the model's value (a yaw damping named stronger on one
fold and weaker on the other does not replicate). Its values across the folds show how far it
moves between subsets of the data, which is the honest spread when the intervals are not.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from validation.core.errors import BadInputError
from validation.diagnose.data import PreparedData
from validation.diagnose.explain import Explanation, explain
from validation.diagnose.locate import Location
from validation.vehicles.effects import EffectModel, effect_key


@dataclass
class Replication:
    """Result of :func:`replicate`.

    Attributes
    ----------
    folds : list of dict
        Per fold: ``recordings`` (names) and ``effects`` (the effect dicts its search named).
    named_in : dict of (str, str) -> list of float or None
        Per finding of the full diagnosis, by ``(effect, target)``: its value in each fold, None
        where that fold did not name it.
    """

    folds: list
    named_in: dict

    def summary(self) -> dict:
        """diagnosis.json's ``replication``: ``folds`` as above."""
        return {"folds": self.folds}

    def of(self, finding: dict) -> dict:
        """A finding's ``replication``: ``folds`` (K), ``named_in`` (how many named it),
        ``values`` (per fold, None where not named) and ``replicated`` (every fold named it and
        moved it the same way from the model's value, ``finding["model_value"]``, 0 for delays,
        lags and biases, as the full diagnosis did)."""
        key = effect_key(finding)
        values = self.named_in.get(key, [None] * len(self.folds))
        named = sum(value is not None for value in values)
        null = finding.get("model_value") or 0.0
        direction = np.sign(finding["value"] - null)
        same_way = all(v is not None and np.sign(v - null) == direction for v in values)
        return {"folds": len(self.folds), "named_in": named, "values": values, "replicated": bool(same_way)}


def fold_recordings(data: PreparedData, folds: int) -> list[list[int]]:
    """Indices of the diagnosed recordings dealt round-robin into ``folds`` folds (recordings
    with fitted samples only; held-out recordings take no part)."""
    fitted = [i for i, mask in enumerate(data.fit_mask) if mask.any()]
    if folds < 2:
        raise BadInputError(f"folds must be 2 or more to replicate findings, got {folds}")
    if len(fitted) < folds:
        raise BadInputError(f"{folds} folds need at least {folds} diagnosed recordings (besides the held-out "
                            f"ones); there are {len(fitted)}")
    return [fitted[k::folds] for k in range(folds)]


def replicate(data: PreparedData, location: Location, explanation: Explanation, reference: EffectModel, *,
              folds: int, progress=None) -> Replication:
    """Run :func:`validation.diagnose.explain.explain` on each of ``folds`` folds of the
    diagnosed recordings (module docstring) and record which of ``explanation``'s findings
    each fold names, with its value there."""
    results = []
    for members in fold_recordings(data, folds):
        fold = explain(data.fitting_only(members), location, reference, progress=progress)
        results.append({"recordings": [data.recording_names[i] for i in members], "effects": fold.effects})
    named_in = {}
    for effect in explanation.effects:
        key = effect_key(effect)
        named_in[key] = [next((e["value"] for e in fold["effects"] if effect_key(e) == key), None)
                         for fold in results]
    return Replication(results, named_in)
