"""Model: the corrected reference and residual GPs.

The accepted effects make the corrected reference
(:class:`validation.vehicles.effect_vehicle.EffectVehicle`, saved as ``corrected_model.json``).
Where the corrected model still misfits the fitted samples beyond the noise
(:func:`validation.diagnose.noise.noise_excess`), a residual GP (squared-exponential ARD,
type-II maximum likelihood, :mod:`gp_model`) models the rest and the output gets an
``unexplained`` finding. A GP fitted to the *uncorrected* residual shows how much of each named
effect it would absorb: a GP alone would hide the physics the named effect makes explicit.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gp_model import GaussianProcess, SquaredExponentialARD, maximize_marginal_likelihood
from validation.diagnose.data import PreparedData
from validation.diagnose.explain import Explanation, NamedEffect
from validation.diagnose.locate import Location
from validation.diagnose.noise import noise_excess
from validation.vehicles.effect_vehicle import EffectVehicle
from validation.vehicles.effects import EffectModel, effect_unit

#: Most GP training points per output (every k-th fit sample): the exact GP costs O(n^3) per
#: likelihood evaluation, and 300 points of a 20 s recording (one per 0.07 s at 100 Hz) still
#: resolve the 1-3 Hz rigid-body modes.
MAX_GP_POINTS = 300


class ResidualGPs:
    """Residual GPs of one replay, one per output, each fitted when first asked for.

    Features per sample (:func:`_gp_features`) come from the replay's states (those the
    reference lets the GPs see, :attr:`~validation.vehicles.effects.EffectModel.residual_gp_states`); targets are
    measured minus replayed outputs on the fitted samples, every k-th so that at most
    :data:`MAX_GP_POINTS` remain.

    Parameters
    ----------
    data : PreparedData
    replay : list of ndarray, shape (n_r, n_out)
        Replayed outputs per recording.
    states : sequence of ndarray, shape (n_r, n_states)
        The same replay's states per recording.
    reference : EffectModel
    seed : int
        Seed of the hyperparameter restarts.
    """

    def __init__(self, data: PreparedData, replay: list, states, reference: EffectModel, *, seed: int):
        excited_columns = [data.input_names.index(n) for n in data.excited]
        state_columns = [reference.state_names.index(n) for n in reference.residual_gp_states]
        self.features = [_gp_features(x[:, state_columns], u, t, excited_columns)
                         for x, u, t in zip(states, data.inputs, data.time)]
        self._data, self._replay, self._seed = data, replay, seed
        n_fit = int(sum(m.sum() for m in data.fit_mask))
        self._stride = max(1, -(-n_fit // MAX_GP_POINTS))
        self._fitted = {}

    def fit(self, output: int):
        """``(gp, X, y)``: the GP of output index ``output`` and its training rows
        ``X`` (N, n_features) and targets ``y`` (N,), output units."""
        if output not in self._fitted:
            masks = self._data.fit_mask
            X = np.vstack([f[m] for f, m in zip(self.features, masks) if m.any()])[::self._stride]
            y = np.concatenate([(me[:, output] - r[:, output])[m] for me, r, m
                                in zip(self._data.measured, self._replay, masks) if m.any()])[::self._stride]
            self._fitted[output] = (_fit_residual_gp(X, y, seed=self._seed), X, y)
        return self._fitted[output]

    def predict(self, output: int) -> list:
        """The GP's mean of output index ``output`` per recording, shape (n_r,) each."""
        gp = self.fit(output)[0]
        return [gp.predict(f) for f in self.features]


@dataclass
class Models:
    """Result of :func:`build_models`.

    Attributes
    ----------
    corrected : EffectVehicle
        The reference with the named effects it keeps.
    corrected_replay : list of ndarray, shape (n_r, n_out)
    gp_prediction : dict of str to list of ndarray, shape (n_r,)
        Per output the corrected model misfits beyond the noise: its residual GP's mean per
        recording (outputs not listed have no residual GP).
    unexplained : list of dict
        diagnosis.json findings ``{"effect": "unexplained", "output", "value" (RMS misfit,
        output units), "unit", "noise_ratio", "data": "fit"}``.
    gp_absorbs : list of float
        Per named effect of the explanation, in its order: the fraction, 0 to 1, of what the
        effect explains that a GP fitted to the uncorrected residual reproduces (in-sample).
    reference_gps : ResidualGPs
        GPs on the uncorrected residual (fitted for the outputs asked for).
    """

    corrected: EffectVehicle
    corrected_replay: list
    gp_prediction: dict
    unexplained: list
    gp_absorbs: list
    reference_gps: ResidualGPs


