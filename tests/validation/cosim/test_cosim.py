"""fmpy co-simulation of the GP rate-predictor FMU against recordings (flightgp cosim)."""
import json
from statistics import NormalDist

import numpy as np
import pytest
from fmpy import read_model_description

from validation.cli import main
from validation.core.recordings import write_recording
from validation.cosim.cosimulation import OpenFmu, cosimulate, simulate
from validation.models.narx import narx_arrays


@pytest.fixture(scope="module")
def case(tmp_path_factory, bo105_flights, bo105_trained, rate_predictor_fmu):
    """The paper's training manoeuvre (also as a CSV file in the returned folder), its GP-NARX
    and that model's FMU (tests/conftest.py)."""
    folder = tmp_path_factory.mktemp("cosim")
    recording = bo105_flights["training"]
    write_recording(folder / "flight.csv", recording)
    return folder, recording, bo105_trained, rate_predictor_fmu


def test_fmu_free_run_equals_the_python_moment_matching_rollout(case):
    """The FMU takes the vehicle as steady before t0 (docs/conventions.md, "FMU sampling convention") and predicts
    from t1; the Python moment-matching free run on the same history, padded with the t0 values,
    must agree, bounds included (the FMU's exact moments; its fast path is held to 2 % of the sd
    in the FMU's tests)."""
    folder, recording, trained, fmu = case
    result = cosimulate(fmu, recording, exact_moments=True)
    _, u, y = narx_arrays(recording, trained.config)
    pad = trained.config.structure().max_lag - 1
    u_padded = np.vstack([np.repeat(u[:1], pad, axis=0), u])
    python = trained.model.free_run(u_padded, np.repeat(y[:1], pad + 1, axis=0), method="moment_matching")
    z = NormalDist().inv_cdf(0.975)  # the FMU's default confidence_level, 0.95
    for j, axis in enumerate(result.axes):
        # Same model, same arithmetic up to summation order: 1e-9 rad/s.
        np.testing.assert_allclose(result.gp.outputs[axis], python.mean[pad:, j], rtol=0, atol=1e-9)
        np.testing.assert_allclose(result.gp.outputs[f"{axis}_upper"] - result.gp.outputs[axis],
                                   z * np.sqrt(python.var[pad:, j]), rtol=0, atol=1e-9)


def test_cross_check_files_and_summary(case, tmp_path):
    folder, recording, _, fmu = case
    result = cosimulate(fmu, recording, out_dir=tmp_path)
    name = result.gp.name  # the FMU's model name names its Cross-Check files
    model = tmp_path / name
    inputs = np.genfromtxt(model / f"{name}_in.csv", delimiter=",", names=True)
    outputs = np.genfromtxt(model / f"{name}_ref.csv", delimiter=",", names=True)
    assert inputs.dtype.names[:2] == ("time", "theta_1s")
    assert {"p", "q_lower", "r_upper"} <= set(outputs.dtype.names)
    np.testing.assert_allclose(outputs["q"], result.gp.outputs["q"], rtol=1e-15)
    options = dict(line.split(", ") for line in (model / f"{name}_ref.opt").read_text().splitlines())
    assert float(options["StepSize"]) == pytest.approx(0.1) and float(options["StopTime"]) == pytest.approx(8.0)
    summary = json.loads((tmp_path / "cosim.json").read_text())
    assert summary["rmse"] == result.rmse() and summary["axes"] == ["p", "q", "r"]
    # The coverage is of the FMU's 95 % band (its confidence_level as built), and says so.
    assert summary["coverage"] == result.coverage() and summary["coverage_level"] == 0.95
    # Nothing asked: the FMU's own defaults run and are recorded (the paper model's build measured
    # its fast path within 1 %, so exact_moments defaults to false).
    starts = {v.name: v.start for v in read_model_description(str(fmu)).modelVariables}
    assert summary["gp_parameters"] == {"exact_moments": False, "parallel": False}
    assert starts["exact_moments"] == starts["parallel"] == "false"
    assert (tmp_path / "cosim.png").stat().st_size > 10_000


def test_cli_cosim_with_a_recording_and_with_a_manoeuvre(case, tmp_path, capsys):
    folder, _, _, fmu = case
    assert main(["cosim", str(fmu), "--recording", str(folder / "flight.csv"), "--out", str(tmp_path / "a")]) == 0
    first = capsys.readouterr().out
    assert "GP FMU (free run)" in first
    assert first.splitlines()[-2].startswith("GP 95 % band coverage ")  # which band the coverage is of
    assert main(["cosim", str(fmu), "--vehicle", "bo105-80kt-flight", "--input", "theta_1s",
                 "--duration", "8", "--out", str(tmp_path / "b")]) == 0
    # The same manoeuvre and seed as the recording: the same table.
    assert capsys.readouterr().out.splitlines()[1:4] == first.splitlines()[1:4]
    # The exact moments move the GP's RMSE by far less than its printed 4 decimals' last unit
    # (the fast path is within 2 % of the sd; measured 1e-5 of it), and not the reference's.
    assert main(["cosim", str(fmu), "--recording", str(folder / "flight.csv"), "--exact-moments",
                 "--out", str(tmp_path / "c")]) == 0
    assert capsys.readouterr().out.splitlines()[1:4] == first.splitlines()[1:4]
    ran = [json.loads((tmp_path / out / "cosim.json").read_text())["gp_parameters"] for out in "ac"]
    assert ran == [{"exact_moments": False, "parallel": False}, {"exact_moments": True, "parallel": False}]


