"""Tests of the blimp RKGP Tables I, II and III reproduction (validation/reproduce/blimp*.py) and
its command.

One quick campaign (one seed, every table's QUICK_SETUP) runs end to end through the command;
the assertions are what holds by construction or by physics, and that the goals and notes say
what the tables measured. The paper's margins are not asserted: docs/reproductions.md reports
the full campaign's numbers, met or missed.
"""
import contextlib
import dataclasses
import io
import json
import math

import numpy as np
import pytest

from validation.cli import main
from validation.models.blimp_greybox import (
    COMMAND_LAGS,
    GP_STATE_COLUMNS,
    MIN_NOISE_VARIANCE,
    smoothed_states,
    step_inputs,
)
from validation.reproduce import blimp_control, blimp_prediction, blimp_spread
from validation.reproduce.blimp_prediction import (
    GROUPS,
    HORIZON_FRAMES,
    METHODS,
    RK_MAX_STEP,
    START_KINDS,
    horizon_rmse,
    random_command_flight,
)
from validation.reproduce.blimp_report import format_results
from validation.reproduce.blimp_spread import (
    CALIBRATED_ROWS,
    CALIBRATION_ITERATIONS,
    CALIBRATION_TOLERANCE,
    QUICK_SETUP,
    ROWS,
    Table2Setup,
    calibrate_spread,
    table2,
)
from validation.vehicles.blimp import STATE_NAMES

SEED = 3
#: Table II in the quick campaign of :func:`quick`: 4 stand-in runs and 8 samples instead of 8 and 20.
SPREAD_SETUP = dataclasses.replace(QUICK_SETUP, stand_in_runs=4, n_samples=8)
#: Iterations of the ODE's identification in the quick campaign here: on seed 3's 30 s training
#: flight it converges in 21 (about 10 s); after 10 its RMS residual is the converged one to
#: 0.01 % (0.53423 against 0.53421). (After 6, 0.536, Table II's calibrated spread with noise
#: came out below the one without, 0.00264 against 0.00267 m: a comparison of 8 samples each
#: that holds in expectation, not by construction.)
IDENTIFICATION_ITERATIONS = 10


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """``flightgp reproduce blimp --quick --seeds 3``: the output folder, results.json and what
    the command printed.

    Table III's policy search gets 6 cost evaluations per simulator instead of the quick setup's
    12 (the 4-parameter Nelder-Mead's start simplex, 5 evaluations, and one step), one PEGASUS
    scenario instead of 2, 3 s turns instead of 6 s (a full-command turn takes about 3 s) and one
    stand-in turn per controller instead of 2: its tests check what holds for any budget (finite
    errors of a turn that moved, the best vertex no worse than the start), and the search is most
    of the campaign's time. Table I scores 5 start states instead of 20 on an 8 s held-out flight
    instead of 15 s (its tests check bounds that hold for every start and the physics
    integrators' agreement; the 30 s training flight stays: the identification takes twice as
    many iterations on 15 s), and the ODE is identified in :data:`IDENTIFICATION_ITERATIONS`
    iterations instead of until it converges. Table II takes :data:`SPREAD_SETUP` (what it
    checks holds for any number of runs and samples above one)."""
    out = tmp_path_factory.mktemp("blimp")
    printed = io.StringIO()
    with pytest.MonkeyPatch.context() as patch, contextlib.redirect_stdout(printed):
        patch.setattr(blimp_control, "QUICK_SETUP", dataclasses.replace(
            blimp_control.QUICK_SETUP, max_evaluations=6, n_scenarios=1, horizon_s=3.0, stand_in_runs=1))
        patch.setattr(blimp_prediction, "QUICK_SETUP", dataclasses.replace(
            blimp_prediction.QUICK_SETUP, n_starts=5, held_out_duration=8.0,
            identification_iterations=IDENTIFICATION_ITERATIONS))
        patch.setattr(blimp_spread, "QUICK_SETUP", SPREAD_SETUP)
        assert main(["reproduce", "blimp", "--out", str(out), "--quick", "--seeds", str(SEED)]) == 0
    return out, json.loads((out / "results.json").read_text()), printed.getvalue()


