"""Named physical effects on a reference model: the effect contract and the protocol through
which a reference takes effects.

An *effect* is a dict in the shape of a ``flightgp diagnose`` finding (docs/diagnose.md,
"diagnosis.json"; docs/vehicles.md lists the effects each reference takes)::

    {"effect": "time_delay", "input": "theta_1s", "value": 0.08}        # s
    {"effect": "input_lag", "input": "theta_1c", "value": 0.07}         # s, first-order time constant
    {"effect": "control_derivative", "term": "M_theta_1s", "value": -20.0}
    {"effect": "stability_derivative", "term": "L_q", "value": -3.35}   # new value, not a change
    {"effect": "sensor_bias", "output": "q", "value": 0.01}             # output units
    {"effect": "output_scale", "output": "q", "value": 1.08}            # 1 (a scale factor)
    {"effect": "sensor_lag", "output": "q", "value": 0.05}              # s, first-order time constant
    {"effect": "sensor_drift", "output": "q", "value": 1e-4}            # output units per s
    {"effect": "sensor_cross_axis", "output": "q_from_p", "value": 0.05}  # 1: recorded q sees 0.05 p
    {"effect": "quadratic_drag", "term": "X_UU", "value": -0.2}         # the blimp's
    {"effect": "force_offset", "term": "Z_0", "value": 0.003}           # the blimp's
    {"effect": "aerodynamic_coefficient", "term": "c_l_alpha", "value": 3.5}  # the RGBlimp's

Other keys (``unit``, ``interval``, ``statement`` ...) are ignored, so the findings of a
diagnosis can be fed back in unchanged. Delays, lags and the effects of the measurement chain
(:data:`OUTPUT_KINDS`, applied by :func:`apply_measurement_chain` on every reference) mean the
same on every reference; what a *term* (a derivative, a drag coefficient, a force offset) is, how effects enter
the reference's equations and which hypotheses diagnose tests on it is the reference's own
business, supplied by an object implementing :class:`EffectModel`:
:class:`validation.vehicles.bo105_effects.Bo105Effects` for every ``bo105-<V>kt``,
:class:`validation.vehicles.blimp_effects.BlimpEffects` for the ``blimp``,
:class:`validation.vehicles.rgblimp_effects.RGBlimpEffects` for the ``rgblimp``.
:mod:`validation.vehicles.effect_vehicle` finds the effect model of a reference
(:func:`~validation.vehicles.effect_vehicle.effect_model`) and applies effects to it
(:class:`~validation.vehicles.effect_vehicle.EffectVehicle`).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.signal import lfilter

from validation.core.errors import BadInputError
from validation.core.recordings import column_unit

#: Every named effect kind and the key naming its target (``unexplained``, the finding of what
#: no named effect explains, has none: it is not an effect that can be applied).
TARGET_KEYS = {"time_delay": "input", "input_lag": "input", "control_derivative": "term",
               "stability_derivative": "term", "sensor_bias": "output", "quadratic_drag": "term",
               "force_offset": "term", "aerodynamic_coefficient": "term", "cg_offset": "term",
               "added_mass": "term", "steady_wind": "term", "draught_field": "term", "gondola_offset": "term",
               "input_gain": "input", "output_scale": "output",
               "fmu_parameter": "term", "dead_band": "input", "backlash": "input", "nonlinear_damping": "term",
               "saturation": "input", "rate_limit": "input", "search_term": "term",
               "nonlinear_stiffness": "term", "quadratic_stiffness": "term", "sensor_lag": "output",
               "sensor_drift": "output", "sensor_cross_axis": "output"}
#: The effects of the measurement chain, between the vehicle and the recording of one output, in
#: the order :func:`apply_measurement_chain` applies them. A ``sensor_cross_axis`` names its
#: target ``"<recorded>_from_<source>"`` (:func:`cross_axis_target`).
OUTPUT_KINDS = ("output_scale", "sensor_cross_axis", "sensor_lag", "sensor_bias", "sensor_drift")
#: Largest delay and lag accepted, s: far beyond any actuator or rotor (the Bo105's flap time
#: constant is 0.07 s, Padfield, *Helicopter Flight Dynamics*, 2nd ed., 2007, ch. 3), small
#: enough to keep the augmented systems well conditioned.
MAX_DELAY = 1.0
MAX_LAG = 2.0
#: Joins the recorded output and the source state of a ``sensor_cross_axis`` target.
CROSS_AXIS_JOIN = "_from_"


@dataclass(frozen=True)
class Hypothesis:
    """One effect kind on one target with its value free: what ``flightgp diagnose`` fits.

    Attributes
    ----------
    effect : str
        Effect kind, a key of :data:`TARGET_KEYS`.
    target : str
        The input, term or output it acts on.
    null : float
        The value at which it does nothing (0 for delays, lags and biases; the reference's own
        value of a term).
    lower, upper : float
        Bounds of the value (``-inf``/``inf`` for none).
    step : float
        Finite-difference step of the screening, in the value's unit: large enough to move the
        outputs well above rounding, small enough for the response to stay linear; negative
        where the null is the upper bound (a limit that does nothing at the largest excursion).
    reciprocal : bool
        Whether the search's parameter is the reciprocal of the effect's value (``null``,
        ``lower``, ``upper`` and ``step`` then in the reciprocal's unit): a rate limit is
        searched as the time a unit of input takes to ramp, s per input unit, which is nearly
        linear in its effect and whose null (almost 0) is a limit that never bites.
    """

    effect: str
    target: str
    null: float
    lower: float
    upper: float
    step: float
    reciprocal: bool = False

    def effect_value(self, parameter: float) -> float:
        """The effect's value at search parameter ``parameter`` (its reciprocal where
        :attr:`reciprocal`)."""
        return 1.0 / float(parameter) if self.reciprocal else float(parameter)

    def as_effect(self, parameter: float) -> dict:
        """The effect dict at search parameter ``parameter`` (:meth:`effect_value`)."""
        return {"effect": self.effect, TARGET_KEYS[self.effect]: self.target, "value": self.effect_value(parameter)}

    @property
    def key(self) -> tuple[str, str]:
        """``(effect, target)``: what identifies the hypothesis."""
        return self.effect, self.target


def effect_key(effect: dict) -> tuple[str, str]:
    """``(effect, target)`` of an effect dict: what identifies it, as :attr:`Hypothesis.key` does
    a hypothesis."""
    return effect["effect"], effect[TARGET_KEYS[effect["effect"]]]


class EffectModel(Protocol):
    """How a reference model takes named effects: everything ``flightgp diagnose``, its
    concealed-effect bench and :class:`~validation.vehicles.effect_vehicle.EffectVehicle` need to
    know of a reference, so that none of them asks which reference it is.

    A new reference (an FMU, a state-space model read from a file ...) becomes diagnosable by
    implementing this protocol and entering its registry names in
    :data:`validation.vehicles.effect_vehicle.EFFECT_MODELS`.

    Attributes
    ----------
    name : str
        The reference's registry name (``"bo105-80kt"``, ``"blimp"``).
    family : str
        What the references of one effect model share, whatever their registry name
        (``"bo105"`` for every ``bo105-<V>kt``, ``"blimp"``): the key of whatever an application
        keeps per kind of reference (the concealed-effect suites of ``flightgp diagnose-bench``).
    input_names : tuple of str
        Its inputs, in recording-column order.
    state_names : tuple of str
        Its states, which recordings may measure (any subset).
    kinds : tuple of str
        The effect kinds it takes, keys of :data:`TARGET_KEYS`, in the order messages list them.
    terms : mapping of str to tuple of str
        Per effect kind whose target is a ``term``: the terms it takes.
    batches_simulations : bool
        Whether :meth:`simulate_many` integrates its members together (one vectorised replay
        for many effect lists, worth using for slow models) rather than one after the other.
    needs_even_sampling : bool
        Whether :meth:`simulate_many` needs evenly sampled times (``t0 + k h``).
    sensor_noise_sd : dict of str to float
        White sensor-noise standard deviation per state, state units, of the recordings the
        concealed-effect bench makes.
    sample_time : float
        s, the interval of its identification manoeuvre's recordings (and of the bench's).
    absolute_inputs : bool
        Whether its inputs are absolute values that act in a flight that holds them (the
        RGBlimp's thrusts and gondola position) rather than perturbations from trim, where
        nothing acts until an input moves and a diagnosis needs an input that moves.
    residual_gp_states : tuple of str
        The states whose replayed values (and rates) the residual GPs of a diagnosis see: all
        of them, or without those a residual cannot depend on (where the vehicle is and which way
        it faces, for the RGBlimp, as Ko et al., ICRA 2007, sec. IV-B).
    min_noise_sd : dict of str to float
        Per state, a floor under the noise standard deviation that weighs its residuals (state
        units; states not named have none): where recordings are filtered so smooth that their
        estimated noise says nothing of how well any model could fit them (the RGBlimp's).

    Optional attributes: ``signal_units`` (dict input or state -> unit, where the reference
    declares its own, :func:`effect_unit`) and ``workers`` (settable: processes its replays
    run on, :func:`validation.diagnose.diagnose`); an FMU reference has both; ``pose_score``
    (True where the reference's own score of a free run, the RGBlimp source's, belongs in the
    fidelity scorecard, :func:`validation.diagnose.fidelity.pose_scores`). Optional method:
    ``value_context(term, value, extent) -> str | None``, a sentence that puts a term's fitted
    value in physical perspective over ``extent`` (output -> (min, max) over the diagnosed
    recordings), which a finding's statement then carries (the RGBlimp's draught field).
    """

    name: str
    family: str
    input_names: tuple[str, ...]
    state_names: tuple[str, ...]
    kinds: tuple[str, ...]
    terms: Mapping[str, tuple[str, ...]]
    batches_simulations: bool
    needs_even_sampling: bool
    sensor_noise_sd: dict[str, float]
    sample_time: float
    absolute_inputs: bool
    residual_gp_states: tuple[str, ...]
    min_noise_sd: dict[str, float]

    def model_value(self, term: str) -> float:
        """The reference's own value of ``term`` (``M_q`` of a Bo105, ``X_UU`` of the blimp),
        in :meth:`term_unit`."""
        ...

    def term_unit(self, term: str) -> str:
        """The unit of ``term``'s value (``"1/s"``, ``"N s^2/m^2"`` ...)."""
        ...

    def term_description(self, term: str) -> str:
        """What ``term`` is, in words (``"pitch damping"`` for a Bo105's ``M_q``, ``"quadratic
        surge drag"`` for the blimp's ``X_UU``), for the statements of a diagnosis; ``term``
        itself when the reference has no words for it."""
        ...

    def term_value_problem(self, term: str, value: float) -> str | None:
        """What is wrong with ``value`` for ``term`` beyond being finite (e.g. a thrust per unit
        command that is not positive), as the end of a sentence with the numbers; ``None`` when
        it is acceptable."""
        ...

    def term_hypotheses(self, excited_inputs: Sequence[str]) -> list[Hypothesis]:
        """The term hypotheses worth testing when ``excited_inputs`` move: each with its
        reference value as ``null``, its bounds and a screening step (delays, lags and biases
        are added by diagnose for every reference)."""
        ...

    def start_state(self, recording) -> np.ndarray | None:
        """The state a replay of ``recording`` starts from, shape (n_states,), or None for the
        reference's own start (trim, or rest); BadInputError when the recording cannot give it."""
        ...

    def simulate_recordings(self, effect_lists: Sequence[list[dict]], times: Sequence[np.ndarray],
                            inputs: Sequence[np.ndarray], starts: Sequence) -> list[np.ndarray]:
        """:meth:`simulate_many` for several recordings at once (``times``, ``inputs``,
        ``starts`` one per recording), a list of arrays (B, n_r, n_states); references whose
        replays are dominated by per-step overhead batch the recordings too
        (:func:`simulate_each_recording` replays them one after the other)."""
        ...

    def simulate_many(self, effect_lists: Sequence[list[dict]], time: np.ndarray,
                      inputs: np.ndarray, *, start: np.ndarray | None = None) -> np.ndarray:
        """Recorded states of the reference with each of B lists of effects, from trim or from
        ``start``.

        Parameters
        ----------
        effect_lists : sequence of list of dict
            B lists of checked effects (:func:`check_effects`).
        time : ndarray, shape (n,)
            Strictly increasing sample times, s; evenly spaced if :attr:`needs_even_sampling`.
        inputs : ndarray, shape (n, n_inputs)
            Inputs in reference units, zero-order hold (row k acts from ``time[k]`` to
            ``time[k+1]``).
        start : ndarray, shape (n_states,), optional
            The state at ``time[0]`` (:meth:`start_state`); None: the reference's own start.

        Returns
        -------
        ndarray, shape (B, n, n_states)
            The states as recorded (through :func:`apply_measurement_chain`), SI units, in :attr:`state_names`
            order.
        """
        ...

    def identification_manoeuvre(self, *, duration: float, sample_time: float,
                                 variant: int) -> tuple[np.ndarray, np.ndarray]:
        """An input history that excites every effect the reference takes, from trim.

        Parameters
        ----------
        duration, sample_time : float
            s.
        variant : int
            0 for fitting; 1 for a different manoeuvre (other amplitudes, timing, order) to
            hold out.

        Returns
        -------
        time : ndarray, shape (n,)
        inputs : ndarray, shape (n, n_inputs)
        """
        ...


def simulate_each_recording(reference: EffectModel, effect_lists, times, inputs, starts) -> list[np.ndarray]:
    """:meth:`EffectModel.simulate_recordings` by one :meth:`EffectModel.simulate_many` per
    recording: a list of arrays (B, n_r, n_states)."""
    return [reference.simulate_many(effect_lists, t, u, start=s) for t, u, s in zip(times, inputs, starts)]


def starts_at_trim(reference: EffectModel, recording) -> None:
    """:meth:`EffectModel.start_state` of a reference whose recordings start at its own trim or
    rest state (docs/conventions.md, "Time"): None, whatever the recording."""
    return None


def delayed_interval_means(signal_: np.ndarray, delay: float, time: np.ndarray) -> np.ndarray:
    """Interval means of the zero-order-held ``signal_`` delayed by ``delay`` s: exact in the
    input's integral over each interval, continuous and piecewise linear in ``delay``
    (docstring of :mod:`validation.vehicles.blimp_effects`).

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


def lagged_interval_means(signals: np.ndarray, time_constants: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Interval means of first-order lags' outputs for held inputs, each lag starting at trim (0):
    the exact zero-order-hold discretisation taken interval by interval (docstring of
    :mod:`validation.vehicles.blimp_effects`).

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


def dead_band_inputs(signal_: np.ndarray, half_width: float, *, centre: float = 0.0) -> np.ndarray:
    """A command through a dead band of ``half_width`` about ``centre``: nothing
    passes while the command stays within ``half_width`` of the centre, and beyond it the command
    arrives short by ``half_width`` (continuous, slope 1 outside: the dead-zone nonlinearity of
    Slotine and Li, *Applied Nonlinear Control*, 1991, sec. 5.2).

    Parameters
    ----------
    signal_ : ndarray, any shape
        Commands, in the input's unit.
    half_width : float
        >= 0, the input's unit.
    centre : float
        Where the dead band sits: trim (0 for inputs that are perturbations from trim), or the
        command held at the start of a recording.

    Returns
    -------
    ndarray, the shape of ``signal_``
    """
    deviation = signal_ - centre
    return centre + np.sign(deviation) * np.maximum(np.abs(deviation) - half_width, 0.0)


def backlash_inputs(signal_: np.ndarray, half_width: float, *, centre: float = 0.0) -> np.ndarray:
    """A command through free play (backlash) of ``half_width`` on either side: the driven part
    stays where it is until the command has crossed the play and pushes it, and then follows the
    command ``half_width`` behind, on the side it was pushed from. This is the play operator
    (Krasnosel'skii & Pokrovskii, *Systems with Hysteresis*, 1989; Brokate & Sprekels,
    *Hysteresis and Phase Transitions*, 1996, sec. 2.3), the elementary hysteresis of a control
    path: a surface on a spring linkage held by Coulomb friction whose breakout force equals its
    sliding force acts the same, with ``half_width`` the friction force over the linkage's
    stiffness. On commands held over each interval it is exact at every sample:
    ``y_k = min(max(y_{k-1}, u_k - w), u_k + w)``, ``y_{-1} = centre`` (the part centred in its
    play at the start).

    Unlike a dead band (:func:`dead_band_inputs`) it remembers the way it was last pushed: on
    steps from trim to ``+A`` and ``-A`` both give ``+-(A - w)``, but back at trim a dead band
    gives trim and free play leaves the part ``w`` off it, on the side of the last step.

    Parameters
    ----------
    signal_ : ndarray, shape (n,)
        Commands held over each interval, in the input's unit.
    half_width : float
        >= 0, the input's unit.
    centre : float
        Where the part starts (trim, 0 for inputs that are perturbations from it, or the command
        held at the start of a recording).

    Returns
    -------
    ndarray, shape (n,)
    """
    width = float(half_width)
    if width <= 0.0:
        return np.array(signal_, dtype=float)
    commands = np.asarray(signal_, dtype=float)
    # A sequential recursion, over runs of equal commands (held inputs change at a few samples).
    starts = np.concatenate([[0], np.flatnonzero(np.diff(commands) != 0.0) + 1]) if len(commands) else np.zeros(0, int)
    positions = np.empty(len(starts))
    position = float(centre)
    for r, command in enumerate(commands[starts].tolist()):
        position = min(max(position, command - width), command + width)
        positions[r] = position
    return np.repeat(positions, np.diff(np.append(starts, len(commands))))


#: The effects that shape an input before it acts, in the order every reference applies them,
#: whatever the order of the list (:func:`shaped_inputs`).
SHAPING_KINDS = ("dead_band", "backlash", "saturation", "rate_limit")


def shaped_inputs(effects, time: np.ndarray, inputs: np.ndarray, input_names, *, centre=None) -> np.ndarray:
    """The inputs through ``effects``' dead bands, free play, position limits and rate limits
    (:data:`SHAPING_KINDS`, in that order), each about ``centre``: :func:`dead_band_inputs`,
    :func:`backlash_inputs`, a clip at ``centre +- limit`` and :func:`rate_limited_interval_means`
    (interval means of the ramps over rows 0 .. n-2; the last row is left as given).

    Parameters
    ----------
    effects : list of dict
        Checked effects (:func:`check_effects`); those of other kinds are ignored.
    time : ndarray, shape (n,)
        s.
    inputs : ndarray, shape (n, m)
        Commands held over each interval, in ``input_names`` order.
    input_names : sequence of str
    centre : ndarray, shape (m,), optional
        Trim or rest of each input (default 0: inputs that are perturbations from trim), or
        the commands held at the start of a recording.

    Returns
    -------
    ndarray, shape (n, m)
        ``inputs`` itself when no effect shapes them, otherwise a new array.
    """
    centre = np.zeros(inputs.shape[1]) if centre is None else np.asarray(centre, dtype=float)
    shaped = inputs
    for kind in SHAPING_KINDS:
        for effect in (e for e in effects if e["effect"] == kind):
            shaped = shaped.copy() if shaped is inputs else shaped
            j, value = list(input_names).index(effect["input"]), effect["value"]
            if kind == "dead_band":
                shaped[:, j] = dead_band_inputs(shaped[:, j], value, centre=centre[j])
            elif kind == "backlash":
                shaped[:, j] = backlash_inputs(shaped[:, j], value, centre=centre[j])
            elif kind == "saturation":
                np.clip(shaped[:, j], centre[j] - value, centre[j] + value, out=shaped[:, j])
            else:
                shaped[:-1, j] = rate_limited_interval_means(shaped[:-1, j], value, np.diff(time), centre=centre[j])
    return shaped


def rate_limited_interval_means(held: np.ndarray, rate: float, steps: np.ndarray, *,
                                centre: float = 0.0) -> np.ndarray:
    """Interval means of an actuator that follows a zero-order-held command no faster than
    ``rate``: over each interval it ramps at ``rate`` towards the command and stops there (the
    rate-limit nonlinearity of an actuator, Slotine and Li, *Applied Nonlinear Control*, 1991,
    sec. 5.2; continuous in time, so a step of ``d`` ramps over ``|d| / rate`` s whatever the
    sampling). Starting at ``centre`` (trim, or the command held before the recording), with
    ``y`` the actuator's position at an interval's start, ``u`` the command held over it,
    ``d = u - y`` and ``tau = |d| / rate``: the mean is ``u - d tau / (2 h)`` when the ramp ends
    within the interval (``tau <= h``), else ``y + sign(d) rate h / 2``; the input's integral over
    each interval is exact.

    Parameters
    ----------
    held : ndarray, shape (m,)
        The command held over each interval, the input's unit.
    rate : float
        > 0, the input's unit per s (``inf``: no limit).
    steps : ndarray, shape (m,)
        Interval lengths ``h``, s.
    centre : float
        Where the actuator stands before the first interval.

    Returns
    -------
    ndarray, shape (m,)
        The actuator's mean over each interval.
    """
    if not math.isfinite(rate):
        return held.copy()
    means = np.empty(len(held))
    position = float(centre)
    for k, (command, step) in enumerate(zip(held.tolist(), steps.tolist())):  # Python floats: a sequential recursion
        distance = command - position
        reach = rate * step
        if abs(distance) <= reach:
            means[k] = command - distance * abs(distance) / (2.0 * reach)
            position = command
        else:
            sign = 1.0 if distance > 0 else -1.0
            means[k] = position + sign * 0.5 * reach
            position += sign * reach
    return means


def search_axes_jacobian(rows_of, states, inputs, signals, state_names, input_names) -> np.ndarray:
    """How strongly each signal drives each row of a nonlinear reference, for the residual search's
    axes (``search_jacobian`` of the blimp and the RGBlimp): the RMS over the samples of
    ``d rows_of(x, u) / d signal``, by central differences (a step of 1e-6 of the signal's RMS,
    at least 1e-6).

    Parameters
    ----------
    rows_of : callable
        ``rows_of(states (n, n_states), inputs (n, n_inputs)) -> (n, n_rows)``.
    states, inputs : list of ndarray
        Per recording, shapes (n_r, n_states) and (n_r, n_inputs).
    signals : sequence of str
        Names of states or inputs.
    state_names, input_names : sequence of str

    Returns
    -------
    ndarray, shape (n_rows, len(signals))
    """
    x, u = np.concatenate(states), np.concatenate(inputs)
    columns = []
    for name in signals:
        where, column = (x, list(state_names).index(name)) if name in state_names else \
            (u, list(input_names).index(name))
        step = 1e-6 * max(1.0, float(np.sqrt(np.mean(where[:, column] ** 2))))
        moved = []
        for sign in (1.0, -1.0):
            moved_x, moved_u = x.copy(), u.copy()
            (moved_x if where is x else moved_u)[:, column] += sign * step
            moved.append(rows_of(moved_x, moved_u))
        columns.append(np.sqrt(np.mean(((moved[0] - moved[1]) / (2 * step)) ** 2, axis=0)))
    return np.stack(columns, axis=1)


def check_trim_start(start, name: str) -> None:
    """BadInputError unless ``start`` is None: the ``name`` reference replays from its own start."""
    if start is not None:
        raise BadInputError(f"the {name} reference replays recordings from its own start state "
                            "(they start there, docs/conventions.md, \"Time\"); got another start state")


def signal_unit(name: str, reference: EffectModel) -> str:
    """The unit of input or state ``name`` of ``reference``: the reference's own (its optional
    ``signal_units`` mapping: an FMU's declared units, a linear reference's) or else flightgp's
    (:func:`validation.core.recordings.column_unit`; ``"?"`` for an unknown column)."""
    return getattr(reference, "signal_units", {}).get(name) or column_unit(name)


def effect_unit(effect: dict, reference: EffectModel) -> str:
    """Unit of ``effect["value"]`` on ``reference``: s for delays and lags (of an input or a
    sensor), 1 for a gain, a scale or a cross-axis sensitivity, the input's unit for a dead band,
    a free play or a saturation (per s for a rate limit), the output's unit for a bias (per s for a drift),
    the reference's unit of a term (:func:`signal_unit`)."""
    kind = effect["effect"]
    if kind in ("time_delay", "input_lag", "sensor_lag"):
        return "s"
    if kind in ("input_gain", "output_scale", "sensor_cross_axis"):
        return "1"
    if kind in ("dead_band", "backlash", "saturation", "sensor_bias", "rate_limit", "sensor_drift"):
        unit = signal_unit(effect[TARGET_KEYS[kind]], reference)
        return f"{unit}/s" if kind in ("rate_limit", "sensor_drift") else unit
    return reference.term_unit(effect["term"])


