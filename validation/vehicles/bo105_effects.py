"""Named effects on the linear Bo105 reference (:mod:`validation.vehicles.bo105`): its
:class:`~validation.vehicles.effects.EffectModel`, :class:`Bo105Effects`, and the multi-axis
identification manoeuvre that excites them.

The effect dicts are those of :mod:`validation.vehicles.effects` (docs/vehicles.md). A Bo105
takes delays, lags and sensor biases, and as terms its derivatives: ``stability_derivative``
``<row>_<state>`` and ``control_derivative`` ``<row>_<input>`` with the row letters ``X, Z, M,
Y, L, N`` of :data:`validation.vehicles.bo105.ROW_LETTERS` (``M_q``, ``L_theta_1c`` ...). How each
effect enters the linear Bo105 (``x_dot = A x + B u``):

- derivatives replace entries of ``A`` (stability) or ``B`` (control) through
  :meth:`~validation.vehicles.bo105.Bo105Reference.with_derivatives`;
- ``input_lag`` on input ``j``: ``T z_dot = -z + u_j`` and column ``j`` of ``B`` acts on ``z``
  (an augmented state starting at trim, 0), discretised exactly with the rest;
- ``time_delay`` on input ``j``: ``u_j(t - tau)``. With the zero-order hold of the recordings and
  ``tau = (m + f) h`` (integer ``m``, ``0 <= f < 1``) the delayed input switches inside each
  interval, and ``x[k+1] = Phi x[k] + Gamma_a u_j[k-m-1] + Gamma_b u_j[k-m]`` with
  ``Gamma_b = int_0^{(1-f)h} e^{As} ds b_j`` and ``Gamma_a = e^{A(1-f)h} int_0^{fh} e^{As} ds b_j``
  (Franklin, Powell & Workman, *Digital Control of Dynamic Systems*, 3rd ed., 1998, sec. 4.3.3).
  The result is exact and continuous in ``tau``, which a fit needs;
- ``sensor_bias`` adds a constant to a recorded output.

Replays are one exact discretisation each (milliseconds), so they are not batched, and they
need evenly sampled recordings (one step).
"""
from __future__ import annotations

import math

import numpy as np

from validation.core.manoeuvres import doublet, three_two_one_one, time_grid
from validation.core.recordings import column_phrase, column_unit
from validation.core.sampling import check_history
from validation.vehicles.bo105 import (
    INPUT_NAMES,
    ROW_LETTERS,
    STATE_NAMES,
    Bo105Reference,
    propagate,
)
from validation.vehicles.bo105_flight import SENSOR_NOISE_STD
from validation.vehicles.effects import Hypothesis, check_trim_start, simulate_each_recording, starts_at_trim
from validation.vehicles.linear_discretisation import zero_order_hold

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


