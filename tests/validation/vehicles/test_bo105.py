"""Bo105 reference (Padfield's linear models) and the flight-test stand-in, effect by effect."""
import json
import math
from importlib.resources import files

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from validation.core.errors import BadInputError
from validation.core.manoeuvres import three_two_one_one, time_grid
from validation.vehicles import bo105_flight, get_vehicle
from validation.vehicles.bo105 import BO105_SPEEDS_KT, INPUT_NAMES, STATE_NAMES, Bo105Reference
from validation.vehicles.bo105_flight import EFFECTS, Bo105FlightTest
from validation.vehicles.linear_discretisation import zero_order_hold

P, Q, R, U, V, W = (STATE_NAMES.index(name) for name in ("p", "q", "r", "u", "v", "w"))
THETA_0, THETA_1S = INPUT_NAMES.index("theta_0"), INPUT_NAMES.index("theta_1s")
ALL_OFF = dict.fromkeys(EFFECTS, False)


def table(speed_kt):
    data = json.loads((files("validation.vehicles") / "data" / "bo105_padfield_linear.json").read_text())
    return next(c for c in data["conditions"] if c["speed_kt"] == speed_kt)


DEGREE = math.radians(1.0)


def cyclic_3211(*, duration=8.0, sample_time=0.01, step_time=0.4, amplitude=DEGREE):
    """The Bo105 paper's manoeuvre: theta_1s 3-2-1-1 starting at 1 s."""
    time = time_grid(duration=duration, sample_time=sample_time)
    inputs = np.zeros((len(time), 4))
    inputs[:, THETA_1S] = three_two_one_one(time, amplitude=amplitude, step_time=step_time, start=1.0)
    return time, inputs


def integrate_piecewise(rhs, time, inputs, n_states):
    """Tight adaptive RK (DOP853) through each stretch of constant input, sampled at ``time``."""
    states = np.zeros((len(time), n_states))
    changes = np.flatnonzero(np.any(np.diff(inputs[:-1], axis=0) != 0, axis=1)) + 1
    edges = np.concatenate(([0], changes, [len(time) - 1]))
    x = np.zeros(n_states)
    for k0, k1 in zip(edges[:-1], edges[1:]):
        solution = solve_ivp(lambda t, x, held=inputs[k0]: rhs(x, held), (time[k0], time[k1]), x,
                             method="DOP853", t_eval=time[k0:k1 + 1], rtol=1e-11, atol=1e-13)
        states[k0:k1 + 1] = solution.y.T
        x = solution.y[:, -1]
    return states


def flight(speed_kt=80, **on):
    """A stand-in with only the named effects on."""
    return Bo105FlightTest(speed_kt, **{**ALL_OFF, **on})


# --- The reference ---------------------------------------------------------------------------

@pytest.mark.parametrize("speed_kt", BO105_SPEEDS_KT)
def test_reference_is_the_tabulated_model(speed_kt):
    reference = Bo105Reference(speed_kt)
    A = np.array(table(speed_kt)["A"])
    np.testing.assert_array_equal(reference.A, A)
    np.testing.assert_array_equal(reference.B, np.array(table(speed_kt)["B"]))
    assert reference.name == f"bo105-{speed_kt}kt"


@pytest.mark.parametrize("speed_kt", BO105_SPEEDS_KT)
def test_discrete_eigenvalues_are_exp_of_continuous_ones(speed_kt):
    """Exact ZOH: the eigenvalues of Phi = expm(A h) are exp(lambda h) for every mode of A."""
    reference = Bo105Reference(speed_kt)
    h = 0.01
    phi, _ = reference.discretisation(h)
    expected = np.sort_complex(np.exp(np.linalg.eigvals(np.array(table(speed_kt)["A"])) * h))
    # Eigenvalues of a non-normal 8x8 matrix are computed to ~1e-12 here; modes are distinct.
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(phi)), expected, atol=1e-10)


