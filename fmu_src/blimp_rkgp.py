"""The blimp RKGP FMU (Ko et al., ICRA 2007, sec. IV-B): motor commands in; the full state and a
standard deviation per state out; the blimp ODE integrated by RK4 plus a GP on its one-step
residual inside (:class:`gp_model.GreyBoxGP` with the physics ``blimp_rk4``).

This file is copied into every blimp RKGP FMU (``resources/<package>/blimp_rkgp.py``), so it
imports only :mod:`._base`, :mod:`._runtime` (its envelope margin), numpy and the standard
library. :func:`blimp_dynamics` and the RK4 step are copies of
:func:`validation.vehicles.blimp.blimp_dynamics` and :func:`validation.models.blimp_identification.physics_step`
(for one state), with the same formulas in the same order, so the FMU reproduces
``GreyBoxGP.rollout`` with that physics to rounding (tests/test_fmu.py, 1e-9).

Model file (``model.npz``, written by :func:`pack_model`, read without pickle)
------------------------------------------------------------------------------
``format``, ``version``; ``parameter_names``, ``parameters`` (the
``BlimpParameters.to_vector`` the model was trained with), ``max_step`` (longest RK4 substep, s);
``state_columns`` (state columns the GP sees); ``envelope_low``, ``envelope_high`` (range of the
training GP inputs ``[states[state_columns], u_gondola, mu, u_tail, dt]``). Per GP part ``p``
(one for a shared GP, twelve for one GP per state), prefix ``"<p>/"``, in standardised units:
``basis`` (m, d) training inputs, ``weights`` (m, q) ``alpha``, ``variance_factor`` (m, m)
``L^-1``, ``kernel_weights`` (d,) ``w`` of ``k = sigma_f^2 exp(-sum_i w_i (x_i - x'_i)^2)``,
``log_signal_variance`` (), ``input_mean``, ``input_scale`` (d,), ``output_mean``,
``output_scale`` (q,); q = 12 for a shared part, 1 otherwise.

Timing (the sampling convention of :mod:`._base`)
-------------------------------------------------
The model was trained on frame pairs with the frame interval as its fourth input column ``dt``
(:func:`validation.models.blimp_identification.recording_arrays`): the physics integrates over ``dt``
and the GP sees it. The FMU does exactly that with ``dt = h``, the communication step: the host
chooses ``h`` (the default experiment's step is the median training frame interval), the first
``fmi2DoStep`` fixes it until reset, and a step outside the training range of ``dt`` (widened by
the envelope margin) is refused (logged Error, ``fmi2Discard``): the residual of another step
length is not what the GP learned. The commands set at ``t_k`` are held over ``[t_k, t_{k+1})``;
``fmi2DoStep(t_k, h)`` sets the state outputs to

    s(t_{k+1}) = RK4_blimp(s(t_k), u(t_k), h) + E[residual | s(t_k), u(t_k), h]

(each step cut into equal RK4 substeps no longer than ``max_step``), which is
``GreyBoxGP.rollout`` (the mean rollout: the mean is fed back). The outputs at ``t0`` are the
start state, the ``<state>_start`` parameters (default: at rest at the origin hanging in the
static attitude of the model's parameters, as :class:`validation.vehicles.blimp.BlimpReference` starts).

Standard deviations
-------------------
``<state>_sd`` at ``t_{k+1}`` is the one-step standard deviation: the square root of the GP's
latent predictive variance of the residual at ``(s(t_k), u(t_k), h)``, i.e. the spread of
``s(t_{k+1})`` *given that* ``s(t_k)`` is exactly the FMU's state at ``t_k`` (measurement noise
not included; ``GreyBoxGP.predict_one_step`` with ``include_noise=False``). It is 0 at ``t0``.
It is not the spread of a free run over many steps: that needs propagating the state
distribution through the dynamics (``GreyBoxGP.sample_rollouts``); summing one-step variances
would ignore that a velocity error integrates into position and that residuals are correlated
along a run, so it would be neither an upper nor a lower bound. The one-step sd says how far
the GP is from its data at this step: it grows toward the prior's outside the training envelope.

Envelope: when a GP input leaves the training range (by more than 10 % of the range), the FMU
logs a Warning once per excursion; the GP then extrapolates, and the sd outputs grow.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ._base import TIME_TOLERANCE, FlightgpSlave, Variable
from ._runtime import Envelope, kernel_rows

FORMAT = "flightgp-fmu-blimp-rkgp"
VERSION = 1
#: The model file inside the FMU's package folder.
MODEL_FILE = "model.npz"
STATE_NAMES = ("x", "y", "z", "phi", "theta", "psi", "U", "V", "W", "P", "Q", "R")
INPUT_NAMES = ("u_gondola", "mu", "u_tail")
STANDARD_GRAVITY = 9.80665  # as validation.vehicles.blimp
#: Arrays per GP part and their number of dimensions.
PER_PART = {"basis": 2, "weights": 2, "variance_factor": 2, "kernel_weights": 1,
            "log_signal_variance": 0, "input_mean": 1, "input_scale": 1, "output_mean": 1,
            "output_scale": 1}


def pack_model(*, parameter_names, parameters, max_step: float, state_columns, envelope_low,
               envelope_high, parts) -> dict:
    """Arrays for ``numpy.savez`` (module docstring); ``parts`` is a list of dicts of
    :data:`PER_PART` arrays."""
    arrays = {"format": np.array(FORMAT), "version": np.array(VERSION),
              "parameter_names": np.array(list(parameter_names), dtype=str),
              "parameters": np.asarray(parameters, dtype=float), "max_step": np.array(float(max_step)),
              "state_columns": np.asarray(state_columns, dtype=np.int64),
              "envelope_low": np.asarray(envelope_low, dtype=float),
              "envelope_high": np.asarray(envelope_high, dtype=float)}
    for p, part in enumerate(parts):
        for name in PER_PART:
            arrays[f"{p}/{name}"] = np.asarray(part[name], dtype=float)
    return arrays


def blimp_rkgp_variables(*, inputs, states) -> tuple:
    """The variable table of the blimp RKGP FMU.

    Parameters
    ----------
    inputs : sequence of (name, unit, limit, phrase)
        The commands: name, unit (a key of :data:`._base.UNITS`), largest magnitude, phrase.
    states : sequence of (name, unit, limit, phrase, start)
        The states, with the default start value (the hanging equilibrium).

    Returns
    -------
    tuple of Variable
        Commands (inputs); states and their one-step standard deviations (outputs); each
        state's start value (fixed parameters ``<state>_start``).
    """
    limits = lambda limit: (None, None) if limit is None else (-limit, limit)  # noqa: E731
    table = [Variable(name, "input", "continuous", None, unit,
                      f"{phrase}, held from this communication point to the next", 0.0, *limits(limit))
             for name, unit, limit, phrase in inputs]
    table += [Variable(name, "output", "continuous", "exact", unit,
                       f"{phrase}: RK4 physics plus GP residual mean (mean rollout)", start)
              for name, unit, _, phrase, start in states]
    table += [Variable(f"{name}_sd", "output", "continuous", "exact", unit,
                       f"one-step standard deviation of the {phrase}: latent GP residual sd of the "
                       "last step given the state before it (0 at the start)", 0.0)
              for name, unit, _, phrase, _ in states]
    table += [Variable(f"{name}_start", "parameter", "fixed", "exact", unit,
                       f"{phrase} at the start time (default: at rest at the origin, hanging)", start,
                       *limits(limit))
              for name, unit, limit, phrase, start in states]
    return tuple(table)


class BlimpParameterSet:
    """The ``BlimpParameters`` fields the ODE needs, from the model file's named vector."""

    def __init__(self, names, values) -> None:
        vector = dict(zip((str(n) for n in names), (float(v) for v in values)))
        triple = lambda field: np.array([vector[f"{field}_{a}"] for a in "xyz"])  # noqa: E731
        self.mass = vector["mass"]
        self.added_mass, self.inertia = triple("added_mass"), triple("inertia")
        self.added_inertia, self.rotational_damping = triple("added_inertia"), triple("rotational_damping")
        self.linear_drag, self.quadratic_drag = triple("linear_drag"), triple("quadratic_drag")
        self.cg_position = triple("cg_position")
        for name in ("net_lift", "gondola_thrust_forward", "gondola_thrust_backward", "gondola_arm",
                     "tail_thrust_positive", "tail_thrust_negative", "tail_arm", "fin_lift"):
            setattr(self, name, vector[name])
        # M = M_RB + M_A about the CB (Fossen 2011, eq. 3.44; as validation.vehicles.blimp.mass_matrix).
        rx, ry, rz = self.cg_position
        skew = np.array([[0.0, -rz, ry], [rz, 0.0, -rx], [-ry, rx, 0.0]])
        matrix = np.zeros((6, 6))
        matrix[:3, :3] = self.mass * np.eye(3)
        matrix[:3, 3:] = -self.mass * skew
        matrix[3:, :3] = self.mass * skew
        matrix[3:, 3:] = np.diag(self.inertia)
        matrix += np.diag(np.concatenate([self.added_mass, self.added_inertia]))
        self.matrix, self.inverse = matrix, np.linalg.inv(matrix)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def blimp_dynamics(state: np.ndarray, inputs: np.ndarray, P: BlimpParameterSet) -> np.ndarray:
    """``d state / dt``, state (12,), inputs (3,): :func:`validation.vehicles.blimp.blimp_dynamics`
    (Ko et al. 2007, sec. III, in Fossen's form; equations and sources there)."""
    angles, nu = state[3:6], state[6:12]
    v, w = nu[:3], nu[3:]
    sf, cf = np.sin(angles[0]), np.cos(angles[0])
    st, ct = np.sin(angles[1]), np.cos(angles[1])
    sp, cp = np.sin(angles[2]), np.cos(angles[2])
    rotation = np.array([cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st,
                         sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf,
                         -st, ct * sf, ct * cf]).reshape(3, 3)
    position_dot = np.einsum("ij,j->i", rotation, v)
    tt = np.tan(angles[1])
    p, q, r = w
    angles_dot = np.array([p + sf * tt * q + cf * tt * r, cf * q - sf * r, (sf * q + cf * r) / ct])

    generalised_momentum = nu @ P.matrix.T
    momentum, angular_momentum = generalised_momentum[:3], generalised_momentum[3:]
    down = np.array([-np.sin(angles[1]), np.cos(angles[1]) * np.sin(angles[0]),
                     np.cos(angles[1]) * np.cos(angles[0])])
    weight = P.mass * STANDARD_GRAVITY

    u_gondola, mu, u_tail = inputs
    gondola = u_gondola * (P.gondola_thrust_forward if u_gondola >= 0 else P.gondola_thrust_backward)
    tail = u_tail * (P.tail_thrust_positive if u_tail >= 0 else P.tail_thrust_negative)
    thrust_force = np.array([gondola * np.cos(mu), -tail, -gondola * np.sin(mu)])
    thrust_moment = np.array([0.0, P.gondola_arm * gondola * np.cos(mu), P.tail_arm * tail])
    fin_gain = P.fin_lift * np.abs(v[0])
    fin_side = -fin_gain * (v[1] - P.tail_arm * w[2])
    fin_normal = -fin_gain * (v[2] + P.tail_arm * w[1])
    fin_force = np.array([0.0, fin_side, fin_normal])
    fin_moment = np.array([0.0, P.tail_arm * fin_normal, -P.tail_arm * fin_side])

    force = (thrust_force + fin_force - P.net_lift * down
             - P.linear_drag * v - P.quadratic_drag * np.abs(v) * v
             - _cross(w, momentum))
    moment = (thrust_moment + fin_moment + _cross(P.cg_position, weight * down)
              - P.rotational_damping * w
              - _cross(v, momentum) - _cross(w, angular_momentum))
    nu_dot = np.concatenate([force, moment]) @ P.inverse.T
    return np.concatenate([position_dot, angles_dot, nu_dot])


