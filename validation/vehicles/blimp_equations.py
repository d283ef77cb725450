"""The blimp's equations of motion, once: numpy and the standard library only.

The blimp physics reference and its flight-test stand-in (:mod:`validation.vehicles.blimp`,
:mod:`validation.vehicles.blimp_flight`), the grey-box physics of identification
(:func:`validation.models.blimp_identification.physics_step`) and the blimp RKGP FMU all
evaluate these functions, so they agree to rounding. The FMU carries a copy of this file
(docs/fmus.md, "Blimp RKGP"), which is why it imports nothing else and checks no arguments:
:mod:`validation.vehicles.blimp` checks what users hand in. The native FMU repeats the formulas
in C, in the same order (``fmu_src/blimp_rkgp/blimp_model.c``, tested against these to 1e-9).

Conventions (docs/conventions.md, "Units and axes"): earth axes NED, body axes x forward,
y right, z down, origin at the centre of buoyancy (CB). State (:data:`STATE_NAMES`)
``x, y, z, phi, theta, psi, U, V, W, P, Q, R`` (earth position, m; ZYX Euler angles, rad; body
velocities, m/s; body rates, rad/s); inputs (:data:`INPUT_NAMES`) ``u_gondola`` (-1..1, positive pushes forward),
``mu`` (rad, gondola thrust angle, positive tilts the thrust up), ``u_tail`` (-1..1, positive
yaws the nose right).

Parameters: any object with the fields of :class:`validation.vehicles.blimp.BlimpParameters`
(SI units; scalars as floats, the (x, y, z) triples as tuples of three floats, which
:func:`mass_matrix` needs hashable). As one named vector (identification, model files, the FMU's
model file): :func:`parameter_names`, :func:`parameter_vector` and :func:`parameters_from_vector`,
a scalar field ``f`` as the entry ``f``, a triple as ``f_x, f_y, f_z``.

Equations of motion
-------------------
Ko, Klein, Fox & Haehnel, "Gaussian processes and reinforcement learning for identification and
control of an autonomous blimp", ICRA 2007, sec. III: rigid body with added mass, gravity,
buoyancy, drag, gondola thrust at vectoring angle ``mu``, tail motor and rotational drag. We
write it in Fossen's matrix form (Fossen, *Handbook of Marine Craft Hydrodynamics and Motion
Control*, 2011), the form in which Zufferey et al. (2006) give the EPFL blimp model::

    eta_dot = J(eta) nu                                  (Fossen 2011, sec. 2.2.1)
    M nu_dot + C(nu) nu + D(nu) nu + g(eta) = tau_thrust

with ``M = M_RB + M_A`` (rigid body about the CB with the CG at ``r_g``, Fossen 2011 eq. 3.44,
plus diagonal added mass), ``C`` from ``M`` by Fossen 2011 Theorem 3.2 (Sagatun & Fossen 1991;
it includes Munk's moment ``v x p``), linear and quadratic translational drag and linear
rotational damping (Zufferey et al. 2006), weight at the CG and buoyancy at the CB (Fossen 2011,
sec. 4.1), and quasi-steady tail-fin lift. Ko et al. write ``v_dot = M^-1 (F - w x M v)``,
``w_dot = J^-1 (T - w x J w)``: this model with ``r_g = 0``, no fins and no Munk moment. We keep
Munk's moment because without it the added-mass Coriolis force does work
(``-v . (w x M v) != 0`` for unequal added masses), so energy would not be conserved. With it a
finless hull is directionally unstable (straight flight at 0.84 m/s diverges in yaw at about
1.1 /s with the default parameters), which is why real blimps carry tail fins; the fin term
restores weathercock stability (slowest yaw/sway eigenvalue about -0.25 /s at 0.84 m/s).
"""
from __future__ import annotations

import functools

import numpy as np

#: State names, in the order of the last axis of every state array.
STATE_NAMES = ("x", "y", "z", "phi", "theta", "psi", "U", "V", "W", "P", "Q", "R")
#: Input names, in the order of the last axis of every input array.
INPUT_NAMES = ("u_gondola", "mu", "u_tail")

#: Standard gravity, m/s^2 (ISO 80000-3).
STANDARD_GRAVITY = 9.80665

