"""``flightgp record`` and ``flightgp inspect`` through the real entry point (exit codes, files)."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from validation.cli import main
from validation.core.files import WRITTEN_LIST
from validation.core.recordings import Recording
from validation.vehicles import read_recording

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _record_c172x(out, *extra):
    return main(["record", "--vehicle", "jsbsim:c172x", "--input", "elevator", "--amplitude", "0.2",
                 "--duration", "4", "--out", str(out), *extra])


def _one_error_line(capsys, command):
    """The whole stderr of a failed command: exactly one line, starting with the command's name."""
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"flightgp {command}: error: ")
    return err


def test_record_writes_recording_sidecar_and_plot(tmp_path, capsys):
    out = tmp_path / "new" / "folder" / "c172x.csv"
    assert _record_c172x(out, "--plot") == 0
    recording = read_recording(out)
    assert recording.metadata["vehicle"] == "jsbsim:c172x"
    assert recording.metadata["manoeuvre"] == {"kind": "3211", "input": "elevator", "amplitude": 0.2,
                                               "unit": "1", "step_time": 0.4, "start": 1.0}
    assert len(recording.time) == 401 and recording.time[-1] == 4.0
    assert recording.input("elevator").max() == 0.2
    assert np.abs(recording.output("q")).max() > 0.1  # the manoeuvre reached the aircraft
    assert out.with_suffix(".png").read_bytes().startswith(PNG_SIGNATURE)
    assert sorted(p.name for p in out.parent.iterdir()) == [WRITTEN_LIST, "c172x.csv", "c172x.json", "c172x.png"]
    assert str(out) in capsys.readouterr().out


def test_record_amplitude_deg_is_converted_to_rad(tmp_path, monkeypatch):
    calls = []
    fake = _FakeVehicle("fake", gain=1.0, calls=calls)
    monkeypatch.setattr("validation.cli.arguments.get_vehicle", lambda name: fake)
    assert main(["record", "--vehicle", "fake", "--input", "theta_1s", "--amplitude-deg", "2",
                 "--out", str(tmp_path / "f.csv")]) == 0
    assert calls[0][1][:, 0].max() == pytest.approx(np.radians(2.0), rel=1e-15)


def test_record_flight_stand_in_plot_overlays_its_reference(tmp_path, monkeypatch):
    calls = []
    vehicles = {"fake-flight": _FakeVehicle("fake-flight", gain=2.0, calls=calls),
                "fake": _FakeVehicle("fake", gain=1.0, calls=calls)}
    monkeypatch.setattr("validation.cli.arguments.get_vehicle", vehicles.__getitem__)
    monkeypatch.setattr("validation.cli.record.get_vehicle", vehicles.__getitem__)
    out = tmp_path / "f.csv"
    assert main(["record", "--vehicle", "fake-flight", "--input", "theta_1s", "--out", str(out), "--plot"]) == 0
    assert [name for name, _ in calls] == ["fake-flight", "fake"]
    assert np.array_equal(calls[0][1], calls[1][1])  # the reference flew the same inputs
    assert out.with_suffix(".png").read_bytes().startswith(PNG_SIGNATURE)


@pytest.mark.parametrize("arguments, message", [
    (["--vehicle", "jsbsim:c172x", "--input", "theta_1s"],
     "--input 'theta_1s' is not an input of jsbsim:c172x; choose one of elevator, aileron, rudder"),
    (["--vehicle", "jsbsim:c172x", "--input", "elevator", "--amplitude-deg", "1"],
     "--amplitude-deg is for angle inputs; 'elevator' is a normalised command (-1..1): give --amplitude"),
    (["--vehicle", "zeppelin", "--input", "q"], "unknown vehicle 'zeppelin'"),
    (["--vehicle", "jsbsim:c172x", "--input", "elevator", "--start", "12"], "--start must lie in [0, 10) s"),
    (["--vehicle", "jsbsim:c172x", "--input", "elevator", "--duration", "-1"], "duration must be a positive"),
    (["--vehicle", "jsbsim:ZLT-NT", "--input", "elevator"], "JSBSim cannot trim jsbsim:ZLT-NT"),
])
def test_record_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, arguments, message):
    out = tmp_path / "out" / "r.csv"
    assert main(["record", *arguments, "--out", str(out)]) == 2
    assert message in _one_error_line(capsys, "record")
    assert not (tmp_path / "out").exists()