@pytest.mark.slow
def test_table1_has_every_start_kind_method_and_group_with_its_noise_floor(quick):
    out, results, printed = quick
    by_seed = results["table1"]["by_seed"][str(SEED)]
    assert set(by_seed) == {"noise_floor", *START_KINDS}
    # The setup recorded is the one that ran (the fixture's, not the module's quick setup).
    assert (results["setup"]["n_starts"], results["setup"]["held_out_duration"], results["setup"]["quick"]) == (
        5, 8.0, True)
    assert all(math.isfinite(v) and v > 0 for v in by_seed["noise_floor"].values())
    for kind in START_KINDS:
        assert set(by_seed[kind]) == set(METHODS)
        for method, row in by_seed[kind].items():
            for key in (*GROUPS, *(f"against_true.{g}" for g in GROUPS)):
                value = row["against_true"][key.split(".")[1]] if "." in key else row[key]
                assert math.isfinite(value) and value > 0, (kind, method, key)
    assert all(by_seed["filtered"][m]["time_s"] > 0 for m in METHODS)
    # The noise floor is the true states' error against the recording: a perfect model's score.
    # Every model's error against the recording is above it, and against the truth it is smaller
    # than against the recording plus the floor (triangle inequality, per start then RMS).
    for method in METHODS:
        row = by_seed["true"][method]
        for group in GROUPS:
            assert row[group] <= row["against_true"][group] + by_seed["noise_floor"][group] + 1e-12
    assert all(method in printed for method in METHODS) and "noise floor" in printed


@pytest.mark.slow
def test_physics_integrators_agree_and_physics_beats_gp_only_on_position(quick):
    table = quick[1]["table1"]["by_seed"][str(SEED)]["true"]
    # Same identified ODE, RK4 at one step per frame vs RK45 at rtol 1e-8: the integrator error
    # is far below the 1 mm / 0.5 deg mocap noise, so the two agree to 1 % on every group.
    for group in GROUPS:
        assert table["ODE"][group] == pytest.approx(table["RK"][group], rel=0.01)
    # Position needs yaw (earth-frame kinematics), which the GP inputs leave out: GP-only cannot.
    assert table["RKGP"]["position"] < table["GPonly"]["position"]
    assert table["RK"]["position"] < table["GPonly"]["position"]


@pytest.mark.slow
def test_goals_say_what_the_tables_measured(quick):
    results = quick[1]
    summary = results["table1"]["summary"]["filtered"]
    smallest = summary["RK_over_RKGP_smallest"]
    goal = results["goals"]["table1_RKGP_beats_RK_every_group_and_seed"]
    assert goal["met"] == all(smallest[g] > 1 for g in GROUPS)
    table = results["table1"]["by_seed"][str(SEED)]["filtered"]
    for group in GROUPS:
        assert smallest[group] == pytest.approx(table["RK"][group] / table["RKGP"][group], rel=1e-12)
    margin = results["goals"]["table1_margin_over_RK"]
    assert margin["met"] == (smallest["position"] >= 3 and smallest["velocity"] >= 3)
    ratio = results["table2"]["by_seed"][str(SEED)]["spread_ratio_calibrated"]
    assert results["goals"]["table2_calibrated_spread_within_30_percent"]["met"] == (abs(ratio - 1) <= 0.3)
    third = results["table3"]["by_seed"][str(SEED)]
    assert third["yaw_error_ratio_RK_to_RKGP"] == pytest.approx(
        third["RK"]["yaw_error_deg"] / third["RKGP"]["yaw_error_deg"], rel=1e-12)
    # Every missed goal is a note with its number.
    for name, entry in results["goals"].items():
        assert entry["met"] or any(note.startswith(f"Goal missed: {name}") for note in results["notes"])


@pytest.mark.slow
def test_table2_rows_and_their_properties(quick):
    out, results, printed = quick
    second = results["table2"]["by_seed"][str(SEED)]
    assert set(ROWS) <= set(second)
    for row in ROWS:
        assert all(math.isfinite(v) for v in second[row].values()), row
    # The mean rollout is one deterministic end point: zero spread by construction; sampling
    # draws different residual functions, and the stand-in runs differ in drift, jitter, noise.
    assert second["rkgp_mean"]["position_spread_m"] == 0.0 and second["rkgp_mean"]["yaw_std_deg"] == 0.0
    assert second["rkgp_sampled"]["position_spread_m"] > 0 and second["stand_in"]["position_spread_m"] > 0
    assert second["spread_ratio_noise"] == pytest.approx(
        second["rkgp_sampled_noise"]["position_spread_m"] / second["stand_in"]["position_spread_m"], rel=1e-12)
    assert second["setup"]["stand_in_runs"] == SPREAD_SETUP.stand_in_runs and "Table II" in printed
    # The calibrated rows: the same normals at the scale chosen on validation repeats.
    calibration = second["calibration"]
    assert set(CALIBRATED_ROWS) <= set(second) and calibration["spread_scale"] > 0
    assert (abs(calibration["calibrated_spread_m"] / calibration["stand_in_spread_m"] - 1) <= CALIBRATION_TOLERANCE
            or calibration["rescalings"] == CALIBRATION_ITERATIONS)
    assert second["rkgp_calibrated"]["position_spread_m"] < second["rkgp_calibrated_noise"]["position_spread_m"]
    assert second["spread_ratio_calibrated"] == pytest.approx(
        second["rkgp_calibrated_noise"]["position_spread_m"] / second["stand_in"]["position_spread_m"], rel=1e-12)


