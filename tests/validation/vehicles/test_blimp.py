"""Tests of the blimp reference and its flight-test stand-in (validation/vehicles/blimp.py,
its equations in validation/vehicles/blimp_equations.py).

Properties, not only numbers: equilibria, hand-computed force balances, the small-angle
pendulum formula, energy dissipation, vectorisation, and each documented stand-in effect.
"""
import dataclasses

import numpy as np
import pytest

from validation.core.errors import BadInputError
from validation.core.manoeuvres import doublet, three_two_one_one, time_grid
from validation.vehicles import get_vehicle
from validation.vehicles.blimp import BlimpParameters, BlimpReference, blimp_dynamics
from validation.vehicles.blimp_equations import (
    STANDARD_GRAVITY,
    parameter_names,
    parameters_from_vector,
    rk4_advance,
)
from validation.vehicles.blimp_flight import FLIGHT_TEST_PARAMETERS, BlimpFlightTest

PARAMS = BlimpParameters()


def held(time, *, u_gondola=0.0, mu=0.0, u_tail=0.0):
    """Constant inputs, shape (n, 3)."""
    return np.column_stack([np.full_like(time, u_gondola), np.full_like(time, mu), np.full_like(time, u_tail)])


def manoeuvre_inputs(time):
    """Gondola 3-2-1-1, vectoring doublet and tail doublet: excites every axis of the ODE."""
    return np.column_stack([
        three_two_one_one(time, amplitude=0.8, step_time=1.0, start=0.5),
        doublet(time, amplitude=0.4, step_time=1.5, start=2.0),
        doublet(time, amplitude=0.6, step_time=1.0, start=5.0),
    ])


def mass_matrix(params):
    """M = M_RB + M_A (6, 6) built here independently from Fossen 2011 eq. 3.44."""
    m, r_g = params.mass, np.asarray(params.cg_position)
    skew = np.array([[0, -r_g[2], r_g[1]], [r_g[2], 0, -r_g[0]], [-r_g[1], r_g[0], 0]])
    matrix = np.block([[m * np.eye(3), -m * skew], [m * skew, np.diag(params.inertia)]])
    return matrix + np.diag(np.concatenate([params.added_mass, params.added_inertia]))


def kinetic_energy(states, params):
    """1/2 nu' M nu, rigid body plus added mass, J; states (..., 12) -> (...)."""
    nu = states[..., 6:12]
    return 0.5 * np.einsum("...i,ij,...j->...", nu, mass_matrix(params), nu)


def potential_energy(states, params):
    """Weight at the CG and buoyancy at the CB, J, zero hanging at rest at z = 0. NED: z is
    down, so net lift does work when z decreases; the CG sits (n . r_g) below the CB, n the
    down direction in body axes, and |r_g| below it when hanging."""
    phi, theta = states[..., 3], states[..., 4]
    down = np.stack([-np.sin(theta), np.cos(theta) * np.sin(phi), np.cos(theta) * np.cos(phi)], axis=-1)
    r_g = np.asarray(params.cg_position)
    return params.net_lift * states[..., 2] + params.mass * STANDARD_GRAVITY * (np.linalg.norm(r_g) - down @ r_g)


# --------------------------------------------------------------------------------------------
# Reference: equilibria, force balances, modes, energy


@pytest.mark.parametrize("method", ["rk4", "adaptive"])
def test_neutral_hover_with_zero_input_stays_put(method):
    time = time_grid(duration=10.0, sample_time=0.05)
    states = BlimpReference().simulate_states(time, held(time), method=method)
    # Hover at rest is an exact equilibrium (every force and moment is exactly 0.0), so any
    # departure is a modelling error; 1e-12 only spares us from demanding bit-exact zeros.
    assert np.max(np.abs(states)) < 1e-12


