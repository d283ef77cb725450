"""The air moved: atmospheric turbulence as the competitor of every named effect.

Real flights are flown in air that moves. The residual of even a perfect model is then the
model's response to the gusts, coloured rather than white, and an output-error test (white
residuals) accepts any extra term that soaks up a gust. Flight-test practice estimates in
turbulence with the *filter-error method* (Jategaonkar, *Flight Vehicle System Identification*,
2006, ch. 5; Maine & Iliff, NASA RP-1168, 1986, ch. 7): the model is driven by a process noise
as well as measured with sensor noise, and a Kalman filter's innovations give the likelihood.

Here the process noise is the air's: gust velocities ``u_g, v_g, w_g`` from Dryden filters
(:func:`validation.vehicles.turbulence.dryden_filter`, one time constant ``T = L / V`` for the
three, a standard deviation each) act on the model's ``u, v, w`` columns, ``x_dot = A x -
A[:, (u, v, w)] gust`` (the way the flight-test stand-in's turbulence enters,
:mod:`validation.vehicles.bo105_flight`). The output-error residual ``r = y - y_model`` of a
model is the response of this augmented system (8 aircraft states and 5 filter states on the
Bo105) plus white sensor noise of the standard deviations the locate stage estimated, ``R =
diag(sd^2)``. With the steady-state Kalman filter of the system discretised exactly at the
sample interval (Van Loan, IEEE TAC 23(3), 1978; the prior covariance ``P`` from the discrete
algebraic Riccati equation; Jategaonkar 2006, sec. 5.3, the steady-state filter of a linear
time-invariant system), the innovations ``e_k`` with covariance ``S = H P H^T + R`` give

    -2 ln L = sum_k e_k^T S^-1 e_k + n ln det S        (up to a constant)

over the fitted samples, against ``sum_k r_k^T R^-1 r_k + n ln det R`` for still air (the
output-error likelihood). The four gust parameters (``sigma_u, sigma_v, sigma_w``, m/s, and
``T``, s) are estimated by maximum likelihood (Nelder-Mead on their logarithms); the likelihood
ratio of gusts against still air is :attr:`GustFit.likelihood_ratio`.

Every effect the stepwise search would accept is weighed against the air too
(:func:`weigh_against_air`): the model with the effect and the model without it, each in the
turbulence estimated for it, by the filter-error likelihood ratio. An effect that output error
accepts only because it soaks up gusts gains little there. The effect's value stays the
output-error estimate, so the ratio is a lower bound of the one at the filter-error optimum.

Only a model the filter can carry takes part: a linear reference (:class:`LinearEffects`) with
states ``u, v, w``; its derivatives are the model's (effects on inputs, a delay or a lag, do not
change how it answers a gust; the measurement chain's effects and polynomial terms are left out
of the gust path, which is then approximate).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg, signal, stats
from scipy.optimize import minimize

from validation.diagnose.fitting import FAMILY_ALPHA, FitData, akaike_weights, step_threshold
from validation.diagnose.noise import UNEXPLAINED_RATIO
from validation.vehicles.bo105 import KNOT
from validation.vehicles.effects import EffectModel
from validation.vehicles.linear_discretisation import expm
from validation.vehicles.state_space import propagate
from validation.vehicles.turbulence import dryden_filter

#: Start of the search for the gust parameters: standard deviation, m/s, and time constant, s.
_START_SIGMA, _START_TIME_CONSTANT = 0.3, 5.0
#: Nelder-Mead's largest number of likelihood evaluations per fit.
_MAX_EVALUATIONS = 160
#: Bounds of the time constant searched, s: 0.5 s is a scale length of 20 m at 80 kt, shorter
#: than the low-altitude model's at 65 ft (MIL-F-8785C, sec. 3.7.2.3: ``L_w = h``); 200 s longer
#: than any recording this tool fits.
_TIME_CONSTANT_BOUNDS = (0.5, 200.0)
#: Largest gust standard deviation searched, m/s: over three times the severe turbulence of the
#: low-altitude model at 500 ft (``W_20 = 45 kt``: ``sigma_u`` 2.9 m/s,
#: :func:`validation.vehicles.turbulence.low_altitude_turbulence`). A residual that wants more is
#: not the air's; without the bound the filter takes any misfit for gusts.
_SIGMA_CEILING = 10.0
#: Gauss-Newton steps of a candidate's value towards the filter error's optimum when refining and
#: screening (:meth:`AirCompetitor.refine`, :meth:`AirCompetitor.screen`), and their forward
#: difference as a fraction of the hypothesis' screening step.
_FILTER_ERROR_STEPS, _DIFFERENCE_STEP = 3, 0.1
#: Hypotheses fitted by filter error per step, the best of the score test
#: (:meth:`AirCompetitor.screen`).
SCREENED = 6
#: Time constants, s, of the filters of the inputs' increments the innovations are tested
#: against (:func:`_input_coherence`): a response within a sample or two, one of a rotor or an
#: actuator, one of the short-period and roll modes.
_INPUT_TIME_CONSTANTS = (0.02, 0.2, 1.0)
#: A gust standard deviation below this, m/s, is still air (the search's floor).
_SIGMA_FLOOR = 1e-4


@dataclass
class GustFit:
    """The turbulence that best explains a model's residual (module docstring).

    Attributes
    ----------
    sigma : ndarray, shape (3,)
        Standard deviations of ``u_g, v_g, w_g``, m/s.
    time_constant : float
        The Dryden filters' ``T = L / V``, s.
    minus_two_log_likelihood : float
        ``-2 ln L`` of the filter error at the estimate (up to the constant shared with
        ``still_air``).
    still_air : float
        ``-2 ln L`` of output error (no gusts), same constant.
    evaluate : callable or None
        ``evaluate(residuals)``: ``-2 ln L`` of other residuals (per fitted recording, (n_r,
        n_out), output units) in this turbulence and this model's gust response; None for still
        air.
    whiten : callable or None
        ``whiten(residuals)``: their innovations in this filter, whitened (``e_k L``, ``L L^T =
        S^-1``), flattened; linear, so it takes sensitivities alike. None for still air.
    n_residuals : int
        Fitted samples times outputs.
    input_p_value : float
        :func:`_input_coherence`'s p-value: small where the innovations follow the inputs, which
        gusts do not.
    excess : float
        The innovations' energy beyond its expectation, ``sum e^T S^-1 e - N`` (``N`` residuals),
        at least 0: what the air does not explain (for still air, ``RSS - N``).
    """

    sigma: np.ndarray
    time_constant: float
    minus_two_log_likelihood: float
    still_air: float
    evaluate: object = None
    excess: float = 0.0
    whiten: object = None
    n_residuals: int = 0
    input_p_value: float = 1.0

    @property
    def likelihood_ratio(self) -> float:
        """Gusts against still air, ``-2 ln`` of the likelihood ratio, at least 0."""
        return max(self.still_air - self.minus_two_log_likelihood, 0.0)

    @property
    def intensity(self) -> float:
        """The gusts' root-mean-square over the three axes, ``sqrt(mean(sigma^2))``, m/s."""
        return float(np.sqrt(np.mean(self.sigma ** 2)))


