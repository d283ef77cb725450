"""Tests of the RGBlimp real-flight reproduction (validation/reproduce/rgblimp.py) and its command.

The score against a hand-made case, the fit/test split rule on folders of empty files (the rule
reads names only), the one-line errors of bad folders through the command, and one small run
end to end on the first two seconds of the two configurations of the excerpt shipped with the
package (:data:`validation.vehicles.rgblimp_data.EXCERPT_FOLDER`: spirals 117 .. 119, straight
flights 121 .. 123) with hand-made score ranges and a quick setup: the results.json schema and summaries
that follow from the entries, and the RKGP model files. The measured numbers are in
docs/reproductions.md.
"""
import contextlib
import io
import json
import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gp_model import GreyBoxGP, load_model, read_header
from validation.cli import main
from validation.core.errors import BadInputError
from validation.models.rgblimp_greybox import RGBlimpStepDescription
from validation.models.rgblimp_identification import RGBlimpModel
from validation.models.rgblimp_rollout import RolloutHybrid, RolloutSetup
from validation.reproduce.rgblimp import (
    RGBlimpSetup,
    flight_metrics,
    read_score_ranges,
    reproduce_rgblimp,
    rkgp_model_path,
    split_flights,
)
from validation.reproduce.rgblimp_report import BAND_MODELS, MODELS
from validation.vehicles.rgblimp_data import EXCERPT_FOLDER, SOURCE_STATE_WIDTH, read_rgblimp_flight, source_score

RANGES = np.array([2.0, 4.0, 1.0, 0.25, 0.5, 2 * np.pi])


def test_score_is_the_sources_weighted_mean_square_over_23_columns():
    recorded = np.zeros((10, 12))
    predicted = recorded.copy()
    predicted[:, 0] = 0.1                 # x off by 0.1 m everywhere: (0.1 / 2)^2
    predicted[5:, 4] = 0.05               # theta off by 0.05 rad on half the samples: (0.05 / 0.5)^2 / 2
    predicted[:, 6:] = 7.0                # velocities and rates do not count
    expected = ((0.1 / 2.0) ** 2 + (0.05 / 0.5) ** 2 / 2) / SOURCE_STATE_WIDTH
    assert math.isclose(source_score(predicted, recorded, RANGES), expected, rel_tol=1e-12)
    # Yaw just across the wrap: 0.1 rad when wrapped, almost a turn in the source's literal form.
    across = recorded.copy()
    recorded_yaw, predicted_yaw = np.full(10, np.pi - 0.05), np.full(10, -np.pi + 0.05)
    across[:, 5] = predicted_yaw
    behind = recorded.copy()
    behind[:, 5] = recorded_yaw
    wrapped = source_score(across, behind, RANGES)
    literal = source_score(across, behind, RANGES, wrap_yaw=False)
    assert math.isclose(wrapped, (0.1 / RANGES[5]) ** 2 / 23, rel_tol=1e-9)
    assert math.isclose(literal, ((2 * np.pi - 0.1) / RANGES[5]) ** 2 / 23, rel_tol=1e-9)
    # A continuous yaw a turn on is the same yaw to the source, whose integrator wraps it.
    turned = across.copy()
    turned[:, 5] += 2 * np.pi
    assert math.isclose(source_score(turned, behind, RANGES, wrap_yaw=False), literal, rel_tol=1e-9)


def test_flight_metrics_position_errors_and_band_coverage():
    recorded = np.zeros((4, 12))
    predicted = recorded.copy()
    predicted[:, :3] = [0.03, 0.04, 0.0]          # 5 cm everywhere
    predicted[-1, :3] = [0.0, 0.0, 0.1]           # 10 cm at the end
    wide, narrow = np.full((4, 3), 1.0), np.full((4, 3), 1e-3)
    metrics = flight_metrics(predicted, recorded, RANGES, position_sd=wide)
    assert math.isclose(metrics["position_rmse_m"], math.sqrt((3 * 0.05**2 + 0.1**2) / 4))
    assert math.isclose(metrics["final_position_error_m"], 0.1)
    assert metrics["yaw_rmse_rad"] == 0 and metrics["coverage95_position"] == 1.0
    # With 1 mm sd only the exactly-zero coordinates (z on three samples, x and y on the last) lie inside.
    assert flight_metrics(predicted, recorded, RANGES, position_sd=narrow)["coverage95_position"] == 5 / 12
    assert "coverage95_position" not in flight_metrics(predicted, recorded, RANGES)