def test_gondola_thrust_reaches_the_hand_computed_terminal_velocity():
    mu = 0.5
    time = time_grid(duration=40.0, sample_time=0.05)
    # 0.05 s steps: a steady state is a fixed point of RK4 whatever the step, and the fastest
    # mode (roll pendulum, 4.8 rad/s) stays well inside RK4's stability region (h w = 0.24).
    final = BlimpReference(max_step=0.05).simulate_states(time, held(time, u_gondola=1.0, mu=mu))[-1]
    thrust = PARAMS.gondola_thrust_forward
    # Steady, w = 0, neutral buoyancy. Surge: T cos(mu) = d_x U^2. Heave: the upward thrust
    # T sin(mu) balances quadratic drag d_z W^2 plus fin lift k U |W|, a quadratic in |W|.
    u_expected = np.sqrt(thrust * np.cos(mu) / PARAMS.quadratic_drag[0])
    k, d_z = PARAMS.fin_lift * u_expected, PARAMS.quadratic_drag[2]
    w_expected = -(-k + np.sqrt(k**2 + 4 * d_z * thrust * np.sin(mu))) / (2 * d_z)
    # Pitch: thrust moment + Munk moment U W (Z_w' - X_u') + fin moment -l k U W
    # = pendulum moment m g z_g sin(theta).
    munk = u_expected * w_expected * (PARAMS.added_mass[2] - PARAMS.added_mass[0])
    fin = -PARAMS.tail_arm * k * w_expected
    sin_theta = (PARAMS.gondola_arm * thrust * np.cos(mu) + munk + fin) / (
        PARAMS.mass * STANDARD_GRAVITY * PARAMS.cg_position[2])
    # After 40 s the slowest transient (pitch oscillation, decay rate 0.21 /s) is down by
    # e^-8 and surge/heave (rates ~0.4 /s) by e^-16: 1e-4 relative is 30x that residue.
    assert final[6] == pytest.approx(u_expected, rel=1e-4)
    assert final[8] == pytest.approx(w_expected, rel=1e-4)
    assert final[4] == pytest.approx(np.arcsin(sin_theta), rel=1e-4)
    assert np.abs(final[[7, 9, 10, 11]]).max() < 1e-5  # no sideslip and no rotation left


def test_rk4_and_adaptive_solver_agree_on_a_manoeuvre():
    time = time_grid(duration=10.0, sample_time=0.05)
    inputs = manoeuvre_inputs(time)
    reference = BlimpReference()
    rk4 = reference.simulate_states(time, inputs, method="rk4")
    adaptive = reference.simulate_states(time, inputs, method="adaptive")
    assert np.ptp(rk4[:, 0]) > 1.0  # the manoeuvre really moves the blimp (metres)
    # RK4 with h = 0.01 s has a global error ~ (w h)^4 ~ 5e-6 of a mode's amplitude for the
    # fastest mode (4.8 rad/s, amplitudes < 1 in SI units); the adaptive solver runs at
    # rtol 1e-8. Measured difference ~1e-8; 1e-6 leaves room and still catches a wrong step.
    np.testing.assert_allclose(rk4, adaptive, rtol=0, atol=1e-6)