def test_inspect_summarises_a_recording(tmp_path, capsys):
    out = tmp_path / "c172x.csv"
    assert _record_c172x(out) == 0
    capsys.readouterr()
    assert main(["inspect", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"{out}: valid recording of jsbsim:c172x"
    assert lines[1] == "401 samples, 0 .. 4 s (duration 4 s), sample time 0.01 s (100 Hz)"
    elevator = next(line.split() for line in lines if line.startswith("elevator "))
    assert elevator == ["elevator", "input", "1", "-0.2", "0.2"]
    assert next(line.split() for line in lines if line.startswith("q "))[1:3] == ["output", "rad/s"]


def test_inspect_bad_recording_exits_2_naming_row_and_column(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("time,theta_0,theta_1s,theta_1c,theta_0T,q\n0,0,0,0,0,0.1\n0.01,0,0,0,0,abc\n")
    assert main(["inspect", str(bad)]) == 2
    assert f"{bad}, row 3, column 6 ('q'): 'abc' is not a number" in _one_error_line(capsys, "inspect")


def test_inspect_checks_columns_against_the_vehicle(tmp_path, capsys):
    path = tmp_path / "r.csv"
    path.write_text("time,elevator,aileron,rudder,q\n0,0,0,0,0\n0.01,0,0,0,0\n")
    assert main(["inspect", str(path), "--vehicle", "jsbsim:c172x"]) == 0
    capsys.readouterr()
    assert main(["inspect", str(path), "--vehicle", "jsbsim:ah1s"]) == 2
    assert "row 1, column 2 ('elevator'): unknown column for vehicle jsbsim:ah1s" in _one_error_line(capsys, "inspect")


def test_console_script_gives_exit_2_one_line_no_traceback(tmp_path):
    """The installed ``flightgp`` script (next to this Python) on a file with degrees in it."""
    bad = tmp_path / "bad.csv"
    bad.write_text("time,theta_0,theta_1s,theta_1c,theta_0T,q\n0,0,0,0,0,0\n0.01,0,0,0,0,28.6\n")
    script = Path(sys.executable).with_name("flightgp")
    result = subprocess.run([str(script), "inspect", str(bad)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stdout == ""
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert "row 3, column 6 ('q')" in result.stderr and "looks like degrees" in result.stderr


class _FakeVehicle:
    """A first-order lag on ``theta_1s`` (q' = gain * theta_1s - q); records every simulate call."""

    input_names = ("theta_1s", "theta_0")
    state_names = ("q",)
    sample_time = 0.05

    def __init__(self, name, *, gain, calls):
        self.name, self.gain, self.calls = name, gain, calls

    def simulate(self, time, inputs, *, seed=0):
        self.calls.append((self.name, inputs.copy()))
        q = np.zeros(len(time))
        for k in range(1, len(time)):
            q[k] = q[k - 1] + self.sample_time * (self.gain * inputs[k - 1, 0] - q[k - 1])
        return Recording(time, inputs, self.input_names, q, self.state_names, {"vehicle": self.name})


def test_inspect_flags_a_recording_that_does_not_start_at_trim(tmp_path, capsys):
    """The Bo105's columns are perturbations from trim: u recorded absolute (41 m/s at 80 kt,
    moving by 0.3 m/s) is flagged, the same motion as a perturbation is not."""
    rows = [(k * 0.01, 0.0, 0.01 * (k > 50), 0.0, 0.0, 0.3 * (k > 60), 0.02 * (k > 55)) for k in range(200)]
    for name, trim_u, flagged in (("absolute.csv", 41.2, True), ("perturbation.csv", 0.0, False)):
        path = tmp_path / name
        path.write_text("time,theta_0,theta_1s,theta_1c,theta_0T,u,q\n"
                        + "".join(",".join(map(repr, (*row[:5], row[5] + trim_u, row[6]))) + "\n" for row in rows))
        assert main(["inspect", str(path), "--vehicle", "bo105-80kt"]) == 0
        warnings = [line for line in capsys.readouterr().out.splitlines() if line.startswith("warning:")]
        assert warnings == (["warning: u starts at 41.2 m/s and moves by 0.3 only; bo105-80kt's columns are "
                             "perturbations from trim, so its recordings start near 0: subtract the trim values "
                             "(docs/conventions.md, \"Units and axes\")"] if flagged else [])
