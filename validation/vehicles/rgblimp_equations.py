"""The RGBlimp's first-principle model, once: numpy, the standard library and plain project modules.

The RGBlimp (robotic gliding blimp: a helium envelope with a pair of wings, two propellers and a
gondola mass that can be moved along the body) of Zhu, Cheng & Zhang, "Data-Driven Dynamics
Modeling of Miniature Robotic Blimps Using Neural ODEs With Parameter Auto-Tuning", IEEE
Robotics and Automation Letters, 2024 (arXiv 2404.18580). Their first-principle model is the
class ``RGBlimp`` of ``models/RGBlimp_dynamics.py`` in the repository ``zhu-yj/ABNODE`` (MIT
licence), with the parameter values of its ``utils/parameters.py``; it is integrated there by
one classical RK4 step per motion-capture sample (``utils/solvers.py``, ``RK_RGB``, step 1/60 s).
This module writes the same equations in numpy, vectorised over leading axes; the values of
:class:`RGBlimpParameters` are the source's. Like :mod:`validation.vehicles.blimp_equations` it
checks no array arguments (an FMU can carry it as it is); :class:`RGBlimpParameters` checks its
fields. docs/rgblimp.md describes the model and the port
test (``tests/validation/vehicles/test_rgblimp.py``), which reproduces the accelerations the
source stored in its recordings to 4e-10 m/s^2 (rad/s^2) with the coefficients they were
computed with (:data:`validation.vehicles.rgblimp_data.RECORDED_MODEL_PARAMETERS`) and to 1.1e-4
with the published ones, which are rounded to four decimals.

Conventions (docs/conventions.md, "Units and axes"): earth axes with z down (the source's
motion-capture frame; gravity is ``+g`` along earth z), body axes x forward, y right, z down
with the origin at the centre of buoyancy (CB); ZYX Euler angles. State (:data:`STATE_NAMES`,
the source's ``p, e, vb, wb``) ``x, y, z, phi, theta, psi, U, V, W, P, Q, R`` (m, rad, m/s,
rad/s), the names and units of flightgp's blimp. Inputs (:data:`INPUT_NAMES`) ``thrust_left``,
``thrust_right`` (N, each propeller's thrust along body x) and ``gondola_x, gondola_y,
gondola_z`` (m, the gondola mass's position in body axes; the source's ``rb``).

The source's 23-wide state also carries the gondola's velocity and acceleration, and its
derivative integrates the gondola position with them; no term of the accelerations uses them,
and they are zero in every recording, so here the gondola position is an input held over a step
like the thrusts.

Equations of motion
-------------------
With ``m_t = m + m_b`` (hull and gondola mass), ``l = m r + m_b r_b`` (their first mass moment
about the CB), ``J = I - m_b S(r_b)^2`` (``S(a) b = a x b``: the hull's inertia plus the
gondola's as a point mass) and ``n = [-sin theta, cos theta sin phi, cos theta cos phi]`` (earth
down in body axes)::

    p_dot     = R(Theta) v                                    (body -> earth, ZYX)
    Theta_dot = T(Theta) omega                                (Euler angle rates)
    [[m_t I3, -S(l)], [S(l), J]] [v_dot; omega_dot] = [f; tau]
    f   = m_t v x omega + (omega x l) x omega + (m_t - B) g n + R_bw [-D, S_y, -L] + (F_l + F_r) e_x
    tau = (J omega) x omega + l x (v x omega) + l x (g n) + R_bw (M + K omega)
          + (F_l + F_r) r_b,z e_y + (F_l - F_r) d e_z

Buoyancy ``B g`` acts at the CB (the origin), so it has no moment. The aerodynamic forces and
moments are quadratic in airspeed ``|v|`` with polynomial coefficients in the angle of attack
``alpha = atan2(W, U + eps)`` and the sideslip ``beta = asin(V / (|v| + eps))`` (``eps`` the
source's guard against division by zero at rest, :data:`ZERO_SPEED_GUARD`), and are rotated from
wind to body axes by ``R_bw(alpha, beta)`` (:func:`rotation_wind_to_body`); see
:func:`aerodynamic_force_and_moment`. As in the source, the linear rate damping ``K omega`` is
rotated with the aerodynamic moment ``M``, and there is no added mass.

Added mass (not in the source's model; flightgp's diagnosis tests it as a term the model lacks,
:mod:`validation.vehicles.rgblimp_effects`): a body moving through a fluid carries some of it
along. With diagonal added masses ``A_v = diag(X_Udot, Y_Vdot, Z_Wdot)`` (kg, entered positive)
and added inertias ``A_w = diag(K_Pdot, M_Qdot, N_Rdot)`` (kg m^2) about the CB, Kirchhoff's
equations for a rigid body in an ideal fluid (Fossen, *Handbook of Marine Craft Hydrodynamics
and Motion Control*, 2011, sec. 6.3.1) add ``A_v`` and ``A_w`` to the diagonal blocks of the
mass matrix and the terms ``(A_v v) x omega`` to ``f`` and ``(A_v v) x v + (A_w omega) x omega``
to ``tau`` (the second is the Munk moment, which turns an elongated hull broadside to the flow).
:class:`RGBlimpParameters` has none by default, which leaves the source's equations as they are.

Terms a real small airship may need and the source's model lacks (flightgp's diagnosis tests them,
:mod:`validation.vehicles.rgblimp_effects`; every one is zero by default, which leaves the
source's equations as they are):

- **Thrust that falls with airspeed.** A fixed-pitch propeller at fixed speed loses thrust as its
  advance ratio ``J = V / (n D)`` grows, nearly linearly over the range a slow vehicle flies in
  (``C_T(J)`` of small propellers: Brandt & Selig, "Propeller performance data at low Reynolds
  numbers", AIAA 2011-1255; McCormick, *Aerodynamics, Aeronautics, and Flight Mechanics*, 2nd
  ed., 1995, ch. 6). Each thrust is the recorded one times ``1 - k_T U_a`` (``k_T``,
  ``thrust_speed_loss``, s/m; ``U_a`` the airspeed along body x): one ``k_T`` for both
  propellers and every thrust setting, a first-order model of the curves.
- **A thrust line off the centreline** (``thrust_line_y``, ``y_T``, m, positive right): the
  total thrust yaws the hull by ``-y_T (F_l + F_r)``, a yaw moment that grows with the thrust
  rather than with the thrust difference.
- **Cross-flow forces on the hull** (Allen & Perkins, NACA Report 1048, 1951; Jorgensen, NASA TR
  R-474, 1977): beyond the linear (potential-flow) terms, a slender body's normal force and
  moment grow with the square of the flow angle, ``sin(a) |sin(a)|``: ``c_s_beta_abs beta
  |beta|`` in side force, ``c_mz_beta_abs beta |beta|`` in yawing moment, ``c_l_alpha_abs alpha
  |alpha|`` in lift and ``c_my_alpha_abs alpha |alpha|`` in pitching moment (per rad^2; the
  moments in m as the source's).
- **A draught that varies across the room**: the air's velocity ``w(p) = G_x x + G_y y`` (earth
  axes, m/s; ``G_x``, ``G_y`` the fields ``draught_gradient_x``, ``draught_gradient_y``, 1/s,
  each the rate of change of the three wind components along the room's x and y) enters the
  aerodynamics, which see the air-relative velocity ``v - R(Theta)^T w(p)`` (the forces,
  moments, thrust loss and wind angles above). The field is linear about the motion capture's
  origin, so a uniform part is the steady wind of :func:`advance`; with one, the field is
  evaluated in the frame of the air mass that wind carries along (a pattern advected with the
  mean flow: Taylor's frozen-field hypothesis, Taylor, Proc. R. Soc. A 164, 1938). The
  added-mass terms keep the body velocity (the field's gradient is small on the hull's length).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from validation.core.errors import BadInputError
from validation.vehicles.blimp_equations import euler_rates, rk4, rotation_body_to_earth
from validation.vehicles.polynomial_terms import slot_values

#: State names, in the order of the last axis of every state array (the source's ``p, e, vb, wb``).
STATE_NAMES = ("x", "y", "z", "phi", "theta", "psi", "U", "V", "W", "P", "Q", "R")
#: Unit of each state, in :data:`STATE_NAMES` order.
STATE_UNITS = ("m", "m", "m", "rad", "rad", "rad", "m/s", "m/s", "m/s", "rad/s", "rad/s", "rad/s")
#: Input names, in the order of the last axis of every input array (the source's ``Fl, Fr, rb``).
INPUT_NAMES = ("thrust_left", "thrust_right", "gondola_x", "gondola_y", "gondola_z")
#: Unit of each input, in :data:`INPUT_NAMES` order.
INPUT_UNITS = ("N", "N", "m", "m", "m")

#: Motion-capture sample rate, Hz, and the source's RK4 step, s (``step_size = 1/60`` in its
#: ``methods/*.py``).
SAMPLE_RATE = 60.0
SAMPLE_TIME = 1.0 / SAMPLE_RATE

#: The source's ``eps`` in ``alpha = atan2(W, U + eps)`` and ``beta = asin(V / (|v| + eps))``,
#: m/s: it keeps both defined at rest, where the aerodynamic forces vanish anyway.
ZERO_SPEED_GUARD = 1e-10

#: The gondola's position in the source's ``utils/parameters.py`` (``rb``), m, body axes: the
#: nominal configuration; the recordings move it along x by -1 .. 4 cm.
NOMINAL_GONDOLA_POSITION = (0.0747, 0.0006, 0.2380)

#: Rows a search term of the residual search (``flightgp diagnose``,
#: :mod:`validation.vehicles.rgblimp_effects`) adds to, and the state each accelerates: the six
#: body accelerations (:func:`search_accelerations`).
SEARCH_ROWS = {"X": "U", "Y": "V", "Z": "W", "L": "P", "M": "Q", "N": "R"}
#: States a search term's factor may use: the body velocity relative to the steady air, the
#: rates, roll and pitch (position and heading carry no force; the inputs are held through a
#: flight, so a factor of them is a constant, which the named offsets are).
SEARCH_SIGNALS = ("U", "V", "W", "P", "Q", "R", "phi", "theta")
_SEARCH_COLUMNS = tuple(STATE_NAMES.index(name) for name in SEARCH_SIGNALS)


def _field_width(field: dataclasses.Field) -> int:
    """3 for the (x, y, z) triples of :class:`RGBlimpParameters` (annotated ``tuple[...]``), else 1."""
    return 3 if str(field.type).startswith("tuple") else 1


@dataclass(frozen=True)
class RGBlimpParameters:
    """Physical parameters of the RGBlimp model (SI units; body axes, origin at the CB).

    Every default is the value of the same-named entry (in brackets) of ``utils/parameters.py``
    in ``zhu-yj/ABNODE`` (Zhu, Cheng & Zhang 2024; MIT licence). The aerodynamic coefficients
    there are rounded to four decimals; the source's recordings were computed with six of them
    slightly different (:data:`validation.vehicles.rgblimp_data.RECORDED_MODEL_PARAMETERS`).
    ``dataclasses.replace`` makes variants. Not used by the source's equations, so not here:
    ``rho`` (0.1690, helium density, kg/m^3), ``G`` (0.06713, "gravitational force") and ``I``
    (the diagonal of ``inertia`` again).

    Attributes
    ----------
    air_density : float
        kg/m^3 [``Rho``].
    gravity : float
        m/s^2 [``g``].
    buoyancy_mass : float
        Mass of the displaced air, kg: the buoyancy is ``buoyancy_mass * gravity`` at the CB
        [``B``; the source's comment calls it a force, its equations use it as a mass].
    hull_mass : float
        Mass of everything but the gondola, kg [``m``].
    gondola_mass : float
        The movable gondola, kg [``mb``]; its position is an input.
    hull_cg : (3,) tuple
        Centre of gravity of ``hull_mass`` relative to the CB, m [``r``].
    propeller_arm : float
        Lateral distance of each propeller from the body x axis, m: the thrust difference yaws
        with this arm [``d``].
    reference_area : float
        Aerodynamic reference area, m^2 [``A``].
    inertia : (3,) tuple
        Principal moments of inertia of the hull about the CB, kg m^2 [``Ix, Iy, Iz``].
    rate_damping : (3,) tuple
        Linear rate damping, N m s/rad: the moment is ``rate_damping * omega`` (negative
        values damp) [``K1, K2, K3``].
    c_d0, c_d_alpha2, c_d_beta2 : float
        Drag ``D = qbar A (c_d0 + c_d_alpha2 alpha^2 + c_d_beta2 beta^2)`` [``Cd0, Cda, Cdb``].
    c_s0, c_s_alpha2, c_s_beta : float
        Side force ``S = qbar A (c_s0 + c_s_alpha2 alpha^2 + c_s_beta beta)`` [``Cs0, Csa, Csb``].
    c_l0, c_l_alpha, c_l_beta2 : float
        Lift ``L = qbar A (c_l0 + c_l_alpha alpha + c_l_beta2 beta^2)`` [``Cl0, Cla, Clb``].
    c_mx0, c_mx_alpha, c_mx_beta : float
        Rolling moment ``qbar A (c_mx0 + c_mx_alpha alpha + c_mx_beta beta)``, so in m (the
        source's moment coefficients include the reference length) [``Cmx0, Cmxa, Cmxb``].
    c_my0, c_my_alpha, c_my_beta4 : float
        Pitching moment ``qbar A (c_my0 + c_my_alpha alpha + c_my_beta4 beta^4)``, m
        [``Cmy0, Cmya, Cmyb``].
    c_mz0, c_mz_alpha, c_mz_beta : float
        Yawing moment ``qbar A (c_mz0 + c_mz_alpha alpha + c_mz_beta beta)``, m
        [``Cmz0, Cmza, Cmzb``].
    c_s_beta_abs, c_l_alpha_abs, c_my_alpha_abs, c_mz_beta_abs : float
        Cross-flow terms ``beta |beta|`` in side force and yawing moment, ``alpha |alpha|`` in
        lift and pitching moment, per rad^2 (module docstring; not in the source: 0).
    added_mass : (3,) tuple
        Added masses along body x, y, z, kg (module docstring; not in the source: 0).
    added_inertia : (3,) tuple
        Added moments of inertia about body x, y, z, kg m^2 (module docstring; not in the
        source: 0).
    thrust_speed_loss : float
        ``k_T``: each thrust is the recorded one times ``1 - k_T U_a``, s/m (module docstring;
        not in the source: 0).
    thrust_line_y : float
        Lateral offset of the thrust line, m, positive right: a yawing moment ``-y_T (F_l +
        F_r)`` (module docstring; not in the source: 0).
    draught_gradient_x, draught_gradient_y : (3,) tuple
        The room's air velocity per metre along earth x and along earth y, 1/s: the draught
        ``w(p) = G_x x + G_y y`` (module docstring; not in the source: 0).
    """

    air_density: float = 1.2187
    gravity: float = 9.8
    buoyancy_mass: float = 0.15204
    hull_mass: float = 0.10482
    gondola_mass: float = 0.05407
    hull_cg: tuple[float, float, float] = (-0.0432, -0.0003, 0.0079)
    propeller_arm: float = 0.150
    reference_area: float = 0.250
    inertia: tuple[float, float, float] = (0.0300, 0.0150, 0.0100)
    rate_damping: tuple[float, float, float] = (-0.0503, -0.0264, -0.0137)
    c_d0: float = 0.2425
    c_d_alpha2: float = 4.4195
    c_d_beta2: float = 7.5080
    c_s0: float = 0.0083
    c_s_alpha2: float = -0.0744
    c_s_beta: float = -2.1140
    c_l0: float = 0.1594
    c_l_alpha: float = 2.9375
    c_l_beta2: float = 4.5537
    c_mx0: float = 0.0131
    c_mx_alpha: float = -0.0301
    c_mx_beta: float = -0.5256
    c_my0: float = 0.0568
    c_my_alpha: float = 0.0933
    c_my_beta4: float = 5.2357
    c_mz0: float = 0.0006
    c_mz_alpha: float = -0.0012
    c_mz_beta: float = -0.0936
    c_s_beta_abs: float = 0.0
    c_l_alpha_abs: float = 0.0
    c_my_alpha_abs: float = 0.0
    c_mz_beta_abs: float = 0.0
    added_mass: tuple[float, float, float] = (0.0, 0.0, 0.0)
    added_inertia: tuple[float, float, float] = (0.0, 0.0, 0.0)
    thrust_speed_loss: float = 0.0
    thrust_line_y: float = 0.0
    draught_gradient_x: tuple[float, float, float] = (0.0, 0.0, 0.0)
    draught_gradient_y: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            value, width = getattr(self, field.name), _field_width(field)
            try:
                values = tuple(float(v) for v in value) if width == 3 else (float(value),)
            except (TypeError, ValueError):
                values = ()
            if len(values) != width:
                raise BadInputError(
                    f"RGBlimpParameters.{field.name} needs {'3 numbers (x, y, z)' if width == 3 else 'one number'}"
                    f", got {value!r}")
            if not all(math.isfinite(v) for v in values):
                raise BadInputError(f"RGBlimpParameters.{field.name} must be finite, got {value!r}")
            object.__setattr__(self, field.name, values if width == 3 else values[0])


#: Components of a 3-vector rolled by one and by two (:func:`_cross`).
_ROLL_ONE, _ROLL_TWO = np.array([1, 2, 0]), np.array([2, 0, 1])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` over the last axis (length 3), leading axes broadcast: ``numpy.cross`` written
    out as ``a[1, 2, 0] b[2, 0, 1] - a[2, 0, 1] b[1, 2, 0]`` (component by component ``a1 b2 -
    a2 b1``, ...), which costs a fraction of it on the small batches of a free run."""
    a, b = np.asarray(a), np.asarray(b)
    return (a.take(_ROLL_ONE, axis=-1) * b.take(_ROLL_TWO, axis=-1)
            - a.take(_ROLL_TWO, axis=-1) * b.take(_ROLL_ONE, axis=-1))


def _stack_last(*components) -> np.ndarray:
    """``numpy.stack(components, axis=-1)`` of components of one shape, filled in place: on the
    small arrays here numpy.stack's own work costs more than the copy."""
    stacked = np.empty(np.shape(components[0]) + (len(components),), dtype=np.result_type(*components))
    for i, component in enumerate(components):
        stacked[..., i] = component
    return stacked


def _skew(a: np.ndarray) -> np.ndarray:
    """``S(a)`` with ``S(a) b = a x b``: (..., 3) -> (..., 3, 3)."""
    zero = np.zeros_like(a[..., 0])
    rows = [zero, -a[..., 2], a[..., 1], a[..., 2], zero, -a[..., 0], -a[..., 1], a[..., 0], zero]
    return _stack_last(*rows).reshape(a.shape[:-1] + (3, 3))


def wind_angles(velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angle of attack and sideslip, rad, of body velocity ``velocity`` (..., 3), m/s, as the
    source computes them: ``alpha = atan2(W, U + eps)``, ``beta = asin(V / (|v| + eps))``
    (:data:`ZERO_SPEED_GUARD`); each of shape (...)."""
    speed = np.linalg.norm(velocity, axis=-1)
    alpha = np.arctan2(velocity[..., 2], velocity[..., 0] + ZERO_SPEED_GUARD)
    beta = np.arcsin(velocity[..., 1] / (speed + ZERO_SPEED_GUARD))
    return alpha, beta


def rotation_wind_to_body(alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Rotation from wind to body axes, (...) rad -> (..., 3, 3): its first column is the unit
    airspeed direction ``[cos alpha cos beta, sin beta, sin alpha cos beta]`` (the source's
    ``Rbv``)."""
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    entries = [ca * cb, -ca * sb, -sa,
               sb, cb, np.zeros_like(sb),
               sa * cb, -sa * sb, ca]
    return _stack_last(*entries).reshape(np.shape(alpha) + (3, 3))


def aerodynamic_force_and_moment(velocity: np.ndarray, rates: np.ndarray, params) -> tuple[np.ndarray, np.ndarray]:
    """Aerodynamic force, N, and moment with the rate damping, N m, in body axes.

    ``qbar A`` times the coefficient polynomials of :class:`RGBlimpParameters` (with the
    cross-flow terms of the module docstring), ``qbar = rho |v|^2 / 2``; the force ``[-D, S,
    -L]`` and the moment ``M + K omega`` rotated from wind to body axes by
    :func:`rotation_wind_to_body` (the source's ``Rbv @ [-D, S, -L]`` and ``Rbv @ (M +
    Damping)``).

    Parameters
    ----------
    velocity, rates : ndarray, shape (..., 3)
        Body velocity relative to the air, m/s, and body rates, rad/s.
    params : RGBlimpParameters

    Returns
    -------
    force, moment : ndarray, shape (..., 3)
    """
    alpha, beta = wind_angles(velocity)
    qbar_area = 0.5 * params.air_density * np.sum(velocity**2, axis=-1) * params.reference_area
    alpha_cross, beta_cross = alpha * np.abs(alpha), beta * np.abs(beta)
    drag = qbar_area * (params.c_d0 + params.c_d_alpha2 * alpha**2 + params.c_d_beta2 * beta**2)
    side = qbar_area * (params.c_s0 + params.c_s_alpha2 * alpha**2 + params.c_s_beta * beta
                        + params.c_s_beta_abs * beta_cross)
    lift = qbar_area * (params.c_l0 + params.c_l_alpha * alpha + params.c_l_beta2 * beta**2
                        + params.c_l_alpha_abs * alpha_cross)
    moment = qbar_area[..., None] * _stack_last(
        params.c_mx0 + params.c_mx_alpha * alpha + params.c_mx_beta * beta,
        params.c_my0 + params.c_my_alpha * alpha + params.c_my_beta4 * beta**4 + params.c_my_alpha_abs * alpha_cross,
        params.c_mz0 + params.c_mz_alpha * alpha + params.c_mz_beta * beta + params.c_mz_beta_abs * beta_cross)
    moment = moment + np.asarray(params.rate_damping) * rates
    rotation = rotation_wind_to_body(alpha, beta)
    force = np.einsum("...ij,...j->...i", rotation, _stack_last(-drag, side, -lift))
    return force, np.einsum("...ij,...j->...i", rotation, moment)


def _broadcast(state: np.ndarray, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``state`` (..., 12) and ``inputs`` (..., 5) with their leading axes broadcast together."""
    leading = np.broadcast_shapes(state.shape[:-1], inputs.shape[:-1])
    return (np.broadcast_to(state, leading + state.shape[-1:]),
            np.broadcast_to(inputs, leading + inputs.shape[-1:]))


def mass_properties(inputs: np.ndarray, params) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the accelerations need of the masses, which the gondola position (an input) sets and
    the state does not: one evaluation serves every stage of an RK4 step (:func:`rk4_step`).

    Parameters
    ----------
    inputs : ndarray, shape (..., 5)
        Only the gondola position ``inputs[..., 2:5]`` (m) is used.
    params : RGBlimpParameters

    Returns
    -------
    mass_moment : ndarray, shape (..., 3)
        ``l = m r + m_b r_b``, kg m.
    inertia : ndarray, shape (..., 3, 3)
        ``J = I - m_b S(r_b)^2``, kg m^2 (without added inertia).
    inverse_mass_matrix : ndarray, shape (..., 6, 6)
        The inverse of ``[[m_t I3 + A_v, -S(l)], [S(l), J + A_w]]`` (module docstring).
    """
    gondola = np.asarray(inputs, dtype=float)[..., 2:5]
    mass_moment = params.hull_mass * np.asarray(params.hull_cg) + params.gondola_mass * gondola
    gondola_skew = _skew(gondola)
    inertia = np.diag(params.inertia) - params.gondola_mass * gondola_skew @ gondola_skew
    translational = (params.hull_mass + params.gondola_mass + np.asarray(params.added_mass)[..., None]) * np.eye(3)
    rotational = inertia + np.asarray(params.added_inertia)[..., None] * np.eye(3)
    mass_moment_skew = _skew(mass_moment)
    leading = np.broadcast_shapes(translational.shape[:-2], rotational.shape[:-2], mass_moment_skew.shape[:-2])
    matrix = np.empty(leading + (6, 6))
    matrix[..., :3, :3] = translational
    matrix[..., :3, 3:] = -mass_moment_skew
    matrix[..., 3:, :3] = mass_moment_skew
    matrix[..., 3:, 3:] = rotational
    return mass_moment, inertia, np.linalg.inv(matrix)


def body_accelerations(state: np.ndarray, inputs: np.ndarray, params, *, masses=None) -> np.ndarray:
    """Body accelerations ``[v_dot, omega_dot]`` of the RGBlimp (the source's ``dot_v, dot_w``).

    Parameters
    ----------
    state : ndarray, shape (..., 12)
        ``x, y, z, phi, theta, psi, U, V, W, P, Q, R`` (m, rad, m/s, rad/s).
    inputs : ndarray, shape (..., 5)
        ``thrust_left, thrust_right`` (N), ``gondola_x, gondola_y, gondola_z`` (m); leading axes
        broadcast against those of ``state``.
    params : RGBlimpParameters
    masses : tuple, optional
        :func:`mass_properties` of ``inputs`` and ``params``, when the caller has them.

    Returns
    -------
    ndarray, shape (broadcast leading axes, 6)
        ``U_dot, V_dot, W_dot`` (m/s^2) and ``P_dot, Q_dot, R_dot`` (rad/s^2), body axes
        (the equations of the module docstring).
    """
    state, inputs = _broadcast(np.asarray(state, dtype=float), np.asarray(inputs, dtype=float))
    angles, velocity, rates = state[..., 3:6], state[..., 6:9], state[..., 9:12]
    thrust_left, thrust_right, gondola_z = inputs[..., 0], inputs[..., 1], inputs[..., 4]
    mass_moment, inertia, inverse = masses if masses is not None else mass_properties(inputs, params)

    total_mass = params.hull_mass + params.gondola_mass
    down = _stack_last(-np.sin(angles[..., 1]),
                       np.cos(angles[..., 1]) * np.sin(angles[..., 0]),
                       np.cos(angles[..., 1]) * np.cos(angles[..., 0]))
    air_velocity = velocity - draught_in_body(state, params)
    aero_force, aero_moment = aerodynamic_force_and_moment(air_velocity, rates, params)
    thrust_factor = 1.0 - params.thrust_speed_loss * air_velocity[..., 0]
    thrust_left, thrust_right = thrust_left * thrust_factor, thrust_right * thrust_factor
    thrust = thrust_left + thrust_right
    zero = np.zeros_like(thrust)

    velocity_cross_rates = _cross(velocity, rates)
    added_momentum = np.asarray(params.added_mass) * velocity
    force = (total_mass * velocity_cross_rates
             + _cross(added_momentum, rates)
             + _cross(_cross(rates, mass_moment), rates)
             + (total_mass - params.buoyancy_mass) * params.gravity * down
             + aero_force
             + _stack_last(thrust, zero, zero))
    moment = (_cross(np.einsum("...ij,...j->...i", inertia, rates), rates)
              + _cross(added_momentum, velocity)
              + _cross(np.asarray(params.added_inertia) * rates, rates)
              + _cross(mass_moment, velocity_cross_rates)
              + _cross(mass_moment, params.gravity * down)
              + aero_moment
              + _stack_last(zero, thrust * gondola_z,
                            (thrust_left - thrust_right) * params.propeller_arm - params.thrust_line_y * thrust))
    right_side = np.concatenate([force, moment], axis=-1)
    return np.einsum("...ij,...j->...i", inverse, right_side)


def search_accelerations(xp, state, slots):
    """The body accelerations (m/s^2, rad/s^2) that search terms held in slots add at
    ``state``: ``sum_k value_k factor_k`` on row ``row_k`` of :data:`SEARCH_ROWS`, each factor
    of :data:`SEARCH_SIGNALS` (:func:`validation.vehicles.polynomial_terms.slot_values`), for
    numpy or ``jax.numpy`` (``xp``).

    Parameters
    ----------
    xp : module
    state : ndarray, shape (..., 12)
        In the steady air's frame, as every stage of a free run sees it (:func:`advance`).
    slots : dict of str to ndarray
        :data:`~validation.vehicles.polynomial_terms.SLOT_KEYS`, each shape (..., K).

    Returns
    -------
    ndarray, shape (broadcast leading axes, 6)
    """
    return slot_values(xp, state[..., xp.asarray(_SEARCH_COLUMNS)], slots)


def draught_in_body(state: np.ndarray, params) -> np.ndarray | float:
    """The room's draught ``w(p) = G_x x + G_y y`` at the state's position, in body axes,
    ``R(Theta)^T w(p)``, m/s, shape (..., 3); 0.0 without one (module docstring).

    Parameters
    ----------
    state : ndarray, shape (..., 12)
    params : RGBlimpParameters
        ``draught_gradient_x`` and ``draught_gradient_y`` (3,) (or batched (..., 3)), 1/s.
    """
    gradient_x, gradient_y = np.asarray(params.draught_gradient_x), np.asarray(params.draught_gradient_y)
    if not (np.any(gradient_x) or np.any(gradient_y)):
        return 0.0
    earth = state[..., 0:1] * gradient_x + state[..., 1:2] * gradient_y
    return np.einsum("...ji,...j->...i", rotation_body_to_earth(state[..., 3:6]), earth)


def rgblimp_dynamics(state: np.ndarray, inputs: np.ndarray, params, *, masses=None,
                     extra_acceleration=None) -> np.ndarray:
    """Time derivative of the RGBlimp state (the module docstring's equations).

    Parameters
    ----------
    state : ndarray, shape (..., 12)
        ``x, y, z, phi, theta, psi, U, V, W, P, Q, R`` (m, rad, m/s, rad/s).
    inputs : ndarray, shape (..., 5)
        ``thrust_left, thrust_right`` (N), ``gondola_x, gondola_y, gondola_z`` (m); leading axes
        broadcast against those of ``state``.
    params : RGBlimpParameters
    masses : tuple, optional
        :func:`mass_properties` of ``inputs`` and ``params``, when the caller has them.
    extra_acceleration : callable, optional
        ``extra_acceleration(state, inputs) -> (..., 6)``, added to the body accelerations (m/s^2,
        rad/s^2): a learned correction (:mod:`validation.models.rgblimp_hybrid_step`).

    Returns
    -------
    ndarray, shape (broadcast leading axes, 12)
        ``d state / dt`` in the units of ``state`` per second.
    """
    state, inputs = _broadcast(np.asarray(state, dtype=float), np.asarray(inputs, dtype=float))
    angles, velocity = state[..., 3:6], state[..., 6:9]
    position_dot = np.einsum("...ij,...j->...i", rotation_body_to_earth(angles), velocity)
    accelerations = body_accelerations(state, inputs, params, masses=masses)
    if extra_acceleration is not None:
        accelerations = accelerations + extra_acceleration(state, inputs)
    return np.concatenate([position_dot, euler_rates(angles, state[..., 9:12]), accelerations], axis=-1)


def wrap_heading(state: np.ndarray) -> np.ndarray:
    """``state`` (..., 12) with ``psi`` moved by one turn into [-pi, pi] if it left it, as the
    source's ``RK_RGB`` does after each step (one step never turns the blimp by a full turn)."""
    psi = state[..., 5]
    wrapped = np.where(psi > math.pi, psi - 2 * math.pi, np.where(psi < -math.pi, psi + 2 * math.pi, psi))
    return np.concatenate([state[..., :5], wrapped[..., None], state[..., 6:]], axis=-1)


def rk4_step(state: np.ndarray, inputs: np.ndarray, params, *, extra_acceleration=None) -> np.ndarray:
    """The RGBlimp one sample (:data:`SAMPLE_TIME`, 1/60 s) later, inputs held, as the source
    integrates: one classical RK4 step of :func:`rgblimp_dynamics`, then :func:`wrap_heading`.

    Parameters
    ----------
    state : ndarray, shape (..., 12)
    inputs : ndarray, shape (..., 5)
        Held over the step; leading axes broadcast against those of ``state``.
    params : RGBlimpParameters
    extra_acceleration : callable, optional
        Added to the body accelerations in every stage (:func:`rgblimp_dynamics`).

    Returns
    -------
    ndarray, shape (broadcast leading axes, 12)
    """
    state, inputs = _broadcast(np.asarray(state, dtype=float), np.asarray(inputs, dtype=float))
    masses = mass_properties(inputs, params)  # the inputs are held: one for the four stages
    return wrap_heading(rk4(lambda s: rgblimp_dynamics(s, inputs, params, masses=masses,
                                                       extra_acceleration=extra_acceleration), state, SAMPLE_TIME))


def advance(states, inputs, params, *, thrust_gain=1.0, wind=(0.0, 0.0), extra_acceleration=None) -> np.ndarray:
    """The source's RK4 step over one sample with a thrust factor and a steady horizontal wind.

    A uniform, steady wind ``w`` (earth axes) moves the air mass at constant velocity, and the
    equations of motion hold unchanged in a frame moving with it (a Galilean change of frame:
    the aerodynamics see the airspeed, the inertial terms only accelerations and rates). So the
    step converts the state to the air mass's frame (body velocity ``v - R^T w``), takes
    :func:`rk4_step` there, and converts back (position
    plus ``w h``, velocity plus ``R^T w`` at the new attitude); with ``w = 0`` it is ``rk4_step``.

    Parameters
    ----------
    states : ndarray, shape (..., 12)
    inputs : ndarray, shape (..., 5)
        The thrusts are multiplied by ``thrust_gain`` (:func:`scaled_thrust`).
    params : RGBlimpParameters or a namespace of its fields, some batched (e.g.
        :func:`validation.models.rgblimp_identification.batched_parameters`)
    thrust_gain : float or ndarray
        Broadcasting against ``inputs[..., 0]``.
    wind : (2,) sequence or ndarray, shape (..., 2)
        The air's velocity along the earth (motion-capture) x and y axes, m/s; leading axes
        broadcast against the states'.
    extra_acceleration : callable, optional
        Added to the body accelerations in every RK4 stage, called with the state in the air
        mass's frame and the inputs with the thrust factor applied (:func:`rgblimp_dynamics`).

    Returns
    -------
    ndarray, shape (broadcast leading axes, 12)
    """
    states = np.asarray(states, dtype=float)
    inputs = scaled_thrust(inputs, thrust_gain)
    wind = np.asarray(wind, dtype=float)
    if not np.any(wind):
        return rk4_step(states, inputs, params, extra_acceleration=extra_acceleration)
    wind = np.concatenate([wind, np.zeros(wind.shape[:-1] + (1,))], axis=-1)
    in_air = _with_velocity_offset(states, wind, -1.0)
    moved = rk4_step(in_air, inputs, params, extra_acceleration=extra_acceleration)
    position = moved[..., :3] + SAMPLE_TIME * wind
    return _with_velocity_offset(np.concatenate([position, moved[..., 3:]], axis=-1), wind, 1.0)


def free_run(initial_state, inputs, params, *, thrust_gain=1.0, wind=(0.0, 0.0), extra_acceleration=None) -> np.ndarray:
    """Many :func:`advance` steps at once: the whole run in the air mass's frame, then back.

    Equal to stepping :func:`advance` sample by sample (the conversions between the frames
    cancel), with one conversion each way instead of two per step.

    Parameters
    ----------
    initial_state : ndarray, shape (..., 12)
    inputs : ndarray, shape (..., n, 5)
        ``inputs[..., k, :]`` held from sample k to k + 1; the last row is unused.
    params, thrust_gain, wind, extra_acceleration
        As for :func:`advance` (``thrust_gain`` broadcasting against ``inputs[..., 0, 0]``,
        ``wind`` against ``initial_state[..., :2]``).

    Returns
    -------
    ndarray, shape (..., n, 12)
        Row 0 is the start.
    """
    inputs = scaled_thrust(inputs, np.asarray(thrust_gain, dtype=float)[..., None])
    wind = np.asarray(wind, dtype=float)
    wind = np.concatenate([wind, np.zeros(wind.shape[:-1] + (1,))], axis=-1)
    path = simulate(lambda s, u: rk4_step(s, u, params, extra_acceleration=extra_acceleration),
                    _with_velocity_offset(np.asarray(initial_state, float), wind, -1.0), inputs)
    if not np.any(wind):
        return path
    drift = SAMPLE_TIME * np.arange(path.shape[-2])[:, None] * wind[..., None, :]  # t_k = k h
    path = np.concatenate([path[..., :3] + drift, path[..., 3:]], axis=-1)
    return _with_velocity_offset(path, wind[..., None, :], 1.0)


def _with_velocity_offset(states: np.ndarray, wind: np.ndarray, sign: float) -> np.ndarray:
    """``states`` with ``sign R(Theta)^T wind`` added to the body velocity."""
    offset = np.einsum("...ji,...j->...i", rotation_body_to_earth(states[..., 3:6]), wind)
    return np.concatenate([states[..., :6], states[..., 6:9] + sign * offset, states[..., 9:]], axis=-1)


def scaled_thrust(inputs, gain) -> np.ndarray:
    """``inputs`` (..., 5) with both thrusts multiplied by ``gain`` (a float, or an array
    broadcasting against ``inputs[..., 0]``)."""
    inputs = np.asarray(inputs, dtype=float)
    gain = np.asarray(gain, dtype=float)
    thrusts = inputs[..., :2] * gain[..., None]
    leading = thrusts.shape[:-1]
    return np.concatenate([thrusts, np.broadcast_to(inputs[..., 2:], leading + (3,))], axis=-1)


def simulate(step, initial_state, inputs) -> np.ndarray:
    """Roll ``step(states, inputs) -> next_states`` from ``initial_state`` (..., 12) through
    ``inputs`` (..., n, m): states (..., n, 12), row 0 the start; the last input row is unused."""
    state = np.asarray(initial_state, dtype=float)
    inputs = np.asarray(inputs, dtype=float)
    path = [state]
    for k in range(inputs.shape[-2] - 1):
        state = step(state, inputs[..., k, :])
        path.append(state)
    return np.stack(path, axis=-2)