def cross_axis_target(recorded: str, source: str) -> str:
    """The target of a ``sensor_cross_axis``: ``"q_from_p"`` for a recorded ``q`` that sees some
    of the vehicle's ``p``."""
    return f"{recorded}{CROSS_AXIS_JOIN}{source}"


def split_cross_axis(target: str, output_names) -> tuple[str, str] | None:
    """``(recorded, source)`` of a ``sensor_cross_axis`` target (:func:`cross_axis_target`), both
    among ``output_names``; None when it names no such pair."""
    for name in output_names:
        prefix = name + CROSS_AXIS_JOIN
        if target.startswith(prefix) and target[len(prefix):] in output_names:
            return name, target[len(prefix):]
    return None


def cross_axis_pairs(reference: EffectModel, output_names) -> list[tuple[str, str]]:
    """Every ``(recorded, source)`` pair of a recorded output (``output_names``) and another state
    of ``reference`` in the same known unit (:func:`signal_unit`): the cross-axis sensitivities
    a diagnosis can test."""
    units = {name: signal_unit(name, reference) for name in reference.state_names}
    return [(a, b) for a in output_names for b in reference.state_names
            if a != b and units[a] == units[b] and units[a] not in ("?", "")]


def _output_of(effect: dict, output_names) -> tuple[int, int | None]:
    """Column of the recorded output an output effect acts on and, for a cross-axis
    sensitivity, of its source (None otherwise)."""
    if effect["effect"] == "sensor_cross_axis":
        recorded, source = split_cross_axis(effect["output"], output_names)
        return output_names.index(recorded), output_names.index(source)
    return output_names.index(effect["output"]), None


