"""The RGBlimp hybrid model inside the RGBlimp hybrid FMU: the identified RGBlimp model plus the
rollout-trained correction of its body accelerations
(:class:`validation.models.rgblimp_rollout.RolloutHybrid`), stepped by RK4 over one 1/60 s
sample, and the state covariance its band's random acceleration gives, propagated along the run.
numpy and the standard library only.

Every RGBlimp hybrid FMU (pythonfmu) carries a copy of this file and of what it imports: the FMU
runtime, the grey-box FMUs' covariance propagation (:mod:`fmu_src.fmi.greybox`), the RGBlimp's
equations and the hybrid's numpy step (:mod:`validation.models.rgblimp_hybrid_step`), so its
mean equals ``RolloutHybrid.simulate`` to rounding (tested to 1e-9). The native FMU evaluates the
same formulas in C (``rgblimp_hybrid_model.c``).

Model file (``model.npz``, written by :func:`pack_model`, read without pickle)
------------------------------------------------------------------------------
``format``, ``version``; ``physics`` (JSON text: every parameter, the thrust factor and the
wind); the correction ``inducing`` (M, 11), ``weights`` (M, 6), ``length_scale`` (11,),
``amplitude`` (6,) (:class:`validation.models.rgblimp_hybrid_step.Correction`);
``disturbance_sd`` (6,) and ``disturbance_time`` (the band's random acceleration, m/s^2,
rad/s^2 and s); ``propagation_step``; ``envelope_low``, ``envelope_high`` (11,), the range of
each feature the correction was fitted on.

Standard deviations
-------------------
``RolloutHybrid.band`` spreads 32 free runs by a first-order Gauss-Markov random acceleration
``d`` (Gelb 1974, sec. 3.8), held over each sample: ``d(k+1) = a d(k) + sqrt(1 - a^2) sd e(k)``,
``a = exp(-h / T)``, started at its stationary distribution. The FMU propagates the covariance
of the state augmented with ``d`` (18 states) to first order instead
(:class:`fmu_src.fmi.greybox.FirstOrderPropagation`): ``P(0) = diag(0, sd^2)``,
``P(k+1) = J P(k) J^T + diag(0, (1 - a^2) sd^2)`` with ``J`` the central differences of the
augmented step. It is the linearisation of the band (the prediction step of an extended Kalman
filter); the sampled band may differ where the spread reaches the nonlinear range.
"""
from __future__ import annotations

import json
import math

import numpy as np

from fmu_src.fmi.greybox import FirstOrderPropagation
from fmu_src.fmi.runtime import Envelope, ModelFormatError, check_header, freeze, model_header, read_model_file
from validation.models.rgblimp_hybrid_step import FEATURE_NAMES, Correction, air_features, hybrid_step
from validation.models.rgblimp_step import parameters_from_dict
from validation.vehicles.rgblimp_equations import SAMPLE_TIME

FORMAT = "flightgp-fmu-rgblimp-hybrid"
VERSION = 1
#: The model file's arrays besides the header and the physics, and their shapes (M: inducing points).
ARRAYS = {"inducing": ("M", len(FEATURE_NAMES)), "weights": ("M", 6), "length_scale": (len(FEATURE_NAMES),),
          "amplitude": (6,), "disturbance_sd": (6,), "disturbance_time": (), "propagation_step": (),
          "envelope_low": (len(FEATURE_NAMES),), "envelope_high": (len(FEATURE_NAMES),)}
#: The states of the covariance propagation: the 12 states, then the 6 random accelerations.
N_STATES, N_DISTURBANCES = 12, 6


def pack_model(*, physics: dict, correction: Correction, disturbance_sd, disturbance_time: float,
               propagation_step: float, envelope) -> dict:
    """Arrays for ``numpy.savez`` (module docstring).

    Parameters
    ----------
    physics : dict
        ``parameters`` (:func:`validation.models.rgblimp_step.parameters_as_dict`), ``thrust_gain``,
        ``wind`` ([w_x, w_y], m/s).
    correction : Correction
    disturbance_sd : sequence of 6 float
    disturbance_time : float
    propagation_step : float
    envelope : (low, high), each 11 floats
    """
    return {**model_header(FORMAT, VERSION), "physics": np.array(json.dumps(physics)),
            "inducing": correction.inducing, "weights": correction.weights,
            "length_scale": correction.length_scale, "amplitude": correction.amplitude,
            "disturbance_sd": np.asarray(disturbance_sd, dtype=float),
            "disturbance_time": np.array(float(disturbance_time)),
            "propagation_step": np.array(float(propagation_step)),
            "envelope_low": np.asarray(envelope[0], dtype=float), "envelope_high": np.asarray(envelope[1], dtype=float)}


