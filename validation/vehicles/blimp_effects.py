"""Named effects on the blimp reference (:mod:`validation.vehicles.blimp`), simulated in batches:
its :class:`~validation.vehicles.effects.EffectModel`, :class:`BlimpEffects`, and the
identification manoeuvre that excites them.

The effect dicts are those of :mod:`validation.vehicles.effects` (the ``flightgp diagnose``
finding shape, docs/vehicles.md). On the blimp they act on the ODE of
:func:`validation.vehicles.blimp_equations.blimp_dynamics` as follows (body axes, SI units; ``M`` is the
blimp's system inertia matrix, so an extra generalised force ``tau`` adds ``M^-1 tau`` to
``nu_dot``):

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
- ``search_term`` ``<row>_<factor>`` (:mod:`validation.vehicles.polynomial_terms`; the terms the
  residual search of ``flightgp diagnose`` regresses on, :data:`SEARCH_ROWS`): an extra
  generalised force ``value * factor`` on the row's axis (``X``, ``Y``, ``Z`` forces in N, ``L``,
  ``M``, ``N`` moments in N m, per unit of the factor), the factor a signed square, cube or
  product of :data:`SEARCH_SIGNALS` (body velocities and rates, roll and pitch, and the commands
  as the ODE receives them, after delays and lags, before the thrust gains) or, for the
  search's linear columns, one signal itself (``M_Q``: a force linear in it); at most
  :data:`SEARCH_SLOTS` per replay;
- the effects of the measurement chain on any of the 12 states (``output_scale``,
  ``sensor_cross_axis``, ``sensor_lag``, ``sensor_bias``, ``sensor_drift``), on the replayed
  states as recorded, through :func:`~validation.vehicles.effects.apply_measurement_chain`;
- ``dead_band``, ``backlash``, ``saturation`` and ``rate_limit`` on an input, before its delay and
  lag: a dead band of the half-width about rest (:func:`~validation.vehicles.effects.dead_band_inputs`),
  free play of the half-width centred at rest (:func:`~validation.vehicles.effects.backlash_inputs`), the
  command clipped at +/- the limit, and a fan or servo that ramps no faster than the rate limit
  (:func:`~validation.vehicles.effects.rate_limited_interval_means`), in command units (per s).

Integration: classical RK4 with one step per recording interval, each of its own length
``h_k = t_{k+1} - t_k`` (motion-capture frames arrive with timing jitter, so recordings may be
unevenly sampled), from the reference's hanging state (:class:`~validation.vehicles.blimp.BlimpReference`
uses substeps of at most 0.01 s; at 20 Hz the two agree to far below the sensor noise, see
``tests/validation/diagnose/test_diagnose_blimp.py``). All members of a batch are integrated together, one
vectorised :func:`~validation.vehicles.blimp_equations.blimp_dynamics` call per RK4 stage
(:func:`~validation.vehicles.blimp_equations.rk4`), and all lags of a batch
are propagated together, which is what makes output-error fitting of many hypotheses affordable.
By default the integration runs compiled (:mod:`validation.vehicles.blimp_jax`, the same
equations in ``jax.numpy``, equal to rounding; 7.9x the numpy step on 24 hypotheses over 20 s,
``flightgp bench rgblimp``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import partial

import numpy as np

from validation.core.manoeuvres import doublet, time_grid
from validation.vehicles import polynomial_terms
from validation.vehicles.blimp import (
    INPUT_NAMES,
    SAMPLE_TIME,
    STATE_NAMES,
    BlimpReference,
    check_command_history,
    hanging_state,
)
from validation.vehicles.blimp_equations import blimp_dynamics, mass_matrix, rk4
from validation.vehicles.blimp_flight import ATTITUDE_NOISE_STD, POSITION_NOISE_STD
from validation.vehicles.blimp_jax import compiled_replay
from validation.vehicles.effects import (
    Hypothesis,
    apply_measurement_chains,
    check_trim_start,
    delayed_interval_means,
    lagged_interval_means,
    search_axes_jacobian,
    shaped_inputs,
    simulate_each_recording,
    starts_at_trim,
)
from validation.vehicles.polynomial_terms import library, search_slots, slot_values, term_name

#: Control-derivative terms: fan, command column, sign of the commands it applies to.
CONTROL_TERMS = {"gondola_thrust_forward": ("u_gondola", 1.0), "gondola_thrust_backward": ("u_gondola", -1.0),
                 "tail_thrust_positive": ("u_tail", 1.0), "tail_thrust_negative": ("u_tail", -1.0)}
#: Stability-derivative terms: the rotational-rate column (0 P, 1 Q, 2 R).
STABILITY_TERMS = {"L_P": 0, "M_Q": 1, "N_R": 2}
#: Quadratic-drag terms: the body-velocity column (0 U, 1 V, 2 W).
DRAG_TERMS = {"X_UU": 0, "Y_VV": 1, "Z_WW": 2}
#: Force-offset terms: the generalised-force column (0-2 forces, 5 yaw moment; Z_0 earth-vertical).
OFFSET_TERMS = {"X_0": 0, "Y_0": 1, "Z_0": 2, "N_0": 5}
#: Rows a search term adds to: the generalised force (0-2 forces, 3-5 moments) and the body
#: velocity or rate it accelerates (the row's own state, for the residual search's axes).
SEARCH_ROWS = {"X": "U", "Y": "V", "Z": "W", "L": "P", "M": "Q", "N": "R"}
#: Signals a search term's factor may use: the body velocities and rates, roll and pitch (the
#: heading and position carry no force) and the commands.
SEARCH_SIGNALS = ("U", "V", "W", "P", "Q", "R", "phi", "theta", *INPUT_NAMES)
#: Search terms one replay holds at most (a diagnosis names at most four effects, the candidate
#: of its last step among them): a fixed size, so that the compiled replay compiles once.
SEARCH_SLOTS = 4
#: Search terms the named terms already are (``X_U|U|`` is ``X_UU``): not searched.
NAMED_SEARCH_TERMS = {term_name(letter, "signed_square", state): named
                      for named, (letter, state) in {"X_UU": ("X", "U"), "Y_VV": ("Y", "V"),
                                                     "Z_WW": ("Z", "W")}.items()}
#: The residual search's library on the blimp: every row's linear terms and its polynomial terms,
#: less those the named ``quadratic_drag`` is. The linear ``L_P``, ``M_Q`` and ``N_R`` are the
#: named damping: the search regresses on them (its base columns) but never offers them.
SEARCH_LIBRARY = tuple(f"{letter}_{signal}" for letter in SEARCH_ROWS for signal in SEARCH_SIGNALS) + tuple(
    term for term in library(SEARCH_ROWS, SEARCH_SIGNALS) if term not in NAMED_SEARCH_TERMS)
#: The search terms an effect may name: the library less the named damping.
SEARCH_TERMS = tuple(term for term in SEARCH_LIBRARY if term not in STABILITY_TERMS)
TERMS = {"control_derivative": tuple(CONTROL_TERMS), "stability_derivative": tuple(STABILITY_TERMS),
         "quadratic_drag": tuple(DRAG_TERMS), "force_offset": tuple(OFFSET_TERMS), "search_term": SEARCH_TERMS}
TERM_UNITS = {**dict.fromkeys(CONTROL_TERMS, "N"), **dict.fromkeys(STABILITY_TERMS, "N m s/rad"),
              **dict.fromkeys(DRAG_TERMS, "N s^2/m^2"), "X_0": "N", "Y_0": "N", "Z_0": "N", "N_0": "N m"}
#: Every term in words (module docstring), for the statements of a diagnosis.
TERM_DESCRIPTIONS = {"gondola_thrust_forward": "gondola thrust per unit forward command",
                     "gondola_thrust_backward": "gondola thrust per unit backward command",
                     "tail_thrust_positive": "tail-fan thrust per unit positive command",
                     "tail_thrust_negative": "tail-fan thrust per unit negative command",
                     "L_P": "roll damping", "M_Q": "pitch damping", "N_R": "yaw damping",
                     "X_UU": "quadratic surge drag", "Y_VV": "quadratic sway drag", "Z_WW": "quadratic heave drag",
                     "X_0": "constant surge force", "Y_0": "constant side force",
                     "Z_0": "buoyancy imbalance (net downward force)", "N_0": "constant yaw moment"}

#: Units of the search terms' signals (:data:`SEARCH_SIGNALS`; the commands of the fans are
#: fractions of full thrust, the gondola's elevation angle ``mu`` in rad).
SEARCH_SIGNAL_UNITS = {**dict.fromkeys(("U", "V", "W"), "m/s"), **dict.fromkeys(("P", "Q", "R"), "rad/s"),
                       "phi": "rad", "theta": "rad", "u_gondola": "1", "mu": "rad", "u_tail": "1"}
_SEARCH_ROW_UNITS = {**dict.fromkeys("XYZ", "N"), **dict.fromkeys("LMN", "N m")}
_SEARCH_ROW_WORDS = {"X": "surge force", "Y": "side force", "Z": "heave force", "L": "roll moment",
                     "M": "pitch moment", "N": "yaw moment"}


def parse_search_term(term: str) -> tuple[str, str, tuple]:
    """``(row letter, factor kind, signals)`` of a search term (module docstring): the kind one
    of :data:`~validation.vehicles.polynomial_terms.SLOT_FACTOR_KINDS` (``linear`` for ``M_U``),
    the one or two signals of :data:`SEARCH_SIGNALS` in its factor."""
    return polynomial_terms.parse_search_term(term, SEARCH_ROWS, SEARCH_SIGNALS)


def search_term_unit(term: str) -> str:
    """A search term's unit: its row's (N or N m) per unit of its factor (``N m/(rad/s)^2`` for
    ``M_Q|Q|``, ``N/(m/s rad/s)`` for ``Y_U*R``, ``N m/rad`` for ``M_mu``; a command is a fraction
    of full thrust, no unit: ``N`` for ``X_u_gondola^3``)."""
    return polynomial_terms.search_term_unit(term, SEARCH_ROWS, SEARCH_SIGNALS, row_units=_SEARCH_ROW_UNITS,
                                             signal_units=SEARCH_SIGNAL_UNITS)


def search_term_description(term: str) -> str:
    """``"<row force or moment> proportional to <factor>"`` (``"yaw moment proportional to
    V|V|"``)."""
    return polynomial_terms.search_term_description(term, _SEARCH_ROW_WORDS)


#: White sensor noise per state of the blimp recordings (the ``blimp-flight`` stand-in's marker
#: noise, 1 mm and 0.5 deg; velocities and rates at the noise of its 5-sample quadratic-fit
#: differentiator at the reference's 20 Hz, :data:`validation.vehicles.blimp.SAMPLE_TIME`,
#: ``sd / (sqrt(10) h)``, but white here).
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
    if term in OFFSET_TERMS or term in SEARCH_TERMS:
        return 0.0  # no constant force, no term beyond the model's
    raise KeyError(term)


def simulate_batch(reference: BlimpReference, effect_lists, time, inputs, *, compiled: bool = True) -> np.ndarray:
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
    compiled : bool
        Integrate with the compiled step of :mod:`validation.vehicles.blimp_jax` (the default)
        or the numpy step (equal to rounding; the benchmark's peer).

    Returns
    -------
    ndarray, shape (B, n, 12)
        ``x, y, z, phi, theta, psi, U, V, W, P, Q, R`` as recorded (through the measurement
        chain), SI units,
        from the reference's hanging state at rest.
    """
    time, inputs = check_command_history(time, inputs)
    steps = np.diff(time)
    params = reference.params
    held = _held_inputs(effect_lists, time, inputs)
    changes = _TermChanges.of(reference, effect_lists)
    if compiled:
        changed = {**{f.name: getattr(changes, f.name) for f in fields(changes) if f.name != "slots"},
                   **changes.slots}
        states = compiled_replay(params, changed, hanging_state(params), held, steps)
        return apply_measurement_chains(states, time, effect_lists, STATE_NAMES)
    _, inverse = mass_matrix(params.mass, params.added_mass, params.inertia, params.added_inertia,
                             params.cg_position)
    states = np.empty((len(effect_lists), len(time), 12))
    state = np.repeat(hanging_state(params)[None], len(effect_lists), axis=0)
    states[:, 0] = state
    for k, step in enumerate(steps):  # one RK4 step over [t_k, t_{k+1}), input row k held
        command = held[:, k]
        state = rk4(partial(changes.rates, command=command, params=params, inverse=inverse), state, step)
        states[:, k + 1] = state
    return apply_measurement_chains(states, time, effect_lists, STATE_NAMES)


def _held_inputs(effect_lists, time: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """What acts over each interval for each member: the inputs (n, 3) through the member's
    dead bands, limits and rate limits, then delayed, then lagged (module docstring), shape
    (B, n - 1, 3)."""
    held = np.repeat(inputs[None, :-1], len(effect_lists), axis=0)
    lags = []  # (member, input column, time constant)
    for b, effects in enumerate(effect_lists):
        commanded = shaped_inputs(effects, time, inputs, INPUT_NAMES)  # about rest (0)
        held[b] = commanded[:-1]
        for effect in effects:  # delays first: a lag acts on the delayed input
            if effect["effect"] == "time_delay" and effect["value"] > 0:
                j = INPUT_NAMES.index(effect["input"])
                held[b, :, j] = delayed_interval_means(commanded[:, j], effect["value"], time)
        lags += [(b, INPUT_NAMES.index(effect["input"]), effect["value"]) for effect in effects
                 if effect["effect"] == "input_lag" and effect["value"] > 0]
    if lags:
        members, columns, time_constants = (np.array(values) for values in zip(*lags))
        held[members, :, columns] = lagged_interval_means(held[members, :, columns], time_constants, np.diff(time))
    return held


@dataclass
class _TermChanges:
    """What the term effects of B members change in the blimp's ODE (module docstring), one row
    per member: thrust gains for positive and negative commands (3 inputs), extra rotational
    damping (P, Q, R) and quadratic drag (U, V, W), constant generalised forces (6) and extra net
    downward force, N."""

    gain_positive: np.ndarray
    gain_negative: np.ndarray
    extra_damping: np.ndarray
    extra_drag: np.ndarray
    constant: np.ndarray
    extra_down: np.ndarray
    slots: dict

    @classmethod
    def of(cls, reference: BlimpReference, effect_lists) -> _TermChanges:
        batch = len(effect_lists)
        changes = cls(np.ones((batch, 3)), np.ones((batch, 3)), np.zeros((batch, 3)), np.zeros((batch, 3)),
                      np.zeros((batch, 6)), np.zeros(batch),
                      search_slots(effect_lists, SEARCH_ROWS, SEARCH_SIGNALS, SEARCH_SLOTS))
        for b, effects in enumerate(effect_lists):
            for effect in effects:
                if "term" in effect and effect["effect"] != "search_term":
                    changes.set_term(b, effect["term"], effect["value"], model_value(reference, effect["term"]))
        return changes

    def set_term(self, member: int, term: str, value: float, model: float) -> None:
        """Term ``term`` of member ``member`` at ``value`` instead of the model's ``model``."""
        if term in CONTROL_TERMS:
            column, sign = CONTROL_TERMS[term]
            gains = self.gain_positive if sign > 0 else self.gain_negative
            gains[member, INPUT_NAMES.index(column)] = value / model
        elif term in STABILITY_TERMS:
            self.extra_damping[member, STABILITY_TERMS[term]] = value - model
        elif term in DRAG_TERMS:
            self.extra_drag[member, DRAG_TERMS[term]] = value - model
        elif term == "Z_0":
            self.extra_down[member] = value - model
        else:
            self.constant[member, OFFSET_TERMS[term]] = value - model

    def rates(self, state: np.ndarray, command: np.ndarray, params, inverse: np.ndarray) -> np.ndarray:
        """State derivatives (B, 12) of the changed ODEs at ``state`` (B, 12) with the held
        ``command`` (B, 3); ``inverse`` is the inverse system inertia matrix (6, 6)."""
        effective = command * np.where(command >= 0, self.gain_positive, self.gain_negative)
        v, w, angles = state[:, 6:9], state[:, 9:12], state[:, 3:6]
        down = np.stack([-np.sin(angles[:, 1]), np.cos(angles[:, 1]) * np.sin(angles[:, 0]),
                         np.cos(angles[:, 1]) * np.cos(angles[:, 0])], axis=-1)
        force = self.constant.copy()
        force[:, :3] += self.extra_drag * np.abs(v) * v + self.extra_down[:, None] * down
        force[:, 3:] += self.extra_damping * w
        signals = np.concatenate([state[:, 6:12], state[:, 3:5], command], axis=-1)  # SEARCH_SIGNALS
        force += slot_values(np, signals, self.slots)
        rates = blimp_dynamics(state, effective, params)
        rates[:, 6:] += force @ inverse.T
        return rates


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


#: Screening steps of the blimp's force offsets: 1 mN (about 1 % of full gondola thrust, the
#: buoyancy drift of the stand-in) and 1 mN m.
_OFFSET_STEPS = {"X_0": 1e-3, "Y_0": 1e-3, "Z_0": 1e-3, "N_0": 1e-3}


class BlimpEffects:
    """The :class:`~validation.vehicles.effects.EffectModel` of the ``blimp`` reference (module
    docstring): every effect kind, replays batched, recordings may be unevenly sampled.

    Parameters
    ----------
    reference : BlimpReference

    Attributes
    ----------
    reference : BlimpReference
    sensor_noise_sd : dict of str to float
        :data:`SENSOR_NOISE_STD`.

    The other attributes and the methods are those of the protocol.
    """

    family = "blimp"
    kinds = ("time_delay", "input_lag", "control_derivative", "stability_derivative", "sensor_bias", "quadratic_drag",
             "force_offset", "dead_band", "backlash", "saturation", "rate_limit", "output_scale", "sensor_cross_axis",
             "sensor_lag", "sensor_drift", "search_term")
    terms = TERMS
    search_rows = SEARCH_ROWS
    search_signals = SEARCH_SIGNALS
    search_library = SEARCH_LIBRARY
    max_search_terms = SEARCH_SLOTS
    batches_simulations = True
    absolute_inputs = False
    needs_even_sampling = False
    sensor_noise_sd = SENSOR_NOISE_STD
    min_noise_sd = {}
    residual_gp_states = STATE_NAMES
    start_state = starts_at_trim
    simulate_recordings = simulate_each_recording

    def __init__(self, reference: BlimpReference):
        self.reference = reference
        self.name, self.sample_time = reference.name, reference.sample_time
        self.input_names, self.state_names = reference.input_names, reference.state_names

    def model_value(self, term: str) -> float:
        return model_value(self.reference, term)

    def term_unit(self, term: str) -> str:
        """:data:`TERM_UNITS`; a search term's :func:`search_term_unit`."""
        return TERM_UNITS[term] if term in TERM_UNITS else search_term_unit(term)

    def term_description(self, term: str) -> str:
        """:data:`TERM_DESCRIPTIONS`; a search term's :func:`search_term_description`."""
        if term in TERM_DESCRIPTIONS:
            return TERM_DESCRIPTIONS[term]
        return search_term_description(term) if term in SEARCH_TERMS else term

    def term_value_problem(self, term: str, value: float) -> str | None:
        """Fan thrust per unit command (the control-derivative terms) must be positive."""
        if term in CONTROL_TERMS and not value > 0:
            return f"thrust per unit command must be positive, got {value} N"
        return None

    def term_hypotheses(self, excited_inputs) -> list[Hypothesis]:
        """The thrust gains of the excited fans (positive), the rotational damping ``L_P, M_Q,
        N_R``, the quadratic drag ``X_UU, Y_VV, Z_WW`` (screening steps 5 % of the model's
        value) and the force offsets ``X_0, Y_0, Z_0, N_0`` (steps of :data:`_OFFSET_STEPS`)."""
        hypotheses = []
        for term, (column, _) in CONTROL_TERMS.items():
            if column in excited_inputs:
                value = self.model_value(term)
                hypotheses.append(Hypothesis("control_derivative", term, value, 0.0, math.inf, 0.05 * value))
        for kind, terms in (("stability_derivative", STABILITY_TERMS), ("quadratic_drag", DRAG_TERMS)):
            for term in terms:
                value = self.model_value(term)
                hypotheses.append(Hypothesis(kind, term, value, -math.inf, math.inf, 0.05 * abs(value)))
        for term, step in _OFFSET_STEPS.items():
            hypotheses.append(Hypothesis("force_offset", term, self.model_value(term), -math.inf, math.inf, step))
        return hypotheses

    def search_jacobian(self, states, inputs) -> np.ndarray:
        """How strongly each search signal drives each search row: the RMS over the samples of
        ``d tau_row / d signal`` (``tau = M nu_dot``, the generalised force of the row,
        :data:`SEARCH_ROWS`; signals :data:`SEARCH_SIGNALS`), by central differences of the
        reference's ODE at the given states, for the residual search's axes.

        Parameters
        ----------
        states : list of ndarray, each shape (n_r, 12)
            Replayed states per recording.
        inputs : list of ndarray, each shape (n_r, 3)
            The recordings' inputs.

        Returns
        -------
        ndarray, shape (6, len(SEARCH_SIGNALS))
        """
        params = self.reference.params
        matrix, _ = mass_matrix(params.mass, params.added_mass, params.inertia, params.added_inertia,
                                params.cg_position)
        return search_axes_jacobian(lambda x, u: blimp_dynamics(x, u, params)[:, 6:] @ matrix.T, states, inputs,
                                    SEARCH_SIGNALS, STATE_NAMES, INPUT_NAMES)

    def simulate_many(self, effect_lists, time, inputs, *, start=None) -> np.ndarray:
        """:func:`simulate_batch`, shape (B, n, 12), from the hanging state (``start`` must be
        None: :meth:`start_state`)."""
        check_trim_start(start, self.name)
        return simulate_batch(self.reference, effect_lists, time, inputs)

    identification_manoeuvre = staticmethod(identification_manoeuvre)
