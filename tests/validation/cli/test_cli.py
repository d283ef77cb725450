"""The flightgp command line: exit codes, `flightgp bench` option handling and files (the
benchmarks themselves: tests/validation/bench), demo."""
import json
import subprocess
import sys

import pytest

from validation.cli import main


def test_bench_writes_each_report_and_the_combined_summary(tmp_path, capsys):
    assert main(["bench", "gp", "--sizes", "30", "--restarts", "0", "--out-dir", str(tmp_path),
                 "--summary", str(tmp_path / "bench.json")]) == 0
    report = json.loads((tmp_path / "gp.json").read_text())
    combined = json.loads((tmp_path / "bench.json").read_text())
    # The options reach the benchmark (--sizes, --restarts) and the report records --threads.
    assert [row["n"] for row in report["rows"]] == [30]
    assert (report["n_restarts"], report["blas_threads"]) == (0, 1)
    assert combined["reports"] == {"gp": report}
    # Each headline row: a stable id, a number with its unit, a numeric goal, met or not.
    [row] = combined["summary"]
    assert (row["benchmark"], row["id"], row["unit"], row["goal"], row["goal_is"]) == (
        "gp", "gp.fit.speedup.n30", "x", 6.0, "at least")
    assert row["value"] == report["rows"][0]["fit_speedup"] and row["met"] == (row["value"] >= 6.0)
    out = capsys.readouterr().out
    assert "speedup" in out and "met" in out  # the benchmark's table, then the combined one


def test_bench_unknown_name_exits_2(tmp_path, capsys):
    assert main(["bench", "nope", "--out-dir", str(tmp_path), "--summary", str(tmp_path / "b.json")]) == 2
    err = capsys.readouterr().err
    assert "unknown benchmark nope" in err and "Traceback" not in err
    assert not any(tmp_path.iterdir())


def test_usage_error_exits_2_without_traceback():
    result = subprocess.run([sys.executable, "-m", "validation.cli", "no-such-command"],
                            capture_output=True, text=True)
    assert result.returncode == 2
    assert "invalid choice" in result.stderr and "Traceback" not in result.stderr


def test_help_lists_every_command_with_its_own_help_line(capsys):
    """``flightgp --help`` lists every command with the help line its module gives its subparser
    (main lists them without importing the modules: COMMANDS)."""
    from validation.cli.main import COMMANDS, build_parser

    def help_lines(parser):
        subparsers = next(a for a in parser._actions if a.dest == "command")  # noqa: SLF001
        return {action.dest: action.help for action in subparsers._choices_actions}  # noqa: SLF001

    full = help_lines(build_parser())
    assert list(full) == [name for name, _, _ in COMMANDS]
    assert help_lines(build_parser(only="")) == full == help_lines(build_parser(only="train"))
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    printed = " ".join(capsys.readouterr().out.split())  # argparse wraps long help lines
    assert all(f"{name} {help_line}" in printed for name, help_line in full.items())


def test_a_command_imports_its_own_module_only():
    """``flightgp record`` starts without the other commands' modules (nor the GP core)."""
    script = ("import sys; from validation.cli import main; from validation.cli.main import COMMANDS; "
              "sys.argv = ['flightgp', 'record', '--help']\n"
              "try:\n    main()\nexcept SystemExit:\n    pass\n"
              "print(sorted(m for _, m, _ in COMMANDS if 'validation.cli.' + m in sys.modules), "
              "'gp_model' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert result.stdout.splitlines()[-1] == "['record'] False"


def test_a_broken_model_file_exits_2_with_one_line(tmp_path, capsys):
    model, recording = tmp_path / "model.npz", tmp_path / "run.csv"
    model.write_bytes(b"not a model")
    recording.write_text("time,theta_1s,p,q,r\n0,0,0,0,0\n0.01,0,0,0,0\n")
    assert main(["predict", str(model), str(recording), "--out", str(tmp_path / "pred.csv")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("flightgp predict: error:") and len(err.splitlines()) == 1 and "Traceback" not in err


@pytest.mark.slow
def test_demo_runs_the_bo105_case_end_to_end(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    names = {p.name for p in tmp_path.iterdir()}
    assert {"flight_test_training.csv", "bo105_gp_narx.npz", "fmp.png", "osap.png", "results.json",
            "bo105_gp_rate_predictor.fmu", "bo105_80kt_reference.fmu", "report.md"} <= names
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["config"]["training_points"] == 32
    cosim = json.loads((tmp_path / "cosim_training" / "cosim.json").read_text())
    assert set(cosim["rmse"]) == {"gp", "reference"}
    assert (tmp_path / "cosim_unseen" / "bo105_gp_rate_predictor" / "bo105_gp_rate_predictor_ref.csv").is_file()
    assert "GP FMU (free run)" in (tmp_path / "report.md").read_text()
    assert "FMP   GP" in capsys.readouterr().out


def test_demo_onto_a_file_exits_2(tmp_path, capsys):
    target = tmp_path / "taken"
    target.write_text("keep me")
    assert main(["demo", "--out", str(target)]) == 2
    assert "is not a folder" in capsys.readouterr().err
    assert target.read_text() == "keep me"


def test_bench_summary_or_out_dir_that_cannot_be_written_exits_2_before_running(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    assert main(["bench", "gp", "--out-dir", str(tmp_path / "file"), "--summary", str(tmp_path / "b.json")]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err
    assert main(["bench", "gp", "--out-dir", str(tmp_path / "o"), "--summary", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_bench_option_of_a_benchmark_not_run_or_below_its_minimum_exits_2(tmp_path, capsys):
    assert main(["bench", "gp", "--runs", "50", "--out-dir", str(tmp_path), "--summary",
                 str(tmp_path / "b.json")]) == 2
    assert "--runs applies to `bench narx` only" in capsys.readouterr().err
    assert main(["bench", "fmu", "--fmu-steps", "5", "--out-dir", str(tmp_path), "--summary",
                 str(tmp_path / "b.json")]) == 2
    assert "--fmu-steps (FMU steps) must be at least 10" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
