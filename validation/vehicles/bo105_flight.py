"""The Bo105 flight-test stand-in ``bo105-<V>kt-flight``: the "real aircraft" of the synthetic
experiments, richer than the reference :class:`~validation.vehicles.bo105.Bo105Reference`.

:class:`Bo105FlightTest` starts from the same ``A, B`` and adds, effect by effect (each switchable by a
keyword of the same name; all on by default):

``flapping`` -- rotor flapping dynamics.
    The reference's rotor moments are quasi-static: they follow control and body rates at once.
    A real rotor's tip-path plane settles with the flap time constant
    ``tau_beta = 16 / (gamma Omega) = 16 / (5.09 * 44.4 rad/s) = 0.071 s`` (Padfield 2007, ch. 2
    and sec. 3.2, centre-spring rotor; Bo105 Lock number and rotor speed: Padfield 2007, appendix 4B). The
    rotor part of each hub force and moment passes through ``tau_beta z_dot = -z + f_rotor``.
    The split: the rotor part is the main-rotor control columns (``theta_0, theta_1s,
    theta_1c``) of the X, Y, L, M, N rows, plus the rate terms ``L_p, L_q, M_p, M_q``. ``L_q``
    and ``M_p`` are rotor-only; of ``L_p`` and ``M_q`` the rotor share is the hover value over
    the value at speed, at most 1, because in hover fuselage and empennage add no rate damping
    and a hingeless rotor's damping changes little with speed (80 kt: 94 % of ``M_q``, all of
    ``L_p``). Steady states are unchanged; the lag grows with frequency (80 kt, pitch rate to
    ``theta_1s``: 1 deg at 0.2 Hz, 37 deg at 1.5 Hz), and the roll subsidence (-13.7 1/s at
    80 kt) becomes a coupled roll/flap oscillation (-7.1 +/- 11.8j 1/s).
``dynamic_inflow`` -- Pitt-Peters uniform dynamic inflow.
    The reference's thrust derivatives (Z row: ``Z_w`` and the main-rotor controls) hold the
    induced inflow at its quasi-steady value. With the Pitt-Peters first-order inflow
    (Pitt & Peters, Vertica 5(1), 1981; Padfield 2007, sec. 3.2, rotor inflow)
    ``(8/(3 pi)) dlambda/dpsi + 2 V_m lambda = C_T`` and blade-element thrust
    ``dC_T/dlambda = -a s / 4``, a thrust derivative ``Z`` becomes
    ``Z (tau_lambda s + 1) / (tau_lambda/(1+K) s + 1)`` with ``K = a s / (8 V_m)`` and
    ``tau_lambda = 8/(3 pi) / (2 V_m Omega)``: the initial thrust response is ``1+K`` times the
    quasi-steady one, decaying to it with ``tau_lambda / (1+K)``. ``V_m = (mu^2 + 2 lambda_0^2)
    / sqrt(mu^2 + lambda_0^2)`` (Peters & HaQuang, JAHS 33(4), 1988), ``lambda_0`` from Glauert's
    momentum theory at the trim thrust ``m g`` (ISA sea level, disc incidence neglected).
    80 kt: ``mu = 0.19``, ``K = 0.28``, ``tau_lambda = 0.050 s``; hover: ``K = 0.54``,
    ``tau_lambda = 0.097 s``.
``actuators`` -- control actuators, ``delta / delta_cmd = w_a^2 / (s^2 + 2 zeta_a w_a s + w_a^2)``
    on all four controls with ``w_a = 30 rad/s`` and ``zeta_a = 0.7`` (assumed: typical of a
    hydraulically boosted control system; no Bo105 source). Equivalent delay
    ``2 zeta_a / w_a = 0.047 s``; steady states are unchanged.
``transport_delay`` -- a pure delay of 0.04 s on all controls (assumed: linkage, data-system
    and sensor latency of a few tens of ms), a whole number of internal steps.
``off_axis_coupling`` -- the pitch/roll cross-coupling that quasi-static rotor models get wrong.
    Rotor models without wake distortion mispredict the off-axis response to pitch and roll
    rate, often with the wrong sign: a pitching or rolling rotor curves its wake, which changes
    the inflow gradient and the flapping (Keller, JAHS 41(4), 1996, pp. 322-330; review: Rosen,
    J. Aerospace Sci. Tech. 57(1), 2023, pp. 114-141, where an aerodynamic phase lag is the
    simpler of the corrections). Here the rate-induced rotor moment (the ``L_p, L_q, M_p,
    M_q`` rotor part of the ``flapping`` split) is rotated in the disc plane by
    ``delta_w = 20 deg``; control derivatives are untouched::

        L' = cos(delta_w) L + sin(delta_w) (I_yy / I_xx) M
        M' = -sin(delta_w) (I_xx / I_yy) L + cos(delta_w) M

    with the moments scaled by ``I_xx = 1433``, ``I_yy = 4973 kg m^2`` (the product of inertia
    is neglected). The sign is the one that reverses the quasi-static cross-damping, as
    Keller's wake distortion does. At 80 kt: ``L_q`` 1.17 -> -3.35, ``M_p`` -0.23 -> 1.13,
    ``L_p`` -13.61 -> -13.06, ``M_q`` -4.00 -> -3.89 (1/s). With ``flapping`` off the
    stand-in is exactly the reference with these four derivatives changed.
``turbulence`` -- Dryden turbulence (MIL-F-8785C, 1980; MIL-HDBK-1797, 1997;
    :mod:`validation.vehicles.turbulence`): gust velocities
    ``u_g, v_g, w_g`` from ``H_u = sigma sqrt(2T) / (Ts + 1)`` and
    ``H_v = H_w = sigma sqrt(T) (sqrt(3) T s + 1) / (Ts + 1)^2``, ``T = L_t / V``, driven by
    unit-intensity white noise so that each gust has standard deviation ``sigma``. Isotropic
    medium-altitude scale ``L_t = 1750 ft = 533.4 m``; ``sigma = 0.3 m/s``, below the
    handbooks' "light" turbulence (``sigma_w = 0.1 W_20 = 0.77 m/s`` for ``W_20 = 15 kt``): a
    calm day, as chosen for identification flying. In hover the frozen-field advection speed is
    taken as 5 m/s. The filters are discretised exactly (Van Loan, IEEE TAC 23(3), 1978),
    start from their stationary distribution, and each gust is held over one internal step
    (5 ms, far shorter than ``T``, 13 s at 80 kt). The aerodynamic derivatives (the reference's
    u, v, w columns) act on the airmass-relative velocity ``x - x_gust``.
``sensor_noise`` -- white Gaussian noise on every recorded sample: 0.003 rad/s on ``p, q, r``
    (rate gyros), 0.002 rad on ``theta, phi``, 0.1 m/s on ``u, v, w`` (assumed values typical of
    flight-test instrumentation sampled at 100 Hz).

Together, for a 1 deg, 0.4 s ``theta_1s`` 3-2-1-1 at 80 kt (noise and turbulence off, 0-6 s),
the pitch rate keeps its shape and nearly its peak (0.205 against 0.220 rad/s; correlation 0.998
once shifted by the 0.13 s that delay, actuators and flapping add, 0.90 unshifted), while the
off-axis rates differ by more than their own size (RMS difference against the RMS of the
reference's signal: p 0.057 vs 0.051, r 0.033 vs 0.029 rad/s).

Numbers are module constants so that tests and diagnosis can compare findings with the truth.
Every random draw comes from ``np.random.default_rng(seed)``, split into independent streams for
turbulence and sensor noise, so switching one effect off leaves the other's draws unchanged.
"""
from __future__ import annotations

