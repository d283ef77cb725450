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
from tests.fmu_src.rate_predictor.contract import (
    RatePredictorContract,
    assert_fast_free_run_within_tolerance,
    rate_predictor_case,
)
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


@pytest.mark.parametrize("flight", ["training", "unseen"])
def test_the_fast_free_run_is_within_2_percent_of_the_predicted_sd_of_the_exact_one(case, bo105_flights, flight):
    """exact_moments = false (the default) takes the pair terms of eq. 6 in float32
    (MomentMatcher's single_precision), as the native FMU's fast path: within 2 % of the
    predicted sd of the exact free run along the paper's 3-2-1-1 and the unseen one; measured at
    most 1.2e-5 (means) and 3.9e-4 (standard deviations)."""
    assert_fast_free_run_within_tolerance(case.path, bo105_flights[flight].input("theta_1s")[::10])


def test_the_build_defaults_to_the_exact_moments_where_its_check_of_the_fast_path_fails(rate_predictor_fmu,
                                                                                        bo105_model_file, tmp_path,
                                                                                        monkeypatch):
    """The build free-runs a test 3-2-1-1 with both paths (fast_path_error): on the paper's model
    the fast path is off by 6.1e-4 of the sd, under the check's 1 %, so exact_moments defaults to
    false and the description says what was measured (the session's FMU of that model, built with
    the defaults); a model whose check fails (its error stood in for here) gets exact_moments =
    true by default, in the pythonfmu and the native FMU alike."""
    from fmpy import read_model_description

    import fmu_src.rate_predictor.build as build
    from fmu_src import build_native_rate_predictor_fmu

    def default(fmu):
        description = read_model_description(str(fmu))
        start = next(v.start for v in description.modelVariables if v.name == "exact_moments")
        return start in (True, "true"), description.description

    exact, text = default(rate_predictor_fmu)
    error = float(text.split("by at most ")[1].split(" % of the predicted standard deviation")[0]) / 100
    assert not exact and 0 < error <= build.FAST_PATH_CHECK and "(within the 1 % allowed), so exact_moments " \
        "defaults to false." in text
    monkeypatch.setattr(build, "fast_path_error", lambda predictor: 0.05)
    for builder in (build_rate_predictor_fmu, build_native_rate_predictor_fmu):
        exact, text = default(builder(bo105_model_file, tmp_path / builder.__name__))
        assert exact and "by at most 5 % of the predicted standard deviation (over the 1 % allowed), so " \
            "exact_moments defaults to true." in text


def test_the_descriptions_say_what_the_host_must_feed_and_where_the_model_is_valid(rate_predictor_fmu):
    """For a simulator engineer who never saw flightgp: the FMU's description states the vehicle
    and trim it was trained at (from the model file), p_prev what to set and when, free_run that
    the host must then feed measured rates back; no jargon of the build's check."""
    from fmpy import read_model_description

    description = read_model_description(str(rate_predictor_fmu))
    assert "Trained on recordings of bo105-80kt-flight, trimmed at 80 kt: valid near that flight condition only" \
        in description.description
    variables = {v.name: v.description for v in description.modelVariables}
    assert variables["p_prev"].startswith("roll rate at the communication point t_k the next step starts from: "
                                          "with free_run false (the default) the host must set it before every "
                                          "step to the roll rate measured at t_k")
    assert "must then feed back into the *_prev inputs at every step" in variables["free_run"]
    assert all(word not in text for text in (description.description, *variables.values())
               for word in ("fast path", "of the sd", "moment matching", "GP mean"))


def test_a_model_file_that_does_not_name_its_condition_says_so():
    from fmu_src.rate_predictor.build import condition_words

    assert condition_words({}).startswith("The model file does not name the vehicle or flight condition")
    assert condition_words({"vehicle": "blimp-flight"}) == ("Trained on recordings of blimp-flight: valid near the "
                                                           "conditions flown in them only")


@pytest.mark.parametrize("fault", ["nan", "refused"])
def test_a_test_free_run_that_fails_counts_as_an_infinite_fast_path_error(bo105_trained, monkeypatch, fault):
    """fast_path_error must not let a failed measurement pass for a small error (max() drops NaN):
    a fast path turning non-finite, or a belief the matcher refuses, gives inf, so the FMU
    defaults to the exact moments."""
    from fmu_src.rate_predictor.build import FAST_PATH_CHECK, export_narx_arrays, fast_path_error
    from fmu_src.rate_predictor.predictor import NarxPredictor

    predictor = NarxPredictor(export_narx_arrays(bo105_trained))
    assert 0.0 < fast_path_error(predictor) <= FAST_PATH_CHECK
    step = predictor.free_run_step

    def faulty(history, belief, *, exact_moments=True):
        mean, var, belief = step(history, belief, exact_moments=exact_moments)
        if not exact_moments and fault == "refused":
            raise ValueError("mean or cov contains NaN or inf")
        return mean, var if exact_moments else np.full_like(var, np.nan), belief

    monkeypatch.setattr(predictor, "free_run_step", faulty)
    assert fast_path_error(predictor) == np.inf