def apply_measurement_chain(outputs: np.ndarray, time: np.ndarray, effects, output_names) -> np.ndarray:
    """The outputs as recorded through the measurement chain of ``effects``: the sensor effects
    between the vehicle and the recording of one output (:data:`OUTPUT_KINDS`; the others in
    ``effects`` are ignored), the same on every reference. With ``y`` the vehicle's outputs and
    ``m`` the recorded ones, for output ``i``, in this order:

    1. scale and cross-axis sensitivity, on the vehicle's values: ``s_i y_i + sum_j c_ij y_j``
       (``output_scale`` ``s_i``, ``sensor_cross_axis`` ``c_ij`` on ``"i_from_j"``, ``j`` of the
       same unit: a misaligned or cross-coupled sensor);
    2. a first-order sensor lag of time constant ``T``: ``T z_dot = -z + (step 1)``, ``z`` starting
       at the first sample's value of step 1 (a sensor at rest on its signal);
    3. a constant bias ``b_i`` and a drift ``d_i`` growing from 0 at the first sample:
       ``m_i = z_i + b_i + d_i (t - t_0)``.

    These are the sensor models of a flight-data compatibility check (scale factor, bias,
    misalignment, time lag; Jategaonkar, *Flight Vehicle System Identification*, 2nd ed., 2015,
    ch. 10) with the bias's slow change taken as linear over one recording. The lag is
    discretised exactly for a signal linear between the samples (first-order hold): with
    ``h_k = t_{k+1} - t_k``, ``a = exp(-h_k / T)`` and ``g = (T / h_k) (1 - a)``,
    ``z[k+1] = a z[k] + (g - a) x[k] + (1 - g) x[k+1]`` (:func:`lagged_samples`); it is exact
    wherever the vehicle's output is piecewise linear between samples and otherwise errs by the
    curvature within one interval (second order in ``h``), and it is continuous at ``T = 0``.

    Parameters
    ----------
    outputs : ndarray, shape (n, m)
        The vehicle's outputs at ``time``, in ``output_names`` order, their units.
    time : ndarray, shape (n,)
        Strictly increasing sample times, s (even or not).
    effects : list of dict
        Checked effects (:func:`check_effects`).
    output_names : sequence of str
        The m outputs' names.

    Returns
    -------
    ndarray, shape (n, m)
        The outputs as recorded; ``outputs`` itself when no output effect acts.
    """
    chain = [e for e in effects if e["effect"] in OUTPUT_KINDS]
    if not chain:
        return outputs
    names = list(output_names)
    time = np.asarray(time, dtype=float)
    mixing, bias = _static_chain(chain, names)
    # The bias acts after the lag; a lag starting at rest passes a constant unchanged, so adding
    # it first is the same. The drift does not pass unchanged: it comes after.
    recorded = np.asarray(outputs, dtype=float) @ mixing.T + bias
    for effect in chain:
        if effect["effect"] == "sensor_lag" and effect["value"] > 0:
            column = names.index(effect["output"])
            recorded[:, column] = lagged_samples(recorded[:, column], effect["value"], time)
    for effect in chain:
        if effect["effect"] == "sensor_drift":
            recorded[:, names.index(effect["output"])] += effect["value"] * (time - time[0])
    return recorded


