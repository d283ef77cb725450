"""The blimp's grey-box models (Ko et al., ICRA 2007, sec. IV-B): a physics step plus residual GPs,
trained on smoothed states with the fans' command history as GP inputs.

Three choices make the residual GP learn what the physics leaves out rather than the motion
capture's noise (measured on a validation flight, docs/reproductions.md, "Blimp RKGP"):

- **Training states** are re-estimated from the recorded poses alone by a quadratic through
  :data:`SMOOTHING_WINDOW` frames (:func:`smoothed_states`; Ko et al. obtained velocities "by a
  smoothed calculation of the slope"). The recorded velocities and rates are slopes of a 5-frame
  fit, so their noise (6 mm/s, 0.055 rad/s) dominated the one-frame residuals the GP was
  trained on.
- **GP inputs** add, to Ko et al.'s states and commands, each fan command passed through
  first-order lags of the time constants :data:`COMMAND_LAGS` (:func:`lagged_commands`): a fan
  spins up with a lag the physics does not model, so the residual depends on the commands of the
  last few tenths of a second, which the current state and command cannot show.
- **One GP per residual output** (not one set of hyperparameters shared by all, as Ko et al.),
  with a floor :data:`MIN_NOISE_VARIANCE` under each noise variance: the position and angle
  residuals of smoothed states are nearly functions of the inputs, and without the floor their
  noise falls to ~1e-7 of their spread, which makes the GP ill-conditioned.

A model file of such a model stores the GPs and :class:`BlimpStepDescription` as its ``physics``
(``gp_model.save_model(..., physics=description.as_dict())``): the identified parameters, the
RK4 substep and the command lags, from which the physics step and the GP inputs are rebuilt.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from gp_model import GreyBoxGP
from validation.core.errors import BadInputError
from validation.core.smoothing import local_polynomial
from validation.models.blimp_identification import physics_step, recording_arrays
from validation.models.state_estimation import extended_kalman_filter
from validation.vehicles.blimp import (
    ADAPTIVE_ATOL,
    ADAPTIVE_RTOL,
    INPUT_NAMES,
    MAX_STEP,
    STATE_NAMES,
    BlimpParameters,
)
from validation.vehicles.blimp_equations import blimp_dynamics, states_from_poses

#: The states the GPs see: every state but absolute position and yaw (Ko et al. 2007, sec. IV-B).
GP_STATE_COLUMNS = tuple(STATE_NAMES.index(n) for n in ("phi", "theta", "U", "V", "W", "P", "Q", "R"))
#: Time constants of the command lags the GPs see, s, bracketing the fans' spin-up (chosen on the
#: validation flight among one lag of 0.3 s, two of 0.2 and 0.4 s, and these three).
COMMAND_LAGS = (0.15, 0.3, 0.6)
#: The commands that drive a fan (the gondola angle ``mu`` acts at once), as step-input columns.
FAN_COMMANDS = ("u_gondola", "u_tail")
#: Frames and degree of the pose fit that re-estimates the training states (0.6 s at 20 Hz; chosen
#: on the validation flight among 9, 13, 17 frames quadratic and 21 frames cubic).
SMOOTHING_WINDOW, SMOOTHING_ORDER = 13, 2
#: Floor under each residual GP's noise variance, standardised (1 % of the residual's spread).
MIN_NOISE_VARIANCE = 1e-4
#: Every this many-th training transition is a GP training point (exact GPs cost n^3).
TRAINING_STRIDE = 3
#: Standard deviation per frame of the state estimator's process noise: position and angles
#: (m, rad; the kinematics are exact), velocities (m/s), rates (rad/s) (chosen on the validation
#: flight among 1, 2, 3 and 5 times these, docs/reproductions.md, "Blimp RKGP").
PROCESS_NOISE_SD = (1e-4,) * 6 + (1e-3,) * 3 + (1e-2,) * 3
#: Prior standard deviation of the state estimator at the first frame: 1 mm, 0.01 rad, 0.01 m/s
#: and 0.1 rad/s about the first recorded frame.
INITIAL_STATE_SD = (1e-3,) * 3 + (1e-2,) * 3 + (1e-2,) * 3 + (1e-1,) * 3
BLIMP_PHYSICS = "blimp_rk4"


def advance_lags(lags, commands, dt, *, time_constants) -> np.ndarray:
    """The lagged fan commands one frame on: ``T z_dot = -z + u`` with ``u`` held over the frame
    interval is exact as ``z(k+1) = a z(k) + (1 - a) u(k)``, ``a = exp(-dt(k) / T)`` (Franklin,
    Powell & Workman, *Digital Control of Dynamic Systems*, 3rd ed., 1998, sec. 4.3).

    Parameters
    ----------
    lags : ndarray, shape (..., 2 * len(time_constants))
        ``z(k)``: for each time constant, the gondola and the tail fan.
    commands : ndarray, shape (..., 3)
        ``u_gondola, mu, u_tail`` held from frame k to k + 1.
    dt : float or ndarray, shape (...)
        Frame interval, s.
    time_constants : sequence of float
        ``T`` of each lag, s.

    Returns
    -------
    ndarray, shape (..., 2 * len(time_constants))
        ``z(k + 1)``.
    """
    fans = np.asarray(commands, dtype=float)[..., [INPUT_NAMES.index(name) for name in FAN_COMMANDS]]
    decay = np.exp(-np.asarray(dt, dtype=float)[..., None] / np.repeat(time_constants, len(FAN_COMMANDS)))
    return decay * lags + (1.0 - decay) * np.tile(fans, len(time_constants))


def lagged_commands(commands: np.ndarray, dt: np.ndarray, *, time_constants, initial=None) -> np.ndarray:
    """The fan commands passed through first-order lags (:func:`advance_lags`), at every frame.

    Parameters
    ----------
    commands : ndarray, shape (n, 3)
        ``u_gondola, mu, u_tail`` held from frame k to k + 1.
    dt : ndarray, shape (n,)
        Frame intervals, s.
    time_constants : sequence of float
        ``T`` of each lag, s.
    initial : ndarray, shape (2 * len(time_constants),), optional
        The lags' outputs at frame 0; default 0 (fans at rest).

    Returns
    -------
    ndarray, shape (n, 2 * len(time_constants))
        ``z(k)`` before command k acts: for each time constant, the gondola and the tail fan.
    """
    z = np.zeros(len(FAN_COMMANDS) * len(time_constants)) if initial is None else np.asarray(initial, dtype=float)
    out = np.empty((len(commands), len(z)))
    for k in range(len(commands)):
        out[k] = z
        z = advance_lags(z, commands[k], dt[k], time_constants=time_constants)
    return out


def lag_names(time_constants) -> list[str]:
    """Names of the :func:`lagged_commands` columns, e.g. ``u_gondola_lag_0.15s``."""
    return [f"{fan}_lag_{tau:g}s" for tau in time_constants for fan in FAN_COMMANDS]


def step_inputs(recording, *, command_lags=COMMAND_LAGS) -> np.ndarray:
    """The grey-box model's inputs at every frame of ``recording``, shape (n, 4 + 2 L): the
    commands, the frame interval ``dt`` to the next frame (the last repeats the one before) and
    the :func:`lagged_commands` from fans at rest at the recording's start."""
    _, inputs = recording_arrays(recording)
    return np.hstack([inputs, lagged_commands(inputs[:, :3], inputs[:, 3], time_constants=command_lags)])


