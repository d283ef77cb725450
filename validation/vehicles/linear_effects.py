"""Named effects on any linear reference ``x_dot = A x + B u``
(:class:`validation.vehicles.state_space.LinearReference`: the Bo105's and any state-space model
read from JSON): its :class:`~validation.vehicles.effects.EffectModel`, :class:`LinearEffects`.

The effect dicts are those of :mod:`validation.vehicles.effects` (docs/vehicles.md). A linear
reference takes delays, lags and the sensor effects, and as terms its derivatives:
``stability_derivative`` ``<row>_<state>`` and ``control_derivative`` ``<row>_<input>`` with the
reference's row letters (``X, Z, M, Y, L, N`` for a flight vehicle: ``M_q``, ``L_theta_1c`` ...).
How each effect enters ``x_dot = A x + B u``:

- derivatives replace entries of ``A`` (stability) or ``B`` (control) through
  :meth:`~validation.vehicles.state_space.LinearReference.with_derivatives`;
- ``input_lag`` on input ``j``: ``T z_dot = -z + u_j`` and column ``j`` of ``B`` acts on ``z``
  (an augmented state starting at trim, 0), discretised exactly with the rest;
- ``time_delay`` on input ``j``: ``u_j(t - tau)``. With the zero-order hold of the recordings and
  ``tau = (m + f) h`` (integer ``m``, ``0 <= f < 1``) the delayed input switches inside each
  interval, and ``x[k+1] = Phi x[k] + Gamma_a u_j[k-m-1] + Gamma_b u_j[k-m]`` with
  ``Gamma_b = int_0^{(1-f)h} e^{As} ds b_j`` and ``Gamma_a = e^{A(1-f)h} int_0^{fh} e^{As} ds b_j``
  (Franklin, Powell & Workman, *Digital Control of Dynamic Systems*, 3rd ed., 1998, sec. 4.3.3).
  The result is exact and continuous in ``tau``, which a fit needs;
- the effects of the measurement chain (``output_scale``, ``sensor_cross_axis``, ``sensor_lag``,
  ``sensor_bias``, ``sensor_drift``) act on the replayed states as recorded, through
  :func:`validation.vehicles.effects.apply_measurement_chain`, as on every reference;
- ``dead_band`` on input ``j``: the input passes through a dead band of the given
  half-width about trim (:func:`validation.vehicles.effects.dead_band_inputs`) before it acts;
  ``backlash``: free play of the half-width, centred at trim at the start
  (:func:`validation.vehicles.effects.backlash_inputs`), after the dead band;
  ``input_gain``: the input acts ``gain`` times as strongly (a gearing or control-effectiveness
  error: every control derivative of the input scaled at once); ``saturation``: the input's
  deflection from trim is clipped at +/- the limit (a position limit). On a manoeuvre that moves an
  input between trim and one amplitude only, the three are the same effect (a dead band of
  half-width ``w`` on steps of ``A`` is a gain of ``1 - w/A``, a limit ``L`` a gain of ``L/A``);
  two amplitudes tell them apart; ``rate_limit``: the input's actuator ramps towards the command
  no faster than the limit (:func:`validation.vehicles.effects.rate_limited_interval_means`),
  held over each interval at its mean, so the input's integral is exact and the state error is
  second order in the step. A rate limit costs a step of ``d`` a ramp of ``d / rate``: on the
  3-2-1-1's steps of one and two amplitudes it is neither a delay nor a lag;
- ``nonlinear_stiffness`` ``<row>_<s>^3`` adds ``c s^3`` to the derivative of the row's state,
  ``s`` another state the row depends on (``N_v^3``: a weathercock stability that hardens or
  softens with sideslip, the Duffing term of Nayfeh & Mook, *Nonlinear Oscillations*, 1979,
  ch. 4), replayed as the damping below; ``quadratic_stiffness`` ``<row>_<s>|<s>|`` the same
  with the signed square ``c s |s|`` (``N_v|v|``: a weathercock stability growing with the
  sideslip's size, as a fuselage's cross-flow force does; Padfield, *Helicopter Flight
  Dynamics*, 2nd ed., 2007, ch. 4); ``search_term``: any polynomial term
  (:mod:`validation.vehicles.polynomial_terms`), what the residual search of ``diagnose`` finds;
- ``nonlinear_damping`` ``<row>_<s>|<s>|`` adds ``c s |s|`` to the derivative of the row's
  state, ``s`` that state itself (``M_q|q|``: a pitch moment per unit inertia quadratic in the
  pitch rate, as blade stall or a fuselage's cross-flow drag make it; Padfield, *Helicopter
  Flight Dynamics*, 2nd ed., 2007, ch. 4 on where the linear derivatives stop holding). The term
  enters through the same exact discretisation as an input, held over each sample interval at
  its mean of the interval's two ends (Heun's predictor-corrector: ``x[k+1] = Phi x[k] +
  Gamma u[k] + Gamma_c c (s[k]|s[k]| + s'|s'|) / 2`` with ``s'`` the end predicted with the
  start's term), so the replay runs step by step; its error is second order in the step.

Replays are one exact discretisation each (milliseconds), so they are not batched, and they
need evenly sampled recordings (one step).
"""
from __future__ import annotations

