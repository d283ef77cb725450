"""Tests of the blimp RKGP Tables I, II and III reproduction (validation/reproduce/blimp.py) and its command.

The quick reproduction (one 30 s training flight, 20 start states, about 10 s) runs end to end;
the assertions are the properties that hold by construction or by physics, not the paper's
headline (RKGP beating RK does not come out on this stand-in; results.json explains why).
"""
import dataclasses
import json
import math

import numpy as np
import pytest

from validation.cli import main
from validation.reproduce.blimp import (
    GROUPS,
    METHODS,
    adaptive_step,
    format_results,
    random_command_flight,
    reproduce_blimp,
)
from validation.vehicles.blimp import SAMPLE_TIME, BlimpParameters, BlimpReference


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("blimp")
    return out, reproduce_blimp(out, quick=True, progress=False)


def test_quick_reproduction_writes_table1_with_finite_values(quick):
    out, results = quick
    written = json.loads((out / "results.json").read_text())
    assert (out / "predictions.png").stat().st_size > 0
    assert set(written["table1"]) == set(METHODS)
    for method in METHODS:
        row = written["table1"][method]
        assert set(row) == {*GROUPS, "time_s"}
        assert all(math.isfinite(v) and v > 0 for v in row.values()), (method, row)
    for entry in written["identification"]["parameters"].values():
        assert math.isfinite(entry["value"]) and entry["standard_error"] > 0
    assert written["notes"]
    assert "RKGP" in format_results(written) and "position" in format_results(written)


TABLE2_ROWS = ("stand_in", "rkgp_sampled", "rkgp_mean")
SPREAD_KEYS = {"x_std_m", "y_std_m", "z_std_m", "yaw_std_deg", "position_spread_m",
               "offset_from_stand_in_m", "yaw_offset_from_stand_in_deg"}


def test_quick_reproduction_writes_table2(quick):
    out, results = quick
    table2 = json.loads((out / "results.json").read_text())["table2"]
    assert (out / "table2.png").stat().st_size > 0
    assert set(table2) == {*TABLE2_ROWS, "setup"}
    for row in TABLE2_ROWS:
        assert SPREAD_KEYS <= set(table2[row])
        assert all(math.isfinite(v) for v in table2[row].values()), (row, table2[row])
    # The mean-only rollout is one deterministic end point: zero spread by construction. GP
    # sampling draws different residual functions, so its end points spread; so do the stand-in
    # runs (drift, jitter, marker noise differ with the seed).
    spreads = {row: table2[row]["position_spread_m"] for row in TABLE2_ROWS}
    assert spreads["rkgp_mean"] == 0.0 and table2["rkgp_mean"]["yaw_std_deg"] == 0.0
    assert spreads["rkgp_sampled"] > spreads["rkgp_mean"] and spreads["stand_in"] > 0
    assert table2["stand_in"]["offset_from_stand_in_m"] == pytest.approx(0.0, abs=1e-12)
    assert table2["setup"]["stand_in_runs"] == 20 and table2["setup"]["n_samples"] == 20
    assert "RKGP sampled" in format_results(results)
    assert any(note.startswith("Table II") for note in results["notes"])