def smoothed_states(recording, *, window: int = SMOOTHING_WINDOW, order: int = SMOOTHING_ORDER) -> np.ndarray:
    """The 12 states at every frame re-estimated from the recorded poses alone: positions and
    Euler angles and their slopes from :func:`validation.core.smoothing.local_polynomial`, turned
    into body velocities and rates; shape (n, 12)."""
    states, _ = recording_arrays(recording)
    positions, position_rates = local_polynomial(recording.time, states[:, 0:3], window=window, order=order)
    angles, angle_rates = local_polynomial(recording.time, states[:, 3:6], window=window, order=order)
    return states_from_poses(positions, angles, position_rates, angle_rates)


def filtered_states(recording, step, *, command_lags=COMMAND_LAGS,
                    process_noise_sd=PROCESS_NOISE_SD) -> np.ndarray:
    """The 12 states at every frame estimated causally from the recorded poses through a
    one-step model: :func:`validation.models.state_estimation.extended_kalman_filter` with the
    recording's marker noise (``sensor_noise_std`` of its sidecar) as measurement noise.

    Unlike :func:`smoothed_states`, frame k's estimate uses frames 0..k only, so it is a start
    state a predictor could have had at frame k.

    Parameters
    ----------
    recording : Recording
        All 12 states recorded, ``sensor_noise_std`` of x, y, z, phi, theta, psi in its metadata.
    step : callable
        ``step(states (m, 12), inputs (m, 4 + 2 L)) -> next states``, inputs as :func:`step_inputs`.
    command_lags : sequence of float
    process_noise_sd : sequence of float, shape (12,)
        :data:`PROCESS_NOISE_SD`.

    Returns
    -------
    ndarray, shape (n, 12)
    """
    noise = recording.metadata.get("sensor_noise_std", {})
    missing = [name for name in STATE_NAMES[:6] if name not in noise]
    if missing:
        raise BadInputError(f"filtering needs the marker noise of {', '.join(missing)} (sensor_noise_std "
                            "in the recording's sidecar)")
    states, _ = recording_arrays(recording)
    return extended_kalman_filter(
        step, states[:, :6], step_inputs(recording, command_lags=command_lags), measured_columns=range(6),
        measurement_variance=[float(noise[name]) ** 2 for name in STATE_NAMES[:6]],
        process_variance=np.square(process_noise_sd), initial_mean=states[0],
        initial_covariance=np.diag(np.square(INITIAL_STATE_SD))).mean