#: Suffixes of the three entries of a parameter vector that hold one (x, y, z) triple.
AXIS_SUFFIXES = ("_x", "_y", "_z")

#: An interval counts as a whole number n of ``max_step`` substeps when it exceeds n ``max_step``
#: by less than this fraction of ``max_step`` (the rounding of a frame time, not a longer frame).
SUBSTEP_ROUNDING = 1e-9


def parameter_names(fields) -> tuple[str, ...]:
    """Names of the entries of :func:`parameter_vector`.

    Parameters
    ----------
    fields : mapping of str -> float or tuple of 3 floats
        Parameter name -> value, in the vector's order.

    Returns
    -------
    tuple of str
        A scalar ``f`` as ``f``, a triple ``f`` as ``f_x, f_y, f_z`` (:data:`AXIS_SUFFIXES`).
    """
    names = []
    for name, value in fields.items():
        names += [name + axis for axis in AXIS_SUFFIXES] if isinstance(value, tuple) else [name]
    return tuple(names)


def parameter_vector(fields) -> np.ndarray:
    """The values of ``fields`` (as :func:`parameter_names`) as one flat array, shape
    (n_entries,), SI units, in :func:`parameter_names` order."""
    return np.concatenate([np.atleast_1d(np.asarray(value, dtype=float)) for value in fields.values()])


def parameters_from_vector(names, vector) -> dict:
    """Inverse of :func:`parameter_vector`: parameter name -> value, in order.

    Parameters
    ----------
    names : sequence of str
        :func:`parameter_names` of the vector: three consecutive entries ``f_x, f_y, f_z`` make
        the triple ``f``, any other entry the scalar of its name.
    vector : array_like, shape (len(names),)

    Returns
    -------
    dict of str -> float or tuple of 3 floats
    """
    names, values = [str(name) for name in names], [float(value) for value in vector]
    fields, i = {}, 0
    while i < len(names):
        stem = names[i][:-len(AXIS_SUFFIXES[0])]
        if tuple(names[i:i + 3]) == tuple(stem + axis for axis in AXIS_SUFFIXES):
            fields[stem], i = tuple(values[i:i + 3]), i + 3
        else:
            fields[names[i]], i = values[i], i + 1
    return fields


@functools.lru_cache(maxsize=64)
def mass_matrix(mass, added_mass, inertia, added_inertia, cg_position) -> tuple[np.ndarray, np.ndarray]:
    """System inertia matrix ``M = M_RB + M_A`` (6, 6) about the CB and its inverse (6, 6).

    ``M_RB = [[m I, -m S(r_g)], [m S(r_g), I_o]]`` (Fossen 2011, eq. 3.44; ``S(a) b = a x b``),
    ``M_A = diag(added_mass, added_inertia)`` (diagonal, as identified by Zufferey et al. 2006).

    Parameters
    ----------
    mass : float
        kg.
    added_mass, inertia, added_inertia, cg_position : tuple of 3 floats
        kg, kg m^2, kg m^2 and m (hashable: the result is cached per parameter set).
    """
    rx, ry, rz = cg_position
    skew = np.array([[0.0, -rz, ry], [rz, 0.0, -rx], [-ry, rx, 0.0]])
    matrix = np.zeros((6, 6))
    matrix[:3, :3] = mass * np.eye(3)
    matrix[:3, 3:] = -mass * skew
    matrix[3:, :3] = mass * skew
    matrix[3:, 3:] = np.diag(inertia)
    matrix += np.diag(np.concatenate([added_mass, added_inertia]))
    return matrix, np.linalg.inv(matrix)


def rotation_body_to_earth(angles: np.ndarray) -> np.ndarray:
    """ZYX Euler rotation matrix body -> earth (Fossen 2011, sec. 2.2.1); angles (..., 3), rad
    -> (..., 3, 3)."""
    sf, cf = np.sin(angles[..., 0]), np.cos(angles[..., 0])
    st, ct = np.sin(angles[..., 1]), np.cos(angles[..., 1])
    sp, cp = np.sin(angles[..., 2]), np.cos(angles[..., 2])
    return _rotation(sf, cf, st, ct, sp, cp)