def physics_step(state: np.ndarray, commands: np.ndarray, dt: float, P: BlimpParameterSet,
                 max_step: float) -> np.ndarray:
    """RK4 over ``dt`` in equal substeps no longer than ``max_step``, commands held
    (:func:`validation.models.blimp_identification.physics_step` for one state)."""
    n_sub = max(1.0, math.ceil(dt / max_step - 1e-9))
    h = dt / n_sub
    for _ in range(int(n_sub)):
        k1 = blimp_dynamics(state, commands, P)
        k2 = blimp_dynamics(state + 0.5 * h * k1, commands, P)
        k3 = blimp_dynamics(state + 0.5 * h * k2, commands, P)
        k4 = blimp_dynamics(state + h * k3, commands, P)
        state = state + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return state


class RKGPModel:
    """A blimp RKGP model loaded from an FMU model file (module docstring)."""

    def __init__(self, arrays: dict) -> None:
        try:
            if str(arrays["format"]) != FORMAT or int(arrays["version"]) != VERSION:
                raise ValueError(f"not a {FORMAT} model file of version {VERSION}")
            self.params = BlimpParameterSet(arrays["parameter_names"], arrays["parameters"])
            self.max_step = float(arrays["max_step"])
            self.state_columns = np.asarray(arrays["state_columns"], dtype=int)
            envelope_low, envelope_high = arrays["envelope_low"], arrays["envelope_high"]
            self.parts, p = [], 0
            while f"{p}/basis" in arrays:
                part = {n: np.array(arrays[f"{p}/{n}"], dtype=float, order="C") for n in PER_PART}
                if any(part[n].ndim != ndim for n, ndim in PER_PART.items()):
                    raise ValueError(f"part {p}: arrays of the wrong number of dimensions")
                part["signal_variance"] = np.array(np.exp(part["log_signal_variance"]))
                for value in part.values():
                    value.flags.writeable = False  # shared by every instance in the process
                self.parts.append(part)
                p += 1
        except KeyError as error:
            raise ValueError(f"model file lacks the array {error}") from None
        d = len(self.state_columns) + len(INPUT_NAMES) + 1
        outputs = sum(part["weights"].shape[1] for part in self.parts)
        if (outputs != len(STATE_NAMES) or np.shape(envelope_low) != (d,) or np.shape(envelope_high) != (d,)
                or any(part["basis"].shape[1] != d for part in self.parts)):
            raise ValueError(f"the GP parts must map {d} inputs to {len(STATE_NAMES)} residuals")
        if not self.max_step > 0:
            raise ValueError(f"max_step must be positive, got {self.max_step}")
        self.input_names = tuple(STATE_NAMES[c] for c in self.state_columns) + INPUT_NAMES + ("dt",)
        self.envelope = Envelope(envelope_low, envelope_high, self.input_names)

    @classmethod
    def load(cls, path) -> RKGPModel:
        with np.load(path, allow_pickle=False) as npz:
            return cls({name: npz[name] for name in npz.files})

    def step_range(self) -> tuple[float, float]:
        """Communication steps (s) the model accepts: the training range of ``dt`` plus the
        envelope margin and the base's time tolerance (evenly sampled training data has one
        ``dt``, up to rounding)."""
        slack = TIME_TOLERANCE * float(self.envelope.high[-1])
        return float(self.envelope.lower[-1]) - slack, float(self.envelope.upper[-1]) + slack

    def gp_input(self, state: np.ndarray, commands: np.ndarray, dt: float) -> np.ndarray:
        return np.concatenate([state[self.state_columns], commands, [dt]])

    def residual(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Latent mean and variance of the 12 residuals at GP input ``x`` (d,), as
        ``GaussianProcess.predict(return_var=True)`` (R&W Alg. 2.1, lines 4-6)."""
        means, variances = [], []
        for part in self.parts:
            xs = (x - part["input_mean"]) / part["input_scale"]
            k = kernel_rows(xs, part["basis"], part["kernel_weights"][None], part["log_signal_variance"][None])[0]
            mean = k @ part["weights"]  # (q,)
            v = part["variance_factor"] @ k
            latent = max(float(part["signal_variance"] - v @ v), 0.0)
            # The one-component mixture of GaussianProcess.predict, rounding included.
            var = np.maximum((latent + mean**2) - mean**2, 0.0)
            means.append(mean * part["output_scale"] + part["output_mean"])
            variances.append(var * part["output_scale"] ** 2)
        return np.concatenate(means), np.concatenate(variances)

    def step(self, state: np.ndarray, commands: np.ndarray, dt: float):
        """Next state (mean), the residual variance (12,) and the GP input of this step."""
        x = self.gp_input(state, commands, dt)
        mean, var = self.residual(x)
        return physics_step(state, commands, dt, self.params, self.max_step) + mean, var, x

    def describe(self) -> str:
        return json.dumps({"gp_inputs": list(self.input_names), "gp_parts": len(self.parts),
                           "basis_points": int(self.parts[0]["basis"].shape[0]),
                           "max_step_s": self.max_step, "step_range_s": list(self.step_range())})


class BlimpRKGP(FlightgpSlave):
    """Blimp RKGP (the generated subclass sets PACKAGE, DEFAULT_STEP_SIZE and VARIABLES)."""

    PACKAGE = ""
    STATE_ATTRIBUTES = ("_state", "_outside_envelope")
    CONSTANT_ATTRIBUTES = ("_model",)

    def load_constants(self) -> None:
        self._model = self.shared_model(RKGPModel.load, Path(self.resources) / self.PACKAGE / MODEL_FILE,
                                        "blimp RKGP model")

    def step_problem(self, h: float) -> str | None:
        low, high = self._model.step_range()
        if not low <= h <= high:
            return (f"communicationStepSize {h:.16g} s is outside {low:.6g} .. {high:.6g} s, the "
                    "frame intervals the GP residual was trained on (plus 10 %); step with the "
                    "default experiment's step size")
        return None

    def start_model(self, t0: float) -> None:
        self._state = np.array([self.values[f"{name}_start"] for name in STATE_NAMES])
        self._outside_envelope = False
        self._set_outputs(self._state, np.zeros(len(STATE_NAMES)))

    def advance_model(self, k: int, t: float, h: float) -> None:
        commands = np.array([self.values[name] for name in INPUT_NAMES])
        state, var, x = self._model.step(self._state, commands, h)
        if not (np.isfinite(state).all() and np.isfinite(var).all()):
            raise FloatingPointError(f"non-finite state {state.tolist()} at t = {t + h:.16g} s")
        outside = self.report_envelope(self._model.envelope.outside(x), self._outside_envelope, t + h,
                                       "its standard deviations grow")
        # Commit only after everything that can fail (a refused step leaves the state as it was).
        self._state, self._outside_envelope = state, outside
        self._set_outputs(state, var)

    def _set_outputs(self, state: np.ndarray, var: np.ndarray) -> None:
        for name, value, variance in zip(STATE_NAMES, state.tolist(), var.tolist()):
            self.values[name] = value
            self.values[f"{name}_sd"] = math.sqrt(variance)