import math

import numpy as np

from validation.core.recordings import Recording
from validation.core.sampling import check_history
from validation.vehicles.bo105 import (
    AIR_DENSITY,
    BLADE_CHORD,
    GRAVITY,
    I_XX,
    I_YY,
    INPUT_NAMES,
    KNOT,
    LIFT_SLOPE,
    LOCK_NUMBER,
    MASS,
    N_BLADES,
    ROTOR_RADIUS,
    ROTOR_SPEED,
    ROW_LETTERS,
    SAMPLE_TIME,
    STATE_NAMES,
    Bo105Reference,
    padfield_condition,
    padfield_table,
)
from validation.vehicles.state_space import cached_zero_order_hold, propagate
from validation.vehicles.turbulence import dryden_gusts

_STATE = {name: i for i, name in enumerate(STATE_NAMES)}
_INPUT = {name: i for i, name in enumerate(INPUT_NAMES)}

# Flight-test stand-in effects (module docstring gives each source).
FLAP_TIME_CONSTANT = 16.0 / (LOCK_NUMBER * ROTOR_SPEED)  # s, 0.0708


ACTUATOR_NATURAL_FREQUENCY = 30.0  # rad/s


ACTUATOR_DAMPING = 0.7


TRANSPORT_DELAY = 0.04  # s