class RGBlimpHybridModel:
    """An RGBlimp hybrid loaded from an FMU model file (module docstring).

    Attributes
    ----------
    params : validation.vehicles.rgblimp_equations.RGBlimpParameters
    thrust_gain : float
    wind : ndarray, shape (2,)
    correction : Correction
    decay : float
        ``a = exp(-h / T)`` of the random acceleration over one sample.
    disturbance_variance : ndarray, shape (6,)
        ``sd^2``.
    process_noise : ndarray, shape (18,)
        The diagonal ``Q`` added each step: 0 for the 12 states, ``(1 - a^2) sd^2`` for the
        random accelerations.
    propagation : FirstOrderPropagation
        Of the 18 augmented states.
    envelope : fmu_src.fmi.runtime.Envelope
        The features' fitting range.
    """

    def __init__(self, arrays: dict) -> None:
        check_header(arrays, format_name=FORMAT, version=VERSION)
        try:
            physics = json.loads(str(arrays["physics"]))
            self.params = parameters_from_dict(physics["parameters"])
            self.thrust_gain = float(physics["thrust_gain"])
            self.wind = np.array(physics["wind"], dtype=float)
            values = {name: np.array(arrays[name], dtype=float) for name in ARRAYS}
        except KeyError as error:
            raise ModelFormatError(f"the model file lacks {error}") from None
        except (TypeError, ValueError) as error:
            raise ModelFormatError(f"the model file's physics is unusable: {error}") from None
        m = len(values["inducing"])
        for name, shape in ARRAYS.items():
            expected = tuple(m if d == "M" else d for d in shape)
            if values[name].shape != expected or not np.isfinite(values[name]).all():
                raise ModelFormatError(f"{name} must be finite of shape {expected}, got {values[name].shape}")
        if not (self.wind.shape == (2,) and np.isfinite(self.wind).all() and math.isfinite(self.thrust_gain)):
            raise ModelFormatError("thrust_gain and the two wind components must be finite")
        if not (values["disturbance_time"] > 0 and values["disturbance_sd"].min() >= 0):
            raise ModelFormatError("the random acceleration needs standard deviations >= 0 and a positive time")
        self.correction = Correction(values["inducing"], values["weights"], values["length_scale"], values["amplitude"])
        self.decay = math.exp(-SAMPLE_TIME / float(values["disturbance_time"]))
        self.disturbance_variance = values["disturbance_sd"] ** 2
        self.propagation = FirstOrderPropagation(N_STATES + N_DISTURBANCES, float(values["propagation_step"]))
        self.envelope = Envelope(values["envelope_low"], values["envelope_high"], FEATURE_NAMES)
        self.process_noise = np.concatenate([np.zeros(N_STATES), (1 - self.decay**2) * self.disturbance_variance])
        freeze((self.wind, self.disturbance_variance, self.process_noise, *vars(self.correction).values()))

    @classmethod
    def load(cls, path) -> RGBlimpHybridModel:
        """Read ``path`` (an ``.npz`` written from :func:`pack_model`; never unpickles)."""
        return cls(read_model_file(path))

    def start_hidden(self) -> np.ndarray:
        """No hidden state beyond the mean and its covariance: shape (0,)."""
        return np.zeros(0)

    def start_covariance(self) -> np.ndarray:
        """A known state and the random acceleration at its stationary spread: (18, 18)."""
        return np.diag(np.concatenate([np.zeros(N_STATES), self.disturbance_variance]))

    def step(self, state: np.ndarray, covariance: np.ndarray, hidden: np.ndarray, inputs: np.ndarray, h: float):
        """One sample on under ``inputs`` (5,) held.

        Parameters
        ----------
        state : ndarray, shape (12,)
        covariance : ndarray, shape (18, 18)
            Of the state and the random acceleration (whose mean stays 0).
        hidden : ndarray, shape (0,)
        inputs : ndarray, shape (5,)
        h : float
            The communication step, the FMU's ``STEP_SIZE`` (one sample).

        Returns
        -------
        state : ndarray, shape (12,)
            The hybrid's step (its mean free run).
        covariance : ndarray, shape (18, 18)
        hidden : ndarray, shape (0,)
        x : ndarray, shape (11,)
            The correction's features at the state, for the envelope check.
        """
        points = self.propagation.points(np.concatenate([state, np.zeros(N_DISTURBANCES)]))  # (37, 18)
        moved = np.hstack([hybrid_step(points[:, :N_STATES], inputs, self.params, thrust_gain=self.thrust_gain,
                                       wind=self.wind, correction=self.correction,
                                       disturbance=points[:, N_STATES:]),
                           self.decay * points[:, N_STATES:]])
        augmented, covariance = self.propagation.advance(moved, covariance, self.process_noise)
        x = air_features(state, inputs, thrust_gain=self.thrust_gain, wind=self.wind)
        return augmented[:N_STATES], covariance, hidden, x

    def describe(self) -> str:
        """One line for the log."""
        return json.dumps({"inducing_points": len(self.correction.inducing), "thrust_gain": self.thrust_gain,
                           "wind_m_s": self.wind.tolist(),
                           "disturbance_sd": np.sqrt(self.disturbance_variance).tolist(),
                           "propagation_step": self.propagation.step})