def _folder(path: Path, numbers, *, data_info: bool = True) -> Path:
    """Empty data_N.csv files (the split reads names only) and, optionally, a data_info folder."""
    path.mkdir(parents=True, exist_ok=True)
    for number in numbers:
        (path / f"data_{number}.csv").write_text("")
    if data_info:
        (path / "data_info").mkdir(exist_ok=True)
        spiral = np.array([np.zeros(38), np.ones(38), np.full(38, 3.0), np.full(38, -1.0)])
        np.savetxt(path / "data_info" / "data_info_spiral.csv", spiral, delimiter=",")
        np.savetxt(path / "data_info" / "data_info_straight.csv", np.array([np.full(38, 2.0), np.zeros(38)]),
                   delimiter=",")
    return path


def test_split_fits_on_all_but_the_highest_numbered_flight_present(tmp_path):
    folder = _folder(tmp_path, [1, 2, 3, 5, 9, 12, 121, 122, 123, 124])
    splits = split_flights(folder)
    assert [(s.configuration, s.fit, s.test, s.kind) for s in splits] == [
        (0, (1, 2), 3, "spiral"), (2, (9,), 12, "spiral"), (30, (121, 122, 123), 124, "straight")]
    assert [s.configuration for s in split_flights(folder, configurations=[30, 0])] == [0, 30]
    with pytest.raises(BadInputError, match="configuration 1 has 1 flight"):
        split_flights(folder, configurations=[1])
    with pytest.raises(BadInputError, match="no configuration has two flights"):
        split_flights(_folder(tmp_path / "lonely", [1, 5, 9]))


def test_score_ranges_are_max_minus_min_from_the_sources_rows(tmp_path):
    folder = _folder(tmp_path, [])
    ranges = read_score_ranges(folder)
    np.testing.assert_array_equal(ranges["spiral"], np.full(6, 4.0))    # rows 3 and 4: 3 - (-1)
    np.testing.assert_array_equal(ranges["straight"], np.full(6, 2.0))  # rows 1 and 2: 2 - 0
    (folder / "data_info" / "data_info_straight.csv").write_text("1,2,3,4,5,6\n")
    with pytest.raises(BadInputError, match="rows"):
        read_score_ranges(folder, kinds=["straight"])


def test_the_excerpt_carries_the_sources_score_ranges():
    ranges = read_score_ranges(EXCERPT_FOLDER)
    # Position ranges of a few metres, angle ranges within a turn: the source's statistics.
    for kind in ("spiral", "straight"):
        assert np.all((ranges[kind][:3] > 1) & (ranges[kind][:3] < 10))
        assert np.all((ranges[kind][3:] > 0.1) & (ranges[kind][3:] <= 2 * np.pi + 1e-3))


def _command(*args) -> tuple[int, str]:
    errors = io.StringIO()
    with contextlib.redirect_stderr(errors), contextlib.redirect_stdout(io.StringIO()):
        code = main(["reproduce", "rgblimp", *args])
    return code, errors.getvalue()


@pytest.mark.parametrize(("numbers", "data_info", "extra", "message"), [
    ([], True, [], "no RGBlimp recordings"),
    ([1, 2, 5], True, ["--configurations", "1"], "configuration 1 has 1 flight"),
    ([1, 2], False, [], "data_info_spiral.csv: missing"),
], ids=["no-data-files", "one-flight", "no-data-info"])
def test_bad_folders_give_one_line_and_exit_2(tmp_path, numbers, data_info, extra, message):
    folder = _folder(tmp_path / "data", numbers, data_info=data_info)
    code, errors = _command("--data", str(folder), "--out", str(tmp_path / "out"), *extra)
    assert code == 2
    assert errors.count("\n") == 1 and errors.startswith("flightgp reproduce: error: ") and message in errors
    assert not (tmp_path / "out" / "results.json").exists()


def test_options_of_other_papers_are_refused(tmp_path):
    code, errors = _command("--out", str(tmp_path / "out"))
    assert code == 2 and "needs --data" in errors
    with contextlib.redirect_stderr(io.StringIO()) as stderr:
        assert main(["reproduce", "bo105", "--out", str(tmp_path), "--data", str(tmp_path)]) == 2
    assert "apply to reproduce rgblimp only" in stderr.getvalue()


