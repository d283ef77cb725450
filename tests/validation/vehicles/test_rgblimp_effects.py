"""Tests of the RGBlimp's named effects (validation/vehicles/rgblimp_effects.py) and of the added
mass the equations take for them (validation/vehicles/rgblimp_equations.py).

Properties: with added mass, Kirchhoff's equations keep the kinetic energy of a free body (no
gravity, air or thrust), which only the right Coriolis and Munk terms do; the batched replay of
several recordings equals one replay per recording and the identification's own model with the
same coefficients; each term moves the flight the way its physics says; and a residual search's
term is the body acceleration it names.
"""
import dataclasses

import numpy as np
import pytest

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.diagnose.report import statement
from validation.models.rgblimp_identification import RGBlimpModel
from validation.vehicles.blimp_equations import rotation_body_to_earth
from validation.vehicles.effect_vehicle import EffectVehicle, effect_model
from validation.vehicles.polynomial_terms import SLOT_KEYS, slot_indices
from validation.vehicles.rgblimp_data import EXCERPT_FOLDER, read_rgblimp_flight
from validation.vehicles.rgblimp_effects import TERMS, RGBlimpEffects, model_value
from validation.vehicles.rgblimp_equations import (
    NOMINAL_GONDOLA_POSITION,
    SAMPLE_TIME,
    SEARCH_ROWS,
    SEARCH_SIGNALS,
    RGBlimpParameters,
    body_accelerations,
    rk4_step,
    search_accelerations,
)


@pytest.fixture(scope="module")
def flights():
    """The first 2 s of two excerpt flights of different configurations (29 and 30)."""
    recordings = [read_rgblimp_flight(EXCERPT_FOLDER / f"data_{n}.csv").recording for n in (117, 121)]
    return [Recording(r.time[:120], r.inputs[:120], r.input_names, r.outputs[:120], r.output_names, r.metadata)
            for r in recordings]


def _kinetic_energy(state, params, gondola):
    """``1/2 nu^T M nu`` with the system mass matrix of rigid body and added mass."""
    velocity, rates = state[6:9], state[9:12]
    total = params.hull_mass + params.gondola_mass
    moment = params.hull_mass * np.asarray(params.hull_cg) + params.gondola_mass * np.asarray(gondola)
    # J = I - m_b S(r_b)^2 = I + m_b (|r_b|^2 I - r_b r_b^T)
    inertia = np.diag(params.inertia) + params.gondola_mass * (np.dot(gondola, gondola) * np.eye(3)
                                                               - np.outer(gondola, gondola))
    translational = (total + np.asarray(params.added_mass)) * velocity
    rotational = (inertia + np.diag(params.added_inertia)) @ rates
    coupling = np.cross(rates, moment)  # nu^T [[0, -S(l)], [S(l), 0]] nu / 2 = v . (omega x l)
    return 0.5 * (velocity @ translational + rates @ rotational) + velocity @ coupling