WAKE_DISTORTION_PHASE = math.radians(20.0)  # rad


TURBULENCE_STD = 0.3  # m/s, each of u_g, v_g, w_g


TURBULENCE_SCALE_LENGTH = 533.4  # m (1750 ft)


TURBULENCE_MIN_ADVECTION_SPEED = 5.0  # m/s


SENSOR_NOISE_STD = {"u": 0.1, "w": 0.1, "q": 0.003, "theta": 0.002,
                    "v": 0.1, "p": 0.003, "phi": 0.002, "r": 0.003}


#: Longest internal integration step of the stand-in, s; the transport delay is a whole number
#: of internal steps (exact whenever the recording interval is a multiple of 5 ms).
MAX_INTERNAL_STEP = 0.005


EFFECTS = ("flapping", "dynamic_inflow", "actuators", "transport_delay", "off_axis_coupling",
           "turbulence", "sensor_noise")


_MAIN_ROTOR_CONTROLS = [_INPUT["theta_0"], _INPUT["theta_1s"], _INPUT["theta_1c"]]


#: Rows whose rotor part passes through the flap lag (X, Y, L, M, N), in flap-state order.
_FLAP_ROWS = [_STATE[ROW_LETTERS[letter]] for letter in ("X", "Y", "L", "M", "N")]


#: Gust velocities (u_g, v_g, w_g) as the state columns they perturb.
_GUST_COLUMNS = [_STATE["u"], _STATE["v"], _STATE["w"]]


def _inflow_parameters(speed_m_s: float) -> tuple[float, float]:
    """Pitt-Peters inflow time constant ``tau_lambda`` (s) and frozen-inflow gain excess ``K``.

    Formulas and sources in the module docstring (``dynamic_inflow``).
    """
    tip_speed = ROTOR_SPEED * ROTOR_RADIUS
    solidity = N_BLADES * BLADE_CHORD / (math.pi * ROTOR_RADIUS)
    thrust_coefficient = MASS * GRAVITY / (AIR_DENSITY * math.pi * ROTOR_RADIUS**2 * tip_speed**2)
    mu = speed_m_s / tip_speed
    # Glauert: lambda_0 = C_T / (2 sqrt(mu^2 + lambda_0^2)), a quadratic in lambda_0^2.
    inflow_squared = (-mu**2 + math.sqrt(mu**4 + thrust_coefficient**2)) / 2
    mass_flow = (mu**2 + 2 * inflow_squared) / math.sqrt(mu**2 + inflow_squared)
    time_constant = 8 / (3 * math.pi) / (2 * mass_flow * ROTOR_SPEED)
    return time_constant, LIFT_SLOPE * solidity / (8 * mass_flow)


def _rotor_parts(A: np.ndarray, B: np.ndarray, A_hover: np.ndarray):
    """Split ``A, B`` into the flap-lagged rotor part and the inflow (thrust) part.

    Returns ``(A_flap, B_flap, A_thrust, B_thrust)``, each shaped like ``A`` or ``B``; the
    split is the one the module docstring gives under ``flapping`` and ``dynamic_inflow``.
    """
    A_flap, B_flap = np.zeros_like(A), np.zeros_like(B)
    B_flap[np.ix_(_FLAP_ROWS, _MAIN_ROTOR_CONTROLS)] = B[np.ix_(_FLAP_ROWS, _MAIN_ROTOR_CONTROLS)]
    p, q = _STATE["p"], _STATE["q"]
    for row, column in ((p, p), (q, q)):
        A_flap[row, column] = A[row, column] * min(1.0, A_hover[row, column] / A[row, column])
    A_flap[p, q], A_flap[q, p] = A[p, q], A[q, p]
    w = _STATE["w"]
    A_thrust, B_thrust = np.zeros_like(A), np.zeros_like(B)
    A_thrust[w, w] = A[w, w]
    B_thrust[w, _MAIN_ROTOR_CONTROLS] = B[w, _MAIN_ROTOR_CONTROLS]
    return A_flap, B_flap, A_thrust, B_thrust


def _wake_distortion_rotation() -> np.ndarray:
    """(8, 8) map rotating the (L, M) rate-induced rotor moment by ``WAKE_DISTORTION_PHASE``.

    Formula and sign in the module docstring (``off_axis_coupling``).
    """
    c, s = math.cos(WAKE_DISTORTION_PHASE), math.sin(WAKE_DISTORTION_PHASE)
    p, q = _STATE["p"], _STATE["q"]
    rotation = np.eye(len(STATE_NAMES))
    rotation[np.ix_([p, q], [p, q])] = [[c, s * I_YY / I_XX], [-s * I_XX / I_YY, c]]
    return rotation