import math

import numpy as np

from validation.core.manoeuvres import three_two_one_one, time_grid
from validation.core.recordings import column_phrase
from validation.core.sampling import check_history
from validation.vehicles.effects import (
    Hypothesis,
    apply_measurement_chain,
    check_trim_start,
    shaped_inputs,
    simulate_each_recording,
    starts_at_trim,
)
from validation.vehicles.linear_discretisation import zero_order_hold
from validation.vehicles.polynomial_terms import library, parse_term, propagate_with_terms, term_name
from validation.vehicles.state_space import DEFAULT_SAMPLE_TIME, LinearReference, propagate

_ACCELERATION_UNITS = {"m/s": "m/s^2", "rad/s": "rad/s^2"}
#: Common names of derivatives (Padfield, *Helicopter Flight Dynamics*, 2nd ed., 2007, ch. 4 and 7).
DERIVATIVE_NAMES = {"M_q": "pitch damping", "L_p": "roll damping", "N_r": "yaw damping",
                    "L_q": "roll moment due to pitch rate (off-axis coupling)",
                    "M_p": "pitch moment due to roll rate (off-axis coupling)",
                    "M_w": "pitch moment due to heave velocity (incidence stability)",
                    "M_u": "speed stability", "N_v": "weathercock stability", "L_v": "dihedral effect",
                    "X_u": "drag damping", "Z_w": "heave damping", "Y_v": "side-force damping",
                    "M_theta_1s": "pitch control power", "L_theta_1c": "roll control power",
                    "N_theta_0T": "yaw control power", "Z_theta_0": "heave control power"}
#: What each derivative row is a derivative of: the body-axis forces X, Y, Z and moments L, M, N
#: (per unit mass and inertia; Padfield 2007, ch. 4), for the derivatives without a common name.
_ROW_WORDS = {"X": "longitudinal force", "Y": "side force", "Z": "vertical force",
              "L": "roll moment", "M": "pitch moment", "N": "yaw moment"}


def _delayed(signal: np.ndarray, samples: int) -> np.ndarray:
    """``signal[k - samples]`` (trim, 0, before the start), shape like ``signal``."""
    if samples <= 0:
        return signal
    shifted = np.zeros_like(signal)
    shifted[samples:] = signal[:len(signal) - samples]
    return shifted


