"""Tests of blimp parameter identification (validation/models/blimp_identification.py).

Identification recovers known parameters from noise-free reference data, and on noisy data its
standard errors cover the truth. RK4 at one step per 0.05 s frame keeps the tests fast; the
data are generated with the same step, so noise-free recovery is exact up to the optimiser.
"""
import math

import numpy as np
import pytest

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.models.blimp_identification import (
    IDENTIFIED_PARAMETERS,
    identify_parameters,
    physics_step,
    recording_arrays,
)
from validation.vehicles.blimp import STATE_NAMES, BlimpParameters, BlimpReference
from validation.vehicles.blimp_equations import blimp_dynamics, rk4

STEP = 0.05  # s: frame interval and RK4 step of these tests
TRUTH = BlimpParameters()
NAMES = BlimpParameters.vector_names()
INDEX = [NAMES.index(n) for n in IDENTIFIED_PARAMETERS]
#: Noise of the blimp-flight stand-in's mocap (validation/vehicles/blimp_flight.py): 1 mm, 0.5 deg, and the
#: differentiated velocities' 6 mm/s and 0.055 rad/s.
NOISE_STD = np.array([1e-3] * 3 + [math.radians(0.5)] * 3 + [6e-3] * 3 + [0.055] * 3)


def random_flight(duration, seed, *, params=TRUTH) -> Recording:
    """Random commands held for 0.25 s (Ko et al.'s 4 Hz controller), flown by the reference."""
    rng = np.random.default_rng(seed)
    time = np.arange(int(round(duration / STEP)) + 1) * STEP
    held = (np.arange(len(time)) * STEP * 4 + 1e-9).astype(int)
    commands = np.column_stack([rng.uniform(-1, 1, held[-1] + 1), rng.uniform(-0.5, 0.5, held[-1] + 1),
                                rng.uniform(-1, 1, held[-1] + 1)])[held]
    return BlimpReference(params=params, max_step=STEP).simulate(time, commands)


def perturbed_start() -> BlimpParameters:
    vector = TRUTH.to_vector()
    vector[INDEX] *= 1.3
    vector[NAMES.index("cg_position_y")] = 0.01
    return BlimpParameters.from_vector(vector)


def test_physics_step_matches_the_reference_rk4():
    recording = random_flight(2.0, seed=0)
    states, inputs = recording_arrays(recording)
    stepped = physics_step(TRUTH, max_step=0.01)(states[:-1], inputs[:-1])
    expected = states[:-1]
    for _ in range(5):
        expected = rk4(lambda s: blimp_dynamics(s, inputs[:-1, :3], TRUTH), expected, 0.01)
    np.testing.assert_allclose(stepped, expected, rtol=0, atol=1e-12)


def test_recovers_known_parameters_from_noise_free_data():
    result = identify_parameters([random_flight(20.0, seed=1)], initial=perturbed_start(), max_step=STEP)
    truth = TRUTH.to_vector()[INDEX]
    # From 30 % off to the truth: limited by the finite-difference Jacobian and the
    # optimiser's tolerances (1e-8), far below any physical meaning.
    np.testing.assert_allclose(result.values, truth, rtol=1e-5, atol=1e-7)
    assert result.rms_residual < 1e-6
    assert result.params.cg_position[1] == pytest.approx(0.0, abs=1e-7)
    assert set(result.as_dict()) == set(IDENTIFIED_PARAMETERS)


def test_standard_errors_cover_the_truth_on_noisy_data():
    clean = random_flight(30.0, seed=2)
    noise = np.random.default_rng(3).normal(0.0, 1.0, clean.outputs.shape) * NOISE_STD
    noisy = Recording(clean.time, clean.inputs, clean.input_names, clean.outputs + noise,
                      clean.output_names, clean.metadata)
    result = identify_parameters([noisy], initial=perturbed_start(), state_scale=NOISE_STD, max_step=STEP)
    z = (result.values - TRUTH.to_vector()[INDEX]) / result.standard_errors
    # 11 roughly normal z-scores: all within 3.5 (a 1-in-200 miss for one of them), and their
    # root mean square near 1 (an honest scale; over-confident errors give several times 1).
    assert np.all(np.abs(z) < 3.5), z
    assert 0.4 < np.sqrt(np.mean(z**2)) < 1.6, z
    # Residuals scaled by the true noise: about 1 when the model and the noise model are right.
    assert 0.8 < result.rms_residual < 1.2


def test_bad_names_missing_states_and_no_iterations_are_refused():
    recording = random_flight(2.0, seed=4)
    with pytest.raises(BadInputError, match="unknown parameter"):
        identify_parameters([recording], names=("drag",))
    for iterations in (0, 2.5, True):
        with pytest.raises(BadInputError, match=f"max_iterations must be a whole number of at least 1, got "
                                                f"{iterations!r}"):
            identify_parameters([recording], max_iterations=iterations)
    partial = Recording(recording.time, recording.inputs, recording.input_names,
                        recording.outputs[:, :6], STATE_NAMES[:6], {})
    with pytest.raises(BadInputError, match="lacks U, V, W, P, Q, R"):
        identify_parameters([partial])