def _augmented_system(reference: Bo105Reference, effects: dict[str, bool]):
    """Continuous-time stand-in ``X_dot = F X + G [delta_cmd; gust]``.

    ``X`` stacks the 8 rigid-body states, then (when on) actuator positions and rates (4 + 4),
    flap-lag states (one per X, Y, L, M, N row) and the inflow state. ``delta_cmd`` (4) are the
    (delayed) control commands, ``gust`` (3) is ``(u_g, v_g, w_g)``. Returns F (N, N), G (N, 7).
    """
    A, B = reference.A, reference.B
    A_flap, B_flap, A_thrust, B_thrust = _rotor_parts(A, B, np.array(padfield_condition(0)["A"]))
    A_direct, B_direct = A - A_flap - A_thrust, B - B_flap - B_thrust
    if effects["off_axis_coupling"]:
        A_flap = _wake_distortion_rotation() @ A_flap
    n_x, n_u = len(STATE_NAMES), len(INPUT_NAMES)
    size = n_x + 2 * n_u * effects["actuators"] + len(_FLAP_ROWS) * effects["flapping"] \
        + effects["dynamic_inflow"]
    F, G = np.zeros((size, size)), np.zeros((size, n_u + 3))
    # Controls delta = P_delta X + Q_delta U and airmass-relative states x_rel = P_x X + Q_x U.
    P_delta, Q_delta = np.zeros((n_u, size)), np.zeros((n_u, n_u + 3))
    P_x, Q_x = np.zeros((n_x, size)), np.zeros((n_x, n_u + 3))
    P_x[:, :n_x] = np.eye(n_x)
    Q_x[_GUST_COLUMNS, n_u + np.arange(3)] = -1.0
    next_state = n_x
    if effects["actuators"]:
        position, rate = slice(next_state, next_state + n_u), slice(next_state + n_u, next_state + 2 * n_u)
        w_a, zeta_a = ACTUATOR_NATURAL_FREQUENCY, ACTUATOR_DAMPING
        F[position, rate] = np.eye(n_u)
        F[rate, position] = -w_a**2 * np.eye(n_u)
        F[rate, rate] = -2 * zeta_a * w_a * np.eye(n_u)
        G[rate, :n_u] = w_a**2 * np.eye(n_u)
        P_delta[:, position] = np.eye(n_u)
        next_state += 2 * n_u
    else:
        Q_delta[:, :n_u] = np.eye(n_u)

    def forces(A_part, B_part):
        """``A_part x_rel + B_part delta`` as (matrix on X, matrix on U)."""
        return A_part @ P_x + B_part @ P_delta, A_part @ Q_x + B_part @ Q_delta

    F_part, G_part = forces(A_direct, B_direct)
    F[:n_x] += F_part
    G[:n_x] += G_part
    F_part, G_part = forces(A_flap, B_flap)
    if effects["flapping"]:
        flap = np.arange(next_state, next_state + len(_FLAP_ROWS))
        tau = FLAP_TIME_CONSTANT
        F[flap] = F_part[_FLAP_ROWS] / tau
        F[flap, flap] -= 1 / tau
        G[flap] = G_part[_FLAP_ROWS] / tau
        F[_FLAP_ROWS, flap] = 1.0
        next_state += len(_FLAP_ROWS)
    else:
        F[:n_x] += F_part
        G[:n_x] += G_part
    F_part, G_part = forces(A_thrust, B_thrust)
    if effects["dynamic_inflow"]:
        tau, excess = _inflow_parameters(reference.speed_kt * KNOT)
        tau_effective = tau / (1 + excess)
        w, inflow = _STATE["w"], next_state
        F[:n_x] += (1 + excess) * F_part
        G[:n_x] += (1 + excess) * G_part
        F[w, inflow] = -excess
        F[inflow] = F_part[w] / tau_effective
        F[inflow, inflow] -= 1 / tau_effective
        G[inflow] = G_part[w] / tau_effective
    else:
        F[:n_x] += F_part
        G[:n_x] += G_part
    return F, G


