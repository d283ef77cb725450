"""Fixtures of the FMU tests: the trained models and built FMUs only these tests use (session
scope: each is made once per test process; those other packages share are in tests/conftest.py),
and, on a test module's ``case`` (tests/fmu_src/contract.py), the unzipped FMU and a host
instance."""
from __future__ import annotations

import numpy as np
import pytest
from fmpy import extract

from fmu_src import (
    build_blimp_rkgp_fmu,
    build_jsbsim_fmu,
    build_native_blimp_rkgp_fmu,
    build_native_rate_predictor_fmu,
)
from gp_model import GreyBoxGP, save_model
from tests.fmu_src.blimp_rkgp.contract import BLIMP_HOLD
from tests.fmu_src.contract import Host
from validation.models.blimp_greybox import (
    COMMAND_LAGS,
    GP_STATE_COLUMNS,
    MIN_NOISE_VARIANCE,
    BlimpStepDescription,
    smoothed_states,
    step_inputs,
)
from validation.models.blimp_identification import physics_step, recording_arrays
from validation.vehicles.blimp import BlimpParameters
from validation.vehicles.blimp_flight import BlimpFlightTest


# -- the Bo105 GP-NARX rate predictor (flights, model and pythonfmu FMU: tests/conftest.py) ---------
@pytest.fixture(scope="session")
def native_rate_predictor_fmu(bo105_model_file, tmp_path_factory):
    return build_native_rate_predictor_fmu(bo105_model_file, tmp_path_factory.mktemp("native"),
                                           name="bo105_native_rate_predictor")


# -- the physics references (the Bo105 reference FMU: tests/conftest.py) ----------------------------
@pytest.fixture(scope="session")
def jsbsim_fmu(tmp_path_factory):
    return build_jsbsim_fmu("c172x", tmp_path_factory.mktemp("fmu"))


# -- the blimp RKGP (RK4 physics plus GP residual) ----------------------------------------------------
@pytest.fixture(scope="session")
def blimp_trained():
    """10 s of blimp-flight under random piecewise-constant commands (many levels, so maximum
    likelihood finds no degenerate length scale for a command seen at two or three values), and a
    shared-GP RKGP on the reference's RK4 physics, leaving out position and yaw (Ko et al.):
    200 training pairs, about 1 s. Motion capture is off (true states, frames every 0.05 s): on
    the differentiated, noisy mocap velocities the maximum-likelihood GP interpolates the noise
    (noise variance at its lower bound) and its variance is at the prior's along any free run,
    so there would be nothing to widen outside the envelope. The other blimp-flight effects
    (motor lag, dead band, tail asymmetry, CG offset, buoyancy drift) are the residual it learns."""
    time = np.arange(201) * BlimpFlightTest.sample_time
    rng = np.random.default_rng(0)
    levels = lambda low, high: np.repeat(rng.uniform(low, high, 21), BLIMP_HOLD)[:len(time)]  # noqa: E731
    commands = np.column_stack([levels(0.2, 0.8), levels(-0.2, 0.4), levels(-0.6, 0.6)])
    states, inputs = recording_arrays(BlimpFlightTest(mocap=False).simulate(time, commands, seed=0))
    params = BlimpParameters()
    model = GreyBoxGP(state_columns=(3, 4, 6, 7, 8, 9, 10, 11), n_restarts=0).fit_trajectories(
        [(states, inputs)], physics_step(params))
    return {"model": model, "params": params, "states": states, "commands": commands}


@pytest.fixture(scope="session")
def blimp_model_file(tmp_path_factory, blimp_trained):
    return save_model(tmp_path_factory.mktemp("model") / "blimp_rkgp.npz", blimp_trained["model"],
                      physics=BlimpStepDescription(blimp_trained["params"]).as_dict())


@pytest.fixture(scope="session")
def blimp_rkgp_fmu(blimp_model_file, tmp_path_factory):
    return build_blimp_rkgp_fmu(blimp_model_file, tmp_path_factory.mktemp("fmu"))


@pytest.fixture(scope="session")
def native_blimp_rkgp_fmu(blimp_model_file, tmp_path_factory):
    return build_native_blimp_rkgp_fmu(blimp_model_file, tmp_path_factory.mktemp("native"), name="blimp_native")


@pytest.fixture(scope="session")
def blimp_lagged(tmp_path_factory):
    """A grey-box model as validation.models.blimp_greybox fits them, on 4 s of the blimp-flight
    stand-in (motion capture on: jittered frames, noisy poses) under random commands held 0.5 s:
    smoothed states, the fans' lagged commands (COMMAND_LAGS) as GP inputs, one GP per state on
    all 79 transitions. Its hyperparameters stay at their defaults (``optimize=False``): the FMUs
    must equal whatever model they carry, and the fit takes milliseconds (the flight 0.3 s)."""
    time = np.arange(81) * BlimpFlightTest.sample_time
    rng = np.random.default_rng(2)
    levels = lambda low, high: np.repeat(rng.uniform(low, high, 9), BLIMP_HOLD)[:len(time)]  # noqa: E731
    commands = np.column_stack([levels(0.2, 0.8), levels(-0.2, 0.4), levels(-0.6, 0.6)])
    recording = BlimpFlightTest().simulate(time, commands, seed=0)
    params = BlimpParameters()
    description = BlimpStepDescription(params, command_lags=COMMAND_LAGS)
    states, inputs = smoothed_states(recording), step_inputs(recording, command_lags=COMMAND_LAGS)
    model = GreyBoxGP(state_columns=GP_STATE_COLUMNS, shared=False, min_noise_variance=MIN_NOISE_VARIANCE).fit(
        states[:-1], inputs[:-1], states[1:], description.physics_step(), optimize=False)
    path = save_model(tmp_path_factory.mktemp("lagged") / "blimp_lagged.npz", model, physics=description.as_dict())
    return {"model": model, "params": params, "command_lags": COMMAND_LAGS, "states": states,
            "commands": commands, "path": path}


@pytest.fixture(scope="session")
def blimp_lagged_fmu(blimp_lagged, tmp_path_factory):
    return build_blimp_rkgp_fmu(blimp_lagged["path"], tmp_path_factory.mktemp("fmu"), name="blimp_lagged")


@pytest.fixture(scope="session")
def native_blimp_lagged_fmu(blimp_lagged, tmp_path_factory):
    return build_native_blimp_rkgp_fmu(blimp_lagged["path"], tmp_path_factory.mktemp("native"),
                                       name="blimp_lagged_native")


# -- on the test module's case ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def unzipdir(case, tmp_path_factory):
    return extract(str(case.path), unzipdir=str(tmp_path_factory.mktemp("unzipped")))


@pytest.fixture
def host(unzipdir):
    instance = Host(unzipdir)
    yield instance
    instance.close()
