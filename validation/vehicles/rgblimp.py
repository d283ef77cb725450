"""The RGBlimp physics reference ``rgblimp``: the source's first-principle model as a vehicle.

The RGBlimp (robotic gliding blimp) of Zhu, Cheng & Zhang, IEEE RA-L 2024 (arXiv 2404.18580),
whose model :mod:`validation.vehicles.rgblimp_equations` ports from the repository
``zhu-yj/ABNODE`` (MIT licence). This module adds what a vehicle needs around the equations
(docs/vehicles.md, "Names and interface"): argument checks (:class:`BadInputError`), a start
state and :class:`RGBlimpReference`, which flies an input history as the source integrates its
model, one RK4 step per 1/60 s motion-capture sample with the inputs held
(:func:`~validation.vehicles.rgblimp_equations.rk4_step`). docs/rgblimp.md describes the model
and the recordings.

Conventions (docs/conventions.md, "Units and axes"): states ``x, y, z, phi, theta, psi, U, V, W,
P, Q, R`` (earth position with z down, m; ZYX Euler angles, rad; body velocity, m/s; body rates,
rad/s), inputs ``thrust_left, thrust_right`` (N) and ``gondola_x, gondola_y, gondola_z`` (m, the
gondola's position in body axes). The inputs are absolute values, not perturbations: the
source's flights hold thrusts of 0.01 .. 0.06 N and the gondola near
:data:`~validation.vehicles.rgblimp_equations.NOMINAL_GONDOLA_POSITION`.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.core.sampling import check_history, sampling_metadata
from validation.vehicles.rgblimp_equations import (
    INPUT_NAMES,
    SAMPLE_TIME,
    STATE_NAMES,
    RGBlimpParameters,
    rk4_step,
)

#: The registry name of the RGBlimp reference, which its recordings' metadata carry.
VEHICLE_NAME = "rgblimp"

#: How far the sample interval may be from :data:`~validation.vehicles.rgblimp_equations.SAMPLE_TIME`,
#: relative: the even-sampling tolerance of docs/conventions.md, "Time".
_STEP_RTOL = 1e-6


def resting_state(gondola, params: RGBlimpParameters) -> np.ndarray:
    """At rest at the origin, heading north, in the static attitude: the centre of gravity of
    hull and gondola straight below the centre of buoyancy, so that gravity has no moment.

    With the first mass moment ``l = m r + m_b r_b`` (the hull's CG ``r``, the gondola at
    ``r_b``) and earth down in body axes ``n = [-sin theta, cos theta sin phi, cos theta cos
    phi]`` equal to ``l / |l|``: ``phi = atan2(l_y, l_z)``, ``theta = -asin(l_x / |l|)``. With
    the source's parameters and the nominal gondola the blimp hangs 2.0 deg nose up.

    Parameters
    ----------
    gondola : array_like, shape (3,)
        The gondola position in body axes, m (``gondola_x, gondola_y, gondola_z``).
    params : RGBlimpParameters

    Returns
    -------
    ndarray, shape (12,)
        ``x, y, z, phi, theta, psi, U, V, W, P, Q, R``: zero but ``phi`` and ``theta``.
    """
    mass_moment = (params.hull_mass * np.asarray(params.hull_cg)
                   + params.gondola_mass * np.asarray(gondola, dtype=float))
    state = np.zeros(len(STATE_NAMES))
    distance = float(np.linalg.norm(mass_moment))
    if distance > 0:
        state[3] = math.atan2(mass_moment[1], mass_moment[2])
        state[4] = -math.asin(mass_moment[0] / distance)
    return state


class RGBlimpReference:
    """The ``rgblimp`` physics reference: the source's model flown as the source flies it.

    Parameters
    ----------
    params : RGBlimpParameters, optional
        Default ``RGBlimpParameters()``, the values of the source's ``utils/parameters.py``
        (:data:`validation.vehicles.rgblimp_data.RECORDED_MODEL_PARAMETERS` are the ones its
        recordings' model columns were computed with).

    Deterministic: ``simulate``'s ``seed`` is accepted for the
    :class:`~validation.vehicles.Vehicle` interface and ignored.
    """

    name = VEHICLE_NAME
    input_names = INPUT_NAMES
    state_names = STATE_NAMES
    sample_time = SAMPLE_TIME

    def __init__(self, *, params: RGBlimpParameters | None = None) -> None:
        if params is not None and not isinstance(params, RGBlimpParameters):
            raise BadInputError(f"params must be RGBlimpParameters, got {type(params).__name__}")
        self.params = params if params is not None else RGBlimpParameters()

    def simulate_states(self, time, inputs, *, initial_state=None) -> np.ndarray:
        """States at ``time`` with ``inputs[k]`` held over ``[time[k], time[k+1])``: one RK4
        step of 1/60 s per sample, heading kept in [-pi, pi] (the source's ``RK_RGB``).

        Parameters
        ----------
        time : array_like, shape (n,)
            Sample times, s (n >= 2): evenly spaced at 1/60 s, the source's step.
        inputs : array_like, shape (n, 5)
            ``thrust_left, thrust_right`` (N), ``gondola_x, gondola_y, gondola_z`` (m) at each
            sample; the last row is never used.
        initial_state : array_like, shape (12,), optional
            The state at ``time[0]`` (a recording's first state, for the source's free run);
            default :func:`resting_state` for the gondola of ``inputs[0]``.

        Returns
        -------
        ndarray, shape (n, 12)

        Raises
        ------
        BadInputError
            ``time`` is not an even 60 Hz grid, ``inputs`` has the wrong shape or a non-finite
            value, or ``initial_state`` is not 12 finite numbers.
        """
        time, inputs, step = check_history(time, inputs, INPUT_NAMES)
        if abs(step - SAMPLE_TIME) > _STEP_RTOL * SAMPLE_TIME:
            raise BadInputError(f"the {self.name} model steps at 1/60 s (the source's RK4 step and "
                                f"motion-capture rate), but time is sampled at {step:.9g} s: resample to 60 Hz")
        if initial_state is None:
            initial_state = resting_state(inputs[0, 2:5], self.params)
        state = np.asarray(initial_state, dtype=float)
        if state.shape != (len(STATE_NAMES),) or not np.all(np.isfinite(state)):
            raise BadInputError(f"initial_state must be 12 finite numbers ({', '.join(STATE_NAMES)}), "
                                f"got {initial_state!r}")
        states = np.empty((len(time), len(STATE_NAMES)))
        states[0] = state
        for k in range(len(time) - 1):
            states[k + 1] = rk4_step(states[k], inputs[k], self.params)
        return states

    def simulate(self, time, inputs, *, seed: int = 0, initial_state=None) -> Recording:
        """Fly ``inputs`` and record all 12 states at ``time`` (see :meth:`simulate_states`);
        the metadata name the vehicle and its parameters."""
        states = self.simulate_states(time, inputs, initial_state=initial_state)
        time = np.asarray(time, dtype=float)
        metadata = {"vehicle": self.name, "parameters": dataclasses.asdict(self.params),
                    **sampling_metadata(time)}
        return Recording(time, inputs, INPUT_NAMES, states, STATE_NAMES, metadata)