@pytest.mark.parametrize("axis, coupled_translation", [(0, 1), (1, 0)], ids=["roll", "pitch"])
def test_pendulum_period_matches_the_small_angle_formula(axis, coupled_translation):
    """Linearised about hover (CG z_g below the CB), translation and rotation couple through
    M_RB: (m + X_u') U_dot + m z_g Q_dot = 0 and m z_g U_dot + (I_yy + M_q') Q_dot + d_q Q
    + m g z_g theta = 0 (pitch; roll likewise with V and sway). Eliminating U_dot gives
    J Q_dot + d Q + m g z_g theta = 0 with J = I + I_added - (m z_g)^2 / (m + m_added), so
    omega_n = sqrt(m g z_g / J), zeta = d / (2 sqrt(m g z_g J)), T = 2 pi / (omega_n sqrt(1 - zeta^2))."""
    m, z_g = PARAMS.mass, PARAMS.cg_position[2]
    inertia = (PARAMS.inertia[axis] + PARAMS.added_inertia[axis]
               - (m * z_g) ** 2 / (m + PARAMS.added_mass[coupled_translation]))
    stiffness = m * STANDARD_GRAVITY * z_g
    omega_n = np.sqrt(stiffness / inertia)
    zeta = PARAMS.rotational_damping[axis] / (2 * np.sqrt(stiffness * inertia))
    period = 2 * np.pi / (omega_n * np.sqrt(1 - zeta**2))

    time = time_grid(duration=15.0, sample_time=0.05)
    initial = np.zeros(12)
    initial[3 + axis] = 0.02  # rad
    # 0.05 s RK4 steps: frequency error (w h)^4 / 120 < 3e-5 and amplitude error
    # (w h)^6 / 144 per step < 2e-6 at the 4.8 rad/s roll mode, far inside the tolerances.
    angle = BlimpReference(max_step=0.05).simulate_states(time, held(time), initial_state=initial)[:, 3 + axis]
    up = np.flatnonzero((angle[:-1] < 0) & (angle[1:] >= 0))
    crossings = time[up] - angle[up] * (time[up + 1] - time[up]) / (angle[up + 1] - angle[up])
    assert len(crossings) >= 6
    # Errors: finite amplitude lengthens the period by theta0^2/16 = 2.5e-5; interpolating the
    # zero crossings linearly ~1e-5 s. Leaving out the coupling term would shift it by 7 %.
    assert np.mean(np.diff(crossings)) == pytest.approx(period, rel=1e-3)
    peaks = np.flatnonzero((angle[1:-1] > angle[:-2]) & (angle[1:-1] > angle[2:])) + 1
    decrement = np.log(angle[peaks[0]] / angle[peaks[-1]]) / (len(peaks) - 1)
    # Quadratic drag on the small coupled translation adds ~0.3 % damping; 2 % tolerance.
    assert decrement / (2 * np.pi) == pytest.approx(zeta, rel=0.02)


def test_power_balance_drag_is_the_only_sink_when_thrust_is_off():
    """dE/dt = -(v' D_lin v + sum d_q |v|^3 + w' D_rot w + k |U| |c|^2) at any state (c: the
    cross-flow at the fins): C(nu) does no work and gravity/buoyancy are conservative.
    Checked with every coupling switched on."""
    params = dataclasses.replace(
        PARAMS, cg_position=(0.02, -0.01, 0.15), added_inertia=(0.004, 0.01, 0.012),
        linear_drag=(0.01, 0.02, 0.03), net_lift=0.003)
    rng = np.random.default_rng(1)
    states = rng.normal(0.0, 0.4, (20, 12))
    rates = blimp_dynamics(states, np.zeros(3), params)
    kinetic_rate = np.einsum("ni,ij,nj->n", rates[:, 6:], mass_matrix(params), states[:, 6:])
    eps = 1e-6  # central difference of the potential along the kinematic rates, error ~eps^2
    potential_rate = (potential_energy(states + eps * rates, params)
                      - potential_energy(states - eps * rates, params)) / (2 * eps)
    v, w = states[:, 6:9], states[:, 9:12]
    dissipation = (v**2 @ np.asarray(params.linear_drag) + np.abs(v) ** 3 @ np.asarray(params.quadratic_drag)
                   + w**2 @ np.asarray(params.rotational_damping)
                   + params.fin_lift * np.abs(v[:, 0]) * ((v[:, 1] - params.tail_arm * w[:, 2]) ** 2
                                                          + (v[:, 2] + params.tail_arm * w[:, 1]) ** 2))
    # Both sides are sums of O(0.01) W terms evaluated in double precision; 1e-9 W is far
    # below any sign or factor error, which would show at the 1e-3 W level.
    np.testing.assert_allclose(kinetic_rate + potential_rate, -dissipation, rtol=0, atol=1e-9)