def trim_airspeed(reference: EffectModel) -> float | None:
    """The speed the aircraft flies through the air at trim, m/s, where the reference says it (a
    Bo105's ``speed_kt``), else None; None in the hover too, where the gusts are not advected
    past the aircraft and have no scale length to state."""
    speed = getattr(getattr(reference, "reference", None), "speed_kt", None)
    return float(speed) * KNOT if speed else None


def gust_dynamics(reference: EffectModel, effects: list) -> np.ndarray | None:
    """The model's ``A`` (n_states, n_states) with the derivatives among ``effects``, or None
    when the reference is not a linear one with states ``u, v, w`` (module docstring)."""
    linear = getattr(reference, "reference", None)
    if linear is None or not hasattr(linear, "with_derivatives") or not hasattr(linear, "A"):
        return None
    if any(name not in linear.state_names for name in ("u", "v", "w")):
        return None
    derivatives = {e["term"]: e["value"] for e in effects
                   if e["effect"] in ("control_derivative", "stability_derivative")}
    return (linear.with_derivatives(derivatives) if derivatives else linear).A


def _discrete_system(A: np.ndarray, uvw: list, sigma, time_constant: float, step: float):
    """The gust response of ``A`` with the Dryden filters, exactly discretised at ``step`` s:
    transition (m, m) and process-noise covariance (m, m), ``m = n_states + 5``."""
    F_d, G_d, C_d = dryden_filter(sigma, (time_constant,) * 3, 1.0)  # T = L / V with V = 1
    n, m = len(A), len(A) + len(F_d)
    F = np.zeros((m, m))
    F[:n, :n] = A
    F[:n, n:] = -A[:, uvw] @ C_d
    F[n:, n:] = F_d
    G = np.zeros((m, G_d.shape[1]))
    G[n:] = G_d
    E = expm(np.block([[-F, G @ G.T], [np.zeros((m, m)), F.T]]) * step)
    transition = E[m:, m:].T
    covariance = transition @ E[:m, m:]
    return transition, (covariance + covariance.T) / 2


