"""Named effects on the blimp reference (:mod:`validation.vehicles.blimp`), simulated in batches.

The effect dicts are those of :mod:`validation.vehicles.effects` (the ``flightgp diagnose`` finding shape).
On the blimp they act on the ODE of :func:`validation.vehicles.blimp.blimp_dynamics` as follows (body axes,
SI units; ``M`` is the blimp's system inertia matrix, so an extra generalised force ``tau``
adds ``M^-1 tau`` to ``nu_dot``):

- ``time_delay`` on ``u_gondola``, ``mu`` or ``u_tail``: the input ``u_j(t - tau)``. The
  recorded input is zero-order held, row k over ``[t_k, t_{k+1})`` of length ``h_k`` (trim, 0,
  before ``t_0``), so its integral ``U(t)`` is piecewise linear with knots at the sample times; the
  simulation holds the delayed input's *interval mean*
  ``(U(t_{k+1} - tau) - U(t_k - tau)) / h_k`` over each interval (exact in the input's integral
  over each interval, continuous and piecewise linear in ``tau``, which an output-error fit
  needs). On an even grid ``h`` with ``tau = (m + f) h`` this is
  ``(1 - f) u_j[k-m] + f u_j[k-m-1]``: the delayed input switches at fraction ``f`` inside each
  interval;
- ``input_lag`` on an input: ``T z_dot = -z + u_j`` and the ODE sees ``z``. With the input
  ``u_k`` held over an interval of length ``h_k``, ``z`` is exact at the samples,
  ``z[k+1] = a_k z[k] + (1 - a_k) u_k`` with ``a_k = exp(-h_k/T)``, and the simulation holds its
  exact interval mean ``u_k + (z[k] - u_k) (T/h_k) (1 - a_k)`` over the interval (the exact
  zero-order-hold discretisation of a first-order system, Franklin, Powell & Workman, *Digital
  Control of Dynamic Systems*, 3rd ed., 1998, sec. 4.3, taken interval by interval): stable for
  any ``T``, continuous at ``T = 0`` (the mean tends to ``u_k``) with a non-zero slope there, as
  a fit needs (a lag after a delay acts on the delayed interval means);
- ``control_derivative``, terms ``gondola_thrust_forward``, ``gondola_thrust_backward``,
  ``tail_thrust_positive``, ``tail_thrust_negative``: the fan thrust per unit command, N, for
  positive / negative commands (the :class:`~validation.vehicles.blimp.BlimpParameters` of the same
  names); applied as a gain ``value / model value`` on the command after delay and lag;
- ``stability_derivative``, terms ``L_P``, ``M_Q``, ``N_R``: the linear rotational damping
  derivatives ``dL/dP`` etc., N m s/rad (the model's are ``-rotational_damping``); the change
  adds a moment ``(value - model) P``;
- ``quadratic_drag``, terms ``X_UU``, ``Y_VV``, ``Z_WW``: the quadratic translational damping
  derivatives ``dX/d(U|U|)`` etc., N s^2/m^2 (the model's are ``-quadratic_drag``, Zufferey et
  al. 2006); the change adds a force ``(value - model) U|U|``;
- ``force_offset``, terms ``X_0``, ``Y_0`` (body-axis forces, N), ``N_0`` (yaw moment, N m) and
  ``Z_0`` (net downward force, weight minus buoyancy, N, along the earth vertical and acting at
  the centre of buoyancy: a buoyancy imbalance; the model's is ``-net_lift``);
- ``sensor_bias`` on any of the 12 states: a constant added to the recorded output.

Integration: classical RK4 with one step per recording interval, each of its own length
``h_k = t_{k+1} - t_k`` (motion-capture frames arrive with timing jitter, so recordings may be
unevenly sampled), from the reference's hanging state (:class:`~validation.vehicles.blimp.BlimpReference`
uses substeps of at most 0.01 s; at 20 Hz the two agree to far below the sensor noise, see
``tests/test_diagnose_blimp.py``). All members of a batch are integrated together, one
vectorised :func:`~validation.vehicles.blimp.blimp_dynamics` call per RK4 stage, and all lags of a batch
are propagated together, which is what makes output-error fitting of many hypotheses affordable.
"""
from __future__ import annotations