def test_80kt_modes_are_padfields():
    eigenvalues = Bo105Reference(80).eigenvalues()
    real = eigenvalues[np.abs(eigenvalues.imag) < 1e-9].real
    # Tolerances: half a unit in the last digit of the eigenvalues quoted in docs/vehicles.md
    # (-13.7, -4.25, -0.565 +/- 2.641j).
    assert np.min(np.abs(real - (-13.7))) < 0.05, "roll subsidence"
    assert np.min(np.abs(real - (-4.25))) < 0.005, "pitch subsidence"
    dutch_roll = eigenvalues[np.argmin(np.abs(eigenvalues - (-0.565 + 2.641j)))]
    assert abs(dutch_roll.real + 0.565) < 0.0005 and abs(dutch_roll.imag - 2.641) < 0.0005
    phugoid = eigenvalues[np.argmax(eigenvalues.real)]
    assert 0 < phugoid.real < 0.05 and phugoid.imag != 0, "slightly unstable phugoid"


def test_zero_order_hold_matches_fine_runge_kutta():
    reference = Bo105Reference(80)
    time, inputs = cyclic_3211(duration=5.0)
    A, B = reference.A, reference.B
    exact = integrate_piecewise(lambda x, u: A @ x + B @ u, time, inputs, 8)
    # DOP853 at rtol 1e-11 is accurate to ~1e-10 of the signal; the ZOH is exact to rounding.
    np.testing.assert_allclose(reference.simulate(time, inputs).outputs, exact,
                               atol=1e-8 * np.abs(exact).max())


def test_free_response_from_an_initial_state_is_the_matrix_exponential():
    reference = Bo105Reference(80)
    time = time_grid(duration=2.0, sample_time=0.01, start_time=3.0)
    x0 = np.array([1.0, -0.5, 0.02, 0.01, 0.3, -0.05, 0.02, 0.01])
    states = reference.simulate_states(time, np.zeros((len(time), 4)), initial_state=x0)
    for k in (0, 1, 50, 200):
        expected = expm(reference.A * (time[k] - time[0])) @ x0
        # 200 products of one 10 ms exponential against one 2 s exponential: rounding only.
        np.testing.assert_allclose(states[k], expected, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("step_time", [0.3, 0.4, 0.5])
def test_3211_peak_pitch_rate(step_time):
    time, inputs = cyclic_3211(step_time=step_time)
    q = Bo105Reference(80).simulate(time, inputs).output("q")
    # docs/vehicles.md: "about 0.21 rad/s" for 0.3-0.5 s steps; these derivatives give 0.213 (0.3 s) to
    # 0.223 (0.5 s), so the band is 0.21 -0.005 (rounding) / +0.025 (the long-step end).
    assert 0.205 < np.abs(q).max() < 0.235
    # The first excursion has the sign of M_theta_1s (positive in this data set).
    first = q[np.argmax(np.abs(q) > 0.01)]
    assert np.sign(first) == np.sign(Bo105Reference(80).derivative("M_theta_1s"))


def test_derivative_names_address_every_force_and_moment_entry_once():
    reference = Bo105Reference(80)
    names = reference.derivative_names()
    assert len(names) == len(set(names)) == 6 * 12
    changed_entries = set()
    for name in names:
        changed = reference.with_derivatives({name: 1234.5})
        difference = np.hstack([changed.A - reference.A, changed.B - reference.B])
        (row, column), = np.argwhere(difference != 0)
        changed_entries.add((row, column))
        assert changed.derivative(name) == 1234.5
    assert len(changed_entries) == len(names)
    kinematic_rows = {(row, column) for row in (3, 6) for column in range(12)}
    assert not changed_entries & kinematic_rows, "theta_dot and phi_dot have no derivative names"


def test_derivative_get_and_set_round_trip():
    reference = Bo105Reference(80)
    assert reference.derivative("M_q") == reference.A[2, 2] == -3.9954
    assert reference.derivative("L_q") == reference.A[5, 2]
    assert reference.derivative("M_theta_1s") == reference.B[2, 1]
    assert reference.derivative("N_r") == reference.A[7, 7]
    assert reference.derivative("L_theta_1c") == reference.B[5, 2]
    changed = reference.with_derivatives({"M_q": -2.4})
    assert changed.derivative("M_q") == -2.4
    assert reference.derivative("M_q") == -3.9954, "the original is unchanged"
    difference = changed.A - reference.A
    assert np.count_nonzero(difference) == 1 and difference[2, 2] == pytest.approx(-2.4 + 3.9954)
    np.testing.assert_array_equal(changed.B, reference.B)
    # A cached discretisation must not leak: less pitch damping gives a larger pitch response.
    time, inputs = cyclic_3211()
    q_reference = reference.simulate(time, inputs).output("q")
    recording = changed.simulate(time, inputs)
    assert np.abs(recording.output("q")).max() > 1.1 * np.abs(q_reference).max()
    assert recording.metadata["changed_derivatives"] == {"M_q": -2.4}


@pytest.mark.parametrize("name", ["M_x", "Q_q", "Mq", "theta_q", "M_theta_2s"])
def test_unknown_derivative_names_the_valid_ones(name):
    with pytest.raises(BadInputError, match="row letter .*M_q") as error:
        Bo105Reference(80).with_derivatives({name: 1.0})
    assert "\n" not in str(error.value)
    with pytest.raises(BadInputError):
        Bo105Reference(80).derivative(name)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), "fast", None])