def _steady_filters(A, uvw, outputs, noise_sd, step, sigma, time_constant) -> list | None:
    """Per recording (its sensor noise ``noise_sd``), the steady-state Kalman filter of the gust
    response (module docstring) as ``(closed, gain, H, whitening, log_det)``: the predicted
    state follows ``x-_{k+1} = closed x-_k + gain r_k`` (``closed = Phi (I - K H)``, ``gain =
    Phi K``), the innovation is ``e_k = r_k - H x-_k``, ``whitening`` (n_out, n_out) is a
    Cholesky factor ``L`` of ``S^-1`` (``e L`` is white with unit variance) and ``log_det`` is
    ``ln det S``. None where the Riccati equation has no stabilising solution."""
    transition, process = _discrete_system(A, uvw, sigma, time_constant, step)
    m = len(transition)
    H = np.zeros((len(outputs), m))
    H[np.arange(len(outputs)), outputs] = 1.0
    filters = []
    for sd in noise_sd:
        R = np.diag(np.asarray(sd, dtype=float) ** 2)
        try:
            P = linalg.solve_discrete_are(transition.T, H.T, process, R)
            S = H @ P @ H.T + R
            S_inv = np.linalg.inv(S)
            whitening = np.linalg.cholesky((S_inv + S_inv.T) / 2)
        except (np.linalg.LinAlgError, ValueError):
            return None
        sign, log_det = np.linalg.slogdet(S)
        if sign <= 0:
            return None
        K = P @ H.T @ S_inv
        filters.append((transition @ (np.eye(m) - K @ H), transition @ K, H, whitening, log_det))
    return filters


def _whitened_innovations(filters, residuals, masks) -> list:
    """Per recording, the innovations ``e_k L`` (n_fitted, n_out) of ``residuals`` on the masked
    samples (:func:`_steady_filters`); the filter is linear, so it takes sensitivities alike."""
    out = []
    for (closed, gain, H, whitening, _), residual, mask in zip(filters, residuals, masks):
        last = int(np.flatnonzero(mask)[-1]) + 1
        r = residual[:last]
        predicted = propagate(closed, r @ gain.T, np.zeros(len(closed)))
        out.append(((r - predicted[:-1] @ H.T)[mask[:last]]) @ whitening)
    return out


def _minus_two_log_likelihood(A, uvw, outputs, residuals, masks, noise_sd, step, sigma, time_constant, *,
                              energy: bool = False):
    """``-2 ln L`` of the filter error (module docstring) summed over the recordings; inf where
    the Riccati equation has no stabilising solution. With ``energy``, also the innovations'
    energy ``sum e^T S^-1 e`` (its expectation is the number of residuals)."""
    filters = _steady_filters(A, uvw, outputs, noise_sd, step, sigma, time_constant)
    if filters is None:
        return (math.inf, math.inf) if energy else math.inf
    total, innovation_energy = 0.0, 0.0
    for white, filter_ in zip(_whitened_innovations(filters, residuals, masks), filters):
        if not np.all(np.isfinite(white)):
            return (math.inf, math.inf) if energy else math.inf
        part = float(np.sum(white ** 2))
        innovation_energy += part
        total += part + len(white) * filter_[-1]
    return (total, innovation_energy) if energy else total