import math

import numpy as np

from validation.vehicles.blimp import (
    INPUT_NAMES,
    STATE_NAMES,
    BlimpReference,
    blimp_dynamics,
    check_command_history,
    hanging_state,
    mass_matrix,
)
from validation.vehicles.blimp_flight import ATTITUDE_NOISE_STD, POSITION_NOISE_STD

#: Control-derivative terms: fan, command column, sign of the commands it applies to.
CONTROL_TERMS = {"gondola_thrust_forward": ("u_gondola", 1.0), "gondola_thrust_backward": ("u_gondola", -1.0),
                 "tail_thrust_positive": ("u_tail", 1.0), "tail_thrust_negative": ("u_tail", -1.0)}
#: Stability-derivative terms: the rotational-rate column (0 P, 1 Q, 2 R).
STABILITY_TERMS = {"L_P": 0, "M_Q": 1, "N_R": 2}
#: Quadratic-drag terms: the body-velocity column (0 U, 1 V, 2 W).
DRAG_TERMS = {"X_UU": 0, "Y_VV": 1, "Z_WW": 2}
#: Force-offset terms: the generalised-force column (0-2 forces, 5 yaw moment; Z_0 earth-vertical).
OFFSET_TERMS = {"X_0": 0, "Y_0": 1, "Z_0": 2, "N_0": 5}
TERMS = {"control_derivative": tuple(CONTROL_TERMS), "stability_derivative": tuple(STABILITY_TERMS),
         "quadratic_drag": tuple(DRAG_TERMS), "force_offset": tuple(OFFSET_TERMS)}
TERM_UNITS = {**dict.fromkeys(CONTROL_TERMS, "N"), **dict.fromkeys(STABILITY_TERMS, "N m s/rad"),
              **dict.fromkeys(DRAG_TERMS, "N s^2/m^2"), "X_0": "N", "Y_0": "N", "Z_0": "N", "N_0": "N m"}

#: Recording interval of the blimp diagnosis, s: the 20 Hz motion capture of Ko et al. (DESIGN.md).
SAMPLE_TIME = 0.05
#: White sensor noise per state of the blimp recordings (the ``blimp-flight`` stand-in's marker
#: noise, 1 mm and 0.5 deg; velocities and rates at the noise of its 5-sample quadratic-fit
#: differentiator at 20 Hz, ``sd / (sqrt(10) h)``, but white here).
SENSOR_NOISE_STD = {
    **dict.fromkeys(("x", "y", "z"), POSITION_NOISE_STD),
    **dict.fromkeys(("phi", "theta", "psi"), ATTITUDE_NOISE_STD),
    **dict.fromkeys(("U", "V", "W"), POSITION_NOISE_STD / (math.sqrt(10.0) * SAMPLE_TIME)),
    **dict.fromkeys(("P", "Q", "R"), ATTITUDE_NOISE_STD / (math.sqrt(10.0) * SAMPLE_TIME)),
}


def model_value(reference: BlimpReference, term: str) -> float:
    """The reference's value of ``term`` (module docstring for units and signs)."""
    params = reference.params
    if term in CONTROL_TERMS:
        return float(getattr(params, term))
    if term in STABILITY_TERMS:
        return -float(params.rotational_damping[STABILITY_TERMS[term]])
    if term in DRAG_TERMS:
        return -float(params.quadratic_drag[DRAG_TERMS[term]])
    if term == "Z_0":
        return -float(params.net_lift)
    if term in OFFSET_TERMS:
        return 0.0
    raise KeyError(term)


def _delayed_mean(signal_: np.ndarray, delay: float, time: np.ndarray) -> np.ndarray:
    """Interval means of the zero-order-held ``signal_`` delayed by ``delay`` s (module docstring).

    Parameters
    ----------
    signal_ : ndarray, shape (n,)
        Row k held over ``[time[k], time[k+1])``; trim (0) before ``time[0]``.
    delay : float
        s, >= 0.
    time : ndarray, shape (n,)
        Strictly increasing sample times, s (even or not).

    Returns
    -------
    ndarray, shape (n - 1,)
        The delayed input's mean over each interval ``[time[k], time[k+1])``.
    """
    steps = np.diff(time)
    # U(time[k]) = sum_{i<k} u_i h_i; U is linear between the knots, so interpolation is exact.
    integral = np.concatenate(([0.0], np.cumsum(signal_[:-1] * steps)))
    shifted = np.interp(time - delay, time, integral, left=0.0)  # U(time[k] - delay)
    return np.diff(shifted) / steps


