"""The pythonfmu GP-NARX rate predictor FMU (fmu_src/rate_predictor): the FMU contract and the
rate predictor's, on the paper's Bo105 model (400 hyperparameter samples), then what is
particular to the pythonfmu build."""
from __future__ import annotations

import zipfile

import numpy as np
import pytest
from fmpy import extract

from fmu_src import build_rate_predictor_fmu
from tests.fmu_src.contract import FmuContract, Host, standard_run
from tests.fmu_src.rate_predictor.contract import RatePredictorContract, rate_predictor_case
from validation.models.narx import NarxConfig, one_step, save_trained, train_narx


@pytest.fixture(scope="module")
def case(rate_predictor_fmu, bo105_trained, bo105_flights):
    return rate_predictor_case(rate_predictor_fmu, bo105_trained, bo105_flights["training"])


class TestRatePredictorFmu(FmuContract, RatePredictorContract):
    """The FMU contract and the rate predictor's, on the pythonfmu rate predictor."""


def test_two_fmus_of_one_name_run_their_own_models(case, bo105_flights, tmp_path):
    """A Python host shares sys.modules with every FMU it loads (docs/fmus.md, "The FMUs"). Two FMUs
    with the same name but different models get different module names, and each runs its own
    model."""
    other = train_narx([bo105_flights["training"]],
                       NarxConfig(hyperparameters="maximum_likelihood", stride=10), seed=0, n_restarts=0)
    other_path = build_rate_predictor_fmu(save_trained(tmp_path / "other.npz", other), tmp_path / "fmu",
                                          name="bo105_rate_predictor")
    modules = [zipfile.ZipFile(p).read("resources/slavemodule.txt").decode().strip()
               for p in (case.path, other_path)]
    assert modules[0] != modules[1]
    runs = []
    for i, path in enumerate((case.path, other_path)):  # both loaded into this process
        host = Host(extract(str(path), unzipdir=str(tmp_path / f"u{i}")), name=f"fmu{i}")
        try:
            runs.append(standard_run(case, host))
        finally:
            host.close()
    assert np.abs(runs[0] - runs[1]).max() > 1e-3
    expected, first = case.reference()
    np.testing.assert_allclose(runs[0][first:], expected[first:], rtol=0, atol=1e-9)
    q = host.outputs.index("q")
    np.testing.assert_allclose(runs[1][first:, q], one_step(other, bo105_flights["training"]).mean[first:, 1],
                               rtol=0, atol=1e-9)