def test_non_finite_derivative_is_refused(value):
    with pytest.raises(BadInputError, match="M_q must be a finite number"):
        Bo105Reference(80).with_derivatives({"M_q": value})


# --- Bad input -------------------------------------------------------------------------------

@pytest.mark.parametrize("vehicle", [Bo105Reference(80), Bo105FlightTest(80)], ids=lambda v: v.name)
def test_bad_input_is_one_clear_line(vehicle):
    time, inputs = cyclic_3211(duration=1.0)
    cases = []
    nan_inputs = inputs.copy()
    nan_inputs[17, THETA_1S] = np.nan
    cases.append(((time, nan_inputs), "row 17, column 'theta_1s'"))
    cases.append(((time, inputs[:, :3]), r"\(101, 4\).*got shape \(101, 3\)"))
    cases.append(((time, inputs[:-1]), r"\(101, 4\).*got shape \(100, 4\)"))
    uneven = time.copy()
    uneven[50] += 0.003
    cases.append(((uneven, inputs), "evenly spaced"))
    cases.append(((time[::-1], inputs), "strictly increasing"))
    cases.append(((time[:1], inputs[:1]), "at least 2 samples"))
    for (t, u), message in cases:
        with pytest.raises(BadInputError, match=message) as error:
            vehicle.simulate(t, u)
        assert "\n" not in str(error.value)


def test_bad_speed_and_initial_state():
    with pytest.raises(BadInputError, match="0, 20, 40, 60, 80, 100, 120, 140 kt"):
        Bo105Reference(85)
    with pytest.raises(BadInputError, match="0, 20, 40"):
        Bo105FlightTest(85)
    time, inputs = cyclic_3211(duration=1.0)
    with pytest.raises(BadInputError, match="initial_state"):
        Bo105Reference(80).simulate_states(time, inputs, initial_state=np.zeros(7))


def test_vehicle_registry_names_the_bo105_vehicles():
    reference, stand_in = get_vehicle("bo105-80kt"), get_vehicle("bo105-140kt-flight")
    assert isinstance(reference, Bo105Reference) and reference.name == "bo105-80kt"
    assert isinstance(stand_in, Bo105FlightTest) and stand_in.name == "bo105-140kt-flight"


def test_vehicle_interface_and_recording_layout():
    reference, stand_in = Bo105Reference(80), Bo105FlightTest(80)
    assert stand_in.name == "bo105-80kt-flight" and stand_in.sample_time == reference.sample_time == 0.01
    assert all(stand_in.effects.values()), "every effect is on by default"
    time, inputs = cyclic_3211(duration=2.0)
    for vehicle in (reference, stand_in):
        recording = vehicle.simulate(time, inputs, seed=3)
        assert recording.input_names == INPUT_NAMES and recording.output_names == STATE_NAMES
        np.testing.assert_array_equal(recording.time, time)
        np.testing.assert_array_equal(recording.inputs, inputs)
        assert recording.metadata["vehicle"] == vehicle.name
        assert recording.metadata["sample_time"] == pytest.approx(0.01)
        assert "Padfield" in recording.metadata["source"]
        json.dumps(recording.metadata)


# --- The flight-test stand-in, effect by effect ----------------------------------------------