#: Short fits: 3 s segments, 60 GP points; the schema and the bookkeeping, not the numbers. The
#: global hybrid has the per-configuration one's 8 inducing inputs: both share one compiled loss.
QUICK = RGBlimpSetup(segment_duration=3.0, max_segments=8, global_max_segments=12, max_iterations=8,
                     training_points=60, global_training_points=80,
                     rollout=RolloutSetup(inducing_points=8, segment_duration=2.0, max_segments=4, max_iterations=3),
                     global_rollout_iterations=4, global_inducing_points=8)


#: Rows of each shortened excerpt flight (2.07 s at 60 Hz; the header besides): enough for every
#: fit of :data:`QUICK` (a segment longer than a flight is masked past its end).
SHORT_ROWS = 125


def _short_excerpt(path: Path, numbers=(117, 118, 119, 121, 122, 123), *, rows: int = SHORT_ROWS) -> Path:
    """The excerpt's flights ``numbers``, each cut to its first ``rows`` samples, and its data_info
    folder, in ``path``: the same files, shorter, so the fits and the free runs take less."""
    path.mkdir(parents=True, exist_ok=True)
    for number in numbers:
        lines = (EXCERPT_FOLDER / f"data_{number}.csv").read_text().splitlines()[:rows + 1]
        (path / f"data_{number}.csv").write_text("\n".join(lines) + "\n")
    (path / "data_info").mkdir(exist_ok=True)
    for source in (EXCERPT_FOLDER / "data_info").iterdir():
        (path / "data_info" / source.name).write_bytes(source.read_bytes())
    return path


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """Configurations 29 (spirals data_117..119) and 30 (straight data_121..123), their first two
    seconds, run end to end."""
    data = _short_excerpt(tmp_path_factory.mktemp("rgblimp_data"))
    out = tmp_path_factory.mktemp("rgblimp_out")
    # The quick setup with 3 identification iterations (as the unseen study's test): the schema,
    # the files and the bookkeeping, not the numbers.
    results = reproduce_rgblimp(data, out, setup=replace(QUICK, max_iterations=3), progress=False)
    return data, out, results


@pytest.mark.slow
def test_results_json_has_the_issues_schema(small_run):
    _, out, results = small_run
    written = json.loads((out / "results.json").read_text())
    assert written["configurations"] == json.loads(json.dumps(results["configurations"]))
    first, second = written["configurations"]
    assert (first["index"], first["fit"], first["test"]) == (29, ["data_117.csv", "data_118.csv"], "data_119.csv")
    assert (second["index"], second["fit"], second["test"]) == (30, ["data_121.csv", "data_122.csv"], "data_123.csv")
    for entry in written["configurations"]:
        for key in ("score", "position_rmse_m", "final_position_error_m", "yaw_rmse_rad"):
            assert set(entry[key]) == set(MODELS)
            assert all(math.isfinite(v) and v >= 0 for v in entry[key].values())
        assert set(entry["coverage95_position"]) == set(BAND_MODELS)
        assert set(entry["fit_seconds"]) == {"identified", "rkgp", "sindyc", "hybrid"}
        assert set(entry["free_run_seconds"]) == set(MODELS)
        assert all(0 <= v <= 1 for v in entry["coverage95_position"].values())
    summary = written["summary"]
    for key, entry_key in (("mean_score", "score"), ("mean_position_rmse_m", "position_rmse_m")):
        assert set(summary[key]) == set(MODELS)
        for name in MODELS:
            assert math.isclose(summary[key][name], np.mean([e[entry_key][name] for e in written["configurations"]]))
    assert written["global"]["fit"] == ["data_117.csv", "data_118.csv", "data_121.csv", "data_122.csv"]
    assert written["default_model"] in MODELS
    for name in ("score", "position_rmse_m"):
        assert set(summary[f"mean_{name}"]) >= {written["default_model"]}
    for name in ("report.md", "scores.png", "flight_29.png", "flight_30.png"):
        assert (out / name).stat().st_size > 0
    assert all(name in (out / "report.md").read_text() for name in ("## Goals", "scores.png", "data_123.csv"))


