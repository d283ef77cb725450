"""Over time: whether each named effect holds over the whole of the diagnosed flights, or
changes during them.

A finding is a constant. A derivative that grows as a rotor's speed or an airship's helium
temperature drifts, or a lag that appears halfway through a flight, is not: fitted as a constant
it is the flight's average, and stated with an interval it does not deserve. So the final model
(all named effects) is refitted on :data:`WINDOWS` consecutive windows of the fitted samples
(window ``w``: the fitted samples of every diagnosed recording whose time lies in the ``w``-th
of equal parts of that recording's fitted span), each refit jointly from the final values,
giving per window the value ``v_w`` of every effect at the window's centre ``tau_w`` (a fraction
of the flight) and its variance ``s_w^2`` (search-parameter units,
:mod:`validation.diagnose.fitting`: widened to Newey-West where the residual is correlated in
time, since a misfit that lasts seconds would otherwise set windows apart by chance). Each
replay still runs the whole recording from its start: a window's value also acts before the
window, which matters little for a vehicle whose response forgets its inputs within a window.

Three models of the values compete, weighted by ``w_w = 1 / s_w^2`` (generalised least squares
of the window values, whose misfits are chi-squared under each):

- **constant**: one value, Cochran's ``Q = sum_w w_w (v_w - v_bar)^2`` with ``K - 1`` degrees
  of freedom (Cochran, Biometrics 10(1), 1954), the test of a change;
- **drift**: a value linear in time, ``v(tau) = a + b tau``, its misfit ``Q_d`` with ``K - 2``
  degrees of freedom (the drift hypothesis of a constant finding);
- **free**: one value per window (misfit 0, ``K`` parameters).

Their Akaike weights (Akaike, IEEE Trans. Automatic Control 19(6), 1974; Burnham & Anderson,
*Model Selection and Multimodel Inference*, 2nd ed., 2002, sec. 2.9) come from
``AIC = Q + 2 k``. The effect **changes** when ``Q`` is beyond its chi-squared quantile at
:data:`CHANGE_ALPHA`; it then **drifts** when the drift's weight is above the free model's
(stated as the line's values at the start and end of the flights), and the constant's weight
caps the finding's confidence, as the amplitude check caps an amplitude-dependent one
(:func:`validation.diagnose.explain.amplitude_check`).
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy import stats

from validation.diagnose.fitting import FitData, FittedModel, akaike_weights, fit_many
from validation.vehicles.effects import EffectModel

#: Consecutive windows the fitted samples are cut into.
WINDOWS = 3
#: Level of the test of a change: a finding is called changing only on strong evidence.
CHANGE_ALPHA = 0.01


def window_masks(data: FitData, windows: int = WINDOWS) -> list[list[np.ndarray]]:
    """Per window, per recording, the fitted samples in that window (module docstring):
    ``windows`` lists of boolean arrays shaped as ``data.fit_mask``."""
    masks = [[] for _ in range(windows)]
    for time, mask in zip(data.time, data.fit_mask):
        fitted = np.asarray(time)[mask]
        start, end = (float(fitted[0]), float(fitted[-1])) if fitted.size else (0.0, 0.0)
        span = end - start
        position = np.where(mask, (np.asarray(time) - start) / span if span > 0 else 0.0, -1.0)
        index = np.minimum(np.floor(position * windows), windows - 1)
        for w in range(windows):
            masks[w].append(mask & (index == w))
    return masks


def refit_windows(data: FitData, reference: EffectModel, model: FittedModel,
                  windows: int = WINDOWS) -> list[FittedModel | None]:
    """The final ``model`` refitted on each window (:func:`window_masks`), from its values; None
    for a window with no more fitted samples than the model has values."""
    fits = []
    for part in window_masks(data, windows):
        if sum(int(m.sum()) for m in part) <= len(model.hypotheses):
            fits.append(None)
        else:
            fits.append(fit_many(replace(data, fit_mask=part), reference, [(model.hypotheses, model.values)])[0])
    return fits


def time_check(model: FittedModel, index: int, fits: list[FittedModel | None]) -> dict | None:
    """Whether effect ``index`` of ``model`` holds over the flights (module docstring).

    Parameters
    ----------
    model : FittedModel
        The accepted effects, jointly fitted on all the fitted samples.
    index : int
        The effect tested, an index into ``model.hypotheses``.
    fits : list of FittedModel or None
        :func:`refit_windows` of ``model``, one per window, in time order.

    Returns
    -------
    dict or None
        ``values`` (per window, the effect's unit; None for a window that cannot fit it),
        ``window_centres`` (fraction of the flight), ``q`` and ``p_value`` (the constant's test),
        ``changes`` (bool), ``drifts`` (bool: changes, and the drift outweighs one value per
        window), ``drift_start`` and ``drift_end`` (the line's values at the start and end of the
        flights, the effect's unit), ``weights`` (Akaike weights of ``constant``, ``drift`` and
        ``free``) and ``weight_constant`` (the cap on the confidence of a changing effect). None
        when fewer than three windows inform the value (a variance that is zero, not finite or
        from a window too short to fit).
    """
    h, windows = model.hypotheses[index], len(fits)
    centres = (np.arange(windows) + 0.5) / windows
    values, variances, kept = [], [], []
    for w, fit in enumerate(fits):
        variance = fit.covariance[index, index] if fit is not None else math.nan
        if fit is not None and math.isfinite(variance) and variance > 0 and math.isfinite(fit.values[index]):
            values.append(float(fit.values[index]))
            variances.append(float(variance))
            kept.append(w)
    if len(kept) < 3:
        return None
    v, weight, tau = np.array(values), 1.0 / np.array(variances), centres[kept]
    constant = float(np.sum(weight * v) / np.sum(weight))
    q = float(np.sum(weight * (v - constant) ** 2))
    design = np.column_stack([np.ones_like(tau), tau]) * np.sqrt(weight)[:, None]
    line, *_ = np.linalg.lstsq(design, v * np.sqrt(weight), rcond=None)
    q_drift = float(np.sum(weight * (v - line[0] - line[1] * tau) ** 2))
    weights = akaike_weights([q + 2.0, q_drift + 4.0, 2.0 * len(kept)])  # AIC = misfit + 2 k
    p_value = float(stats.chi2.sf(q, len(kept) - 1))
    changes = p_value < CHANGE_ALPHA
    by_window = dict(zip(kept, values))
    return {"values": [h.effect_value(by_window[w]) if w in by_window else None for w in range(windows)],
            "window_centres": [float(c) for c in centres], "q": q, "p_value": p_value, "changes": bool(changes),
            "drifts": bool(changes and weights[1] > weights[2]),
            "drift_start": h.effect_value(float(line[0])), "drift_end": h.effect_value(float(line[0] + line[1])),
            "weights": {"constant": float(weights[0]), "drift": float(weights[1]), "free": float(weights[2])},
            "weight_constant": float(weights[0])}