@pytest.mark.parametrize("speed_kt", BO105_SPEEDS_KT)
def test_stand_in_with_every_effect_off_is_the_reference(speed_kt):
    time, inputs = cyclic_3211(duration=4.0)
    expected = Bo105Reference(speed_kt).simulate(time, inputs).outputs
    # Two 5 ms exponentials against one 10 ms one: equal to rounding.
    np.testing.assert_allclose(flight(speed_kt).simulate(time, inputs).outputs, expected,
                               atol=1e-12 * np.abs(expected).max())
    everything = Bo105FlightTest(speed_kt).simulate(time, inputs, seed=0)
    assert everything.metadata["vehicle"] == f"bo105-{speed_kt}kt-flight"
    assert np.all(np.isfinite(everything.outputs))


@pytest.mark.parametrize("sample_time", [0.01, 0.02])
def test_transport_delay_is_the_reference_with_shifted_inputs(sample_time):
    time, inputs = cyclic_3211(sample_time=sample_time)
    assert bo105_flight.TRANSPORT_DELAY == 0.04  # s, the module docstring's figure
    shift = round(0.04 / sample_time)
    delayed = np.zeros_like(inputs)
    delayed[shift:] = inputs[:-shift]
    expected = Bo105Reference(80).simulate(time, delayed).outputs
    np.testing.assert_allclose(flight(transport_delay=True).simulate(time, inputs).outputs, expected,
                               atol=1e-12 * np.abs(expected).max())


def test_actuators_are_a_second_order_filter_on_the_controls():
    reference = Bo105Reference(80)
    A, B = reference.A, reference.B
    w_a, zeta_a = 30.0, 0.7  # rad/s and damping ratio, the module docstring's figures

    def rhs(x, command):
        body, position, rate = x[:8], x[8:12], x[12:]
        acceleration = w_a**2 * (command - position) - 2 * zeta_a * w_a * rate
        return np.concatenate([A @ body + B @ position, rate, acceleration])

    time, inputs = cyclic_3211(duration=5.0)
    expected = integrate_piecewise(rhs, time, inputs, 16)[:, :8]
    # RK accurate to ~1e-10 of the signal; the stand-in's ZOH is exact.
    np.testing.assert_allclose(flight(actuators=True).simulate(time, inputs).outputs, expected,
                               atol=1e-8 * np.abs(expected).max())


def rotor_split(speed_kt=80):
    """The documented rotor part (A_rotor, B_rotor) of the reference, from named derivatives."""
    reference, hover = Bo105Reference(speed_kt), Bo105Reference(0)
    A_rotor, B_rotor = np.zeros((8, 8)), np.zeros((8, 4))
    for letter, row in (("X", 0), ("Y", 4), ("L", 5), ("M", 2), ("N", 7)):
        for column in (0, 1, 2):
            B_rotor[row, column] = reference.derivative(f"{letter}_{INPUT_NAMES[column]}")
    for name, row, column in (("L_p", P, P), ("M_q", Q, Q)):
        share = min(1.0, hover.derivative(name) / reference.derivative(name))
        A_rotor[row, column] = share * reference.derivative(name)
    A_rotor[P, Q], A_rotor[Q, P] = reference.derivative("L_q"), reference.derivative("M_p")
    return A_rotor, B_rotor


def test_flapping_lags_the_rotor_part_by_the_flap_time_constant():
    reference = Bo105Reference(80)
    A, B = reference.A, reference.B
    A_rotor, B_rotor = rotor_split()
    tau = 16 / (5.09 * 44.4)  # Padfield 2007, sec. 3.2: 16 / (gamma Omega), about 0.07 s
    assert bo105_flight.FLAP_TIME_CONSTANT == pytest.approx(tau) == pytest.approx(0.0708, abs=5e-5)

    def rhs(x, u):
        body, rotor = x[:8], x[8:]
        return np.concatenate([(A - A_rotor) @ body + (B - B_rotor) @ u + rotor,
                               (A_rotor @ body + B_rotor @ u - rotor) / tau])

    time, inputs = cyclic_3211(duration=5.0)
    expected = integrate_piecewise(rhs, time, inputs, 16)[:, :8]
    recorded = flight(flapping=True).simulate(time, inputs).outputs
    np.testing.assert_allclose(recorded, expected, atol=1e-8 * np.abs(expected).max())
    # Property: one sample after the step the lagged moment has built up to about
    # h / (2 tau) = 7 % of the quasi-static one, so q is far below the reference's.
    onset = np.argmax(inputs[:, THETA_1S] != 0) + 1
    q_reference = reference.simulate(time, inputs).output("q")
    assert abs(recorded[onset, Q]) < 0.2 * abs(q_reference[onset])