def _static_chain(chain, names: list) -> tuple[np.ndarray, np.ndarray]:
    """``(M, b)`` of the memoryless part of a measurement chain, ``m = M y + b`` at any one
    sample before the lag and the drift act (:func:`apply_measurement_chain`): ``M = diag(s) +
    C`` of the scales and cross-axis sensitivities (m, m) and ``b`` the biases (m,)."""
    mixing = np.eye(len(names))
    bias = np.zeros(len(names))
    for effect in chain:
        kind = effect["effect"]
        if kind in ("output_scale", "sensor_cross_axis", "sensor_bias"):
            column, source = _output_of(effect, names)
            if kind == "output_scale":
                mixing[column, column] = effect["value"]
            elif kind == "sensor_cross_axis":
                mixing[column, source] = effect["value"]
            else:
                bias[column] = effect["value"]
    return mixing, bias


def apply_measurement_chains(outputs: np.ndarray, time: np.ndarray, effect_lists, output_names) -> np.ndarray:
    """:func:`apply_measurement_chain` of each member of a batch: ``outputs`` (B, n, m), one
    effect list per member; returns (B, n, m) (``outputs`` itself when no member has an output
    effect)."""
    if not any(e["effect"] in OUTPUT_KINDS for effects in effect_lists for e in effects):
        return outputs
    return np.stack([apply_measurement_chain(member, time, effects, output_names)
                     for member, effects in zip(outputs, effect_lists)])


