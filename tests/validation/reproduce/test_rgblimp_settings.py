"""Tests of the RGBlimp settings study (validation/reproduce/rgblimp_settings.py): its split never
reads a configuration's test flight, and a short study on the first two seconds of the shipped
excerpt's flights scores every candidate on the validation flights. The measured numbers are in
docs/rgblimp.md."""
import contextlib
import io
import json
import math
from dataclasses import replace

import numpy as np
import pytest

from validation.cli import main
from validation.core.errors import BadInputError
from validation.models.rgblimp_rollout import RolloutSetup
from validation.reproduce import rgblimp_settings
from validation.reproduce.rgblimp_settings import (
    SCORED,
    format_hybrid_settings,
    format_settings,
    study_hybrid_settings,
    study_settings,
    validation_splits,
)

from .test_rgblimp import QUICK, _folder, _short_excerpt


def test_validation_split_fits_on_the_first_flight_and_leaves_the_test_flight_unread(tmp_path):
    folder = _folder(tmp_path, [1, 2, 3, 5, 6, 9, 10, 11, 12, 121, 122, 123])
    splits = validation_splits(folder)
    assert [(s.configuration, s.fit, s.test) for s in splits] == [(0, (1,), 2), (2, (9,), 10), (30, (121,), 122)]
    with pytest.raises(BadInputError, match="three flights"):
        validation_splits(folder, configurations=[1])
    with pytest.raises(BadInputError, match="three flights"):
        validation_splits(_folder(tmp_path / "two", [1, 2]))


@pytest.mark.slow
def test_a_short_study_scores_each_candidate_without_reading_a_test_flight(tmp_path, monkeypatch):
    data = _short_excerpt(tmp_path / "data")
    read = []
    original = rgblimp_settings.read_rgblimp_flight
    monkeypatch.setattr(rgblimp_settings, "read_rgblimp_flight", lambda path: read.append(path.name) or original(path))
    # The quick setup with 2 identification iterations (the fewest that take a step): the split,
    # the sharing and the means, not the numbers.
    quick = replace(QUICK, max_iterations=2)
    candidates = {"quick": quick, "quick without wind": replace(quick, identified_parameters=("thrust_gain", "c_d0"))}
    results = study_settings(data, candidates=candidates)
    assert sorted(read) == ["data_117.csv", "data_118.csv", "data_121.csv", "data_122.csv"]
    assert [s["validation"] for s in results["splits"]] == ["data_118.csv", "data_122.csv"]
    for entry in results["candidates"].values():
        for key in ("score", "position_rmse_m"):
            assert set(entry[f"mean_{key}"]) == set(SCORED)
            per_configuration = [c[key]["rkgp"] for c in entry["configurations"]]
            assert math.isclose(entry[f"mean_{key}"]["rkgp"], np.mean(per_configuration))
    # The published model depends on no setting.
    first, second = results["candidates"].values()
    assert first["mean_score"]["physics"] == second["mean_score"]["physics"]
    assert first["mean_score"]["identified"] != second["mean_score"]["identified"]
    assert "quick without wind" in format_settings(results)
    json.dumps(results)


@pytest.mark.slow
def test_a_short_hybrid_study_scores_each_candidate_without_reading_a_test_flight(tmp_path, monkeypatch):
    data = _short_excerpt(tmp_path / "data", (121, 122, 123))
    read = []
    original = rgblimp_settings.read_rgblimp_flight
    monkeypatch.setattr(rgblimp_settings, "read_rgblimp_flight", lambda path: read.append(path.name) or original(path))
    tiny = RolloutSetup(inducing_points=8, segment_duration=2.0, max_segments=8, max_iterations=2)
    candidates = {"tiny": tiny, "tiny untuned": replace(tiny, tune_physics=False)}
    # The identification the hybrids start from in 3 iterations, as in the other quick studies.
    results = study_hybrid_settings(data, candidates=candidates, setup=replace(QUICK, max_iterations=3))
    assert sorted(read) == ["data_121.csv", "data_122.csv"]
    for entry in results["candidates"].values():
        (configuration,) = entry["configurations"]
        assert entry["mean_score"] == configuration["score"]
        assert entry["hybrid_beats_identified"] == int(configuration["score"]["hybrid"]
                                                       < configuration["score"]["identified"])
    first, second = results["candidates"].values()
    assert first["mean_score"]["identified"] == second["mean_score"]["identified"]  # shared
    assert "tiny untuned" in format_hybrid_settings(results)
    json.dumps(results)


@pytest.mark.parametrize("paper", ["rgblimp-settings", "rgblimp-hybrid-settings"])
def test_the_command_needs_data_and_writes_nothing_on_a_bad_folder(tmp_path, paper):
    folder = _folder(tmp_path / "data", [1, 2])
    errors = io.StringIO()
    with contextlib.redirect_stderr(errors), contextlib.redirect_stdout(io.StringIO()):
        code = main(["reproduce", paper, "--data", str(folder), "--out", str(tmp_path / "out")])
    assert code == 2 and errors.getvalue().count("\n") == 1 and "three flights" in errors.getvalue()
    assert not any((tmp_path / "out").glob("*settings.json"))