def fitted_phase_and_gain(time, signal, frequency, *, start):
    """Phase (deg) and amplitude of the ``frequency`` component of ``signal`` after ``start``."""
    keep = time >= start
    omega_t = 2 * np.pi * frequency * time[keep]
    # A constant and a ramp absorb the slow (phugoid, spiral) drift.
    basis = np.column_stack([np.sin(omega_t), np.cos(omega_t), np.ones(keep.sum()), time[keep]])
    sine, cosine = np.linalg.lstsq(basis, signal[keep], rcond=None)[0][:2]
    return np.degrees(np.arctan2(cosine, sine)), np.hypot(sine, cosine)


def sine_response(vehicle, frequency, *, duration=10.0):
    time = time_grid(duration=duration, sample_time=0.01)
    inputs = np.zeros((len(time), 4))
    inputs[:, THETA_1S] = math.radians(0.5) * np.sin(2 * np.pi * frequency * time)
    return fitted_phase_and_gain(time, vehicle.simulate(time, inputs).output("q"), frequency, start=5.0)


def extra_lag(vehicle, frequency):
    """Phase lag (deg) and gain ratio of ``vehicle``'s q against the reference's."""
    phase, gain = sine_response(vehicle, frequency)
    phase_reference, gain_reference = sine_response(Bo105Reference(80), frequency)
    return (phase_reference - phase + 180) % 360 - 180, gain / gain_reference


def test_delay_and_actuator_phase_lag_is_as_predicted():
    frequency = 1.5  # Hz, 9.4 rad/s: near the top of the piloted band
    omega, w_a, zeta_a, delay = 2 * np.pi * frequency, 30.0, 0.7, 0.04  # module docstring
    actuator = w_a**2 / (w_a**2 - omega**2 + 2j * zeta_a * w_a * omega)
    predicted = np.degrees(omega * delay - np.angle(actuator))
    lag, gain = extra_lag(flight(transport_delay=True, actuators=True), frequency)
    # The sine fit over 5 s with a drift term is good to ~0.2 deg and ~0.5 % here.
    assert lag == pytest.approx(predicted, abs=1.0)
    assert gain == pytest.approx(abs(actuator), rel=0.02)


def test_flapping_lag_grows_with_frequency():
    stand_in = flight(flapping=True)
    low, _ = extra_lag(stand_in, 0.2)
    high, _ = extra_lag(stand_in, 1.5)
    # A first-order lag of tau_beta = 0.071 s costs atan(omega tau) = 5 deg at 0.2 Hz and 34 deg
    # at 1.5 Hz; inside the damping loop the low-frequency lag is smaller still.
    assert abs(low) < 5.0
    assert high > 20.0


def test_off_axis_coupling_is_the_reference_with_rotated_rate_derivatives():
    reference = Bo105Reference(80)
    A_rotor, _ = rotor_split()
    delta = math.radians(20.0)
    inertia_ratio = 4973.0 / 1433.0  # I_yy / I_xx (Padfield 2007, appendix 4B)
    rotor_L, rotor_M = A_rotor[P, [P, Q]], A_rotor[Q, [P, Q]]
    rotated_L = math.cos(delta) * rotor_L + math.sin(delta) * inertia_ratio * rotor_M
    rotated_M = -math.sin(delta) / inertia_ratio * rotor_L + math.cos(delta) * rotor_M
    new = {"L_p": reference.derivative("L_p") - rotor_L[0] + rotated_L[0], "L_q": rotated_L[1],
           "M_p": rotated_M[0], "M_q": reference.derivative("M_q") - rotor_M[1] + rotated_M[1]}
    # The module docstring's 80 kt figures, quoted to 3-4 significant digits.
    assert new == pytest.approx({"L_p": -13.06, "L_q": -3.35, "M_p": 1.13, "M_q": -3.885}, abs=0.006)
    time, inputs = cyclic_3211()
    expected = reference.with_derivatives(new).simulate(time, inputs).outputs
    np.testing.assert_allclose(flight(off_axis_coupling=True).simulate(time, inputs).outputs, expected,
                               atol=1e-12 * np.abs(expected).max())


