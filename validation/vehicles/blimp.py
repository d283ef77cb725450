"""Ko-type indoor blimp: the physics reference ``blimp`` and the flight-test stand-in ``blimp-flight``.

Conventions (docs/conventions.md, "Units and axes"; docs/vehicles.md, "Blimp"): earth axes NED,
body axes x forward, y right, z down, origin at the centre of buoyancy (CB). States
``x, y, z, phi, theta, psi, U, V, W, P, Q, R`` (earth position, m; ZYX Euler angles, rad; body
velocities, m/s; body rates, rad/s). Inputs ``u_gondola`` (-1..1, positive pushes forward),
``mu`` (rad, gondola thrust angle, positive tilts the thrust up), ``u_tail`` (-1..1, positive
yaws the nose right).

The equations of motion (Ko et al., ICRA 2007, sec. III, in Fossen's 2011 matrix form) live in
:mod:`validation.vehicles.blimp_equations`, which the blimp RKGP FMU carries; this module adds
what a vehicle needs around them: the parameters, argument checks (:class:`BadInputError`), the
hanging start and the integrators of :class:`BlimpReference`.

The flight-test stand-in :class:`~validation.vehicles.blimp_flight.BlimpFlightTest` adds what
this ODE leaves out (motor lag, dead band, tail asymmetry, CG offset, buoyancy drift,
motion-capture timing, noise and differentiated velocities), effect by effect with numbers in its
docstring.

Parameters: scaling the EPFL blimp to Ko's blimp
------------------------------------------------
Zufferey, Guanella, Beyeler & Floreano (2006, EPFL LIS) identified a 0.184 kg indoor blimp
(its numbers are in the :class:`BlimpParameters` docstring). Ko et al.'s blimp weighs about 0.35 kg with a 1.7 m
envelope. We scale by Froude similarity (same g and air): mass ratio
``s_m = 0.35 / 0.184 = 1.902``; both float neutrally in the same air, so mass is proportional
to envelope volume and the length ratio is ``s_L = s_m ** (1/3) = 1.239``; then time scales as
``sqrt(s_L)`` and

=============================  ==========================  ==================================
quantity                       factor                      reason
=============================  ==========================  ==================================
mass, added mass, thrust       ``s_m``                     force ~ mass ~ volume
inertia                        ``s_m s_L**2``              mass times length squared
CG offset below the CB         ``s_L``                     length
quadratic translational drag   ``s_L**2``                  drag area (= ``s_m / s_L``)
linear rotational damping      ``s_m s_L**1.5``            keeps every damping ratio
=============================  ==========================  ==================================

The tail arm (0.85 m, half of Ko's 1.7 m envelope) and the gondola arm (0.35 m: the radius of a
1.7 m prolate envelope holding the 0.337 m^3 of helium that lifts 0.35 kg, 0.31 m, plus about
4 cm to the fan shaft, assumed) come from Ko's geometry directly. Air 1.204 kg/m^3 and helium
0.166 kg/m^3 at 20 deg C give the 1.038 kg/m^3 of lift.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.core.sampling import check_history, sampling_metadata
from validation.vehicles import blimp_equations
from validation.vehicles.blimp_equations import (
    INPUT_NAMES,
    STATE_NAMES,
    parameter_names,
    parameter_vector,
    parameters_from_vector,
    rk4_advance,
)

#: Mass ratio Ko blimp / EPFL blimp: 0.35 kg (Ko et al. 2007) / 0.184 kg (Zufferey et al. 2006).
MASS_RATIO = 0.35 / 0.184
#: Length ratio at equal mean density (mass ~ length**3), see the module docstring.
LENGTH_RATIO = MASS_RATIO ** (1.0 / 3.0)

SAMPLE_TIME = 0.05  # s, motion capture at about 20 Hz (Ko et al. 2007)
MAX_STEP = 0.01  # s, RK4 step; 0.05 rad per step at the 4.8 rad/s roll pendulum frequency
ADAPTIVE_RTOL = 1e-8  # solve_ivp tolerances for the adaptive ("ODE") integrator
ADAPTIVE_ATOL = 1e-10


def _scaled(values, factor: float) -> tuple[float, float, float]:
    return tuple(float(v) * factor for v in values)


def _field_width(field: dataclasses.Field) -> int:
    """3 for the (x, y, z) triples of :class:`BlimpParameters` (annotated ``tuple[...]``), else 1."""
    return 3 if str(field.type).startswith("tuple") else 1


@dataclass(frozen=True)
class BlimpParameters:
    """Physical parameters of the blimp ODE (SI units; body axes, origin at the CB).

    Defaults: the EPFL LIS blimp (Zufferey et al. 2006) scaled to Ko et al.'s 0.35 kg blimp by
    the rules in the module docstring. Triples are (x, y, z) body-axis components, or
    (roll, pitch, yaw) for rotational quantities. ``dataclasses.replace`` makes variants;
    :meth:`to_vector` / :meth:`from_vector` flatten them in the order of :meth:`vector_names`.

    Attributes
    ----------
    mass : float
        Rigid-body mass including the helium, kg. 0.184 kg * s_m = 0.35 kg.
    added_mass : (3,) tuple
        Added mass in surge, sway, heave, kg (positive numbers). EPFL [0.033, 0.129, 0.129] * s_m.
    inertia : (3,) tuple
        Principal moments of inertia about the CB, kg m^2. EPFL [0.0095, 0.0193, 0.0193]
        * s_m s_L^2. Zufferey et al. list no separate added inertia, so these stand for rigid plus
        added inertia.
    added_inertia : (3,) tuple
        Added moments of inertia in roll, pitch, yaw, kg m^2; default 0 (see ``inertia``).
    rotational_damping : (3,) tuple
        Linear rotational damping, N m s/rad. EPFL [0.005, 0.0079, 0.0079] * s_m s_L^1.5.
    linear_drag : (3,) tuple
        Linear translational damping, N s/m. Default 0: Zufferey et al. identified only the
        quadratic term.
    quadratic_drag : (3,) tuple
        Quadratic translational damping, N s^2/m^2 (force ``-k_i |v_i| v_i``). EPFL
        [0.07, 0.28, 0.22] * s_L^2.
    cg_position : (3,) tuple
        Centre of gravity relative to the CB, m. EPFL 0.125 m below the CB * s_L = 0.155 m.
    net_lift : float
        Buoyancy minus weight, N; positive rises. 0: neutrally buoyant.
    gondola_thrust_forward, gondola_thrust_backward : float
        Thrust of both gondola fans per unit ``u_gondola``, N, for positive / negative commands.
        EPFL 0.04 N * s_m = 0.076 N; Zufferey et al. give only the forward value, so symmetric.
    gondola_arm : float
        Distance of the gondola fan shaft below the CB, m (module docstring).
    tail_thrust_positive, tail_thrust_negative : float
        Tail fan thrust per unit ``u_tail``, N, for positive / negative commands. Assumed equal
        to one gondola fan, 0.038 N, both ways (the stand-in makes it stronger one way).
    tail_arm : float
        Distance of the tail fan and of the tail fins behind the CB, m: half of Ko's 1.7 m
        envelope.
    fin_lift : float
        Tail-fin lift per unit forward speed and cross-flow velocity at the fins, kg/m
        (``1/2 rho S a`` per fin plane). Assumed cruciform fins, two per plane of about
        0.08 m^2 (29 cm square) each, lift slope 2 /rad (slender-wing ``pi A / 2`` for aspect
        ratio 1.3): ``0.5 * 1.204 * 0.166 * 2 = 0.2`` kg/m. With less than about 0.14 kg/m the
        fins lose to the hull's Munk moment and straight flight diverges in yaw (module
        docstring).
    """

    mass: float = 0.184 * MASS_RATIO
    added_mass: tuple[float, float, float] = _scaled((0.033, 0.129, 0.129), MASS_RATIO)
    inertia: tuple[float, float, float] = _scaled(
        (0.0095, 0.0193, 0.0193), MASS_RATIO * LENGTH_RATIO**2)
    added_inertia: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotational_damping: tuple[float, float, float] = _scaled(
        (0.005, 0.0079, 0.0079), MASS_RATIO * LENGTH_RATIO**1.5)
    linear_drag: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quadratic_drag: tuple[float, float, float] = _scaled((0.07, 0.28, 0.22), LENGTH_RATIO**2)
    cg_position: tuple[float, float, float] = (0.0, 0.0, 0.125 * LENGTH_RATIO)
    net_lift: float = 0.0
    gondola_thrust_forward: float = 0.04 * MASS_RATIO
    gondola_thrust_backward: float = 0.04 * MASS_RATIO
    gondola_arm: float = 0.35
    tail_thrust_positive: float = 0.02 * MASS_RATIO
    tail_thrust_negative: float = 0.02 * MASS_RATIO
    tail_arm: float = 0.85
    fin_lift: float = 0.2

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            value, width = getattr(self, field.name), _field_width(field)
            try:
                values = tuple(float(v) for v in value) if width == 3 else (float(value),)
            except (TypeError, ValueError):
                values = ()
            if len(values) != width:
                raise BadInputError(
                    f"BlimpParameters.{field.name} needs {'3 numbers (x, y, z)' if width == 3 else 'one number'}"
                    f", got {value!r}")
            if not all(math.isfinite(v) for v in values):
                raise BadInputError(f"BlimpParameters.{field.name} must be finite, got {value!r}")
            object.__setattr__(self, field.name, values if width == 3 else values[0])

    @classmethod
    def vector_names(cls) -> tuple[str, ...]:
        """Names of the entries of :meth:`to_vector`: scalars by field name, triples as
        ``<field>_x``, ``<field>_y``, ``<field>_z``
        (:func:`validation.vehicles.blimp_equations.parameter_names`)."""
        return parameter_names({field.name: field.default for field in dataclasses.fields(cls)})

    def to_vector(self) -> np.ndarray:
        """All parameters as one flat array, shape (n_parameters,), in :meth:`vector_names` order
        (:func:`validation.vehicles.blimp_equations.parameter_vector`)."""
        return parameter_vector({field.name: getattr(self, field.name) for field in dataclasses.fields(self)})

    @classmethod
    def from_vector(cls, vector) -> BlimpParameters:
        """Inverse of :meth:`to_vector`; ``vector`` has shape (n_parameters,)
        (:func:`validation.vehicles.blimp_equations.parameters_from_vector`)."""
        vector = np.asarray(vector, dtype=float)
        names = cls.vector_names()
        if vector.shape != (len(names),):
            raise BadInputError(
                f"a BlimpParameters vector has {len(names)} entries ({', '.join(names)}), "
                f"got shape {vector.shape}")
        return cls(**parameters_from_vector(names, vector))


def _check_last_axis(array: np.ndarray, size: int, what: str, names) -> None:
    if array.ndim == 0 or array.shape[-1] != size:
        raise BadInputError(
            f"{what} must have shape (..., {size}) with columns {', '.join(names)}; got shape {array.shape}")


def blimp_dynamics(state, inputs, params: BlimpParameters) -> np.ndarray:
    """:func:`validation.vehicles.blimp_equations.blimp_dynamics`, the time derivative of the
    blimp state, after checking the arguments' shapes.

    Parameters
    ----------
    state : array_like, shape (..., 12)
        ``x, y, z, phi, theta, psi, U, V, W, P, Q, R`` (m, rad, m/s, rad/s).
    inputs : array_like, shape (..., 3)
        ``u_gondola`` (-1..1), ``mu`` (rad), ``u_tail`` (-1..1); leading axes broadcast
        against those of ``state``.
    params : BlimpParameters

    Returns
    -------
    ndarray, shape (broadcast leading axes, 12)
        ``d state / dt`` in the units of ``state`` per second.

    Raises
    ------
    BadInputError
        ``state`` or ``inputs`` has the wrong last axis.
    """
    state = np.asarray(state, dtype=float)
    inputs = np.asarray(inputs, dtype=float)
    _check_last_axis(state, len(STATE_NAMES), "state", STATE_NAMES)
    _check_last_axis(inputs, len(INPUT_NAMES), "inputs", INPUT_NAMES)
    return blimp_equations.blimp_dynamics(state, inputs, params)


def checked_max_step(max_step: float) -> float:
    """``max_step``, the longest RK4 substep, s, as a float.

    Raises
    ------
    BadInputError
        ``max_step`` is not a positive finite number.
    """
    if not (np.isfinite(max_step) and max_step > 0):
        raise BadInputError(f"max_step must be a positive number of seconds, got {max_step}")
    return float(max_step)


def check_command_history(time, inputs, *, min_samples: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """``time`` (n,) and ``inputs`` (n, 3) as float arrays, or :class:`BadInputError` saying where.

    The blimp accepts unevenly sampled time (motion-capture frames arrive with jitter); its
    commands must stay within -1..1.
    """
    time, inputs, _ = check_history(time, inputs, INPUT_NAMES, evenly_sampled=False)
    if len(time) < min_samples:
        raise BadInputError(f"time must have at least {min_samples} samples, got {len(time)}")
    for column in (0, 2):
        outside = np.flatnonzero(np.abs(inputs[:, column]) > 1.0)
        if outside.size:
            raise BadInputError(
                f"inputs row {outside[0]}, column {INPUT_NAMES[column]!r} is {inputs[outside[0], column]}, "
                "outside the command range -1..1")
    return time, inputs


def hanging_state(params: BlimpParameters) -> np.ndarray:
    """At rest at the origin, hanging with the CG straight below the CB (the static attitude).

    The down direction ``n = [-sin theta, cos theta sin phi, cos theta cos phi]`` (body axes)
    equal to ``r_g / |r_g|`` gives
    ``phi = atan2(y_g, z_g)``, ``theta = -asin(x_g / |r_g|)``; level for a CG on the z axis.
    """
    x_g, y_g, z_g = params.cg_position
    state = np.zeros(len(STATE_NAMES))
    distance = math.hypot(x_g, y_g, z_g)
    if distance > 0:
        state[3] = math.atan2(y_g, z_g)
        state[4] = -math.asin(x_g / distance)
    return state


class BlimpReference:
    """The ``blimp`` physics reference: :func:`blimp_dynamics` integrated without any extras.

    Parameters
    ----------
    params : BlimpParameters, optional
        Defaults to ``BlimpParameters()`` (EPFL blimp scaled to Ko's, module docstring).
    integrator : {"rk4", "adaptive"}
        Default method of :meth:`simulate_states`: fixed-step RK4 (Ko et al.'s "RK") or
        scipy's adaptive Dormand-Prince ``RK45`` (their "ODE"), rtol 1e-8, atol 1e-10.
    max_step : float
        Largest RK4 step, s; each sample interval is cut into equal steps no longer than this.

    Deterministic: ``simulate``'s ``seed`` is accepted for the :class:`~validation.vehicles.Vehicle`
    interface and ignored.
    """

    name = "blimp"
    input_names = INPUT_NAMES
    state_names = STATE_NAMES
    sample_time = SAMPLE_TIME

    def __init__(self, *, params: BlimpParameters | None = None, integrator: str = "rk4",
                 max_step: float = MAX_STEP) -> None:
        if integrator not in ("rk4", "adaptive"):
            raise BadInputError(f"integrator must be 'rk4' or 'adaptive', got {integrator!r}")
        self.params = params if params is not None else BlimpParameters()
        self.integrator = integrator
        self.max_step = checked_max_step(max_step)

    def simulate_states(self, time, inputs, *, initial_state=None, method: str | None = None) -> np.ndarray:
        """States at ``time`` with ``inputs[k]`` held over ``[time[k], time[k+1])``.

        Parameters
        ----------
        time : array_like, shape (n,)
            Strictly increasing sample times, s (n >= 2).
        inputs : array_like, shape (n, 3)
            ``u_gondola, mu, u_tail`` at each sample; the last row is never used.
        initial_state : array_like, shape (12,), optional
            State at ``time[0]``; default hover at rest at the origin in the static attitude.
        method : {"rk4", "adaptive"}, optional
            Default ``self.integrator``.

        Returns
        -------
        ndarray, shape (n, 12)
        """
        time, inputs = check_command_history(time, inputs)
        method = self.integrator if method is None else method
        if initial_state is None:
            initial_state = hanging_state(self.params)
        initial_state = np.asarray(initial_state, dtype=float)
        if initial_state.shape != (len(STATE_NAMES),) or not np.all(np.isfinite(initial_state)):
            raise BadInputError(f"initial_state must be 12 finite numbers ({', '.join(STATE_NAMES)}), "
                                f"got {initial_state}")
        if method == "rk4":
            return self._rk4_states(time, inputs, initial_state)
        if method == "adaptive":
            return self._adaptive_states(time, inputs, initial_state)
        raise BadInputError(f"method must be 'rk4' or 'adaptive', got {method!r}")

    def _rk4_states(self, time, inputs, state) -> np.ndarray:
        states = np.empty((len(time), len(STATE_NAMES)))
        states[0] = state
        for k in range(len(time) - 1):
            state = rk4_advance(state, inputs[k], time[k + 1] - time[k], self.params, max_step=self.max_step)
            states[k + 1] = state
        return states

    def _adaptive_states(self, time, inputs, state) -> np.ndarray:
        """One ``solve_ivp`` per run of equal inputs, so that no step straddles an input change."""
        changes = np.flatnonzero(np.any(np.diff(inputs[:-1], axis=0) != 0, axis=1)) + 1
        edges = np.concatenate(([0], changes, [len(time) - 1]))
        states = np.empty((len(time), len(STATE_NAMES)))
        states[0] = state
        for start, stop in zip(edges[:-1], edges[1:]):
            held = inputs[start]
            solution = solve_ivp(lambda _t, y, held=held: blimp_dynamics(y, held, self.params),
                                 (time[start], time[stop]), states[start], method="RK45",
                                 t_eval=time[start:stop + 1], rtol=ADAPTIVE_RTOL, atol=ADAPTIVE_ATOL)
            if not solution.success:
                raise RuntimeError(f"adaptive integration failed between t = {time[start]} and "
                                   f"{time[stop]} s: {solution.message}")
            states[start + 1:stop + 1] = solution.y.T[1:]
        return states

    def simulate(self, time, inputs, *, seed: int = 0) -> Recording:
        """Fly ``inputs`` and record all 12 states at ``time`` (see :meth:`simulate_states`)."""
        states = self.simulate_states(time, inputs)
        time = np.asarray(time, dtype=float)
        metadata = {"vehicle": self.name, "integrator": self.integrator,
                    "parameters": dict(zip(BlimpParameters.vector_names(),
                                           self.params.to_vector().tolist())),
                    **sampling_metadata(time)}
        return Recording(time, inputs, INPUT_NAMES, states, STATE_NAMES, metadata)