def adaptive_step(params: BlimpParameters):
    """The blimp ODE over one frame by scipy's adaptive ``RK45`` (Ko et al.'s "ODE").

    Returns ``step(states, inputs) -> next_states`` with the conventions of
    :func:`validation.models.blimp_identification.physics_step` (``inputs`` (n, >= 4): commands
    and ``dt``; further columns are ignored). All rows are integrated as one system in rescaled
    time ``tau = t / dt`` on [0, 1] (``ds/dtau = dt f(s, u)``), so rows with different ``dt``
    share one ``solve_ivp`` call; the error norm is then shared too (an RMS over all rows), which
    at rtol 1e-8 is far below the mocap noise.
    """
    def step(states, inputs):
        states = np.asarray(states, dtype=float)
        inputs = np.asarray(inputs, dtype=float)
        commands, dt = inputs[:, :3], inputs[:, 3:4]
        shape = states.shape

        def rate(_tau, y):
            return (dt * blimp_dynamics(y.reshape(shape), commands, params)).ravel()

        solution = solve_ivp(rate, (0.0, 1.0), states.ravel(), method="RK45", t_eval=[1.0],
                             rtol=ADAPTIVE_RTOL, atol=ADAPTIVE_ATOL)
        if not solution.success:
            raise RuntimeError(f"adaptive integration over one frame failed: {solution.message}")
        return solution.y[:, -1].reshape(shape)

    return step


def fit_greybox(recordings, physics, *, command_lags=COMMAND_LAGS, smoothing=(SMOOTHING_WINDOW, SMOOTHING_ORDER),
                stride: int = TRAINING_STRIDE, seed: int = 0) -> GreyBoxGP:
    """A :class:`gp_model.GreyBoxGP` on the residual of ``physics`` (module docstring).

    Parameters
    ----------
    recordings : sequence of Recording
        Training flights (all 12 states recorded).
    physics : callable or None
        ``physics(states, inputs) -> next_states`` (:func:`physics_step`, :func:`adaptive_step`),
        or None for a GP-only model.
    command_lags : sequence of float
        :data:`COMMAND_LAGS`.
    smoothing : (int, int) or None
        Window (frames) and degree of :func:`smoothed_states`; None trains on the recorded states.
    stride : int
        Every ``stride``-th transition of each recording trains the GPs.
    seed : int
        Seed of the hyperparameter search's restarts.
    """
    states, inputs, next_states = [], [], []
    for recording in recordings:
        if smoothing is None:
            smooth = recording_arrays(recording)[0]
        else:
            smooth = smoothed_states(recording, window=smoothing[0], order=smoothing[1])
        step = step_inputs(recording, command_lags=command_lags)
        rows = np.arange(0, len(smooth) - 1, stride)
        states.append(smooth[rows])
        inputs.append(step[rows])
        next_states.append(smooth[rows + 1])
    model = GreyBoxGP(state_columns=GP_STATE_COLUMNS, shared=False, n_restarts=0,
                      min_noise_variance=MIN_NOISE_VARIANCE)
    return model.fit(np.vstack(states), np.vstack(inputs), np.vstack(next_states), physics, seed=seed)