def simulate_linear_with_effects(reference: LinearReference, effects, time, inputs, *,
                                 gusts: np.ndarray | None = None) -> np.ndarray:
    """States as recorded (through the measurement chain) of a linear reference with checked
    ``effects`` (module docstring), from trim.

    Parameters
    ----------
    reference : LinearReference
    effects : list of dict
        Checked (:func:`validation.vehicles.effects.check_effects`).
    time : ndarray, shape (n,)
        Evenly spaced sample times, s.
    inputs : ndarray, shape (n, n_inputs)
        In ``reference.input_names`` order and units, zero-order hold.
    gusts : ndarray, shape (n, 3), optional
        Air velocities ``u_g, v_g, w_g`` along the body axes, m/s, each row held over its
        interval as the inputs are (e.g. :func:`validation.vehicles.turbulence.dryden_gusts`).
        The derivatives act on the velocity relative to the air, so the columns of ``A`` (the
        effects' own, with changed derivatives) for the states ``u, v, w`` act on ``x - gust``:
        ``x_dot = A x + B u - A[:, (u, v, w)] gust``, as the flight-test stand-in's turbulence
        enters (:mod:`validation.vehicles.bo105_flight`). The reference must have states named
        ``u``, ``v`` and ``w``.

    Returns
    -------
    ndarray, shape (n, n_states)
        The states as recorded, in ``reference.state_names`` order.
    """
    time, inputs, step = check_history(time, inputs, reference.input_names)
    if gusts is not None:
        gusts = np.asarray(gusts, dtype=float)
        missing = [name for name in ("u", "v", "w") if name not in reference.state_names]
        if missing or gusts.shape != (len(time), 3):
            raise ValueError(f"gusts: need shape ({len(time)}, 3) and states u, v, w of {reference.name}; got "
                             f"shape {gusts.shape}" + (f", no state {', '.join(missing)}" if missing else ""))
    derivatives = {e["term"]: e["value"] for e in effects
                   if e["effect"] in ("control_derivative", "stability_derivative")}
    polynomial = [(e["term"], e["value"]) for e in effects
                  if e["effect"] in POLYNOMIAL_KINDS and e["value"] != 0]
    model = reference.with_derivatives(derivatives) if derivatives else reference
    A, B = model.A, model.B
    n_states, n_inputs = B.shape
    lags = {reference.input_names.index(e["input"]): e["value"] for e in effects
            if e["effect"] == "input_lag" and e["value"] > 0}
    delays = {reference.input_names.index(e["input"]): e["value"] for e in effects
              if e["effect"] == "time_delay" and e["value"] > 0}
    # Augmented system: rigid body, then one lag state per lagged input.
    size = n_states + len(lags)
    F, G = np.zeros((size, size)), np.zeros((size, n_inputs))
    F[:n_states, :n_states] = A
    G[:n_states] = B
    for extra, (column, time_constant) in enumerate(sorted(lags.items()), start=n_states):
        G[:n_states, column] = 0.0
        F[:n_states, extra] = B[:, column]
        F[extra, extra] = -1.0 / time_constant
        G[extra, column] = 1.0 / time_constant
    Phi, Gamma = zero_order_hold(F, G, step)
    # About trim (0): the inputs are perturbations from it; the gain last, as on every reference.
    held = shaped_inputs(effects, time, inputs, reference.input_names)[:-1]
    gains = [(reference.input_names.index(e["input"]), e["value"]) for e in effects
             if e["effect"] == "input_gain" and e["value"] != 1.0]
    if gains:
        held = held.copy()
        for column, gain in gains:
            held[:, column] *= gain
    undelayed = [column for column in range(n_inputs) if column not in delays]
    forcing = held[:, undelayed] @ Gamma[:, undelayed].T
    for column, delay in delays.items():
        whole = int(math.floor(delay / step + 1e-9))
        fraction = delay / step - whole
        late_Phi, late_Gamma = zero_order_hold(F, G[:, [column]], (1.0 - fraction) * step)
        gamma_late = late_Gamma[:, 0]
        gamma_early = (late_Phi @ zero_order_hold(F, G[:, [column]], fraction * step)[1])[:, 0] \
            if fraction > 1e-12 else np.zeros(size)
        forcing += np.outer(_delayed(held[:, column], whole), gamma_late)
        forcing += np.outer(_delayed(held[:, column], whole + 1), gamma_early)
    if gusts is not None:
        columns = [reference.state_names.index(name) for name in ("u", "v", "w")]
        gust_input = np.zeros((size, 3))
        gust_input[:n_states] = -A[:, columns]
        forcing += gusts[:-1] @ zero_order_hold(F, gust_input, step)[1].T
    if polynomial:
        signal_names = reference.state_names + reference.input_names
        terms = [parse_term(term, reference.row_letters, signal_names) for term, _ in polynomial]
        rows = [reference.state_names.index(reference.row_letters[term.letter]) for term in terms]
        states = propagate_with_terms(terms, [value for _, value in polynomial], rows, F=F, step=step, Phi=Phi,
                                      forcing=forcing, held=held, n_states=n_states,
                                      signal_names=signal_names)[:, :n_states]
    else:
        states = propagate(Phi, forcing, np.zeros(size))[:, :n_states]
    return apply_measurement_chain(states, time, effects, reference.state_names)