def fit_gusts(data: FitData, reference: EffectModel, effects: list) -> GustFit | None:
    """The turbulence that best explains the residual of the reference with ``effects`` on
    ``data``'s fitted samples (module docstring); None where the model cannot carry gusts
    (:func:`gust_dynamics`) or the recordings are not evenly sampled."""
    A = gust_dynamics(reference, effects)
    if A is None:
        return None
    steps = [np.diff(t) for t in data.time]
    if any(len(s) == 0 or not np.allclose(s, s[0], rtol=1e-6) for s in steps):
        return None
    chosen = [i for i, mask in enumerate(data.fit_mask) if mask.any()]
    if not chosen or len({round(float(steps[i][0]), 12) for i in chosen}) != 1:
        return None
    step = float(steps[chosen[0]][0])
    names = reference.state_names
    uvw = [names.index(name) for name in ("u", "v", "w")]
    outputs = [names.index(name) for name in data.output_names]
    replays = data.simulate(reference, effects)
    residuals = [data.measured[i] - replays[i] for i in chosen]
    masks = [data.fit_mask[i] for i in chosen]
    noise_sd = [data.noise_sd[i] for i in chosen]
    still = sum(float(np.sum((r[m] / sd) ** 2)) + int(m.sum()) * float(np.sum(np.log(np.asarray(sd) ** 2)))
                for r, m, sd in zip(residuals, masks, noise_sd))
    low, high = (math.log(b) for b in _TIME_CONSTANT_BOUNDS)

    def objective(parameters):
        sigma = np.clip(np.exp(parameters[:3]), _SIGMA_FLOOR, _SIGMA_CEILING)
        log_t = min(max(parameters[3], low), high)
        with np.errstate(all="ignore"):
            value = _minus_two_log_likelihood(A, uvw, outputs, residuals, masks, noise_sd, step, sigma,
                                              math.exp(log_t))
        return value if math.isfinite(value) else 1e300

    start = np.array([math.log(_START_SIGMA)] * 3 + [math.log(_START_TIME_CONSTANT)])
    result = minimize(objective, start, method="Nelder-Mead",
                      options={"maxfev": _MAX_EVALUATIONS, "xatol": 1e-2, "fatol": 1e-3})
    sigma = np.clip(np.exp(result.x[:3]), _SIGMA_FLOOR, _SIGMA_CEILING)
    best, time_constant = float(result.fun), math.exp(min(max(result.x[3], low), high))
    n_residuals = sum(int(m.sum()) for m in masks) * len(outputs)
    if not best < still:  # the search found nothing better than still air
        rss = sum(float(np.sum((r[m] / sd) ** 2)) for r, m, sd in zip(residuals, masks, noise_sd))
        return GustFit(np.zeros(3), time_constant, still, still, excess=max(rss - n_residuals, 0.0),
                       n_residuals=n_residuals)
    with np.errstate(all="ignore"):
        _, energy = _minus_two_log_likelihood(A, uvw, outputs, residuals, masks, noise_sd, step, sigma,
                                              time_constant, energy=True)

    filters = _steady_filters(A, uvw, outputs, noise_sd, step, sigma, time_constant)

    def evaluate(others):
        with np.errstate(all="ignore"):
            white = _whitened_innovations(filters, others, masks)
        if not all(np.all(np.isfinite(w)) for w in white):
            return math.inf
        return sum(float(np.sum(w ** 2)) + len(w) * f[-1] for w, f in zip(white, filters))

    def whiten(others):
        with np.errstate(all="ignore"):
            return np.concatenate([w.ravel() for w in _whitened_innovations(filters, others, masks)])

    with np.errstate(all="ignore"):
        white = _whitened_innovations(filters, residuals, masks)
    input_p_value = _input_coherence(white, [data.inputs[i] for i in chosen], masks, step)
    return GustFit(sigma, time_constant, best, still, evaluate, excess=max(energy - n_residuals, 0.0),
                   whiten=whiten, n_residuals=n_residuals, input_p_value=input_p_value)


