"""Fixtures of the RGBlimp RKGP FMU tests (session scope: each is made once per test process): a
small RKGP fitted on the repository's excerpt of the RGBlimp's flights, its model file, and its
pythonfmu and native FMUs."""
from __future__ import annotations

import pytest

from fmu_src import build_native_rgblimp_rkgp_fmu, build_rgblimp_rkgp_fmu
from gp_model import save_model
from validation.models.rgblimp_greybox import RGBlimpStepDescription, fit_rkgp
from validation.models.rgblimp_identification import RGBlimpModel
from validation.vehicles.rgblimp_data import EXCERPT_FOLDER, read_rgblimp_flight

#: The physics of the test RKGP: the published model with a thrust factor, a drag coefficient and
#: a steady wind as an identification gives them (not identified: the FMUs must equal whatever
#: model they carry; the wind exercises the step's change to the air mass's frame).
TEST_MODEL = RGBlimpModel().replaced({"thrust_gain": 0.9, "c_d0": 0.3, "wind_x": 0.02, "wind_y": -0.01})


@pytest.fixture(scope="session")
def rgblimp_flights():
    """The excerpt's spirals of configuration 29: data_117 and data_118 to fit on, data_119 to run."""
    return {n: read_rgblimp_flight(EXCERPT_FOLDER / f"data_{n}.csv") for n in (117, 118, 119)}


@pytest.fixture(scope="session")
def rgblimp_trained(rgblimp_flights):
    """An RKGP as validation.models.rgblimp_greybox fits them (one GP per state, smoothed training
    states), on 40 transitions of data_117 and data_118 (about 0.1 s), and the test flight
    data_119's inputs (n, 5), recorded states (n, 12) and first recorded state (12,)."""
    model = fit_rkgp([rgblimp_flights[117], rgblimp_flights[118]], TEST_MODEL, n_points=40)
    test = rgblimp_flights[119].recording
    return {"model": model, "description": RGBlimpStepDescription(TEST_MODEL), "inputs": test.inputs,
            "states": test.outputs, "start": test.outputs[0]}


@pytest.fixture(scope="session")
def rgblimp_model_file(rgblimp_trained, tmp_path_factory):
    return save_model(tmp_path_factory.mktemp("rgblimp_model") / "rgblimp_rkgp.npz", rgblimp_trained["model"],
                      physics=rgblimp_trained["description"].as_dict())


@pytest.fixture(scope="session")
def rgblimp_rkgp_fmu(rgblimp_model_file, tmp_path_factory):
    return build_rgblimp_rkgp_fmu(rgblimp_model_file, tmp_path_factory.mktemp("rgblimp_fmu"))


@pytest.fixture(scope="session")
def native_rgblimp_rkgp_fmu(rgblimp_model_file, tmp_path_factory):
    return build_native_rgblimp_rkgp_fmu(rgblimp_model_file, tmp_path_factory.mktemp("rgblimp_native"),
                                         name="rgblimp_native")