def test_cosim_keeps_the_fmus_own_default_of_exact_moments(case, bo105_model_file, tmp_path, monkeypatch):
    """A GP FMU whose build found its fast path too far off (its error stood in for here) defaults
    to exact_moments = true; a co-simulation that does not ask must run it so, and say so in
    cosim.json."""
    import fmu_src.rate_predictor.build as build
    from fmu_src import build_rate_predictor_fmu

    _, recording, _, fmu = case
    monkeypatch.setattr(build, "fast_path_error", lambda predictor: 0.05)
    exact_default = build_rate_predictor_fmu(bo105_model_file, tmp_path / "fmu", name="exact_default")
    ran = cosimulate(exact_default, recording, out_dir=tmp_path / "out")
    summary = json.loads((tmp_path / "out" / "cosim.json").read_text())
    assert summary["gp_parameters"] == {"exact_moments": True, "parallel": False}
    exact, fast = (cosimulate(fmu, recording, exact_moments=e).gp.outputs["q_upper"] for e in (True, False))
    np.testing.assert_array_equal(ran.gp.outputs["q_upper"], exact)
    assert np.abs(exact - fast).max() > 0.0


def test_an_fmu_without_the_asked_parameter_is_refused(case, bo105_reference_fmu, tmp_path, capsys):
    """--parallel (or --exact-moments) with a GP FMU that has no such parameter (here a physics
    FMU in its place) exits 2 and names the parameter, writing nothing."""
    folder, _, _, _ = case
    assert main(["cosim", str(bo105_reference_fmu), "--recording", str(folder / "flight.csv"), "--parallel",
                 "--out", str(tmp_path / "o")]) == 2
    assert "no parameter parallel" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv, message", [
    (["--out", "OUT"], "give either --recording"),
    (["--recording", "REC", "--vehicle", "bo105-80kt-flight", "--out", "OUT"], "give either --recording"),
    (["--vehicle", "bo105-80kt-flight", "--out", "OUT"], "--vehicle needs --input"),
    (["--recording", "REC", "--reference", "missing.fmu", "--out", "OUT"], "no such FMU"),
])
def test_cli_cosim_bad_usage_exits_2(case, tmp_path, capsys, argv, message):
    folder, _, _, fmu = case
    argv = [a.replace("REC", str(folder / "flight.csv")).replace("OUT", str(tmp_path / "o")) for a in argv]
    assert main(["cosim", str(fmu), *argv]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_files_that_are_no_rate_predictor_fmu_exit_2_with_one_line(case, bo105_reference_fmu, tmp_path, capsys):
    """A file that is not an FMU, a model-exchange FMU, or the physics FMU given as the GP FMU:
    one line naming the file and what it is, exit 2, nothing written (an internal error and a
    numpy message before)."""
    from tests.validation.vehicles.test_fmu_reference import description_only_fmu

    folder = case[0]
    (tmp_path / "text.fmu").write_text("not a zip")
    model_exchange = description_only_fmu(tmp_path / "me.fmu", version="2.0", kind="ModelExchange")
    for fmu, message in ((tmp_path / "text.fmu", "not an FMU"), (model_exchange, "a model-exchange FMU; cosim takes"),
                         (bo105_reference_fmu, "not a flightgp rate-predictor FMU")):
        assert main(["cosim", str(fmu), "--recording", str(folder / "flight.csv"), "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err
    assert not (tmp_path / "o").exists()


# Measured on this case (seed 0, the paper configuration with its 400 annealing samples, the
# model of tests/conftest.py; the FMU's free run by moment matching over the samples): GP FMU RMSE
# p 0.0105, q 0.0136, r 0.0238 rad/s; reference FMU p 0.0483, q 0.0422, r 0.0300. (With 64
# samples: 0.0103, 0.0135, 0.0237; the earlier mean-feedback free run measured 0.0103, 0.0137,
# 0.0219.) The guard allows 30 % above the measured GP values: far more than BLAS or platform
# rounding moves them (< 1e-9), far less than the gap to the reference (2-4x on p, q).
GP_RMSE_GUARD = {"p": 0.0105 * 1.3, "q": 0.0136 * 1.3, "r": 0.0238 * 1.3}


def test_ci_guard_3211_rmse_of_the_fmu_against_the_flight_test(case, bo105_reference_fmu):
    """The CI check of docs/fmus.md: build the Bo105 rate-predictor FMU, co-simulate the 80 kt 3-2-1-1 in
    fmpy, and keep its per-axis RMSE against the flight-test stand-in below the guard and below
    the physics reference FMU's."""
    folder, recording, _, gp_fmu = case
    rmse = cosimulate(gp_fmu, recording, reference_fmu=bo105_reference_fmu).rmse()
    for axis in "pqr":
        assert rmse["gp"][axis] < GP_RMSE_GUARD[axis], (axis, rmse["gp"][axis])
        assert rmse["gp"][axis] < rmse["reference"][axis], axis


def test_an_open_fmu_is_instantiated_once_and_reset_between_runs(bo105_reference_fmu, bo105_flights):
    """Runs through one OpenFmu equal runs each through a fresh instance, whatever ran before
    (``fmi2Reset`` restores the start state and parameters), and instantiate the FMU once."""
    recording = bo105_flights["training"]
    time = recording.time[:301]
    inputs = {name: recording.input(name)[:301] for name in recording.input_names}
    fresh = simulate(bo105_reference_fmu, time=time, inputs=inputs, outputs=["q", "theta"])
    with OpenFmu(bo105_reference_fmu) as fmu:
        changed = simulate(fmu, time=time, inputs=inputs, outputs=["q"], start_values={"M_q": -0.5, "q_start": 0.1})
        again = simulate(fmu, time=time, inputs=inputs, outputs=["q", "theta"])
        assert fmu.instantiations == 1
    assert not np.allclose(changed.outputs["q"], fresh.outputs["q"])
    for name in ("q", "theta"):
        np.testing.assert_array_equal(again.outputs[name], fresh.outputs[name])
