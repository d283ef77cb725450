"""Tests of the RGBlimp SINDYc peer (validation/models/rgblimp_sindyc.py) on a flight of the
shipped excerpt: a known residual is recovered sparsely, and the free run is the published
model's RK4 step with that residual added."""
import dataclasses

import numpy as np

from validation.models.rgblimp_sindyc import fit_sindyc
from validation.vehicles.rgblimp_data import EXCERPT_FOLDER, read_rgblimp_flight
from validation.vehicles.rgblimp_equations import RGBlimpParameters, body_accelerations, rk4_step


def _flight_with_residual(residual_of_state):
    flight = read_rgblimp_flight(EXCERPT_FOLDER / "data_117.csv")
    states, inputs = flight.recording.outputs, flight.recording.inputs
    measured = body_accelerations(states, inputs, RGBlimpParameters()) + residual_of_state(states)
    return dataclasses.replace(flight, measured_accelerations=measured)


def test_a_known_residual_is_recovered_with_few_terms():
    # Extra drag on U (-3 U) and a constant roll acceleration (2 rad/s^2): two terms.
    def residual(states):
        out = np.zeros((len(states), 6))
        out[:, 0] = -3.0 * states[:, 6]
        out[:, 3] = 2.0
        return out

    flight = _flight_with_residual(residual)
    model = fit_sindyc([flight])
    states, inputs = flight.recording.outputs[:50], flight.recording.inputs[:50]
    np.testing.assert_allclose(model.residual(states, inputs), residual(states), atol=1e-6)
    # The monomials are the library's own.
    variables = np.hstack([states[:, [3, 4, 6, 7, 8, 9, 10, 11]], inputs])
    library = np.asarray(model.library.transform(variables))
    np.testing.assert_allclose(model.residual(states, inputs), library @ model.coefficients.T, rtol=1e-12, atol=1e-12)
    # The constant inputs of one flight are collinear with the constant term, so the ridge
    # spreads the roll constant over those features; a handful of terms all the same.
    assert 2 <= model.n_terms <= 12


def test_the_free_run_adds_the_residual_to_the_published_rk4_step():
    flight = _flight_with_residual(lambda states: np.zeros((len(states), 6)))
    model = fit_sindyc([flight])
    assert model.n_terms == 0  # nothing to learn: the published model itself
    states, inputs = flight.recording.outputs, flight.recording.inputs[:30]
    path = model.simulate(states[0], inputs)
    expected = [states[0]]
    for command in inputs[:-1]:
        expected.append(rk4_step(expected[-1], command, RGBlimpParameters()))
    np.testing.assert_allclose(path, np.array(expected), rtol=1e-12, atol=1e-12)