class Bo105FlightTest:
    """The ``bo105-<V>kt-flight`` stand-in: the reference plus the effects the module lists.

    Parameters
    ----------
    speed_kt : int
        Trim speed, kt; one of 0, 20, 40, 60, 80, 100, 120, 140.
    flapping, dynamic_inflow, actuators, transport_delay, off_axis_coupling, turbulence, sensor_noise : bool
        Switch each effect (module docstring) on or off; all on by default. With all off the
        stand-in reproduces :class:`Bo105Reference` to rounding.

    Attributes
    ----------
    name : str
        ``"bo105-<V>kt-flight"``.
    speed_kt : int
    effects : dict of str to bool
        Which effects are on (read-only).
    input_names, state_names : tuple of str
    sample_time : float
        Default recording interval, 0.01 s (100 Hz).
    """

    input_names = INPUT_NAMES
    state_names = STATE_NAMES
    sample_time = SAMPLE_TIME
    #: As the reference's: perturbations from trim (:attr:`LinearReference.perturbations_from_trim`).
    perturbations_from_trim = True

    def __init__(self, speed_kt: int, *, flapping: bool = True, dynamic_inflow: bool = True,
                 actuators: bool = True, transport_delay: bool = True, off_axis_coupling: bool = True,
                 turbulence: bool = True, sensor_noise: bool = True):
        reference = Bo105Reference(speed_kt)
        self.speed_kt = reference.speed_kt
        self.name = f"{reference.name}-flight"
        self._effects = {"flapping": flapping, "dynamic_inflow": dynamic_inflow, "actuators": actuators,
                         "transport_delay": transport_delay, "off_axis_coupling": off_axis_coupling,
                         "turbulence": turbulence, "sensor_noise": sensor_noise}
        self._F, self._G = _augmented_system(reference, self._effects)
        self._discretisations: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def effects(self) -> dict[str, bool]:
        """Which effects are on (a copy)."""
        return dict(self._effects)

    def simulate(self, time, inputs, *, seed: int = 0) -> Recording:
        """Fly ``inputs`` from trim and record all 8 states as the instrumented aircraft would.

        Parameters
        ----------
        time : array_like, shape (n,)
            Evenly spaced sample times, s (``t0 + k*h``), n >= 2.
        inputs : array_like, shape (n, 4)
            ``theta_0, theta_1s, theta_1c, theta_0T``, rad, as commanded; row k is held from
            ``time[k]`` to ``time[k+1]``. Internally each interval is split into
            ``ceil(h / MAX_INTERNAL_STEP)`` equal steps.
        seed : int
            Seeds turbulence and sensor noise; the same seed gives the same recording.

        Returns
        -------
        Recording
            ``inputs`` as commanded and ``u, w, q, theta, v, p, phi, r`` as measured.
        """
        time, inputs, step = check_history(time, inputs, INPUT_NAMES)
        substeps = math.ceil(step / MAX_INTERNAL_STEP - 1e-9)
        internal_step = step / substeps
        n_internal = (len(time) - 1) * substeps
        delay = round(TRANSPORT_DELAY / internal_step) if self._effects["transport_delay"] else 0
        turbulence_rng, noise_rng = np.random.default_rng(seed).spawn(2)

        commands = np.zeros((n_internal, len(INPUT_NAMES)))
        commands[delay:] = np.repeat(inputs[:-1], substeps, axis=0)[:max(n_internal - delay, 0)]
        gusts = np.zeros((n_internal, 3))
        if self._effects["turbulence"]:
            advection = max(self.speed_kt * KNOT, TURBULENCE_MIN_ADVECTION_SPEED)
            gusts = dryden_gusts((TURBULENCE_STD,) * 3, (TURBULENCE_SCALE_LENGTH,) * 3, advection, internal_step,
                                 n_internal, turbulence_rng)
        Ad, Bd = cached_zero_order_hold(self._discretisations, self._F, self._G, internal_step)
        forcing = np.hstack([commands, gusts]) @ Bd.T
        outputs = propagate(Ad, forcing, np.zeros(len(Ad)), every=substeps)[:, :len(STATE_NAMES)]

        metadata = {"vehicle": self.name, "speed_kt": self.speed_kt, "sample_time": step, "seed": seed,
                    "effects": self.effects, "source": padfield_table()["source"]}
        if self._effects["sensor_noise"]:
            noise_std = np.array([SENSOR_NOISE_STD[name] for name in STATE_NAMES])
            outputs += noise_rng.standard_normal(outputs.shape) * noise_std
            metadata["sensor_noise_std"] = dict(SENSOR_NOISE_STD)
        return Recording(time, inputs, INPUT_NAMES, outputs, STATE_NAMES, metadata)