def lagged_samples(signal_: np.ndarray, time_constant: float, time: np.ndarray) -> np.ndarray:
    """Samples of a first-order lag ``T z_dot = -z + x`` of the sampled ``signal_`` ``x``, taken
    linear between its samples (first-order hold), starting at rest on it (``z[0] = x[0]``): the
    exact discretisation of :func:`apply_measurement_chain`.

    Parameters
    ----------
    signal_ : ndarray, shape (n,)
    time_constant : float
        ``T``, s, > 0.
    time : ndarray, shape (n,)
        Strictly increasing, s.

    Returns
    -------
    ndarray, shape (n,)
        ``z`` at ``time``, the unit of ``signal_``.
    """
    steps = np.diff(time)
    ratio = steps / time_constant
    decay = np.exp(-ratio)  # a
    gain = -np.expm1(-ratio) / ratio  # g = (T / h) (1 - a)
    deviation = signal_ - signal_[0]  # from rest at x[0]: z - x[0] starts at 0
    if np.ptp(steps) <= 1e-9 * steps[0]:  # even: one linear filter
        filtered = lfilter([1.0 - gain[0], gain[0] - decay[0]], [1.0, -decay[0]], deviation)
        return signal_[0] + filtered
    lagged = np.empty(len(signal_))
    state = 0.0
    lagged[0] = 0.0
    for k, (a, g, start, end) in enumerate(zip(decay.tolist(), gain.tolist(), deviation[:-1].tolist(),
                                              deviation[1:].tolist())):
        state = a * state + (g - a) * start + (1.0 - g) * end
        lagged[k + 1] = state
    return signal_[0] + lagged