def _rotation(sf, cf, st, ct, sp, cp) -> np.ndarray:
    """:func:`rotation_body_to_earth` from the sines and cosines of roll, pitch and yaw."""
    rotation = np.empty(np.shape(sf) + (3, 3))
    rotation[..., 0, 0] = cp * ct
    rotation[..., 0, 1] = -sp * cf + cp * st * sf
    rotation[..., 0, 2] = sp * sf + cp * cf * st
    rotation[..., 1, 0] = sp * ct
    rotation[..., 1, 1] = cp * cf + sf * st * sp
    rotation[..., 1, 2] = -cp * sf + st * sp * cf
    rotation[..., 2, 0] = -st
    rotation[..., 2, 1] = ct * sf
    rotation[..., 2, 2] = ct * cf
    return rotation


def euler_rates(angles: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Euler angle rates (..., 3), rad/s, from body rates (..., 3), rad/s, at ``angles``
    (..., 3), rad: ``Theta_dot = T(Theta) omega`` (Fossen 2011, sec. 2.2.1).

    Singular at ``theta = +-90 deg``, which a pendulum-stabilised blimp does not reach.
    """
    sf, cf = np.sin(angles[..., 0]), np.cos(angles[..., 0])
    ct, tt = np.cos(angles[..., 1]), np.tan(angles[..., 1])
    p, q, r = rates[..., 0], rates[..., 1], rates[..., 2]
    return np.stack([p + sf * tt * q + cf * tt * r, cf * q - sf * r, (sf * q + cf * r) / ct], axis=-1)


def body_rates(angles: np.ndarray, euler_rates: np.ndarray) -> np.ndarray:
    """Body rates (..., 3), rad/s, from Euler angle rates (..., 3), rad/s, at ``angles`` (..., 3),
    rad: ``omega = T(Theta)^-1 Theta_dot`` (Fossen 2011, sec. 2.2.1; inverse of :func:`euler_rates`)."""
    sf, cf = np.sin(angles[..., 0]), np.cos(angles[..., 0])
    st, ct = np.sin(angles[..., 1]), np.cos(angles[..., 1])
    df, dt, dp = euler_rates[..., 0], euler_rates[..., 1], euler_rates[..., 2]
    return np.stack([df - st * dp, cf * dt + sf * ct * dp, -sf * dt + cf * ct * dp], axis=-1)


def states_from_poses(positions: np.ndarray, angles: np.ndarray, position_rates: np.ndarray,
                      angle_rates: np.ndarray) -> np.ndarray:
    """Full states from poses and their time derivatives, as motion capture measures them.

    Body velocity ``v = R(Theta)^T p_dot`` (:func:`rotation_body_to_earth`) and body rates from
    the Euler angle rates (:func:`body_rates`), at the given attitude.

    Parameters
    ----------
    positions, position_rates : ndarray, shape (n, 3)
        Earth position, m, and its derivative, m/s.
    angles, angle_rates : ndarray, shape (n, 3)
        ZYX Euler angles, rad, and their derivatives, rad/s.

    Returns
    -------
    ndarray, shape (n, 12)
        ``x, y, z, phi, theta, psi, U, V, W, P, Q, R``.
    """
    velocity = np.einsum("nji,nj->ni", rotation_body_to_earth(angles), position_rates)
    return np.concatenate([positions, angles, velocity, body_rates(angles, angle_rates)], axis=1)


#: Columns of ``[v, w]`` for the cross products ``v x p``, ``w x p`` and ``w x h`` of
#: :func:`blimp_dynamics` at once: ``a x b = a[1, 2, 0] b[2, 0, 1] - a[2, 0, 1] b[1, 2, 0]``, with
#: ``a`` = ``[v, w, w]`` taken from ``nu`` and ``b`` = ``[p, p, h]`` from ``M nu``.
_CROSS_A1 = np.array([1, 2, 0, 4, 5, 3, 4, 5, 3])
_CROSS_A2 = np.array([2, 0, 1, 5, 3, 4, 5, 3, 4])
_CROSS_B1 = np.array([1, 2, 0, 1, 2, 0, 4, 5, 3])
_CROSS_B2 = np.array([2, 0, 1, 2, 0, 1, 5, 3, 4])


def blimp_dynamics(state: np.ndarray, inputs: np.ndarray, params) -> np.ndarray:
    """Time derivative of the blimp state (Ko et al. 2007, sec. III, in Fossen's form).

    Parameters
    ----------
    state : ndarray, shape (..., 12)
        ``x, y, z, phi, theta, psi, U, V, W, P, Q, R`` (m, rad, m/s, rad/s).
    inputs : ndarray, shape (..., 3)
        ``u_gondola`` (-1..1), ``mu`` (rad), ``u_tail`` (-1..1); leading axes broadcast
        against those of ``state``.
    params : BlimpParameters or an object with its fields (module docstring)

    Returns
    -------
    ndarray, shape (broadcast leading axes, 12)
        ``d state / dt`` in the units of ``state`` per second.

    Notes
    -----
    Forces and moments on ``nu = [v, w]`` (body velocity, body rate):

    - inertia: ``p = M11 v + M12 w``, ``h = M21 v + M22 w`` and ``C(nu) nu = [w x p, v x p + w x h]``
      (Fossen 2011, Theorem 3.2; ``nu' C nu = 0``, so it does no work);
    - gravity and buoyancy: with ``n = R' e_z = [-sin theta, cos theta sin phi, cos theta cos phi]``
      the earth down direction in body axes, force ``-net_lift n`` and moment
      ``r_g x (m g n)`` (Fossen 2011, sec. 4.1, buoyancy at the origin);
    - drag: ``-(linear_drag v + quadratic_drag |v| v)`` and ``-rotational_damping w``
      (Zufferey et al. 2006);
    - gondola: thrust ``T = k u`` (k forward or backward gain) along ``[cos mu, 0, -sin mu]``
      acting ``gondola_arm`` below the CB, so pitch moment ``gondola_arm T cos mu``;
    - tail: thrust ``T_t`` pushing the tail left (force ``[0, -T_t, 0]``) ``tail_arm`` behind
      the CB, so yaw moment ``tail_arm T_t``;
    - tail fins, ``l = tail_arm`` behind the CB, where the body moves through the air with
      cross-flow ``c = [V - l R, W + l Q]``: quasi-steady lift ``-fin_lift |U| c`` in y and z,
      so moments ``M = -l fin_lift |U| (W + l Q)`` and ``N = l fin_lift |U| (V - l R)``
      (weathercock stability and damping; it only dissipates energy).
    """
    angles, nu = state[..., 3:6], state[..., 6:12]
    v, w = nu[..., :3], nu[..., 3:]
    matrix, inverse = mass_matrix(params.mass, params.added_mass, params.inertia,
                                  params.added_inertia, params.cg_position)
    # The formulas above term by term, each sum in its order (a - b as a + (-b) is the same
    # rounding): small arrays, so the number of numpy calls, not the arithmetic, sets the cost.
    sf, cf = np.sin(angles[..., 0]), np.cos(angles[..., 0])
    st, ct = np.sin(angles[..., 1]), np.cos(angles[..., 1])
    sp, cp = np.sin(angles[..., 2]), np.cos(angles[..., 2])
    tt = np.tan(angles[..., 1])

    u_gondola, mu, u_tail = inputs[..., 0], inputs[..., 1], inputs[..., 2]
    gondola = u_gondola * np.where(u_gondola >= 0, params.gondola_thrust_forward,
                                   params.gondola_thrust_backward)
    tail = u_tail * np.where(u_tail >= 0, params.tail_thrust_positive, params.tail_thrust_negative)
    cos_mu = np.cos(mu)
    arm = params.tail_arm
    fin_gain = params.fin_lift * np.abs(v[..., 0])
    fin_side = -fin_gain * (v[..., 1] - arm * w[..., 2])
    fin_normal = -fin_gain * (v[..., 2] + arm * w[..., 1])
    side_force = -tail + fin_side  # thrust plus fins, y
    leading = np.shape(side_force)  # of state and inputs, broadcast

    derivative = np.empty(leading + (12,))
    derivative[..., :3] = np.einsum("...ij,...j->...i", _rotation(sf, cf, st, ct, sp, cp), v)
    p, q, r = w[..., 0], w[..., 1], w[..., 2]  # Euler angle rates (euler_rates)
    derivative[..., 3] = p + sf * tt * q + cf * tt * r
    derivative[..., 4] = cf * q - sf * r
    derivative[..., 5] = (sf * q + cf * r) / ct

    # [force, moment]: thrust + fins, then - net_lift n and + r_g x (m g n), then the drag and
    # damping, then - quadratic drag and - v x p, then - w x p and - w x h.
    generalised_momentum = nu @ matrix.T  # [p, h] = M nu
    tau = np.empty(leading + (6,))
    tau[..., 0] = gondola * cos_mu + 0.0
    tau[..., 1] = side_force
    tau[..., 2] = -gondola * np.sin(mu) + fin_normal
    tau[..., 3] = 0.0
    tau[..., 4] = params.gondola_arm * gondola * cos_mu + arm * fin_normal
    tau[..., 5] = arm * tail + -arm * fin_side
    down = np.empty(np.shape(sf) + (5,))  # n, then n[0], n[1] again: n[1, 2, 0] and n[2, 0, 1] are slices
    down[..., 0] = -st
    down[..., 1] = ct * sf
    down[..., 2] = ct * cf
    down[..., 3:] = down[..., :2]
    weight_down = params.mass * STANDARD_GRAVITY * down
    cg = np.asarray(params.cg_position)
    tau[..., :3] -= params.net_lift * down[..., :3]
    tau[..., 3:] += (cg.take(_CROSS_A1[:3], axis=-1) * weight_down[..., 2:]
                     - cg.take(_CROSS_A2[:3], axis=-1) * weight_down[..., 1:4])
    tau[..., :3] -= np.asarray(params.linear_drag) * v
    tau[..., 3:] -= np.asarray(params.rotational_damping) * w
    crosses = (nu.take(_CROSS_A1, axis=-1) * generalised_momentum.take(_CROSS_B2, axis=-1)
               - nu.take(_CROSS_A2, axis=-1) * generalised_momentum.take(_CROSS_B1, axis=-1))  # v x p, w x p, w x h
    tau[..., :3] -= np.asarray(params.quadratic_drag) * np.abs(v) * v
    tau[..., 3:] -= crosses[..., :3]
    tau -= crosses[..., 3:]
    derivative[..., 6:] = tau @ inverse.T
    return derivative


def rk4(derivative, state: np.ndarray, dt) -> np.ndarray:
    """One classical fourth-order Runge-Kutta step of ``state_dot = derivative(state)`` over
    ``dt`` seconds (a float, or an array broadcasting against ``state``)."""
    k1 = derivative(state)
    k2 = derivative(state + 0.5 * dt * k1)
    k3 = derivative(state + 0.5 * dt * k2)
    k4 = derivative(state + dt * k3)
    return state + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def substep_count(dt, max_step: float) -> np.ndarray:
    """Number of equal RK4 substeps, none longer than ``max_step``, for intervals ``dt`` (s, any
    shape): ``ceil(dt / max_step)``, at least 1 (less :data:`SUBSTEP_ROUNDING`, so that an
    interval of n ``max_step`` up to rounding takes n substeps, not n + 1)."""
    return np.maximum(1, np.ceil(np.asarray(dt, dtype=float) / max_step - SUBSTEP_ROUNDING)).astype(int)


def rk4_advance(state: np.ndarray, inputs: np.ndarray, dt, params, *, max_step: float) -> np.ndarray:
    """The blimp ``dt`` seconds later, the inputs held: classical RK4 in equal substeps no longer
    than ``max_step`` (:func:`substep_count`).

    Parameters
    ----------
    state : ndarray, shape (..., 12)
    inputs : ndarray, shape (..., 3)
        Held over the interval; leading axes broadcast against those of ``state``.
    dt : float or ndarray, shape (...)
        Interval, s; one per row of ``state`` (each row takes its own number of substeps).
    params : BlimpParameters or an object with its fields (module docstring)
    max_step : float
        Longest substep, s.

    Returns
    -------
    ndarray, shape (broadcast leading axes, 12)
    """
    dt = np.asarray(dt, dtype=float)[..., None]
    substeps = substep_count(dt, max_step)
    h = dt / substeps
    for i in range(int(substeps.max())):
        stepped = rk4(lambda s: blimp_dynamics(s, inputs, params), state, h)
        state = np.where(i < substeps, stepped, state)  # rows with fewer substeps are done
    return state