@pytest.mark.slow
def test_the_published_model_is_scored_as_it_is_and_goals_follow_the_summary(small_run):
    data, _, results = small_run
    for entry in results["configurations"]:
        # The published model's score depends on no fit, so it is the same with any setup.
        flight = read_rgblimp_flight(data / entry["test"])
        ranges = read_score_ranges(data, kinds=[entry["kind"]])[entry["kind"]]
        predicted = RGBlimpModel().simulate(flight.recording.outputs[0], flight.recording.inputs)
        assert math.isclose(entry["score"]["physics"], source_score(predicted, flight.recording.outputs, ranges))
    for name, goal in results["goals"].items():
        assert goal["met"] in (True, False) and "measured" in goal, name
    beats = results["summary"]["beats_physics_in_score"]["rkgp"]
    assert results["goals"]["rkgp_beats_physics_on_every_test_flight"]["met"] == (beats == 2)
    beats = results["summary"]["beats_identified_in_score"]["hybrid"]
    assert results["goals"]["hybrid_beats_identified"]["met"] == (beats == 2)  # 30 of 35 of 2 flights: both


@pytest.mark.slow
def test_each_configurations_rkgp_is_written_as_a_model_file_its_fmu_is_built_from(small_run):
    """OUT/models/rgblimp_rkgp_<j>.npz holds configuration j's RKGP with its identified model as
    the physics (rgblimp_rk4, every coefficient as identified), which `flightgp build-fmu` takes."""
    _, out, results = small_run
    for entry in results["configurations"]:
        path = rkgp_model_path(out, entry["index"])
        assert entry["rkgp_model_file"] == f"models/{path.name}" and path.is_file()
        assert isinstance(load_model(path), GreyBoxGP)
        identified = RGBlimpStepDescription.from_dict(read_header(path)["physics"]).model
        for name, fitted in entry["identification"]["parameters"].items():
            assert identified.value(name) == fitted["value"], name


@pytest.mark.slow
def test_each_configurations_hybrid_is_written_and_reads_back_to_its_free_run(small_run):
    data, out, results = small_run
    for entry in results["configurations"]:
        hybrid = RolloutHybrid.from_dict(json.loads((out / entry["hybrid_model_file"]).read_text()))
        shared = RolloutHybrid.from_dict(json.loads((out / entry["hybrid_global_model_file"]).read_text()))
        # Each fitted with its own iteration limit: the global fit's is the setup's own field, which
        # the setup's global_rollout carries with the global inducing inputs (tested below).
        assert (hybrid.setup.max_iterations, shared.setup.max_iterations) == (QUICK.rollout.max_iterations,
                                                                       QUICK.global_rollout_iterations)
        for name, value in entry["hybrid"]["physics"].items():
            assert hybrid.physics.value(name) == value, name
        test = read_rgblimp_flight(data / entry["test"]).recording
        ranges = read_score_ranges(data, kinds=[entry["kind"]])[entry["kind"]]
        predicted, _ = hybrid.band(test.outputs[0], test.inputs)  # as the reproduction runs it
        assert math.isclose(entry["score"]["hybrid"], source_score(predicted, test.outputs, ranges), rel_tol=1e-12)


@pytest.mark.parametrize("shrinkage", [0.0, -0.25, float("nan"), "0.25", True])
def test_a_setup_with_a_bad_shrinkage_is_refused_when_it_is_made(shrinkage):
    """Refused in one line where the setup is made, before any fit (the global fit alone takes
    minutes); None (each configuration alone) and a positive number are taken."""
    with pytest.raises(BadInputError, match="shrinkage must be a positive number or None"):
        RGBlimpSetup(shrinkage=shrinkage)
    assert RGBlimpSetup(shrinkage=None).shrinkage is None


@pytest.mark.parametrize("field", ["global_rollout_iterations", "global_inducing_points"])
@pytest.mark.parametrize("value", [0, -3, 2.5, "200", True, None])
def test_a_setup_with_no_global_hybrid_iterations_or_inducing_inputs_is_refused(field, value):
    with pytest.raises(BadInputError, match=f"{field} must be a whole number of at least 1, "
                                            f"got {re.escape(repr(value))}"):
        RGBlimpSetup(**{field: value})


def test_the_global_fit_takes_the_setups_own_iterations_and_inducing_inputs():
    setup = RGBlimpSetup(global_rollout_iterations=7, global_inducing_points=5)
    assert setup.global_rollout == replace(setup.rollout, max_iterations=7, inducing_points=5)