def true_first_values(recorded: np.ndarray, effects, output_names) -> np.ndarray:
    """The vehicle's outputs at the first sample from the recorded ones, through the inverse of
    :func:`apply_measurement_chain` there (a lag starts at rest and a drift at 0, so only scales,
    cross-axis sensitivities and biases act: ``m = M y + b`` with ``M = diag(s) + C``): for
    references that replay a recording from its first recorded state, so that a sensor that
    reads wrong from the first sample is not taken for a state the vehicle started in.

    Parameters
    ----------
    recorded : ndarray, shape (m,)
        The recorded first values, ``output_names`` order; NaN where unknown (every output that
        depends on an unknown one is NaN too).
    effects : list of dict
        Checked effects.
    output_names : sequence of str

    Returns
    -------
    ndarray, shape (m,)
        ``recorded`` itself where no output effect acts or ``M`` is singular (a scale of 0).
    """
    chain = [e for e in effects if e["effect"] in ("output_scale", "sensor_cross_axis", "sensor_bias")]
    if not chain:
        return recorded
    mixing, bias = _static_chain(chain, list(output_names))
    try:
        inverse = np.linalg.inv(mixing)
    except np.linalg.LinAlgError:
        return recorded
    difference = np.asarray(recorded, dtype=float) - bias
    terms = np.where(inverse != 0.0, inverse * np.where(np.isfinite(difference), difference, np.nan), 0.0)
    return terms.sum(axis=1)