def build_models(data: PreparedData, location: Location, explanation: Explanation, reference: EffectModel, *,
                 effects: list, seed: int, progress=None) -> Models:
    """The corrected model of ``effects`` (the named effects it keeps, in the explanation's
    order, :mod:`validation.diagnose.carry_over`), the residual GPs where it misfits, and the
    absorption check of every named effect (module docstring); ``seed`` seeds the GPs'
    hyperparameter restarts."""
    corrected_states, reference_states = zip(*data.simulate_states(reference, [effects, []]))
    columns = [reference.state_names.index(name) for name in data.output_names]
    corrected_replay = [states[:, columns] for states in corrected_states]
    corrected_gps = ResidualGPs(data, corrected_replay, corrected_states, reference, seed=seed)
    reference_gps = ResidualGPs(data, location.reference_replay, reference_states, reference, seed=seed)
    unexplained, gp_prediction = [], {}
    for i, name in enumerate(data.output_names):
        ratio, exceeds = noise_excess(data.weighted_output_residual(corrected_replay, i, data.fit_mask))
        if not exceeds:
            continue
        gp_prediction[name] = corrected_gps.predict(i)
        residual = data.output_residual(corrected_replay, i, data.fit_mask)
        unexplained.append({"effect": "unexplained", "output": name, "value": float(np.sqrt(np.mean(residual**2))),
                            "unit": effect_unit({"effect": "sensor_bias", "output": name}, reference),
                            "noise_ratio": ratio, "data": "fit"})
        if progress:
            progress(1, fitted=f"gp:{name}")
    absorbs = []
    for named in explanation.named:
        absorbs.append(_gp_absorbs(named, data, location, reference_gps))
        if progress:
            progress(1, fitted=f"gp-check:{named.target}")
    return Models(EffectVehicle(reference, effects), corrected_replay, gp_prediction,
                  unexplained, absorbs, reference_gps)


def _gp_absorbs(named: NamedEffect, data: PreparedData, location: Location, reference_gps: ResidualGPs) -> float:
    """Fraction of the signal a named effect adds to its main output (the replay with it alone
    minus the reference's, on the GP's training samples) that the GP on the uncorrected
    residual reproduces: ``1 - |gp - signal|^2 / |signal|^2``, clipped to [0, 1]."""
    main = named.main_output
    gp, X, y = reference_gps.fit(main)
    signal_part = np.concatenate([(a[:, main] - r[:, main])[m]
                                  for a, r, m in zip(named.alone, location.reference_replay, data.fit_mask)
                                  if m.any()])
    stride = max(1, -(-len(signal_part) // len(y))) if len(y) else 1
    signal_part = signal_part[::stride][:len(y)]
    absorbed = 1 - float(np.sum((gp.predict(X) - signal_part) ** 2) / max(np.sum(signal_part**2), 1e-300))
    return max(0.0, min(1.0, absorbed))


def _gp_features(states: np.ndarray, inputs: np.ndarray, time: np.ndarray, excited_columns) -> np.ndarray:
    """GP inputs per sample: the model's states, their rates of change (second-order central
    differences on the actual sample times ``time`` (n,), even or not, ``numpy.gradient``) and
    the excited inputs, shape (n, 2 n_states + n_excited). A lag or an unmodelled mode shows up
    as an error proportional to state rates and inputs; states carry the rest."""
    return np.hstack([states, np.gradient(states, time, axis=0), inputs[:, excited_columns]])


def _fit_residual_gp(features: np.ndarray, residual: np.ndarray, *, seed: int):
    """Squared-exponential ARD GP on (features, residual), type-II maximum likelihood
    (Rasmussen & Williams 2006, ch. 5) with one random restart, from unit signal variance,
    length scales 3 and noise variance 0.1 (in the units of the features and the residual);
    returns the fitted GP."""
    gp = GaussianProcess(SquaredExponentialARD(1.0, np.full(features.shape[1], 3.0)), noise_variance=0.1)
    gp.fit(features, residual)
    maximize_marginal_likelihood(gp, n_restarts=1, seed=seed)
    return gp