def _lagged_means(signals: np.ndarray, time_constants: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Interval means of first-order lags' outputs for held inputs (module docstring), each lag
    starting at trim (0).

    Parameters
    ----------
    signals : ndarray, shape (m, n - 1)
        Each lag's input, row ``[:, k]`` held over interval k.
    time_constants : ndarray, shape (m,)
        ``T`` of each lag, s, > 0.
    steps : ndarray, shape (n - 1,)
        Interval lengths ``h_k``, s.

    Returns
    -------
    ndarray, shape (m, n - 1)
        The mean of each lag's output ``z`` over each interval.
    """
    ratio = steps[None, :] / time_constants[:, None]  # h_k / T
    decay = np.exp(-ratio)  # a_k
    rise = -np.expm1(-ratio)  # 1 - a_k
    mean_gain = rise / ratio  # (T / h_k) (1 - a_k)
    lag_state = np.zeros(len(time_constants))  # z[k]
    means = np.empty_like(signals)
    for k in range(signals.shape[1]):
        held = signals[:, k]
        means[:, k] = held + (lag_state - held) * mean_gain[:, k]
        lag_state = decay[:, k] * lag_state + rise[:, k] * held  # z[k+1]
    return means


def simulate_batch(reference: BlimpReference, effect_lists, time, inputs) -> np.ndarray:
    """Recorded outputs of the blimp with each list of effects, all integrated together.

    Parameters
    ----------
    reference : BlimpReference
    effect_lists : sequence of list of dict
        B lists of checked effects (:func:`validation.vehicles.effects.check_effects`).
    time : ndarray, shape (n,)
        Strictly increasing sample times, s; evenly spaced or not (one RK4 step per interval).
    inputs : ndarray, shape (n, 3)
        ``u_gondola, mu, u_tail``, zero-order hold (row k acts from ``time[k]`` to ``time[k+1]``).

    Returns
    -------
    ndarray, shape (B, n, 12)
        ``x, y, z, phi, theta, psi, U, V, W, P, Q, R`` as recorded (biases added), SI units,
        from the reference's hanging state at rest.
    """
    time, inputs = check_command_history(time, inputs)
    steps = np.diff(time)
    params = reference.params
    n, batch = len(time), len(effect_lists)
    held = np.repeat(inputs[None, :-1], batch, axis=0)  # (B, n-1, 3): what acts over each interval
    gain_positive, gain_negative = np.ones((batch, 3)), np.ones((batch, 3))
    extra_damping, extra_drag = np.zeros((batch, 3)), np.zeros((batch, 3))
    constant, extra_down, bias = np.zeros((batch, 6)), np.zeros(batch), np.zeros((batch, 12))
    lags = []  # (member, input column, time constant)
    for b, effects in enumerate(effect_lists):
        for effect in effects:  # delays first: a lag acts on the delayed input
            if effect["effect"] == "time_delay" and effect["value"] > 0:
                j = INPUT_NAMES.index(effect["input"])
                held[b, :, j] = _delayed_mean(inputs[:, j], effect["value"], time)
        for effect in effects:
            kind, value = effect["effect"], effect["value"]
            if kind == "input_lag" and value > 0:
                lags.append((b, INPUT_NAMES.index(effect["input"]), value))
            elif kind == "sensor_bias":
                bias[b, STATE_NAMES.index(effect["output"])] += value
            elif kind in ("control_derivative", "stability_derivative", "quadratic_drag", "force_offset"):
                term = effect["term"]
                change = value - model_value(reference, term)
                if term in CONTROL_TERMS:
                    column, sign = CONTROL_TERMS[term]
                    gains = gain_positive if sign > 0 else gain_negative
                    gains[b, INPUT_NAMES.index(column)] = value / model_value(reference, term)
                elif term in STABILITY_TERMS:
                    extra_damping[b, STABILITY_TERMS[term]] = change
                elif term in DRAG_TERMS:
                    extra_drag[b, DRAG_TERMS[term]] = change
                elif term == "Z_0":
                    extra_down[b] = change
                else:
                    constant[b, OFFSET_TERMS[term]] = change
    if lags:
        members, columns, time_constants = (np.array(values) for values in zip(*lags))
        held[members, :, columns] = _lagged_means(held[members, :, columns], time_constants, steps)
    _, inverse = mass_matrix(params.mass, params.added_mass, params.inertia, params.added_inertia,
                              params.cg_position)

    def derivative(state, command):
        effective = command * np.where(command >= 0, gain_positive, gain_negative)
        v, w, angles = state[:, 6:9], state[:, 9:12], state[:, 3:6]
        down = np.stack([-np.sin(angles[:, 1]), np.cos(angles[:, 1]) * np.sin(angles[:, 0]),
                         np.cos(angles[:, 1]) * np.cos(angles[:, 0])], axis=-1)
        force = constant.copy()
        force[:, :3] += extra_drag * np.abs(v) * v + extra_down[:, None] * down
        force[:, 3:] += extra_damping * w
        rates = blimp_dynamics(state, effective, params)
        rates[:, 6:] += force @ inverse.T
        return rates

    states = np.empty((batch, n, 12))
    state = np.repeat(hanging_state(params)[None], batch, axis=0)
    states[:, 0] = state
    for k, step in enumerate(steps):  # classical RK4 over [t_k, t_{k+1}), input row k held
        command = held[:, k]
        k1 = derivative(state, command)
        k2 = derivative(state + 0.5 * step * k1, command)
        k3 = derivative(state + 0.5 * step * k2, command)
        k4 = derivative(state + step * k3, command)
        state = state + step / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        states[:, k + 1] = state
    return states + bias[:, None, :]


def identification_manoeuvre(*, duration: float = 20.0, sample_time: float = SAMPLE_TIME,
                             variant: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A blimp identification input: gondola thrust steps forward and back (speed builds up
    against quadratic drag, so thrust and drag separate: acceleration at the step measures the
    thrust, the speed it settles to the drag), gondola-angle steps while thrusting (``mu`` only
    acts with thrust on), then a tail-fan doublet (yaw) with the gondola idle, all one after the
    other (Tischler & Remple 2012, ch. 5: one axis at a time).

    Parameters
    ----------
    duration, sample_time : float
        s; 20 s at 20 Hz by default (the mocap rate).
    variant : int
        0: for fitting; 1: other amplitudes, timing and signs (held-out data).

    Returns
    -------
    time : ndarray, shape (n,)
    inputs : ndarray, shape (n, 3)
        ``u_gondola`` (-1..1), ``mu`` (rad), ``u_tail`` (-1..1).
    """
    from validation.core.manoeuvres import doublet, time_grid

    time = time_grid(duration=duration, sample_time=sample_time)
    inputs = np.zeros((len(time), 3))

    def span(start, stop):
        return (time >= start - 1e-9) & (time < stop - 1e-9)

    if variant == 0:
        inputs[span(1.0, 6.0), 0] = 0.8
        inputs[span(6.0, 9.0), 0] = -0.6
        inputs[span(2.5, 4.0), 1] = 0.5
        inputs[span(4.0, 5.5), 1] = -0.5
        inputs[:, 2] = doublet(time, amplitude=0.8, step_time=1.5, start=10.0)
        inputs[span(14.0, 17.0), 0] = 0.5
        inputs[span(15.0, 16.5), 1] = 0.4
    else:
        inputs[:, 2] = -doublet(time, amplitude=0.6, step_time=2.0, start=1.0)
        inputs[span(6.0, 10.0), 0] = 0.6
        inputs[span(7.0, 8.5), 1] = -0.6
        inputs[span(10.0, 12.0), 0] = -0.8
        inputs[span(13.0, 17.0), 0] = 1.0
        inputs[span(14.0, 16.0), 1] = 0.3
    return time, inputs