def test_dynamic_inflow_lead_lag_on_thrust():
    # Independent evaluation of the documented formulas at 80 kt.
    tip_speed = 44.4 * 4.91
    mu = 80 * 1852 / 3600 / tip_speed
    thrust_coefficient = 2200 * 9.80665 / (1.225 * math.pi * 4.91**2 * tip_speed**2)
    inflow = math.sqrt((-mu**2 + math.sqrt(mu**4 + thrust_coefficient**2)) / 2)
    assert inflow == pytest.approx(thrust_coefficient / (2 * math.hypot(mu, inflow)), rel=1e-12)
    mass_flow = (mu**2 + 2 * inflow**2) / math.hypot(mu, inflow)
    tau = 8 / (3 * math.pi) / (2 * mass_flow * 44.4)
    excess = 6.113 * (4 * 0.27 / (math.pi * 4.91)) / (8 * mass_flow)
    assert (tau, excess) == pytest.approx((0.050, 0.28), abs=0.005), "docstring's 80 kt figures"
    reference = Bo105Reference(80)
    A, B = reference.A, reference.B
    a_thrust, b_thrust = np.zeros(8), np.zeros(4)
    a_thrust[W] = reference.derivative("Z_w")
    b_thrust[:3] = [reference.derivative(f"Z_{name}") for name in INPUT_NAMES[:3]]
    tau_effective = tau / (1 + excess)

    def rhs(x, u):
        body, lagged = x[:8], x[8]
        thrust = a_thrust @ body + b_thrust @ u
        body_dot = A @ body + B @ u
        body_dot[W] += excess * (thrust - lagged)
        return np.append(body_dot, (thrust - lagged) / tau_effective)

    time = time_grid(duration=3.0, sample_time=0.01)
    inputs = np.zeros((len(time), 4))
    inputs[(time >= 0.5) & (time < 1.0), THETA_0] = math.radians(1.0)
    expected = integrate_piecewise(rhs, time, inputs, 9)[:, :8]
    recorded = flight(dynamic_inflow=True).simulate(time, inputs).outputs
    np.testing.assert_allclose(recorded, expected, atol=1e-8 * np.abs(expected).max())
    # Property: the thrust response starts at (1 + K) times the quasi-steady one and relaxes with
    # tau_eff, so one sample (h) after the step w is 1 + K (tau_eff / h)(1 - exp(-h / tau_eff))
    # = 1.25 times the reference's; 2 % covers the O(h) coupling to the other states.
    onset = np.argmax(inputs[:, THETA_0] != 0) + 1
    ratio = recorded[onset, W] / reference.simulate(time, inputs).outputs[onset, W]
    h = time[1] - time[0]
    predicted = 1 + excess * tau_effective / h * (1 - math.exp(-h / tau_effective))
    assert ratio == pytest.approx(predicted, rel=0.02)


def test_sensor_noise_has_the_documented_spread_and_nothing_else():
    time, inputs = cyclic_3211(duration=20.0)
    clean = Bo105Reference(80).simulate(time, inputs).outputs
    recording = flight(sensor_noise=True).simulate(time, inputs, seed=11)
    noise = recording.outputs - clean
    # Module docstring: 0.1 m/s on u, v, w; 0.003 rad/s on p, q, r; 0.002 rad on theta, phi.
    documented = np.array([0.1, 0.1, 0.003, 0.002, 0.1, 0.003, 0.002, 0.003])
    # 2001 samples: the sample std scatters by 1/sqrt(2n) = 1.6 %; 8 % is 5 sigma. The mean
    # scatters by std/sqrt(n) = 2.2 % of std; 0.15 std is 7 sigma.
    np.testing.assert_allclose(noise.std(axis=0), documented, rtol=0.08)
    assert np.all(np.abs(noise.mean(axis=0)) < 0.15 * documented)
    # White: the lag-one autocorrelation of white noise scatters by 1/sqrt(n) = 0.022.
    lag_one = [np.corrcoef(column[:-1], column[1:])[0, 1] for column in noise.T]
    assert np.all(np.abs(lag_one) < 0.1)
    assert recording.metadata["sensor_noise_std"] == bo105_flight.SENSOR_NOISE_STD