def test_table2_is_reproducible_from_the_seed(quick):
    from gp_model import GreyBoxGP
    from validation.models.blimp_identification import physics_step
    from validation.reproduce.blimp import GP_STATE_COLUMNS, QUICK_TABLE2, RK_MAX_STEP, _table2, _transitions
    from validation.vehicles.blimp_flight import FLIGHT_TEST_PARAMETERS

    # A cheap model (known parameters, fixed hyperparameters, a short flight) through the same
    # Table II code twice with one seed and once with another: the full run is seeded the same way.
    flight = random_command_flight(3.0, [5, 1, 0])
    rk = physics_step(FLIGHT_TEST_PARAMETERS, max_step=RK_MAX_STEP)
    model = GreyBoxGP(state_columns=GP_STATE_COLUMNS, n_restarts=0).fit(
        *_transitions([flight], 2), rk, optimize=False)
    setup = dataclasses.replace(QUICK_TABLE2, horizon_frames=10, stand_in_runs=3, n_samples=3)
    first, paths = _table2(flight, model, rk, setup, 5, False)
    again, paths_again = _table2(flight, model, rk, setup, 5, False)
    other, other_paths = _table2(flight, model, rk, setup, 6, False)
    for a, b in zip(paths, paths_again):
        np.testing.assert_array_equal(a, b)
    for row in TABLE2_ROWS:
        assert {k: v for k, v in first[row].items() if k != "seconds"} == \
            {k: v for k, v in again[row].items() if k != "seconds"}
    assert first["stand_in"]["position_spread_m"] != other["stand_in"]["position_spread_m"]
    assert first["rkgp_sampled"]["position_spread_m"] != other["rkgp_sampled"]["position_spread_m"]
    np.testing.assert_array_equal(paths[2], other_paths[2])  # the mean rollout has no random part


def test_comparisons_and_notes_agree_with_the_table(quick):
    _, results = quick
    table = results["table1"]
    for group in GROUPS:
        assert results["comparisons"]["RKGP_beats_RK"][group] == (table["RKGP"][group] < table["RK"][group])
    if not all(results["comparisons"]["RKGP_beats_RK"].values()):
        assert any(note.startswith("RKGP does not beat RK") for note in results["notes"])


def test_rk_and_ode_agree_and_physics_beats_gp_only_on_position(quick):
    _, results = quick
    table = results["table1"]
    # Same identified ODE, RK4 at 0.05 s vs RK45 at rtol 1e-8: integrator error is far below
    # the 1 mm / 0.5 deg mocap noise, so the two agree to 1 % on every group.
    for group in GROUPS:
        assert table["ODE"][group] == pytest.approx(table["RK"][group], rel=0.01)
    # Position needs yaw (earth-frame kinematics), which the GP inputs leave out: the physics
    # models know it, GP-only cannot.
    assert table["RKGP"]["position"] < table["GPonly"]["position"]
    assert table["RK"]["position"] < table["GPonly"]["position"]


def test_identification_sees_the_stand_ins_tail_asymmetry(quick):
    parameters = quick[1]["identification"]["parameters"]
    # The stand-in's tail fan is 40 % weaker for u_tail < 0 (validation/vehicles/blimp_flight.py).
    assert parameters["tail_thrust_negative"]["value"] < parameters["tail_thrust_positive"]["value"]


def test_adaptive_step_matches_the_reference_adaptive_integrator():
    params = BlimpParameters()
    time = np.array([0.0, SAMPLE_TIME])
    commands = np.array([[0.7, 0.2, -0.4], [0.0, 0.0, 0.0]])
    start = np.array([0.0, 0.0, 0.0, 0.05, -0.02, 0.3, 0.4, 0.05, -0.02, 0.1, -0.1, 0.2])
    expected = BlimpReference(params=params).simulate_states(time, commands, initial_state=start,
                                                             method="adaptive")[1]
    # Two rows with different dt in one call (rescaled time): row 0 is the reference's frame.
    stepped = adaptive_step(params)(np.stack([start, start]),
                                    np.array([[*commands[0], SAMPLE_TIME], [*commands[0], 0.04]]))
    # Both at rtol 1e-8: agreement to a few 1e-8 relative, far below any physical meaning.
    np.testing.assert_allclose(stepped[0], expected, rtol=1e-6, atol=1e-9)
    assert not np.allclose(stepped[1], stepped[0])


def test_random_command_flight_is_reproducible_and_held_at_4_hz():
    a, b = random_command_flight(2.0, [7, 0, 0]), random_command_flight(2.0, [7, 0, 0])
    np.testing.assert_array_equal(a.outputs, b.outputs)
    # 40 frames at 20 Hz in 8 holds of 5 frames (0.25 s); frame 41 starts a ninth hold.
    holds = a.inputs[:-1].reshape(8, 5, 3)
    assert np.all(holds == holds[:, :1]) and len(np.unique(holds[:, 0, 0])) == 8
    assert np.all(np.abs(a.input("mu")) <= 0.5)


