"""Fixtures of the RGBlimp hybrid FMU tests (session scope): a hybrid with a correction that moves
the free run, its JSON model file, its pythonfmu and native FMUs, and its Python free run."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fmu_src import build_native_rgblimp_hybrid_fmu, build_rgblimp_hybrid_fmu
from fmu_src.rgblimp_hybrid.build import rgblimp_hybrid_parts
from fmu_src.rgblimp_hybrid.model import RGBlimpHybridModel
from validation.core.files import write_json
from validation.models.rgblimp_hybrid_step import air_features, hybrid_step
from validation.models.rgblimp_identification import RGBlimpModel
from validation.models.rgblimp_rollout import RolloutHybrid, RolloutSetup, initial_correction
from validation.vehicles.rgblimp_data import EXCERPT_FOLDER, read_rgblimp_flight

#: Samples of the Python free run the tests compare with (the length the rollout tests compile,
#: so that one compiled free run serves both).
RUN_SAMPLES = 241
#: Where the FMU contract's standard run starts in data_119 (as the RKGP FMUs' contract).
CASE_START = 60


@pytest.fixture(scope="session")
def hybrid_trained(tmp_path_factory):
    """A hybrid of the physics with a thrust factor, a drag coefficient and a wind (the step's
    change of frame), and a correction of 8 inducing points at the states of data_117 and data_118
    with random whitened values (not fitted: the FMUs must equal whatever model they carry; its
    accelerations reach 0.02 rad/s^2 and move the 4 s free run by 8 mm, 10^6 times the tolerance);
    its model file, and data_119's inputs and states."""
    fitted_on = [read_rgblimp_flight(EXCERPT_FOLDER / f"data_{n}.csv") for n in (117, 118)]
    setup = RolloutSetup(inducing_points=8)
    correction = initial_correction(fitted_on, setup)
    correction["whitened"] = 0.3 * np.random.default_rng(1).standard_normal(correction["whitened"].shape)
    physics = RGBlimpModel().replaced({"thrust_gain": 0.9, "c_d0": 0.3, "wind_x": 0.02, "wind_y": -0.01})
    test = read_rgblimp_flight(EXCERPT_FOLDER / "data_119.csv").recording
    # The envelope: the fitting flights' features and those of the hybrid's own free run over the
    # contract's standard run (whose pitch rate dips below the recorded ones), so that run is inside.
    hybrid = RolloutHybrid(physics, correction, setup)
    run, numpy_correction = [test.outputs[CASE_START]], hybrid.numpy_correction()
    for u in test.inputs[CASE_START:CASE_START + 60]:
        run.append(hybrid_step(run[-1], u, physics.params, thrust_gain=physics.thrust_gain, wind=physics.wind,
                               correction=numpy_correction))
    seen = np.concatenate([air_features(f.recording.outputs, f.recording.inputs, thrust_gain=0.9, wind=physics.wind)
                           for f in fitted_on]
                          + [air_features(np.array(run), test.inputs[CASE_START:CASE_START + 61], thrust_gain=0.9,
                                          wind=physics.wind)])
    hybrid = replace(hybrid, envelope=(tuple(seen.min(axis=0)), tuple(seen.max(axis=0))))
    path = write_json(tmp_path_factory.mktemp("hybrid_model") / "rgblimp_hybrid.json", hybrid.as_dict())
    return {"hybrid": hybrid, "path": path, "inputs": test.inputs, "states": test.outputs}


@pytest.fixture(scope="session")
def hybrid_reference(hybrid_trained, tmp_path_factory):
    """What the FMUs must output over RUN_SAMPLES samples of data_119 from its state at CASE_START:
    the free run ``RolloutHybrid.simulate`` and the standard deviations of the numpy propagation
    (:class:`fmu_src.rgblimp_hybrid.model.RGBlimpHybridModel`), shape (RUN_SAMPLES, 24)."""
    hybrid = hybrid_trained["hybrid"]
    inputs = hybrid_trained["inputs"][CASE_START:CASE_START + RUN_SAMPLES]
    start = hybrid_trained["states"][CASE_START]
    mean = hybrid.simulate(start, inputs)
    model = RGBlimpHybridModel(rgblimp_hybrid_parts(hybrid_trained["path"], tmp_path_factory.mktemp("parts")).arrays)
    state, covariance, hidden, sd = start, model.start_covariance(), model.start_hidden(), [np.zeros(12)]
    for u in inputs[:-1]:
        state, covariance, hidden, _ = model.step(state, covariance, hidden, u, 1 / 60)
        sd.append(np.sqrt(np.maximum(np.diag(covariance)[:12], 0.0)))
    return np.hstack([mean, np.array(sd)])


@pytest.fixture(scope="session")
def rgblimp_hybrid_fmu(hybrid_trained, tmp_path_factory):
    return build_rgblimp_hybrid_fmu(hybrid_trained["path"], tmp_path_factory.mktemp("hybrid_fmu"))


@pytest.fixture(scope="session")
def native_rgblimp_hybrid_fmu(hybrid_trained, tmp_path_factory):
    return build_native_rgblimp_hybrid_fmu(hybrid_trained["path"], tmp_path_factory.mktemp("hybrid_native"),
                                           name="rgblimp_hybrid_native")