def test_energy_decays_monotonically_with_thrust_off_but_kinetic_energy_alone_does_not():
    time = time_grid(duration=10.0, sample_time=0.05)
    initial = np.zeros(12)
    initial[3:5] = [0.3, -0.4]  # rad: let go from a tilted attitude ...
    initial[6:12] = [0.6, 0.2, -0.1, 0.0, 0.0, 0.5]  # ... while moving and turning (m/s, rad/s)
    states = BlimpReference().simulate_states(time, held(time), initial_state=initial)
    kinetic = kinetic_energy(states, PARAMS)
    energy = kinetic + potential_energy(states, PARAMS)
    # Drag removes energy every step (RK4's own energy error, ~(w h)^6/144 ~ 1e-10 per step,
    # also removes energy); 1e-12 of the initial energy only absorbs rounding.
    assert np.all(np.diff(energy) <= 1e-12 * energy[0])
    # Pendulum energy decays like exp(-2 zeta omega_n t) = exp(-4) in 10 s (zeta 0.06, 3.3 rad/s).
    assert energy[-1] < 0.1 * energy[0]
    # The pendulum hands energy back to motion, so kinetic energy alone is not monotone.
    assert np.any(np.diff(kinetic) > 1e-6 * kinetic[0])


def test_tail_thrust_gives_mirror_symmetric_yaw_in_the_reference():
    time = time_grid(duration=15.0, sample_time=0.05)
    reference = BlimpReference(max_step=0.05)  # coarse steps: both runs share the same error
    right = reference.simulate_states(time, held(time, u_tail=0.5))
    left = reference.simulate_states(time, held(time, u_tail=-0.5))
    assert right[-1, 11] > 0.3  # positive u_tail yaws the nose right (rad/s)
    mirror = np.array([1, -1, 1, -1, 1, -1, 1, -1, 1, -1, 1, -1])  # y, phi, psi, V, P, R flip
    # Left-right symmetric vehicle: the runs are exact mirror images up to rounding.
    np.testing.assert_allclose(left, right * mirror, rtol=0, atol=1e-12)


# --------------------------------------------------------------------------------------------
# Vectorisation and parameter vectors


def test_vectorised_dynamics_and_rk4_equal_the_per_sample_loop():
    rng = np.random.default_rng(2)
    states = rng.normal(0.0, 0.5, (5, 4, 12))
    inputs = np.column_stack([rng.uniform(-1, 1, 4), rng.uniform(-1, 1, 4), rng.uniform(-1, 1, 4)])
    batched = blimp_dynamics(states, inputs, PARAMS)  # inputs (4, 3) broadcast over axis 0
    stepped = rk4_advance(states, inputs, 0.02, PARAMS, max_step=0.02)  # one RK4 step
    assert batched.shape == stepped.shape == (5, 4, 12)
    for i in range(5):
        for j in range(4):
            # Same arithmetic per element; matrix products may sum in another order (1 ulp).
            np.testing.assert_allclose(batched[i, j], blimp_dynamics(states[i, j], inputs[j], PARAMS),
                                       rtol=1e-13, atol=1e-15)
            one = rk4_advance(states[i, j], inputs[j], 0.02, PARAMS, max_step=0.02)
            np.testing.assert_allclose(stepped[i, j], one, rtol=1e-13, atol=1e-15)


def test_parameter_vector_round_trip_and_replace():
    params = dataclasses.replace(PARAMS, net_lift=0.01, cg_position=(0.01, 0.0, 0.2))
    vector = params.to_vector()
    names = BlimpParameters.vector_names()
    assert vector.shape == (len(names),) == (len(set(names)),)
    assert BlimpParameters.from_vector(vector) == params
    assert vector[names.index("net_lift")] == 0.01
    assert vector[names.index("cg_position_z")] == 0.2
    assert params.mass == PARAMS.mass  # replace changed only what it was asked to
    with pytest.raises(BadInputError, match="30 entries"):
        BlimpParameters.from_vector(vector[:-1])