@pytest.mark.slow
def test_table3_learns_three_controllers_and_flies_them(quick):
    third = quick[1]["table3"]["by_seed"][str(SEED)]
    for name in ("RK", "RKGP", "stand_in"):
        row = third[name]
        for key in ("yaw_error_deg", "yaw_error_std_deg", "yaw_rate_error_deg_s", "final_yaw_error_deg"):
            assert math.isfinite(row[key]), (name, key)
        assert 0 < row["yaw_error_deg"] < 90  # a 90 deg turn that never moved would score 90
        # Nelder-Mead keeps its best vertex, which starts at the initial parameters.
        assert row["pegasus_cost"] <= row["initial_cost"] * (1 + 1e-9)
        assert set(row["parameters"]) == {"b_plus", "b_minus", "damping", "tanh_slope"}


@pytest.mark.slow
def test_report_and_figures_are_written(quick):
    out, results, _ = quick
    report = (out / "report.md").read_text()
    for name in ("table1.png", "predictions.png", "table2.png", "table3.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and name in report
    assert all(title in report for title in ("Table I", "Table II", "Table III"))
    assert results["seeds"] == [SEED] and results["setup"]["quick"]


@pytest.mark.slow
def test_rkgp_fmu_equals_the_propagated_python_rollout(quick):
    """The FMU built from the campaign's RKGP model: states and propagated sds equal
    GreyBoxGP.propagate from the FMU's start (fans at rest) under the same commands, to 1e-9."""
    import fmpy

    from gp_model import load_model, read_header
    from validation.models.blimp_greybox import BlimpStepDescription, lagged_commands

    out, results, _ = quick
    fmu = out / results["fmu"]["fmu"]
    model = load_model(out / results["fmu"]["model"])
    description = BlimpStepDescription.from_dict(read_header(out / results["fmu"]["model"])["physics"])
    assert description.command_lags == COMMAND_LAGS
    step = float(fmpy.read_model_description(str(fmu)).defaultExperiment.stepSize)
    start = np.array([0.0, 0.0, 0.0, 0.01, 0.02, 0.1, 0.05, 0.0, 0.0, 0.0, 0.0, 0.02])
    n = 30
    commands = np.repeat([[0.4, 0.0, -0.3], [-0.2, 0.1, 0.5], [0.6, -0.1, 0.0]], 10, axis=0)
    signal = np.zeros(n + 1, dtype=[("time", float), ("u_gondola", float), ("mu", float), ("u_tail", float)])
    signal["time"] = np.arange(n + 1) * step
    for column, name in enumerate(("u_gondola", "mu", "u_tail")):
        signal[name] = np.append(commands[:, column], commands[-1, column])
    sds = [f"{s}_sd" for s in STATE_NAMES]
    result = fmpy.simulate_fmu(str(fmu), stop_time=n * step, step_size=step, output_interval=step, input=signal,
                               output=[*STATE_NAMES, *sds],
                               start_values={f"{s}_start": float(v) for s, v in zip(STATE_NAMES, start)})
    dt = np.full(n, step)
    inputs = np.column_stack([commands, dt, lagged_commands(commands, dt, time_constants=COMMAND_LAGS)])
    python = model.propagate(start, inputs, description.physics_step())
    np.testing.assert_allclose(np.column_stack([result[s] for s in STATE_NAMES])[:n + 1], python.mean, rtol=0,
                               atol=1e-9)
    np.testing.assert_allclose(np.column_stack([result[s] for s in sds])[:n + 1], python.sd, rtol=0, atol=1e-9)
    assert python.sd[-1, :3].min() > python.sd[1, :3].max()  # the spread grows along the run


def test_table2_is_reproducible_from_the_seed():
    """A cheap model (true parameters, fixed hyperparameters, a short flight) through Table II
    twice with one seed and once with another."""
    from gp_model import GreyBoxGP
    from validation.models.blimp_identification import physics_step
    from validation.vehicles.blimp_flight import FLIGHT_TEST_PARAMETERS

    recording = random_command_flight(3.0, [5, 1, 0]).recording
    rk = physics_step(FLIGHT_TEST_PARAMETERS, max_step=RK_MAX_STEP)
    states, inputs = smoothed_states(recording), step_inputs(recording)
    model = GreyBoxGP(state_columns=GP_STATE_COLUMNS, shared=False, min_noise_variance=MIN_NOISE_VARIANCE).fit(
        states[:-1:2], inputs[:-1:2], states[1::2], rk, optimize=False)
    setup = dataclasses.replace(Table2Setup(), horizon_frames=10, stand_in_runs=3, n_samples=3)
    calibration = calibrate_spread(model, rk, setup, seed=5)
    assert calibrate_spread(model, rk, setup, seed=5) == calibration
    assert (abs(calibration.calibrated_spread_m / calibration.stand_in_spread_m - 1) <= CALIBRATION_TOLERANCE
            or calibration.rescalings == CALIBRATION_ITERATIONS)
    first, paths = table2(recording.inputs, model, rk, setup, seed=5, calibration=calibration)
    again, paths_again = table2(recording.inputs, model, rk, setup, seed=5, calibration=calibration)
    other, other_paths = table2(recording.inputs, model, rk, setup, seed=6)
    for field in dataclasses.fields(paths):
        np.testing.assert_array_equal(getattr(paths, field.name), getattr(paths_again, field.name))
    drop = lambda row: {k: v for k, v in row.items() if k != "seconds"}  # noqa: E731
    assert all(drop(first[row]) == drop(again[row]) for row in ROWS + CALIBRATED_ROWS)
    assert other_paths.calibrated_noise is None and "rkgp_calibrated_noise" not in other
    # After the first step (every sample starts from the same state) a sample's deviation from
    # the mean rollout is its drawn residual and noise: exactly the scale times the uncalibrated one.
    step_noise = paths.sampled_noise[:, 1, :3] - paths.mean[1, :3]
    step_calibrated = paths.calibrated_noise[:, 1, :3] - paths.mean[1, :3]
    np.testing.assert_allclose(step_calibrated, calibration.spread_scale * step_noise, rtol=1e-6, atol=1e-12)
    for row in ("stand_in", "rkgp_sampled", "rkgp_sampled_noise"):
        assert first[row]["position_spread_m"] != other[row]["position_spread_m"], row
    assert drop(first["rkgp_mean"]) != {} and first["rkgp_mean"]["position_spread_m"] == 0.0


def test_random_command_flight_is_reproducible_and_held_at_4_hz():
    a, b = random_command_flight(2.0, [7, 0, 0]), random_command_flight(2.0, [7, 0, 0])
    np.testing.assert_array_equal(a.recording.outputs, b.recording.outputs)
    np.testing.assert_array_equal(a.true_states, b.true_states)
    # 40 frames at 20 Hz in 8 holds of 5 frames (0.25 s); frame 41 starts a ninth hold.
    holds = a.recording.inputs[:-1].reshape(8, 5, 3)
    assert np.all(holds == holds[:, :1]) and len(np.unique(holds[:, 0, 0])) == 8
    assert np.all(np.abs(a.recording.input("mu")) <= 0.5)
    assert not np.allclose(a.recording.outputs, a.true_states)  # motion capture adds noise


@pytest.mark.parametrize("arguments, phrase", [
    (["--seeds", "1,1"], "distinct"),
    (["--seeds", "1,-2"], "0 or more"),
    (["--seed", "1", "--seeds", "2"], "not both"),
])
def test_cli_refuses_bad_seeds(tmp_path, capsys, arguments, phrase):
    """Exit 2 with one message (argparse's for a malformed list), nothing written."""
    try:
        code = main(["reproduce", "blimp", "--out", str(tmp_path / "out"), *arguments])
    except SystemExit as usage_error:
        code = usage_error.code
    assert code == 2
    err = capsys.readouterr().err
    assert phrase in err and "Traceback" not in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_cli_refuses_blimp_options_for_bo105_and_a_file_as_output_folder(tmp_path, capsys):
    assert main(["reproduce", "bo105", "--out", str(tmp_path / "out"), "--quick"]) == 2
    assert "reproduce blimp only" in capsys.readouterr().err
    target = tmp_path / "file"
    target.write_text("x")
    assert main(["reproduce", "blimp", "--out", str(target)]) == 2
    assert "not a folder" in capsys.readouterr().err


@pytest.mark.slow
def test_format_results_names_every_table(quick):
    text = format_results(quick[1])
    assert all(title in text for title in ("Table I", "Table II", "Table III"))


def test_table1_scores_each_group_at_the_one_second_horizon_only():
    """Errors before the horizon count for nothing; at the horizon, each group's Euclidean norm
    (yaw wrapped), RMS over the paths."""
    truth = np.zeros((2, HORIZON_FRAMES + 1, 12))
    predicted = truth.copy()
    predicted[:, :-1] = 5.0  # wrong everywhere but at the horizon
    assert horizon_rmse(predicted, truth) == dict.fromkeys(GROUPS, 0.0)
    predicted[:, -1] = 0.0
    predicted[0, -1, :3] = (3.0, 4.0, 0.0)  # position off by 5 m on one path of two
    predicted[1, -1, 5] = 2 * np.pi - 0.1  # yaw off by -0.1 rad once wrapped
    rmse = horizon_rmse(predicted, truth)
    assert rmse["position"] == pytest.approx(5.0 / np.sqrt(2))
    assert rmse["orientation"] == pytest.approx(0.1 / np.sqrt(2))
    assert rmse["velocity"] == rmse["angular_velocity"] == 0.0