def test_dryden_gusts_have_the_documented_spread_and_correlation():
    """The gusts, recovered from the stand-in's response through the documented way they act:
    on the airmass-relative velocity, ``x_dot = A (x - x_gust)`` in the u, v, w columns, each
    gust held over one internal step. Sampled at that step, with the aircraft at trim and every
    other effect off, ``x[k+1] = Phi x[k] + Gamma gust[k]`` with ``(Phi, Gamma)`` the exact ZOH of
    ``(A, -A[:, uvw])``, so 8 equations give the 3 gusts of each step."""
    speed = 80 * 1852 / 3600
    T = 533.4 / speed  # 12.9 s; 1750 ft scale length (module docstring)
    step = bo105_flight.MAX_INTERNAL_STEP
    time = time_grid(duration=1.0 + step, sample_time=step)  # gusts at 0 s and 1 s
    stand_in = flight(turbulence=True)
    A = Bo105Reference(80).A
    Phi, Gamma = zero_order_hold(A, -A[:, [U, V, W]], step)
    gusts, worst_misfit = [], 0.0
    for seed in range(1000):
        states = stand_in.simulate(time, np.zeros((len(time), 4)), seed=seed).outputs
        pushes = states[1:] - states[:-1] @ Phi.T  # Gamma gust[k], shape (n - 1, 8)
        recovered = np.linalg.lstsq(Gamma, pushes.T, rcond=None)[0].T  # (n - 1, 3), m/s
        worst_misfit = max(worst_misfit, np.abs(recovered @ Gamma.T - pushes).max() / np.abs(pushes).max())
        gusts.append(recovered[[0, -1]])
    gusts = np.array(gusts)  # (1000 runs, 0 s and 1 s, u_g v_g w_g)
    # The gusts act as documented: the 8 equations of every step hold to rounding (measured
    # 1e-14 of the response; gusts entering any other way would miss by order 1).
    assert worst_misfit < 1e-9
    # Each run starts in the stationary state, not in calm air, and stays there: 1000 samples
    # per gust at 0 s and at 1 s, std scatter 1/sqrt(2000) ~2.2 %, so 10 % is 4.5 sigma.
    np.testing.assert_allclose(gusts.std(axis=0), 0.3, rtol=0.1)  # sigma, m/s
    # u_g is first order: correlation exp(-1 s / T) = 0.926 over 1 s (1000 pairs: scatter
    # (1 - 0.926^2) / sqrt(1000) ~0.0045, so 0.02 is 4.4 sigma).
    u_g = gusts[:, :, 0]
    correlation = np.mean(u_g[:, 0] * u_g[:, 1]) / np.mean(u_g**2)
    assert correlation == pytest.approx(math.exp(-1.0 / T), abs=0.02)


def test_turbulence_is_mild_and_seeded():
    time, inputs = cyclic_3211(duration=10.0)
    clean = Bo105Reference(80).simulate(time, inputs).outputs
    stand_in = flight(turbulence=True)
    one, again = stand_in.simulate(time, inputs, seed=1), stand_in.simulate(time, inputs, seed=1)
    other = stand_in.simulate(time, inputs, seed=2)
    np.testing.assert_array_equal(one.outputs, again.outputs)
    disturbance = one.outputs - clean
    assert np.abs(other.outputs - one.outputs).max() > 1e-4
    # Present, but mild: a few mrad/s of body-rate disturbance, small against the 3-2-1-1's
    # off-axis response (0.1 rad/s).
    assert np.all(np.abs(disturbance[:, [P, Q, R]]).max(axis=0) > 1e-3)
    assert np.all(disturbance[:, [P, Q, R]].std(axis=0) < 0.02)