def test_the_numpy_only_decoding_gives_the_fields_of_the_parameters():
    """blimp_equations.parameters_from_vector, which the blimp FMU decodes its model file's named
    vector with, gives every field of BlimpParameters as the dataclass holds it (triples as
    tuples), so the shipped equations read the same numbers."""
    params = dataclasses.replace(PARAMS, net_lift=0.01, cg_position=(0.01, 0.0, 0.2))
    fields = parameters_from_vector(BlimpParameters.vector_names(), params.to_vector())
    assert fields == dataclasses.asdict(params)
    assert list(fields) == [field.name for field in dataclasses.fields(BlimpParameters)]
    assert parameter_names(fields) == BlimpParameters.vector_names()


def test_default_parameters_follow_the_documented_scaling():
    mass_ratio = 0.35 / 0.184
    length_ratio = mass_ratio ** (1 / 3)
    assert PARAMS.mass == pytest.approx(0.35)
    assert PARAMS.added_mass[1] == pytest.approx(0.129 * mass_ratio)
    assert PARAMS.inertia[2] == pytest.approx(0.0193 * mass_ratio * length_ratio**2)
    assert PARAMS.quadratic_drag[0] == pytest.approx(0.07 * length_ratio**2)
    assert PARAMS.cg_position[2] == pytest.approx(0.125 * length_ratio)
    assert PARAMS.gondola_thrust_forward == pytest.approx(0.04 * mass_ratio)


# --------------------------------------------------------------------------------------------
# Vehicle interface and bad input


def test_registry_and_reference_recording():
    time = time_grid(duration=2.0, sample_time=0.05)
    recording = get_vehicle("blimp").simulate(time, manoeuvre_inputs(time))
    assert recording.output_names == ("x", "y", "z", "phi", "theta", "psi", "U", "V", "W", "P", "Q", "R")
    assert recording.input_names == ("u_gondola", "mu", "u_tail")
    assert recording.metadata["sample_time"] == pytest.approx(0.05)
    assert isinstance(get_vehicle("blimp-flight"), BlimpFlightTest)


@pytest.mark.parametrize("vehicle", [BlimpReference(), BlimpFlightTest()], ids=["blimp", "blimp-flight"])
@pytest.mark.parametrize("break_it, message", [
    (lambda t, u: (t, np.where(np.arange(len(t))[:, None] == 3, np.nan, u)), "row 3, column 'u_gondola'"),
    (lambda t, u: (t, u[:, :2]), r"shape \(11, 3\)"),
    (lambda t, u: (t[::-1], u), "strictly increasing"),
    (lambda t, u: (t, u * np.array([1.0, 1.0, 3.0])), "outside the command range"),
])
def test_bad_input_raises_one_clear_error(vehicle, break_it, message):
    time = time_grid(duration=0.5, sample_time=0.05)
    inputs = held(time, u_gondola=0.5, u_tail=0.5)
    with pytest.raises(BadInputError, match=message):
        vehicle.simulate(*break_it(time, inputs))


def test_bad_shapes_in_dynamics_and_parameters_raise():
    with pytest.raises(BadInputError, match=r"state must have shape \(\.\.\., 12\)"):
        blimp_dynamics(np.zeros(11), np.zeros(3), PARAMS)
    with pytest.raises(BadInputError, match=r"inputs must have shape \(\.\.\., 3\)"):
        blimp_dynamics(np.zeros(12), np.zeros(2), PARAMS)
    with pytest.raises(BadInputError, match="added_mass needs 3 numbers"):
        dataclasses.replace(PARAMS, added_mass=(0.1, 0.2))
    with pytest.raises(BadInputError, match="net_lift must be finite"):
        dataclasses.replace(PARAMS, net_lift=float("nan"))


# --------------------------------------------------------------------------------------------
# Flight-test stand-in: each documented effect