def ard_relevance(model: GreyBoxGP, *, command_lags=COMMAND_LAGS) -> dict:
    """Each GP input's share of every residual GP's ARD weights ``w_i = 1 / (2 l_i^2)`` (in
    standardised inputs), by residual output: ``{output: {input: share}}``."""
    names = [STATE_NAMES[c] for c in model.state_columns_] + [*INPUT_NAMES, "dt", *lag_names(command_lags)]
    gps = [model.gp_] if model.shared else model.gp_.gps
    outputs = STATE_NAMES if not model.shared else ["all"]
    relevance = {}
    for output, gp in zip(outputs, gps):
        weights = gp.kernel.weights(gp.theta_[:-1])
        relevance[output] = {name: float(w) for name, w in zip(names, weights / weights.sum())}
    return relevance


@dataclass(frozen=True)
class BlimpStepDescription:
    """What a blimp grey-box model file stores as its ``physics``: the parameters and RK4
    substep of :func:`physics_step` and the command lags of the GP inputs.

    Attributes
    ----------
    params : BlimpParameters
    max_step : float
        Longest RK4 substep, s.
    command_lags : tuple of float
        Time constants of :func:`lagged_commands`, s; empty for Ko et al.'s inputs alone.
    """

    params: BlimpParameters
    max_step: float = MAX_STEP
    command_lags: tuple = ()

    @property
    def input_names(self) -> list[str]:
        """The step-input columns: commands, ``dt`` and the lagged commands."""
        return [*INPUT_NAMES, "dt", *lag_names(self.command_lags)]

    def physics_step(self):
        """The RK4 step (:func:`validation.models.blimp_identification.physics_step`)."""
        return physics_step(self.params, max_step=self.max_step)

    def as_dict(self) -> dict:
        """The JSON description (``kind`` ``blimp_rk4``)."""
        return {"kind": BLIMP_PHYSICS, "parameter_names": list(BlimpParameters.vector_names()),
                "parameters": [float(v) for v in self.params.to_vector()], "max_step": float(self.max_step),
                "command_lags": [float(t) for t in self.command_lags],
                "state_names": list(STATE_NAMES), "input_names": self.input_names}

    @classmethod
    def from_dict(cls, description) -> BlimpStepDescription:
        """The description :meth:`as_dict` wrote.

        Raises
        ------
        validation.core.errors.BadInputError
            Not a ``blimp_rk4`` description, or its parameters, names or lags are unusable.
        """
        if not isinstance(description, dict) or description.get("kind") != BLIMP_PHYSICS:
            kind = description.get("kind") if isinstance(description, dict) else None
            raise BadInputError(f"the model's physics is {kind!r}; a blimp grey-box model needs "
                                f"{BLIMP_PHYSICS!r} (validation.models.blimp_greybox)")
        try:
            lags = tuple(float(t) for t in description.get("command_lags", ()))
            if not all(np.isfinite(t) and t > 0 for t in lags):
                raise ValueError(f"command lags must be positive times in s, got {lags}")
            described = cls(BlimpParameters.from_vector(np.asarray(description["parameters"], dtype=float)),
                            float(description["max_step"]), lags)
            if (list(description["parameter_names"]) != list(BlimpParameters.vector_names())
                    or list(description["state_names"]) != list(STATE_NAMES)
                    or list(description["input_names"]) != described.input_names):
                raise ValueError("its parameter, state or input names differ from this flightgp's blimp")
            if not described.max_step > 0:
                raise ValueError(f"max_step must be positive, got {described.max_step}")
        except (KeyError, TypeError, ValueError) as error:
            raise BadInputError(f"the model's {BLIMP_PHYSICS} physics description is unusable: {error}") from None
        return described