def test_cli_refuses_a_file_as_output_folder(tmp_path, capsys):
    target = tmp_path / "file"
    target.write_text("x")
    assert main(["reproduce", "blimp", "--out", str(target)]) == 2
    assert "not a folder" in capsys.readouterr().err


@pytest.mark.slow
def test_cli_reproduce_blimp_prints_table1(tmp_path, capsys):
    # The full default run (about a minute on one core).
    assert main(["reproduce", "blimp", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert all(method in printed for method in METHODS)
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["setup"]["n_starts"] == 100 and not results["setup"]["quick"]


def test_quick_reproduction_writes_table3_with_finite_values(quick):
    out, results = quick
    table3 = json.loads((out / "results.json").read_text())["table3"]
    assert (out / "table3.png").stat().st_size > 0
    assert set(table3) == {"RK", "RKGP", "setup"}
    for name in ("RK", "RKGP"):
        row = table3[name]
        for key in ("yaw_error_deg", "yaw_error_std_deg", "yaw_rate_error_deg_s",
                    "yaw_rate_error_std_deg_s", "final_yaw_error_deg", "pegasus_cost"):
            assert math.isfinite(row[key]), (name, key, row[key])
        assert row["yaw_error_deg"] > 0 and row["yaw_error_std_deg"] >= 0
        # Nelder-Mead keeps the best vertex, which starts at the initial parameters.
        assert row["pegasus_cost"] <= row["initial_cost"]
        assert set(row["parameters"]) == {"b_plus", "b_minus", "damping", "tanh_slope"}
        assert all(v > 0 for v in row["parameters"].values())
    assert table3["setup"]["stand_in_runs"] == 2
    assert "Table III" in format_results(results)
    assert any(note.startswith("Table III") for note in results["notes"])


def test_reproduction_builds_the_blimp_rkgp_fmu_from_its_model(quick):
    """The blimp RKGP FMU built from this model (the contract suite covers the FMU
    type; here: this model's FMU validates and reproduces the model's rollout)."""
    import fmpy
    from fmpy.validation import validate_fmu

    from gp_model import load_model, read_header
    from validation.models.blimp_identification import blimp_physics_from_description

    out, results = quick
    fmu = out / results["fmu"]["fmu"]
    assert validate_fmu(str(fmu)) == []
    model = load_model(out / results["fmu"]["model"])
    _, physics = blimp_physics_from_description(read_header(out / results["fmu"]["model"])["physics"])
    description = fmpy.read_model_description(str(fmu))
    step = float(description.defaultExperiment.stepSize)
    start = np.array([0.0, 0.0, 0.0, 0.01, 0.02, 0.1, 0.05, 0.0, 0.0, 0.0, 0.0, 0.02])
    names = ["x", "y", "z", "phi", "theta", "psi", "U", "V", "W", "P", "Q", "R"]
    n = 20
    commands = np.column_stack([np.full(n, 0.4), np.zeros(n), np.full(n, -0.3)])
    signal = np.zeros(n + 1, dtype=[("time", float), ("u_gondola", float), ("mu", float), ("u_tail", float)])
    signal["time"] = np.arange(n + 1) * step
    signal["u_gondola"], signal["u_tail"] = 0.4, -0.3
    result = fmpy.simulate_fmu(str(fmu), stop_time=n * step, step_size=step, output_interval=step,
                               input=signal, output=names,
                               start_values={f"{s}_start": float(v) for s, v in zip(names, start)})
    rollout = model.rollout(start, np.column_stack([commands, np.full(n, step)]), physics)
    fmu_states = np.column_stack([result[s] for s in names])[: n + 1]
    # Same model, same RK4 substeps and GP arithmetic: equal to rounding (1e-9).
    np.testing.assert_allclose(fmu_states, rollout, rtol=0, atol=1e-9)