def check_effects(effects, reference: EffectModel) -> list[dict]:
    """Validate effect dicts against ``reference``; returns clean copies (``effect``, target,
    ``value``).

    Raises
    ------
    BadInputError
        Unknown effect or target, a term of the wrong kind (``M_q`` is a stability derivative,
        ``M_theta_1s`` a control derivative), a cross-axis sensitivity whose recorded output
        and source are not two outputs of the same unit, a non-finite value, a delay or a lag
        (of an input or a sensor) outside ``[0, MAX_DELAY]`` / ``[0, MAX_LAG]`` s, a value the reference refuses
        (:meth:`EffectModel.term_value_problem`), two effects of the same kind on the same
        target, or more search terms than the reference's ``max_search_terms`` (where it has one).
    """
    checked, seen = [], set()
    for index, effect in enumerate(effects):
        where = f"effect {index + 1}"
        if not isinstance(effect, dict) or effect.get("effect") not in reference.kinds:
            kind = effect.get("effect") if isinstance(effect, dict) else effect
            raise BadInputError(f"{where}: unknown effect {kind!r} for {reference.name}; "
                                f"known: {', '.join(reference.kinds)}")
        kind = effect["effect"]
        key = TARGET_KEYS[kind]
        target = effect.get(key)
        allowed = {"input": reference.input_names, "output": reference.state_names}.get(key)
        if key == "term":
            allowed = reference.terms[kind]
        if kind == "sensor_cross_axis":
            _check_cross_axis(target, reference, where)
        elif target not in allowed:
            other = [k for k, terms in reference.terms.items() if key == "term" and k != kind and target in terms]
            if other:
                raise BadInputError(f"{where} ({kind}): {target} is a {other[0]} of {reference.name}; "
                                    f"give it as {{\"effect\": \"{other[0]}\", \"term\": \"{target}\"}}")
            listed = ", ".join(allowed) if len(allowed) <= 20 else f"{', '.join(allowed[:8])}, ... ({len(allowed)})"
            raise BadInputError(f"{where} ({kind}): {key} {target!r} is not one of {listed}")
        value = _finite_value(effect, f"{where} ({kind} on {target})")
        limit = {"time_delay": MAX_DELAY, "input_lag": MAX_LAG, "sensor_lag": MAX_LAG}.get(kind)
        if limit is not None and not 0.0 <= value <= limit:
            raise BadInputError(f"{where} ({kind} on {target}): {value} s is outside 0 .. {limit} s")
        if kind in ("dead_band", "backlash") and value < 0:
            raise BadInputError(f"{where} ({kind} on {target}): a half-width cannot be negative, got {value}")
        if kind == "saturation" and value < 0:
            raise BadInputError(f"{where} ({kind} on {target}): a limit cannot be negative, got {value}")
        if kind == "rate_limit" and value <= 0:
            raise BadInputError(f"{where} ({kind} on {target}): the largest rate must be positive, got {value}")
        problem = reference.term_value_problem(target, value) if key == "term" else None
        if problem:
            raise BadInputError(f"{where} ({kind} on {target}): {problem}")
        if (kind, target) in seen:
            raise BadInputError(f"{where}: a second {kind} on {target}; give each effect once")
        seen.add((kind, target))
        checked.append({"effect": kind, key: target, "value": value})
    most = getattr(reference, "max_search_terms", None)
    searched = sum(effect["effect"] == "search_term" for effect in checked)
    if most is not None and searched > most:
        raise BadInputError(f"{searched} search terms; the {reference.name} reference replays at most {most} at once")
    return checked