@pytest.mark.parametrize("added_mass, added_inertia", [((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
                                                       ((0.02, 0.12, 0.12), (0.002, 0.01, 0.01))])
def test_a_free_body_keeps_its_kinetic_energy_with_and_without_added_mass(added_mass, added_inertia):
    """No gravity, no air, no thrust: rigid-body and Kirchhoff added-mass terms only exchange
    energy between the axes (Fossen 2011, sec. 6.3.1); a sign error in a Coriolis or Munk term
    makes the energy drift by far more than RK4's error."""
    params = RGBlimpParameters(gravity=0.0, air_density=0.0, rate_damping=(0.0, 0.0, 0.0),
                               added_mass=added_mass, added_inertia=added_inertia)
    gondola = np.array(NOMINAL_GONDOLA_POSITION)
    inputs = np.concatenate([[0.0, 0.0], gondola])
    state = np.array([0, 0, 0, 0.1, -0.2, 0.3, 0.3, 0.1, 0.2, 0.3, -0.2, 0.5])
    start = _kinetic_energy(state, params, gondola)
    for _ in range(120):
        state = rk4_step(state, inputs, params)
    assert abs(_kinetic_energy(state, params, gondola) / start - 1) < 1e-6
    assert not np.allclose(state[6:], [0.3, 0.1, 0.2, 0.3, -0.2, 0.5], atol=1e-3)  # the motion did change


def test_the_munk_moment_turns_the_hull_broadside():
    """An elongated hull (more added mass across than along) at positive angle of attack gets a
    nose-up pitching moment ``(Z_Wdot - X_Udot) U W``, destabilising (Fossen 2011, sec. 6.3)."""
    base = RGBlimpParameters(air_density=0.0)
    munk = dataclasses.replace(base, added_mass=(0.02, 0.12, 0.12))
    state = np.zeros(12)
    state[6], state[8] = 0.4, 0.1
    inputs = np.concatenate([[0.0, 0.0], NOMINAL_GONDOLA_POSITION])
    pitch = [body_accelerations(state, inputs, p)[4] for p in (base, munk)]
    assert pitch[1] > pitch[0]


def test_batched_replays_equal_one_per_recording_and_the_identified_models(flights):
    """Members and recordings integrated together equal separate replays, and a term set through
    an effect equals the identification's model with the same coefficient (its own free run)."""
    model = effect_model("rgblimp", purpose="test")
    effect_lists = [[], [{"effect": "stability_derivative", "term": "N_R", "value": -0.02},
                         {"effect": "steady_wind", "term": "wind_x", "value": 0.05},
                         {"effect": "control_derivative", "term": "thrust_gain", "value": 0.8}],
                    [{"effect": "aerodynamic_coefficient", "term": "c_l0", "value": 0.2}]]
    starts = [model.start_state(r) for r in flights]
    together = model.simulate_recordings(effect_lists, [r.time for r in flights], [r.inputs for r in flights], starts)
    for recording, start, replay in zip(flights, starts, together):
        alone = model.simulate_many(effect_lists, recording.time, recording.inputs, start=start)
        np.testing.assert_allclose(replay, alone, rtol=0, atol=1e-12)
        expected = [RGBlimpModel(),
                    RGBlimpModel().replaced({"rate_damping_z": -0.02, "wind_x": 0.05, "thrust_gain": 0.8}),
                    RGBlimpModel().replaced({"c_l0": 0.2})]
        for member, identified in enumerate(expected):
            states = identified.simulate(start, recording.inputs)
            states[:, 5] = np.unwrap(states[:, 5])
            np.testing.assert_allclose(replay[member], states, rtol=0, atol=1e-10)


def test_the_compiled_replay_equals_the_numpy_step(flights):
    """The compiled free run (validation/vehicles/rgblimp_jax.py) that diagnose replays with equals
    the numpy step to 1e-12 in SI units (measured 2e-14), for members changing every kind of
    term at once (thrust factor and asymmetry, wind, added mass, CG, buoyancy, coefficients; the
    thrust loss with airspeed, thrust line, draught field, gondola offset and cross-flow terms)
    over two recordings of different configurations, and for the residual search's terms (four
    slots, in a steady wind); a member that diverges (a rate damping of the wrong sign, 50 N m s)
    ends non-finite in both."""
    reference = effect_model("rgblimp", purpose="test").reference
    compiled, numpy_step = RGBlimpEffects(reference), RGBlimpEffects(reference, compiled=False)
    effect_lists = [[], [{"term": "thrust_gain", "value": 0.9}, {"term": "thrust_asymmetry", "value": 0.1},
                         {"term": "wind_y", "value": -0.04}, {"term": "X_Udot", "value": 0.05}],
                    [{"term": "x_G", "value": -0.04}, {"term": "Z_0", "value": 0.02}, {"term": "c_my0", "value": 0.05},
                     {"term": "N_R", "value": -0.02}],
                    [{"term": "thrust_speed_loss", "value": 0.4}, {"term": "thrust_line_y", "value": 0.01},
                     {"term": "wind_x_dy", "value": 0.05}, {"term": "wind_z_dx", "value": -0.03},
                     {"term": "wind_y", "value": 0.03}, {"term": "gondola_dz", "value": 0.01},
                     {"term": "c_mz_beta_abs", "value": -0.2}, {"term": "c_l_alpha_abs", "value": 0.5}],
                    [{"term": "M_Q", "value": 50.0}],
                    [{"effect": "search_term", "term": term, "value": value} for term, value in SEARCHED]
                    + [{"term": "wind_x", "value": 0.05}],
                    [{"term": "wind_x", "value": 0.05}]]
    args = (effect_lists, [r.time for r in flights], [r.inputs for r in flights],
            [compiled.start_state(r) for r in flights])
    for fast, slow in zip(compiled.simulate_recordings(*args), numpy_step.simulate_recordings(*args)):
        np.testing.assert_allclose(fast[[0, 1, 2, 3, 5, 6]], slow[[0, 1, 2, 3, 5, 6]], rtol=0, atol=1e-12)
        assert np.abs(fast[3] - fast[0]).max() > 0.01  # the new terms moved the flight
        assert np.abs(fast[5] - fast[6]).max() > 0.01  # and the search terms, beyond the wind
        assert not np.isfinite(fast[4, -1]).any() and not np.isfinite(slow[4, -1]).any()


#: Search terms of four kinds, one per slot, with their rows (body-acceleration index) and factors.
SEARCHED = (("L_theta", 0.3), ("N_V|V|", -2.0), ("M_U*Q", 0.5), ("X_U^3", -0.1))


def test_search_terms_are_the_body_accelerations_they_name():
    """A search term adds ``value * factor`` to its row's acceleration: each slot's on its own
    row, summed (a roll acceleration linear in pitch, a yaw one in V|V|, a pitch one in U Q, a
    surge one in U^3); units and words follow the row and the factor, and the named hypotheses
    hold none (the residual search offers them)."""
    state = np.array([1.0, 2.0, -1.0, 0.1, -0.2, 0.7, 0.5, -0.1, 0.05, 0.02, -0.03, 0.3])
    slots = {key: np.array(values) for key, values in zip(SLOT_KEYS, zip(*[
        (*slot_indices(term, SEARCH_ROWS, SEARCH_SIGNALS), value) for term, value in SEARCHED]))}
    u, v, q, theta = state[6], state[7], state[10], state[4]
    expected = [-0.1 * u**3, 0.0, 0.0, 0.3 * theta, 0.5 * u * q, -2.0 * v * abs(v)]
    np.testing.assert_allclose(search_accelerations(np, state, slots), expected, rtol=0, atol=1e-15)
    model = effect_model("rgblimp", purpose="test")
    assert model.term_unit("L_theta") == "rad/s^2/rad" and model.term_unit("M_U*Q") == "rad/s^2/(m/s rad/s)"
    assert model.term_unit("X_U^3") == "m/s^2/(m/s)^3"
    assert model.term_description("N_V|V|") == "yaw acceleration proportional to V|V|"
    assert not [h for h in model.term_hypotheses(()) if h.effect == "search_term"]
    with pytest.raises(BadInputError, match="replays at most 4"):
        EffectVehicle("rgblimp", [{"effect": "search_term", "term": t, "value": 0.1}
                                  for t in ("L_theta", "L_U", "L_V", "L_W", "M_U")])


def test_recordings_of_different_lengths_are_padded_and_cut(flights):
    model = effect_model("rgblimp", purpose="test")
    short = flights[1]
    replays = model.simulate_recordings([[]], [flights[0].time, short.time[:100]],
                                        [flights[0].inputs, short.inputs[:100]],
                                        [model.start_state(flights[0]), model.start_state(short)])
    assert replays[1].shape == (1, 100, 12)
    np.testing.assert_allclose(replays[1][0], model.simulate_many([[]], short.time, short.inputs,
                                                                  start=model.start_state(short))[0, :100], atol=1e-12)


@pytest.mark.parametrize("term, value, check", [
    # heavier than the model's 0.067 N: sinks faster at first (z and W down)
    ("Z_0", 0.1, lambda base, changed: changed[30, 8] > base[30, 8] and changed[30, 2] > base[30, 2]),
    ("thrust_gain", 1.5, lambda base, changed: changed[30, 6] > base[30, 6]),  # more thrust: faster at first
    ("X_Udot", 0.05, lambda base, changed: abs(changed[30, 6] - changed[0, 6]) < abs(base[30, 6] - base[0, 6])),
    ("wind_y", 0.1, lambda base, changed: changed[-1, 1] > base[-1, 1] + 0.1),  # drifts east with the air
    ("thrust_asymmetry", 0.3, lambda base, changed: changed[-1, 11] > base[-1, 11]),  # left stronger: yaws right
    ("thrust_speed_loss", 0.5, lambda base, changed: changed[30, 6] < base[30, 6]),  # less thrust once moving
    ("thrust_line_y", 0.02, lambda base, changed: changed[-1, 11] < base[-1, 11]),  # line right: yaws left
    ("gondola_dz", 0.05, lambda base, changed: changed[-1, 4] > base[-1, 4]),  # lower gondola: thrust pitches up more
])
def test_each_term_moves_the_flight_as_its_physics_says(flights, term, value, check):
    model = effect_model("rgblimp", purpose="test")
    kind = next(kind for kind, terms in TERMS.items() if term in terms)
    recording = flights[0]
    base, changed = model.simulate_many([[], [{"effect": kind, "term": term, "value": value}]], recording.time,
                                        recording.inputs, start=model.start_state(recording))
    assert check(base, changed)


def _accelerations_at(params, *, position=(0.0, 0.0), velocity=(0.5, 0.0, 0.0), attitude=(0.1, -0.05, 0.7),
                      thrusts=(0.03, 0.03)):
    state = np.concatenate([[*position, -1.0], attitude, velocity, [0.0, 0.0, 0.0]])
    return body_accelerations(state, np.concatenate([thrusts, NOMINAL_GONDOLA_POSITION]), params)


def test_the_new_terms_act_as_their_equations_say():
    """Each term beyond the source's equals a change the source's model can express at one state
    (no rotation, no added mass): a draught at the blimp's position acts as the opposite body
    velocity in the aerodynamics and thrust; a thrust loss as smaller thrusts; a thrust line as a
    thrust difference of the same sum; a cross-flow coefficient as the linear one grown by its
    value times the angle's size."""
    base = RGBlimpParameters()
    draught = dataclasses.replace(base, draught_gradient_x=(0.05, 0.0, 0.0), draught_gradient_y=(0.0, 0.02, -0.01))
    position, wind = np.array([2.0, -3.0]), np.array([0.05 * 2.0, 0.02 * -3.0, -0.01 * -3.0])
    rotation = rotation_body_to_earth(np.array([0.1, -0.05, 0.7]))
    still_air = np.array([0.5, 0.0, 0.0]) - rotation.T @ wind
    np.testing.assert_allclose(_accelerations_at(draught, position=position),
                               _accelerations_at(base, velocity=still_air), rtol=0, atol=1e-14)

    lossy = dataclasses.replace(base, thrust_speed_loss=0.4)  # at U = 0.5 m/s: 80 % of the thrust
    np.testing.assert_allclose(_accelerations_at(lossy), _accelerations_at(base, thrusts=(0.024, 0.024)), atol=1e-14)

    line = dataclasses.replace(base, thrust_line_y=0.03)  # -y T = (F_l - F_r) d with F_l + F_r = T
    difference = -0.03 * 0.06 / base.propeller_arm
    np.testing.assert_allclose(_accelerations_at(line),
                               _accelerations_at(base, thrusts=(0.03 + difference / 2, 0.03 - difference / 2)),
                               atol=1e-14)

    sideslip = (0.4, -0.1, 0.05)
    beta = np.arcsin(-0.1 / np.linalg.norm(sideslip))
    cross = dataclasses.replace(base, c_mz_beta_abs=-0.3, c_s_beta_abs=0.7)
    linear = dataclasses.replace(base, c_mz_beta=base.c_mz_beta - 0.3 * abs(beta),
                                 c_s_beta=base.c_s_beta + 0.7 * abs(beta))
    np.testing.assert_allclose(_accelerations_at(cross, velocity=sideslip),
                               _accelerations_at(linear, velocity=sideslip), atol=1e-14)


def test_new_terms_have_units_words_and_hypotheses():
    """Every term has a unit and words; the thrust loss is bounded at 0 and refused negative."""
    model = effect_model("rgblimp", purpose="test")
    hypotheses = {h.target: h for h in model.term_hypotheses(())}
    for term in ("thrust_speed_loss", "thrust_line_y", "wind_x_dx", "wind_z_dy", "gondola_dx", "c_my_alpha_abs"):
        assert hypotheses[term].null == 0.0 and hypotheses[term].step > 0
        assert model.term_unit(term) and model.term_description(term) != term
    assert model.term_unit("c_my_alpha_abs") == "m/rad^2" and model.term_unit("wind_y_dx") == "1/s"
    assert hypotheses["thrust_speed_loss"].lower == 0.0
    with pytest.raises(BadInputError, match="thrust loss cannot be negative"):
        EffectVehicle("rgblimp", [{"effect": "control_derivative", "term": "thrust_speed_loss", "value": -0.1}])


def test_z_0_is_the_net_weight_and_sets_the_buoyancy():
    params = RGBlimpParameters()
    net = model_value(params, "Z_0")
    assert net == pytest.approx((0.10482 + 0.05407 - 0.15204) * 9.8)
    vehicle = EffectVehicle("rgblimp", [{"effect": "force_offset", "term": "Z_0", "value": 0.0}])
    time = np.arange(120) * SAMPLE_TIME
    inputs = np.tile(np.concatenate([[0.0, 0.0], NOMINAL_GONDOLA_POSITION]), (120, 1))
    states = vehicle.simulate_states(time, inputs)  # neutrally buoyant at rest: stays put
    np.testing.assert_allclose(states[-1, :3], 0.0, atol=1e-12)


def test_bad_values_and_missing_start_states_are_refused(flights):
    with pytest.raises(BadInputError, match="thrust gain must be positive"):
        EffectVehicle("rgblimp", [{"effect": "control_derivative", "term": "thrust_gain", "value": 0.0}])
    with pytest.raises(BadInputError, match="cannot be negative"):
        EffectVehicle("rgblimp", [{"effect": "added_mass", "term": "Z_Wdot", "value": -0.1}])
    with pytest.raises(BadInputError, match="is not one of"):
        EffectVehicle("rgblimp", [{"effect": "stability_derivative", "term": "M_q", "value": -1.0}])
    model = effect_model("rgblimp", purpose="test")
    recording = flights[0]
    partial = Recording(recording.time, recording.inputs, recording.input_names, recording.outputs[:, :6],
                        recording.output_names[:6], recording.metadata)
    with pytest.raises(BadInputError, match="needs all 12 states; missing U, V, W, P, Q, R"):
        model.start_state(partial)
    with pytest.raises(BadInputError, match="resample the recordings to 60 Hz"):
        model.simulate_many([[]], recording.time * 2, recording.inputs)



def test_a_draught_field_is_stated_with_the_wind_change_it_means():
    """A draught gradient is put in perspective over the diagnosed flights' extent: the change of
    the air's velocity across them, and a warning where that is more than a room's air moves."""
    model = effect_model("rgblimp", purpose="test")
    extent = {"x": (0.1, 3.2), "y": (-1.7, 0.8)}
    strong = model.value_context("wind_x_dy", 0.159, extent)
    assert "Across the 2.5 m" in strong and "change by 0.4 m/s" in strong and "more than the air of a room" in strong
    weak = model.value_context("wind_z_dx", -0.02, extent)
    assert "change by 0.062 m/s." in weak and "more than" not in weak
    assert model.value_context("wind_x", 0.1, extent) is None and model.value_context("wind_y_dy", 0.1, {}) is None
    finding = {"effect": "draught_field", "term": "wind_x_dy", "value": 0.159, "unit": "1/s", "model_value": 0.0,
               "interval": [0.142, 0.176]}
    assert strong in statement(finding, {"rmse_reference": {}}, model, extent=extent)