def _input_coherence(white: list, inputs: list, masks: list, step: float) -> float:
    """Whether the filter's innovations follow the inputs: gusts are independent of what the
    pilot does, a model error is not (a missing lag or a derivative that drifts shows right after
    each input step). Each whitened innovation (unit-variance white noise where the air alone
    is left) is regressed on the inputs' increments passed through first-order filters of
    :data:`_INPUT_TIME_CONSTANTS`; the explained sum of squares over all of them is
    chi-squared with (regressors times outputs) degrees of freedom under the air alone (an F
    test with known variance; e.g. Seber & Lee, *Linear Regression Analysis*, 2nd ed., 2003,
    sec. 4.3). Returns its p-value (1 where no input moves)."""
    total, dof = 0.0, 0
    for w, u, mask in zip(white, inputs, masks):
        last = int(np.flatnonzero(mask)[-1]) + 1
        u = np.asarray(u[:last], dtype=float)
        increments = np.diff(u, axis=0, prepend=u[:1])
        columns = []
        for time_constant in _INPUT_TIME_CONSTANTS:
            a = math.exp(-step / time_constant)
            columns.append(signal.lfilter([1.0 - a], [1.0, -a], increments, axis=0))
        X = np.hstack(columns)[mask[:last]]
        X = X[:, np.abs(X).max(axis=0) > 0]
        if X.shape[1] == 0 or not np.all(np.isfinite(w)):
            continue
        basis, _ = np.linalg.qr(X / np.abs(X).max(axis=0))
        total += float(np.sum((basis.T @ w) ** 2))
        dof += basis.shape[1] * w.shape[1]
    return float(stats.chi2.sf(total, dof)) if dof else 1.0


def weigh_against_air(model_fit: GustFit | None, with_effect: GustFit | None, *, n_tested: int) -> dict | None:
    """An effect against "the air moved" (module docstring): the filter-error likelihood ratio
    of the model with the effect against the model without it, each in its own estimated
    turbulence, its Bonferroni-corrected chi-squared test at
    :data:`~validation.diagnose.fitting.FAMILY_ALPHA` over ``n_tested`` hypotheses (one degree
    of freedom, the effect's value) that must also remove
    :data:`~validation.diagnose.fitting.MIN_EXCESS_FRACTION` of what the air leaves unexplained
    (:attr:`GustFit.excess`, as output error's rule does of ``RSS - N``), and the effect's Akaike
    weight against the air,
    ``1 / (1 + exp(-(LR - 2) / 2))`` (Burnham & Anderson, *Model Selection and Multimodel
    Inference*, 2nd ed., 2002, sec. 2.9). None where either model cannot carry gusts.

    Returns
    -------
    dict or None
        ``likelihood_ratio``, ``threshold``, ``passes``, ``weight``, ``intensity`` (the
        turbulence estimated with the effect, m/s).
    """
    if model_fit is None or with_effect is None:
        return None
    lr = model_fit.minus_two_log_likelihood - with_effect.minus_two_log_likelihood
    threshold = step_threshold(n_tested, excess=model_fit.excess)
    weight = akaike_weights([lr, 2.0])[1]  # AIC without the effect, with it, less the shared -2 log L
    return {"likelihood_ratio": float(lr), "threshold": threshold, "passes": bool(lr > threshold),
            "weight": float(weight), "intensity": with_effect.intensity}


def held_out_cost(data: FitData, reference: EffectModel, effects: list, fit: GustFit):
    """The held-out cost of :mod:`validation.diagnose.carry_over` in turbulence: ``-2 ln L`` of
    the filter error on the held-out samples (``data.holdout_mask``), in the turbulence ``fit``
    estimated and the gust response of the reference with ``effects``, up to a constant
    (``sum e^T S^-1 e``). No model predicts the gusts of a flight it did not see; the filter
    weighs each model's misfit by what the air could have done. Returns ``cost(replay)``
    (``replay`` per recording, (n_r, n_out)), or None where the model cannot carry gusts."""
    A = gust_dynamics(reference, effects)
    chosen = [i for i, mask in enumerate(data.holdout_mask) if mask.any()]
    if A is None or fit.evaluate is None or not chosen:
        return None
    names = reference.state_names
    step = float(data.time[chosen[0]][1] - data.time[chosen[0]][0])
    filters = _steady_filters(A, [names.index(n) for n in ("u", "v", "w")],
                              [names.index(n) for n in data.output_names], [data.noise_sd[i] for i in chosen],
                              step, fit.sigma, fit.time_constant)
    if filters is None:
        return None
    masks = [data.holdout_mask[i] for i in chosen]

    def cost(replay) -> float:
        with np.errstate(all="ignore"):
            white = _whitened_innovations(filters, [data.measured[i] - replay[i] for i in chosen], masks)
        return float(sum(np.sum(w ** 2) for w in white))

    return cost