def simulate_bo105_with_effects(reference: Bo105Reference, effects, time, inputs) -> np.ndarray:
    """States (plus sensor biases) of a Bo105 with checked ``effects`` (module docstring), from trim.

    Parameters
    ----------
    reference : Bo105Reference
    effects : list of dict
        Checked (:func:`validation.vehicles.effects.check_effects`).
    time : ndarray, shape (n,)
        Evenly spaced sample times, s.
    inputs : ndarray, shape (n, 4)
        ``theta_0, theta_1s, theta_1c, theta_0T``, rad, zero-order hold.

    Returns
    -------
    ndarray, shape (n, 8)
        ``u, w, q, theta, v, p, phi, r`` as recorded, SI units.
    """
    time, inputs, step = check_history(time, inputs, INPUT_NAMES)
    derivatives = {e["term"]: e["value"] for e in effects if "term" in e}
    model = reference.with_derivatives(derivatives) if derivatives else reference
    A, B = model.A, model.B
    n_states, n_inputs = B.shape
    lags = {INPUT_NAMES.index(e["input"]): e["value"] for e in effects
            if e["effect"] == "input_lag" and e["value"] > 0}
    delays = {INPUT_NAMES.index(e["input"]): e["value"] for e in effects
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
    held = inputs[:-1]
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
    states = propagate(Phi, forcing, np.zeros(size))[:, :n_states]
    for effect in effects:
        if effect["effect"] == "sensor_bias":
            states[:, STATE_NAMES.index(effect["output"])] += effect["value"]
    return states


def identification_manoeuvre(*, duration: float = 20.0, sample_time: float = 0.01,
                             variant: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A multi-axis Bo105 identification input: a 3-2-1-1 on each cyclic, then doublets on
    pedals and collective, one after the other, so that every control derivative and delay is
    identifiable (Tischler & Remple, *Aircraft and Rotorcraft System Identification*, 2012,
    ch. 5: one axis at a time, multisteps for broad-band excitation).

    Parameters
    ----------
    duration, sample_time : float
        s; manoeuvres that do not fit in ``duration`` are cut off.
    variant : int
        0: 1 deg, 0.4/0.3 s steps (for fitting); 1: 1.5 deg, 0.3/0.5 s steps, signs reversed,
        pedal before lateral cyclic (a different manoeuvre, for held-out data).

    Returns
    -------
    time : ndarray, shape (n,)
    inputs : ndarray, shape (n, 4)
        ``theta_0, theta_1s, theta_1c, theta_0T``, rad.
    """
    time = time_grid(duration=duration, sample_time=sample_time)
    inputs = np.zeros((len(time), len(INPUT_NAMES)))
    degree = math.radians(1.0)
    column = {name: INPUT_NAMES.index(name) for name in INPUT_NAMES}
    if variant == 0:
        inputs[:, column["theta_1s"]] = three_two_one_one(time, amplitude=degree, step_time=0.4, start=1.0)
        inputs[:, column["theta_1c"]] = three_two_one_one(time, amplitude=degree, step_time=0.3, start=6.0)
        inputs[:, column["theta_0T"]] = doublet(time, amplitude=degree, step_time=0.5, start=10.0)
        inputs[:, column["theta_0"]] = doublet(time, amplitude=degree, step_time=0.5, start=14.0)
    else:
        amplitude = -1.5 * degree
        inputs[:, column["theta_1s"]] = three_two_one_one(time, amplitude=amplitude, step_time=0.3, start=1.0)
        inputs[:, column["theta_0T"]] = doublet(time, amplitude=amplitude, step_time=0.4, start=5.0)
        inputs[:, column["theta_1c"]] = three_two_one_one(time, amplitude=amplitude / 1.5, step_time=0.5, start=8.0)
        inputs[:, column["theta_0"]] = doublet(time, amplitude=amplitude, step_time=0.6, start=14.0)
    return time, inputs


class Bo105Effects:
    """The :class:`~validation.vehicles.effects.EffectModel` of a ``bo105-<V>kt`` reference
    (module docstring).

    Parameters
    ----------
    reference : Bo105Reference

    Attributes
    ----------
    reference : Bo105Reference
    sensor_noise_sd : dict of str to float
        The flight-test stand-in's sensor noise,
        :data:`validation.vehicles.bo105_flight.SENSOR_NOISE_STD`.

    The other attributes and the methods are those of the protocol.
    """

    family = "bo105"
    kinds = ("time_delay", "input_lag", "control_derivative", "stability_derivative", "sensor_bias")
    terms = {"control_derivative": tuple(f"{letter}_{column}" for letter in ROW_LETTERS for column in INPUT_NAMES),
             "stability_derivative": tuple(f"{letter}_{column}" for letter in ROW_LETTERS for column in STATE_NAMES)}
    batches_simulations = False
    needs_even_sampling = True
    sensor_noise_sd = SENSOR_NOISE_STD
    min_noise_sd = {}
    residual_gp_states = STATE_NAMES
    start_state = starts_at_trim
    simulate_recordings = simulate_each_recording

    def __init__(self, reference: Bo105Reference):
        self.reference = reference
        self.name, self.sample_time = reference.name, reference.sample_time
        self.input_names, self.state_names = reference.input_names, reference.state_names

    def model_value(self, term: str) -> float:
        return self.reference.derivative(term)

    def term_unit(self, term: str) -> str:
        """(row acceleration)/(column unit), ``1/s`` when they cancel (``M_q``)."""
        letter, _, column = term.partition("_")
        row_unit, column_unit_ = column_unit(ROW_LETTERS[letter]), column_unit(column)
        return "1/s" if row_unit == column_unit_ else f"({_ACCELERATION_UNITS[row_unit]})/({column_unit_})"

    def term_description(self, term: str) -> str:
        """The derivative's common name (:data:`DERIVATIVE_NAMES`), else ``"<row force or moment>
        due to <column>"`` (``"side force due to longitudinal cyclic pitch"``), else ``term``."""
        if term in DERIVATIVE_NAMES:
            return DERIVATIVE_NAMES[term]
        letter, _, column = term.partition("_")
        if letter in _ROW_WORDS and column in STATE_NAMES + INPUT_NAMES:
            return f"{_ROW_WORDS[letter]} due to {column_phrase(column)}"
        return term

    def term_value_problem(self, term: str, value: float) -> None:
        """Every finite derivative is acceptable."""
        return None

    def term_hypotheses(self, excited_inputs) -> list[Hypothesis]:
        """Every control derivative of an excited input and every stability derivative (6 rows
        x 8 states, off-axis couplings included), unbounded; screening step 5 % of the value, at
        least 1 % of the row's largest entry (so that zero entries move too) and 1e-6."""
        hypotheses = []
        A, B = self.reference.A, self.reference.B
        for letter, row_state in ROW_LETTERS.items():
            row = STATE_NAMES.index(row_state)
            for columns, matrix, kind in ((STATE_NAMES, A, "stability_derivative"),
                                          (INPUT_NAMES, B, "control_derivative")):
                typical = np.max(np.abs(matrix[row]))
                for column, column_name in enumerate(columns):
                    if kind == "control_derivative" and column_name not in excited_inputs:
                        continue
                    value = matrix[row, column]
                    step = 0.05 * max(abs(value), 0.01 * typical, 1e-6)
                    hypotheses.append(Hypothesis(kind, f"{letter}_{column_name}", float(value),
                                                 -math.inf, math.inf, step))
        return hypotheses

    def simulate_many(self, effect_lists, time, inputs, *, start=None) -> np.ndarray:
        """:func:`simulate_bo105_with_effects` for each list, shape (B, n, 8), from trim
        (``start`` must be None: :meth:`start_state`)."""
        check_trim_start(start, self.name)
        return np.stack([simulate_bo105_with_effects(self.reference, effects, time, inputs)
                         for effects in effect_lists])

    identification_manoeuvre = staticmethod(identification_manoeuvre)