def quiet_flight_test(**options):
    """The stand-in with buoyancy drift and mocap off (true states out), other effects on."""
    return BlimpFlightTest(**{"buoyancy_drift": 0.0, "mocap": False, **options})


def test_stand_in_with_every_effect_off_is_the_reference():
    time = time_grid(duration=5.0, sample_time=0.05)
    inputs = manoeuvre_inputs(time)
    bare = BlimpFlightTest(params=BlimpParameters(), motor_time_constants=None, dead_band=0.0,
                           buoyancy_drift=0.0, mocap=False)
    # Same RK4 steps on the same states (the fan states are unused): equal up to rounding.
    np.testing.assert_allclose(bare.simulate(time, inputs).outputs,
                               BlimpReference().simulate(time, inputs).outputs, rtol=0, atol=1e-12)


def test_dead_band_small_commands_give_no_motion():
    time = time_grid(duration=3.0, sample_time=0.05)
    inputs = held(time, u_gondola=0.08, u_tail=-0.09)  # both inside the 0.1 dead band
    flight = quiet_flight_test().simulate(time, inputs).outputs
    # No thrust: the blimp hangs in its static attitude (1.8 deg roll), exactly at rest.
    assert np.max(np.abs(flight - flight[0])) < 1e-12
    assert flight[0, 3] == pytest.approx(np.arctan2(0.005, FLIGHT_TEST_PARAMETERS.cg_position[2]))
    reference = BlimpReference().simulate(time, inputs).outputs
    assert reference[-1, 0] > 0.02  # the same commands drive the reference forward (m)


def test_tail_is_stronger_one_way_in_the_stand_in():
    time = time_grid(duration=15.0, sample_time=0.05)
    # Centred CG, so that the only left-right asymmetry left is the tail fan's.
    symmetric_cg = dataclasses.replace(FLIGHT_TEST_PARAMETERS, cg_position=PARAMS.cg_position)
    vehicle = quiet_flight_test(params=symmetric_cg, max_step=0.05)  # same steps in every run
    yaw_rate = {u: vehicle.simulate(time, held(time, u_tail=u)).output("R") for u in (0.5, -0.5, 0.3)}
    # Different magnitudes for +u and -u (measured final ratio 0.48; fin damping grows with
    # the speed the tail force causes, so it is not simply the thrust ratio 0.6).
    assert yaw_rate[0.5][-1] > 0 > yaw_rate[-0.5][-1]
    assert abs(yaw_rate[-0.5][-1]) < 0.8 * yaw_rate[0.5][-1]
    # Precisely: -0.5 pushes 0.6 * 0.5 = 0.3 worth, so it mirrors +0.3 up to rounding.
    np.testing.assert_allclose(yaw_rate[-0.5], -yaw_rate[0.3], rtol=0, atol=1e-12)


def test_motor_lag_delays_the_thrust_but_not_the_terminal_speed():
    time = time_grid(duration=30.0, sample_time=0.05)
    inputs = held(time, u_gondola=1.0)
    lagged = quiet_flight_test(max_step=0.05).simulate(time, inputs).output("U")
    instant = quiet_flight_test(motor_time_constants=None, max_step=0.05).simulate(time, inputs).output("U")
    k = 6  # t = 0.3 s = the gondola fans' time constant
    # Early on U is nearly proportional to the thrust impulse, which the lag cuts to
    # 1 - (1 - e^-1) = 37 % at t = tau; 0.6 leaves room for the pitch coupling.
    assert lagged[k] < 0.6 * instant[k]
    # Both reach the same drag-limited speed (30 s >> 0.3 s lag); 1e-3 is the remaining
    # surge transient, e^-(0.4/s * 30 s) relative, with margin.
    assert lagged[-1] == pytest.approx(instant[-1], rel=1e-3)