def describe(fit: GustFit | None, *, airspeed: float | None = None) -> dict:
    """diagnosis.json's ``disturbance`` (docs/diagnose.md): whether the residual of the final
    model looks like atmospheric disturbance, with the turbulence estimated.

    It does when the gusts' likelihood ratio against still air passes a chi-squared test with
    four degrees of freedom at :data:`~validation.diagnose.fitting.FAMILY_ALPHA` and the
    filter's whitened innovations are within
    :data:`~validation.diagnose.noise.UNEXPLAINED_RATIO` times the noise (``sqrt(sum e^T S^-1 e
    / N)``; an output's residual beyond that ratio is an ``unexplained`` finding). ``fit`` None:
    not tested (a reference that cannot carry gusts). ``airspeed`` (m/s), optional, turns the
    time constant into a scale length.

    Returns
    -------
    dict
        ``tested``, ``looks_like_turbulence``, ``input_p_value``, ``sigma`` (``{"u", "v", "w"}``, m/s),
        ``intensity`` (their root-mean-square, m/s), ``time_constant`` (s), ``scale_length``
        (m, or None), ``likelihood_ratio``, ``p_value``, ``innovation_ratio``.
    """
    if fit is None:
        return {"tested": False, "looks_like_turbulence": False, "input_p_value": None, "sigma": None,
                "intensity": None, "time_constant": None, "scale_length": None, "likelihood_ratio": None,
                "p_value": None, "innovation_ratio": None}
    lr = fit.likelihood_ratio
    ratio = math.sqrt((fit.excess + fit.n_residuals) / fit.n_residuals) if fit.n_residuals else None
    still = lr <= 0 or not math.isfinite(fit.time_constant)
    p_value = float(stats.chi2.sf(lr, 4))
    follows_inputs = fit.input_p_value < FAMILY_ALPHA
    looks = bool(not still and p_value < FAMILY_ALPHA and ratio is not None and ratio <= UNEXPLAINED_RATIO
                 and not follows_inputs)
    return {"tested": True, "looks_like_turbulence": looks, "input_p_value": fit.input_p_value,
            "sigma": dict(zip(("u", "v", "w"), (float(v) for v in fit.sigma))),
            "intensity": fit.intensity, "time_constant": None if still else fit.time_constant,
            "scale_length": None if still or airspeed is None else fit.time_constant * airspeed,
            "likelihood_ratio": float(lr), "p_value": p_value, "innovation_ratio": ratio}