#: The effect kinds that are polynomial terms (:mod:`validation.vehicles.polynomial_terms`).
POLYNOMIAL_KINDS = ("nonlinear_damping", "nonlinear_stiffness", "quadratic_stiffness", "search_term")


def _stiffness_pairs(reference: LinearReference) -> list[tuple[str, str]]:
    """``(row letter, state)`` of every stiffness a row takes: each state other than the row's
    own that its linear rate depends on (a non-zero ``A`` entry: ``N_v`` gives ``N_v^3``)."""
    A = reference.A
    pairs = []
    for letter, row_state in reference.row_letters.items():
        row = reference.state_names.index(row_state)
        pairs += [(letter, state) for column, state in enumerate(reference.state_names)
                  if state != row_state and A[row, column] != 0.0]
    return pairs


class LinearEffects:
    """The :class:`~validation.vehicles.effects.EffectModel` of a linear reference (module
    docstring): a state-space model read from JSON (family ``"state-space"``);
    :class:`validation.vehicles.bo105_effects.Bo105Effects` is the Bo105's.

    Parameters
    ----------
    reference : LinearReference

    Attributes
    ----------
    reference : LinearReference
    signal_units : dict of str to str
        The reference's unit of every state and input (``reference.units``).
    sensor_noise_sd : dict of str to float
        Zero for every state: a user's model comes with no sensor model, so the
        concealed-effect bench's recordings of it are noise-free.

    The other attributes and the methods are those of the protocol.
    """

    family = "state-space"
    kinds = ("time_delay", "input_lag", "control_derivative", "stability_derivative", "sensor_bias",
             "nonlinear_damping", "nonlinear_stiffness", "quadratic_stiffness", "dead_band", "backlash", "input_gain",
             "saturation", "rate_limit", "search_term", "output_scale", "sensor_cross_axis", "sensor_lag",
             "sensor_drift")
    batches_simulations = False
    absolute_inputs = False
    needs_even_sampling = True
    min_noise_sd = {}
    start_state = starts_at_trim
    simulate_recordings = simulate_each_recording

    def __init__(self, reference: LinearReference):
        self.reference = reference
        self.name, self.sample_time = reference.name, reference.sample_time
        self.input_names, self.state_names = reference.input_names, reference.state_names
        self.residual_gp_states = reference.state_names
        self.signal_units = dict(reference.units)
        letters = reference.row_letters
        self.terms = {"control_derivative": tuple(f"{a}_{c}" for a in letters for c in reference.input_names),
                      "stability_derivative": tuple(f"{a}_{c}" for a in letters for c in reference.state_names),
                      "nonlinear_damping": tuple(term_name(a, "signed_square", s) for a, s in letters.items()),
                      "nonlinear_stiffness": tuple(term_name(a, "cube", s) for a, s in _stiffness_pairs(reference)),
                      "quadratic_stiffness": tuple(term_name(a, "signed_square", s)
                                                   for a, s in _stiffness_pairs(reference))}
        self._stiffness = [(kind, parse_term(term, letters, reference.state_names))
                           for kind in ("nonlinear_stiffness", "quadratic_stiffness") for term in self.terms[kind]]
        named = {term for kind in ("nonlinear_damping", "nonlinear_stiffness", "quadratic_stiffness")
                 for term in self.terms[kind]}
        signals = reference.state_names + reference.input_names  # a named term is not also a searched one
        self.terms["search_term"] = tuple(term for term in library(letters, signals) if term not in named)
        self.sensor_noise_sd = dict.fromkeys(reference.state_names, 0.0)

    def _polynomial(self, term: str):
        """The parsed polynomial term (:mod:`validation.vehicles.polynomial_terms`), or None for
        a derivative."""
        return parse_term(term, self.reference.row_letters, self.state_names + self.input_names)

    def model_value(self, term: str) -> float:
        """A derivative's value; 0 for a polynomial term (the model is linear)."""
        return 0.0 if self._polynomial(term) else self.reference.derivative(term)

    def term_unit(self, term: str) -> str:
        """(row rate)/(column unit), ``1/s`` when they cancel (``M_q``): ``(rad/s^2)/(rad)``; a
        polynomial term per unit of its factor: ``(rad/s^2)/(rad/s)^2`` for ``M_q|q|``,
        ``(rad/s^2)/(m/s)^3`` for ``M_w^3``, ``(rad/s^2)/(rad/s m/s)`` for ``M_q*w``."""
        letter, _, column = term.partition("_")
        units = self.reference.units
        row_unit = units[self.reference.row_letters[letter]]
        rate = _ACCELERATION_UNITS.get(row_unit, row_unit + "/s")
        polynomial = self._polynomial(term)
        if polynomial:
            first = units[polynomial.signals[0]]
            factor = {"signed_square": f"({first})^2", "cube": f"({first})^3"}.get(
                polynomial.kind, f"({first} {units[polynomial.signals[-1]]})")
            return f"({rate})/{factor}"
        column_unit_ = units[column]
        if row_unit == column_unit_:
            return "1/s"
        return f"({rate})/({column_unit_})"

    def term_description(self, term: str) -> str:
        """The derivative's common name (:data:`DERIVATIVE_NAMES`), else ``"<row force or moment>
        due to <column>"`` (``"side force due to longitudinal cyclic pitch"``); a polynomial term
        as ``"<row force or moment> proportional to <factor>"``, with what it means where the
        factor is the row's own state (damping that grows with it) or another state's signed
        square or cube (not linear in that state); else ``term``."""
        if term in DERIVATIVE_NAMES:
            return DERIVATIVE_NAMES[term]
        letter, _, column = term.partition("_")
        polynomial = self._polynomial(term)
        if polynomial and letter in _ROW_WORDS:
            signal = polynomial.signals[0]
            meaning = ""
            if polynomial.kind != "product" and signal == self.reference.row_letters[letter]:
                meaning = f" (damping that grows with {column_phrase(signal)})"
            elif polynomial.kind != "product" and signal in self.state_names:
                meaning = f" (not linear in {column_phrase(signal)})"
            return f"{_ROW_WORDS[letter]} proportional to {polynomial.factor}{meaning}"
        if letter in _ROW_WORDS and column in self.state_names + self.input_names:
            return f"{_ROW_WORDS[letter]} due to {column_phrase(column)}"
        return term

    def term_value_problem(self, term: str, value: float) -> None:
        """Every finite derivative is acceptable."""
        return None

    def term_hypotheses(self, excited_inputs) -> list[Hypothesis]:
        """Every control derivative of an excited input and every stability derivative (each
        derivative row x every state, off-axis couplings included), unbounded; screening step 5 % of the value, at
        least 1 % of the row's largest entry (so that zero entries move too) and 1e-6; each
        row's nonlinear damping term (``M_q|q|``) and its cubic stiffness in every other state it
        depends on (``N_v^3``, :func:`_stiffness_pairs`), null 0, unbounded."""
        hypotheses = []
        A, B = self.reference.A, self.reference.B
        for letter, row_state in self.reference.row_letters.items():
            row = self.state_names.index(row_state)
            for columns, matrix, kind in ((self.state_names, A, "stability_derivative"),
                                          (self.input_names, B, "control_derivative")):
                typical = np.max(np.abs(matrix[row]))
                for column, column_name in enumerate(columns):
                    if kind == "control_derivative" and column_name not in excited_inputs:
                        continue
                    value = matrix[row, column]
                    step = 0.05 * max(abs(value), 0.01 * typical, 1e-6)
                    hypotheses.append(Hypothesis(kind, f"{letter}_{column_name}", float(value),
                                                 -math.inf, math.inf, step))
            # c s|s| beside the linear damping A_rr s: a step of |A_rr| 1/(state unit) moves the
            # row's rate by |A_rr| s^2, 5 % of the linear term where |s| = 0.05 (a rate of 3 deg/s).
            damping = abs(A[row, row])
            hypotheses.append(Hypothesis("nonlinear_damping", term_name(letter, "signed_square", row_state), 0.0,
                                         -math.inf, math.inf, max(damping, 1e-3)))
        # c s^3 and c s|s| beside the linear A_rs s: screened at 5 % of |A_rs| per squared (per)
        # state unit.
        for kind, term in self._stiffness:
            row = self.state_names.index(self.reference.row_letters[term.letter])
            derivative = abs(A[row, self.state_names.index(term.signals[0])])
            hypotheses.append(Hypothesis(kind, term.name, 0.0, -math.inf, math.inf, 0.05 * derivative))
        return hypotheses

    def simulate_many(self, effect_lists, time, inputs, *, start=None) -> np.ndarray:
        """:func:`simulate_linear_with_effects` for each list, shape (B, n, n_states), from trim
        (``start`` must be None: :meth:`start_state`)."""
        check_trim_start(start, self.name)
        return np.stack([simulate_linear_with_effects(self.reference, effects, time, inputs)
                         for effects in effect_lists])

    def identification_manoeuvre(self, *, duration: float = 20.0, sample_time: float = DEFAULT_SAMPLE_TIME,
                                 variant: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """:func:`sequential_three_two_one_one` of the reference's inputs."""
        return sequential_three_two_one_one(self.input_names, self.reference.units, duration=duration,
                                            sample_time=sample_time, variant=variant)


def sequential_three_two_one_one(input_names, units: dict, *, duration: float, sample_time: float,
                                 variant: int) -> tuple[np.ndarray, np.ndarray]:
    """A 3-2-1-1 on each input in turn (Tischler & Remple 2012, ch. 5: one axis at a time), each
    given the duration's share: 1 deg for an input in rad (``units``: name -> unit), 10 % of full
    travel otherwise; variant 1 reverses the signs and the order and lengthens the steps by half.

    Returns
    -------
    time : ndarray, shape (n,)
    inputs : ndarray, shape (n, len(input_names))
    """
    time = time_grid(duration=duration, sample_time=sample_time)
    inputs = np.zeros((len(time), len(input_names)))
    order = list(range(len(input_names)))[::(-1 if variant else 1)]
    share = duration / len(order)
    for slot, column in enumerate(order):
        amplitude = math.radians(1.0) if units.get(input_names[column]) == "rad" else 0.1
        step_time = min(0.3 * (1.5 if variant else 1.0), (share - 0.5) / 7)
        inputs[:, column] = three_two_one_one(time, amplitude=(-amplitude if variant else amplitude),
                                              step_time=step_time, start=slot * share + 0.5)
    return time, inputs