def test_random_streams_are_seeded_and_independent():
    time, inputs = cyclic_3211(duration=3.0)
    full = Bo105FlightTest(80)
    first, second = full.simulate(time, inputs, seed=7), full.simulate(time, inputs, seed=7)
    np.testing.assert_array_equal(first.outputs, second.outputs)
    assert not np.allclose(full.simulate(time, inputs, seed=8).outputs, first.outputs)
    # Turbulence and sensor noise draw from separate streams: the noise one seed adds is the
    # same whether or not turbulence is on.
    noise_with_turbulence = (flight(turbulence=True, sensor_noise=True).simulate(time, inputs, seed=7).outputs
                             - flight(turbulence=True).simulate(time, inputs, seed=7).outputs)
    noise_alone = (flight(sensor_noise=True).simulate(time, inputs, seed=7).outputs
                   - flight().simulate(time, inputs, seed=7).outputs)
    np.testing.assert_allclose(noise_with_turbulence, noise_alone, atol=1e-12)


def test_coarser_recording_interval_samples_the_same_aircraft():
    fine_time, fine_inputs = cyclic_3211(sample_time=0.01)
    coarse_time, coarse_inputs = cyclic_3211(sample_time=0.02)
    np.testing.assert_array_equal(fine_inputs[::2], coarse_inputs)
    deterministic = Bo105FlightTest(80, turbulence=False, sensor_noise=False)
    fine = deterministic.simulate(fine_time, fine_inputs).outputs
    coarse = deterministic.simulate(coarse_time, coarse_inputs).outputs
    # Same 5 ms internal steps and 8-step delay; only rounding differs.
    np.testing.assert_allclose(coarse, fine[::2], atol=1e-12 * np.abs(fine).max())


# --- The stand-in against the reference: the differences the GP models and diagnoses learn ---

def test_on_axis_close_off_axis_different():
    time, inputs = cyclic_3211()
    window = time < 6.0  # the manoeuvre and its settling, before the phugoid dominates
    reference = Bo105Reference(80).simulate(time, inputs).outputs[window]
    recorded = Bo105FlightTest(80).simulate(time, inputs, seed=0).outputs[window]
    q_reference, q_flight = reference[:, Q], recorded[:, Q]
    # On-axis: same peak within 25 % (observed -6 %) and the same shape once the
    # 0.13 s that delay, actuators and flapping add is taken out (observed best-lag correlation
    # 0.997; a shape change such as a different short-period mode would drop it below 0.95).
    # Unshifted, that lag alone brings the correlation down to the observed 0.90.
    assert np.abs(q_flight).max() == pytest.approx(np.abs(q_reference).max(), rel=0.25)
    best = max(np.corrcoef(q_reference[:len(q_reference) - lag], q_flight[lag:])[0, 1] for lag in range(30))
    assert best > 0.95
    assert np.corrcoef(q_reference, q_flight)[0, 1] > 0.8
    # Off-axis: the reference's error is as large as the off-axis signal itself (observed
    # ratios 1.1 for p and 1.2 for r), leaving a data-driven model room to beat it.
    for axis in (P, R):
        error = np.sqrt(np.mean((recorded[:, axis] - reference[:, axis]) ** 2))
        assert error > 0.8 * np.sqrt(np.mean(reference[:, axis] ** 2))


def test_delay_shows_as_a_later_onset():
    time, inputs = cyclic_3211()
    reference = Bo105Reference(80).simulate(time, inputs).output("q")
    recorded = Bo105FlightTest(80, turbulence=False, sensor_noise=False).simulate(time, inputs).output("q")
    threshold = 0.01  # rad/s, about 5 % of the peak
    onset_reference = time[np.argmax(np.abs(reference) > threshold)]
    onset_flight = time[np.argmax(np.abs(recorded) > threshold)]
    # At least the 0.04 s transport delay; the actuator and flap lags add more, but not 0.3 s.
    assert 0.04 <= onset_flight - onset_reference < 0.3


def test_full_stand_in_lags_at_high_frequency_only():
    stand_in = Bo105FlightTest(80, turbulence=False, sensor_noise=False)
    low, _ = extra_lag(stand_in, 0.2)
    high, _ = extra_lag(stand_in, 1.5)
    # Delay + actuators alone give 6 deg at 0.2 Hz and 48 deg at 1.5 Hz; flapping adds to both.
    assert low < 15.0
    assert high > 60.0