class AirCompetitor:
    """"The air moved" in one stepwise search (:func:`validation.diagnose.explain.select_effects`):
    the gust fit of each model it meets, each fitted once.

    Where a model's weighted residual sum of squares is below the upper 1 % quantile of the noise's
    (chi-squared with one degree of freedom per residual), the residual is the sensor noise:
    there is no air to weigh against, and no gust fit is made.

    Parameters
    ----------
    data : FitData
    reference : EffectModel
        A reference that carries gusts (:func:`gust_dynamics`).
    """

    def __init__(self, data: FitData, reference: EffectModel):
        self.data, self.reference = data, reference
        self._fits: dict = {}
        self._refined: set = set()
        self._noise_only = float(stats.chi2.isf(FAMILY_ALPHA, data.n_residuals))

    def fit(self, model) -> GustFit | None:
        """:func:`fit_gusts` of ``model`` (a :class:`~validation.diagnose.fitting.FittedModel`)."""
        key = self._key(model)
        if key not in self._fits:
            self._fits[key] = fit_gusts(self.data, self.reference, model.effects())
        return self._fits[key]

    def at_noise(self, model) -> bool:
        """Whether ``model``'s residual is the sensor noise's alone (its RSS within the
        chi-squared quantile of the residual count at
        :data:`~validation.diagnose.fitting.FAMILY_ALPHA`): no air is left to weigh against."""
        return model.rss <= self._noise_only

    def in_play(self, model) -> bool:
        """Whether the air explains some of ``model``'s residual: not noise alone, and the
        gusts' likelihood ratio against still air passes a chi-squared test with four degrees of
        freedom (the gust parameters) at :data:`~validation.diagnose.fitting.FAMILY_ALPHA`."""
        if self.at_noise(model):
            return False
        fit = self.fit(model)
        return fit is not None and fit.likelihood_ratio > stats.chi2.isf(FAMILY_ALPHA, 4)

    @staticmethod
    def _key(model) -> tuple:
        return tuple((h.key, float(v)) for h, v in zip(model.hypotheses, model.values))

    def refine(self, model):
        """``model`` with all its values moved to the filter error's optimum in the turbulence
        estimated for it (:data:`_FILTER_ERROR_STEPS` Gauss-Newton steps on the whitened
        innovations, forward-difference sensitivities of :data:`_DIFFERENCE_STEP` screening
        steps, within the bounds; Jategaonkar 2006, ch. 5, with the turbulence held), its RSS
        the output error's there and its covariance the filter error's Cramér-Rao bound
        ``(J^T J)^-1`` (``J`` the whitened sensitivities). As it is without effects, where the
        model cannot carry gusts, or where it was refined already."""
        key = self._key(model)
        if not model.hypotheses or key in self._refined:
            return model
        fit = self.fit(model)
        if fit is None or fit.whiten is None:
            return model
        chosen = [i for i, mask in enumerate(self.data.fit_mask) if mask.any()]
        hypotheses = model.hypotheses
        lower, upper = np.array([h.lower for h in hypotheses]), np.array([h.upper for h in hypotheses])
        values, information = np.array(model.values, dtype=float), None
        with np.errstate(all="ignore"):
            for _ in range(_FILTER_ERROR_STEPS):
                steps = np.array([h.step * _DIFFERENCE_STEP for h in hypotheses])
                steps = np.where(values + steps > upper, -steps, steps)
                trials = [values] + [values + np.eye(len(values))[j] * steps[j] for j in range(len(values))]
                replays = self.data.simulate_many(self.reference, [[h.as_effect(v) for h, v in zip(hypotheses, t)]
                                                                   for t in trials])
                residuals = [[self.data.measured[i] - replay[i] for i in chosen] for replay in replays]
                white = fit.whiten(residuals[0])
                jacobian = np.column_stack([fit.whiten([a - b for a, b in zip(residuals[0], moved)]) / steps[j]
                                            for j, moved in enumerate(residuals[1:])])
                information = jacobian.T @ jacobian
                if not (np.all(np.isfinite(information)) and np.all(np.isfinite(white))):
                    return model
                values = np.clip(values + np.linalg.lstsq(information, jacobian.T @ white, rcond=None)[0], lower, upper)
        covariance = np.linalg.pinv(information)
        effects = [h.as_effect(v) for h, v in zip(hypotheses, values)]
        rss = float(np.sum(self.data.weighted_residuals(self.reference, effects) ** 2))
        refined = dataclasses.replace(model, values=values, rss=rss, covariance=covariance,
                                      white_covariance=covariance)
        self._refined.add(self._key(refined))
        return refined

    def weigh(self, model, candidate, *, n_tested: int) -> tuple:
        """:func:`weigh_against_air` of ``candidate`` (``model`` plus one effect) against
        ``model``, each first moved to the filter error's optimum (:meth:`refine`, so that the
        effect is not credited with a better value of the others); ``(result, refined
        candidate)``, ``(None, candidate)`` where the candidate leaves only noise (class
        docstring)."""
        if self.at_noise(candidate):
            return None, candidate
        refined = self.refine(candidate)
        return weigh_against_air(self.fit(self.refine(model)), self.fit(refined), n_tested=n_tested), refined

    def screen(self, model, hypotheses: list) -> list:
        """The ``hypotheses`` on top of ``model`` screened and fitted by filter error in the
        turbulence estimated for ``model`` and its gust response: a score test of each (Rao
        1948; the sensitivity of the replay to the hypothesis' value by a forward difference of
        its screening step, whitened by the filter as the residual is), then the
        :data:`SCREENED` best moved to the filter error's optimum (:data:`_FILTER_ERROR_STEPS`
        Gauss-Newton steps from the score test's one-step value, within the bounds). Returns
        ``(fitted, minus_two_log_likelihood)`` pairs, most likely first: each ``fitted`` a
        :class:`~validation.diagnose.fitting.FittedModel` of ``model`` plus one hypothesis, its
        RSS the output error's at that value, the new value's variance the filter error's
        Cramér-Rao bound ``1 / (s^T s)`` with ``s`` the whitened sensitivity (Jategaonkar 2006,
        ch. 5). Empty where ``model``'s residual shows no air."""
        fit = self.fit(model)
        if fit is None or fit.whiten is None or not hypotheses:
            return []
        chosen = [i for i, mask in enumerate(self.data.fit_mask) if mask.any()]
        base = model.effects()

        def residuals(effects_list):
            replays = self.data.simulate_many(self.reference, effects_list)
            return [[self.data.measured[i] - replay[i] for i in chosen] for replay in replays]

        with np.errstate(all="ignore"):
            return self._screen(fit, model, hypotheses, chosen, base, residuals)

    def _screen(self, fit, model, hypotheses, chosen, base, residuals) -> list:
        """:meth:`screen`'s work, with floating-point warnings off (a trial may diverge)."""
        here = residuals([base])[0]
        white = fit.whiten(here)
        moved = residuals([base + [h.as_effect(h.null + h.step)] for h in hypotheses])
        scores = []
        for h, there in zip(hypotheses, moved):
            sensitivity = fit.whiten([a - b for a, b in zip(here, there)]) / h.step
            norm = float(sensitivity @ sensitivity)
            delta = float(sensitivity @ white) / norm if norm > 0 and np.isfinite(norm) else 0.0
            delta = min(max(delta, h.lower - h.null), h.upper - h.null) if np.isfinite(delta) else 0.0
            scores.append((norm * delta ** 2 if np.isfinite(norm) else 0.0, h.null + delta))
        order = np.argsort([-score for score, _ in scores], kind="stable")[:SCREENED]
        results = []
        for index in order:
            h, value = hypotheses[index], scores[index][1]
            information = 0.0
            for _ in range(_FILTER_ERROR_STEPS):
                step = h.step * _DIFFERENCE_STEP * (-1.0 if value + h.step * _DIFFERENCE_STEP > h.upper else 1.0)
                now, after = residuals([base + [h.as_effect(value)], base + [h.as_effect(value + step)]])
                white_now = fit.whiten(now)
                sensitivity = fit.whiten([a - b for a, b in zip(now, after)]) / step
                information = float(sensitivity @ sensitivity)
                if not (information > 0 and np.all(np.isfinite(white_now))):
                    break
                value = float(np.clip(value + float(sensitivity @ white_now) / information, h.lower, h.upper))
            effects = base + [h.as_effect(value)]
            rss = float(np.sum(self.data.weighted_residuals(self.reference, effects) ** 2))
            variance = 1.0 / information if information > 0 else math.inf
            p = len(model.hypotheses)
            covariance = np.zeros((p + 1, p + 1))
            covariance[:p, :p], covariance[p, p] = model.covariance, variance
            white_covariance = np.zeros((p + 1, p + 1))
            white_covariance[:p, :p], white_covariance[p, p] = model.white_covariance, variance
            fitted = dataclasses.replace(model, hypotheses=model.hypotheses + [h],
                                         values=np.append(model.values, value), rss=rss, covariance=covariance,
                                         white_covariance=white_covariance)
            results.append((fitted, fit.evaluate(residuals([effects])[0])))
        return sorted(results, key=lambda pair: pair[1])

    def final_fit(self, model) -> GustFit | None:
        """The gust fit of the search's final ``model``: still air (no fit made) where its
        residual is the noise's (class docstring)."""
        if self.at_noise(model):
            return GustFit(np.zeros(3), math.nan, model.rss, model.rss,
                           excess=max(model.rss - self.data.n_residuals, 0.0), n_residuals=self.data.n_residuals)
        return self.fit(model)
