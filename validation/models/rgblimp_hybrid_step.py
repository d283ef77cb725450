"""The rollout-trained RGBlimp hybrid's step in numpy: the RGBlimp's equations plus the learned
correction of the body accelerations, and the random acceleration of its band. numpy, the
standard library and plain project modules only, so the hybrid's FMU carries this module as it
is (:mod:`fmu_src.fmi.pythonfmu`; docs/fmus.md, "RGBlimp hybrid").

The hybrid (:class:`validation.models.rgblimp_rollout.RolloutHybrid`, which defines it and fits
it in JAX) adds to the identified model's body accelerations, inside every RK4 stage,

    a_o(z) = s_o sum_i exp(-1/2 sum_c ((z_c - Z_ic) / l_c)^2) W_io,    z = features / FEATURE_SCALE,

``Z`` (M, 11) the inducing inputs, ``l`` (11,) the length scales, ``s`` (6,) the amplitudes and
``W = L^-T v`` (M, 6) the weights of the whitened inducing values (computed once, at export, by
the same function the fit uses). :func:`hybrid_step` is the free run's step (the source's RK4
sample in the air mass's frame, :func:`validation.vehicles.rgblimp_equations.advance`) with yaw
carried continuously; it equals ``RolloutHybrid.simulate`` to rounding.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from validation.models.rgblimp_step import carry_yaw
from validation.vehicles.rgblimp_equations import advance, rotation_body_to_earth

#: What the correction sees, in order: air-relative body velocity, body rates, roll and pitch,
#: both thrusts (times the thrust factor) and the gondola's x position.
FEATURE_NAMES = ("U", "V", "W", "P", "Q", "R", "phi", "theta", "thrust_left", "thrust_right", "gondola_x")
#: Their fixed physical scales (m/s, rad/s, rad, N, m).
FEATURE_SCALE = (0.1, 0.05, 0.05, 0.05, 0.05, 0.2, 0.05, 0.05, 0.005, 0.005, 0.01)
#: The state and input columns of the features.
STATE_FEATURES = (6, 7, 8, 9, 10, 11, 3, 4)
INPUT_FEATURES = (0, 1, 2)


@dataclass(frozen=True)
class Correction:
    """The learned correction (module docstring): arrays in the units of the features scaled by
    :data:`FEATURE_SCALE`.

    Attributes
    ----------
    inducing : ndarray, shape (M, 11)
    weights : ndarray, shape (M, 6)
        ``L^-T v``.
    length_scale : ndarray, shape (11,)
    amplitude : ndarray, shape (6,)
        m/s^2 for the forces, rad/s^2 for the moments.
    """

    inducing: np.ndarray
    weights: np.ndarray
    length_scale: np.ndarray
    amplitude: np.ndarray

    def __call__(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """``a`` (..., 6) at air-frame ``states`` (..., 12) and ``inputs`` (..., 5) with the
        thrust factor applied (as :func:`validation.vehicles.rgblimp_equations.rgblimp_dynamics`
        passes them)."""
        return self.at_features(features(states, inputs))

    def at_features(self, values: np.ndarray) -> np.ndarray:
        """``a`` (..., 6) at feature values (..., 11) in physical units (:func:`features`,
        :func:`air_features`)."""
        z = values / np.asarray(FEATURE_SCALE)
        squared = np.sum(((z[..., None, :] - self.inducing) / self.length_scale) ** 2, axis=-1)
        return self.amplitude * (np.exp(-0.5 * squared) @ self.weights)


def features(states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """The correction's inputs (:data:`FEATURE_NAMES`, physical units) of ``states`` (..., 12) and
    ``inputs`` (..., 5): shape (broadcast leading axes, 11)."""
    states, inputs = np.asarray(states, dtype=float), np.asarray(inputs, dtype=float)
    shape = np.broadcast_shapes(states.shape[:-1], inputs.shape[:-1])
    return np.concatenate([np.broadcast_to(states[..., STATE_FEATURES], shape + (len(STATE_FEATURES),)),
                           np.broadcast_to(inputs[..., INPUT_FEATURES], shape + (len(INPUT_FEATURES),))], axis=-1)


def air_features(states, inputs, *, thrust_gain: float, wind) -> np.ndarray:
    """:func:`features` as the correction sees them in a free run: earth-frame ``states``
    (..., 12) with the wind ``(w_x, w_y)`` (m/s) taken off the body velocity, and the recorded
    ``inputs`` (..., 5) with the thrust factor applied."""
    states = np.array(states, dtype=float)
    inputs = np.array(inputs, dtype=float)
    wind3 = np.array([*np.asarray(wind, dtype=float), 0.0])
    states[..., 6:9] -= np.einsum("...ji,j->...i", rotation_body_to_earth(states[..., 3:6]), wind3)
    inputs[..., :2] *= thrust_gain
    return features(states, inputs)


def hybrid_step(states, inputs, params, *, thrust_gain: float, wind, correction: Correction,
                disturbance=None) -> np.ndarray:
    """One sample of the hybrid: the RK4 step of the RGBlimp's equations with ``correction``
    (and ``disturbance``, a constant acceleration (..., 6) over the step, the band's random
    acceleration, or None) added to the body accelerations in every stage, yaw carried
    continuously.

    Parameters
    ----------
    states : ndarray, shape (..., 12)
        Earth-frame states.
    inputs : ndarray, shape (5,) or (..., 5)
        As recorded (the thrust factor is applied here).
    params : RGBlimpParameters
    thrust_gain : float
    wind : sequence of 2 float
        m/s along earth x and y.
    correction : Correction
    disturbance : ndarray, shape (..., 6), optional

    Returns
    -------
    ndarray, shape (..., 12)
    """
    def extra(state, scaled_inputs):
        acceleration = correction(state, scaled_inputs)
        return acceleration if disturbance is None else acceleration + disturbance

    states = np.asarray(states, dtype=float)
    held = np.broadcast_to(np.asarray(inputs, dtype=float), states.shape[:-1] + (5,))
    return carry_yaw(states, advance(states, held, params, thrust_gain=thrust_gain, wind=wind,
                                     extra_acceleration=extra))
