"""Prove: the models scored on held-out data, and the explanation validated there.

Per output, RMSE and Theil's inequality coefficient (:mod:`validation.core.metrics`) on the
held-out samples for the reference, the corrected model and the corrected model + residual GP
(diagnosis.json's ``fit``, docs/diagnose.md).

Validation of the explanation (each named effect's own held-out check is
:mod:`validation.diagnose.carry_over`'s): an output that the corrected model fits to the noise on
the diagnosed data but not on the held-out data gets an ``unexplained`` finding with ``"data":
"holdout"``: the named effects only mimic, on the diagnosed manoeuvre, physics outside the named
list (e.g. an amplitude-dependent gain fitted as a derivative change). An input that moves only
in the held-out data was never tested: a missing effect on it would look like physics outside
the named list, so this check is then skipped.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from validation.core.metrics import rmse, theil_inequality
from validation.diagnose.data import EXCITATION_THRESHOLD, PreparedData
from validation.diagnose.explain import Explanation
from validation.diagnose.locate import Location
from validation.diagnose.model import Models
from validation.diagnose.noise import noise_excess
from validation.vehicles.effects import EffectModel, effect_unit

#: The models scored, as the keys of diagnosis.json's ``fit`` name them.
MODEL_KEYS = ("reference", "corrected", "corrected_gp")
@dataclass
class Proof:
    """Result of :func:`prove`.

    Attributes
    ----------
    fit : dict
        diagnosis.json's ``fit``: ``data``, ``holdout``, ``outputs``, ``rmse_<model>`` and
        ``theil_<model>`` per output for each of :data:`MODEL_KEYS`, ``noise_sd``.
    traces : dict of str to dict
        Per output: ``time``, ``measured`` and one entry per model of :data:`MODEL_KEYS`
        (ndarrays over the held-out samples, recordings concatenated) for the plots.
    rmse_reference_gp : list of float
        Per named effect of the explanation, in its order: held-out RMSE of its main output
        with the reference plus a GP fitted to the reference's residual, output units.
    unexplained : list of dict
        Findings ``{"effect": "unexplained", "output", "value", "unit", "noise_ratio", "data":
        "holdout", "fit_noise_ratio", "rmse_reference_gp"}``.
    untestable : list of str
        Inputs that move only in the held-out data.
    """

    fit: dict
    traces: dict
    rmse_reference_gp: list
    unexplained: list
    untestable: list


def prove(data: PreparedData, location: Location, explanation: Explanation, models: Models,
          reference: EffectModel, *, progress=None) -> Proof:
    """Score the models and validate the explanation on the held-out samples (module docstring)."""
    fit, traces = _scores(data, location, models)
    reference_gp_rmse = {}

    def rmse_reference_gp(output: int) -> float:
        """Held-out RMSE of reference + residual GP of output index ``output`` (computed once)."""
        if output not in reference_gp_rmse:
            held = np.concatenate([(r[:, output] + p)[m] for r, p, m in zip(
                location.reference_replay, models.reference_gps.predict(output), data.holdout_mask) if m.any()])
            reference_gp_rmse[output] = rmse(traces[data.output_names[output]]["measured"], held)
        return reference_gp_rmse[output]

    per_effect = [rmse_reference_gp(named.main_output) for named in explanation.named]
    held_only = [n for j, n in enumerate(data.input_names) if n not in data.excited and any(
        np.ptp(u[m, j]) > EXCITATION_THRESHOLD for u, m in zip(data.inputs, data.holdout_mask) if m.any())]
    untestable = [f"{n}: moves only in the held-out data, so the held-out check of the explanation "
                  "is skipped (a missing effect on it would look like physics outside the named list)"
                  for n in held_only]
    flagged = {f["output"] for f in models.unexplained}
    unexplained = []
    for i, name in enumerate(data.output_names):
        if name in flagged or held_only:
            continue
        held_ratio, exceeds = noise_excess(data.weighted_output_residual(models.corrected_replay, i,
                                                                         data.holdout_mask))
        if not exceeds:
            continue
        fit_ratio = noise_excess(data.weighted_output_residual(models.corrected_replay, i, data.fit_mask))[0]
        unexplained.append({"effect": "unexplained", "output": name, "value": fit["rmse_corrected"][name],
                            "unit": effect_unit({"effect": "sensor_bias", "output": name}, reference),
                            "noise_ratio": held_ratio, "data": "holdout", "fit_noise_ratio": fit_ratio,
                            "rmse_reference_gp": rmse_reference_gp(i)})
        if progress:
            progress(1, fitted=f"gp:{name}")
    return Proof(fit, traces, per_effect, unexplained, untestable)


def _scores(data: PreparedData, location: Location, models: Models) -> tuple[dict, dict]:
    """diagnosis.json's ``fit`` and the held-out traces (:class:`Proof`)."""
    fit = {"data": "holdout", "holdout": data.holdout_description, "outputs": list(data.output_names),
           **{f"rmse_{key}": {} for key in MODEL_KEYS}, **{f"theil_{key}": {} for key in MODEL_KEYS},
           "noise_sd": data.typical_noise_sd}
    traces = {}
    for i, name in enumerate(data.output_names):
        pieces = {"time": [], "measured": [], **{key: [] for key in MODEL_KEYS}}
        for k, mask in enumerate(data.holdout_mask):
            if not mask.any():
                continue
            gp_part = models.gp_prediction[name][k] if name in models.gp_prediction else 0.0
            pieces["time"].append(data.time[k][mask])
            pieces["measured"].append(data.measured[k][mask, i])
            pieces["reference"].append(location.reference_replay[k][mask, i])
            pieces["corrected"].append(models.corrected_replay[k][mask, i])
            pieces["corrected_gp"].append((models.corrected_replay[k][:, i] + gp_part)[mask])
        trace = {key: np.concatenate(value) for key, value in pieces.items()}
        traces[name] = trace
        for key in MODEL_KEYS:
            fit[f"rmse_{key}"][name] = rmse(trace["measured"], trace[key])
            fit[f"theil_{key}"][name] = theil_inequality(trace["measured"], trace[key])
    return fit, traces

