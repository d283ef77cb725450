"""validation.vehicles.polynomial_terms: names parse and print back, factors are what they say,
and the replay of a linear reference with polynomial terms follows RK4 of the continuous model."""
from functools import partial

import numpy as np
import pytest

from validation.vehicles.blimp_equations import rk4
from validation.vehicles.bo105_effects import identification_manoeuvre
from validation.vehicles.effect_vehicle import effect_model
from validation.vehicles.polynomial_terms import factor_values, library, parse_term, term_name

LETTERS = {"M": "q", "N": "r"}


def _rk4_flight(rate, time, inputs, start) -> np.ndarray:
    """Classical RK4 (:func:`validation.vehicles.blimp_equations.rk4`) of ``rate(x, u)`` at the
    recording's step, the inputs held over each interval: the states at every sample."""
    states = [start]
    for k in range(len(time) - 1):
        states.append(rk4(partial(rate, u=inputs[k]), states[-1], time[k + 1] - time[k]))
    return np.array(states)
SIGNALS = ("q", "w", "theta_1s")


@pytest.mark.parametrize("name, kind, signals", [("M_q|q|", "signed_square", ("q",)), ("M_w^3", "cube", ("w",)),
                                                 ("N_q*theta_1s", "product", ("q", "theta_1s"))])
def test_names_parse_and_print_back(name, kind, signals):
    parsed = parse_term(name, LETTERS, SIGNALS)
    assert (parsed.kind, parsed.signals) == (kind, signals)
    assert term_name(parsed.letter, kind, *signals) == name


@pytest.mark.parametrize("name", ["M_q", "X_q|q|", "M_v|v|", "M_q|w|", "M_q*q", "M_q^2", "M_q*w*w", "Mq|q|"])
def test_other_names_are_not_terms(name):
    assert parse_term(name, LETTERS, SIGNALS) is None


def test_factors_and_library():
    signals = np.array([[-2.0, 3.0, 0.5]])
    terms = [parse_term(n, LETTERS, SIGNALS) for n in ("M_q|q|", "M_w^3", "M_q*w", "N_theta_1s|theta_1s|")]
    np.testing.assert_array_equal(factor_values(terms, SIGNALS, signals), [[-4.0, 27.0, -6.0, 0.25]])
    names = library(["M"], SIGNALS)
    assert len(names) == 2 * 3 + 3 and len(set(names)) == len(names)
    assert all(parse_term(n, LETTERS, SIGNALS) is not None for n in names)


@pytest.mark.parametrize("effects", [
    [("nonlinear_stiffness", "N_v^3", 0.006)],
    [("quadratic_stiffness", "N_v|v|", 0.015)],
    [("search_term", "M_q*w", -0.5), ("nonlinear_damping", "M_q|q|", -20.0)],
    [("search_term", "L_theta_1c|theta_1c|", 400.0)],
])
def test_the_replay_with_terms_follows_rk4_of_the_continuous_model(effects):
    """Heun's mean of the terms through the exact discretisation against classical RK4 of
    ``x_dot = A x + B u + sum e_row c f(x, u)`` at the same 10 ms step: within 1e-3 of each
    state's largest excursion (the replay's error is second order in the step)."""
    model = effect_model("bo105-80kt", purpose="test")
    linear = model.reference
    names = linear.state_names + linear.input_names
    time, inputs = identification_manoeuvre(duration=10.0, sample_time=0.01)
    replay = model.simulate_many([[{"effect": k, "term": t, "value": v} for k, t, v in effects]], time, inputs)[0]
    parsed = [(parse_term(t, linear.row_letters, names), v) for _, t, v in effects]
    A, B = linear.A, linear.B

    def rate(x, u):
        dx = A @ x + B @ u
        for term, value in parsed:
            dx[linear.state_names.index(linear.row_letters[term.letter])] += \
                value * factor_values([term], names, np.concatenate((x, u)))[0]
        return dx

    rk4 = _rk4_flight(rate, time, inputs, np.zeros(replay.shape[1]))
    linear_replay = model.simulate_many([[]], time, inputs)[0]
    scale = np.abs(rk4).max(axis=0)
    assert np.all(np.abs(replay - rk4).max(axis=0) <= 1e-3 * scale)
    assert np.abs(replay - linear_replay).max() > 0.01 * scale.max()  # the terms do act


def test_search_terms_have_units_and_words():
    model = effect_model("bo105-80kt", purpose="test")
    assert "N_v^3" in model.terms["nonlinear_stiffness"] and model.model_value("N_v^3") == 0.0
    assert "N_v|v|" in model.terms["quadratic_stiffness"] and model.term_unit("N_v|v|") == "(rad/s^2)/(m/s)^2"
    assert not {"N_v|v|", "N_v^3"} & set(model.terms["search_term"])  # named, so not searched
    assert model.term_unit("N_v^3") == "(rad/s^2)/(m/s)^3"
    assert model.term_unit("M_q*w") == "(rad/s^2)/(rad/s m/s)"
    assert model.term_description("N_v^3") == "yaw moment proportional to v^3 (not linear in lateral velocity)"
    # A named term is not also a searched one: M_q|q| is nonlinear damping only.
    assert "M_q|q|" in model.terms["nonlinear_damping"] and "M_q|q|" not in model.terms["search_term"]
    assert model.term_description("M_q|q|").endswith("(damping that grows with pitch rate)")


def test_a_term_with_a_lagged_input_follows_rk4_of_the_augmented_model():
    """The terms' forcing goes through the augmented system of the lags: N_v^3 with an 80 ms lag
    on theta_1c against RK4 of ``x_dot = A x + B' u + b_c z + e_N c v^3``, ``T z_dot = u_c - z``
    (``B'`` without theta_1c's column): within 1e-3 of each state's largest excursion."""
    model = effect_model("bo105-80kt", purpose="test")
    linear = model.reference
    time, inputs = identification_manoeuvre(duration=10.0, sample_time=0.01)
    lag, value = 0.08, 0.006
    replay = model.simulate_many([[{"effect": "input_lag", "input": "theta_1c", "value": lag},
                                   {"effect": "nonlinear_stiffness", "term": "N_v^3", "value": value}]], time,
                                  inputs)[0]
    A, B = linear.A, linear.B
    column = linear.input_names.index("theta_1c")
    b_lagged = B[:, column].copy()
    B[:, column] = 0.0
    n_row, v = linear.state_names.index("r"), linear.state_names.index("v")

    def rate(state, u):
        x, z = state[:-1], state[-1]
        dx = A @ x + B @ u + b_lagged * z
        dx[n_row] += value * x[v] ** 3
        return np.append(dx, (u[column] - z) / lag)

    rk4 = _rk4_flight(rate, time, inputs, np.zeros(len(linear.state_names) + 1))[:, :-1]
    assert np.all(np.abs(replay - rk4).max(axis=0) <= 1e-3 * np.abs(rk4).max(axis=0))