def _check_cross_axis(target, reference: EffectModel, where: str) -> None:
    """BadInputError unless ``target`` is ``"<recorded>_from_<source>"`` with two different
    outputs of ``reference`` in the same known unit."""
    pair = split_cross_axis(target, reference.state_names) if isinstance(target, str) else None
    if pair is None:
        raise BadInputError(f"{where} (sensor_cross_axis): output {target!r} must name the recorded output and "
                            f"the state it sees, both among {', '.join(reference.state_names)}, as "
                            f"\"{cross_axis_target('q', 'p')}\"")
    recorded, source = pair
    units = signal_unit(recorded, reference), signal_unit(source, reference)
    if recorded == source or units[0] != units[1] or "?" in units:
        raise BadInputError(f"{where} (sensor_cross_axis on {target}): the recorded {recorded} ({units[0]}) can "
                            f"only see another state of the same unit, not {source} ({units[1]})")


def _finite_value(effect: dict, where: str) -> float:
    """``effect["value"]`` as a finite float; BadInputError starting with ``where`` otherwise."""
    try:
        value = float(effect.get("value"))
    except (TypeError, ValueError):
        value = math.nan
    if not math.isfinite(value):
        raise BadInputError(f"{where}: value must be a finite number, got {effect.get('value')!r}")
    return value