def test_buoyancy_drift_moves_a_hovering_blimp_vertically():
    time = time_grid(duration=30.0, sample_time=0.05)
    drifting = BlimpFlightTest(mocap=False, max_step=0.05).simulate(time, held(time), seed=0).output("z")
    steady = quiet_flight_test(max_step=0.05).simulate(time, held(time), seed=0).output("z")
    assert np.max(np.abs(steady)) < 1e-12  # without drift the trimmed blimp stays at z = 0
    # Net lift of order 1 mN against heave drag 0.34 kg/m gives ~5 cm/s: centimetres in 30 s
    # (seed 0; 1 mm is far below that and far above rounding).
    assert np.max(np.abs(drifting)) > 1e-3


@pytest.fixture(scope="module")
def mocap_hover():
    """20 s of zero-input hover through the mocap pipeline (drift off: true pose constant)."""
    time = time_grid(duration=20.0, sample_time=0.05)
    # Coarse RK4 steps are exact here: the true pose stays at the hanging equilibrium.
    return BlimpFlightTest(buoyancy_drift=0.0, max_step=0.05).simulate(time, held(time), seed=3)


def test_mocap_timing_jitter_makes_uneven_sampling(mocap_hover):
    steps = np.diff(mocap_hover.time)
    assert mocap_hover.metadata["uneven_sampling"] is True
    assert mocap_hover.metadata["sample_time_nominal"] == pytest.approx(0.05)
    # Steps are differences of two 4 ms jitters: std 4 ms * sqrt(2) = 5.7 ms; 400 steps give
    # the sample std to ~5 %, so 20 % bounds cannot fail by chance yet catch a wrong jitter.
    assert 0.8 * 0.0057 < np.std(steps) < 1.2 * 0.0057
    assert np.all(np.abs(steps - 0.05) <= 2 * 0.25 * 0.05 + 1e-12)  # clipped at a quarter step
    assert np.mean(steps) == pytest.approx(0.05, abs=1e-4)  # jitter does not drift the clock


def test_mocap_noise_and_differentiated_velocities_match_the_documented_std(mocap_hover):
    out = mocap_hover.outputs
    documented = mocap_hover.metadata["sensor_noise_std"]
    assert (documented["x"], documented["phi"]) == (0.001, pytest.approx(np.radians(0.5)))
    assert (documented["U"], documented["P"]) == pytest.approx(
        (0.001 / (np.sqrt(10) * 0.05), np.radians(0.5) / (np.sqrt(10) * 0.05)))
    # 401 samples estimate a std to within ~3.5 % (1/sqrt(2n)); 20 % bounds.
    np.testing.assert_allclose(out[:, 0:3].std(axis=0), 0.001, rtol=0.2)
    np.testing.assert_allclose(out[:, 3:6].std(axis=0), np.radians(0.5), rtol=0.2)
    # Velocities are slopes of a 5-point quadratic fit of the noisy poses, not the true zeros:
    # std = sigma / (sqrt(10) h) = 6.3 mm/s and 0.055 rad/s on the even grid; jitter changes
    # the weights by a few per cent, so 25 % bounds.
    np.testing.assert_allclose(out[:, 6:9].std(axis=0), 0.001 / (np.sqrt(10) * 0.05), rtol=0.25)
    np.testing.assert_allclose(out[:, 9:12].std(axis=0), np.radians(0.5) / (np.sqrt(10) * 0.05), rtol=0.25)


def test_stand_in_is_reproducible_from_its_seed():
    time = time_grid(duration=3.0, sample_time=0.05)
    inputs = manoeuvre_inputs(time)
    vehicle = BlimpFlightTest()
    first, again, other = (vehicle.simulate(time, inputs, seed=s) for s in (7, 7, 8))
    assert np.array_equal(first.time, again.time) and np.array_equal(first.outputs, again.outputs)
    assert first.metadata == again.metadata
    assert not np.array_equal(first.time, other.time)
    assert not np.array_equal(first.outputs, other.outputs)
