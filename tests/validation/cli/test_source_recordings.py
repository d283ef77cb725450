"""The RGBlimp source's recording files (``data_N.csv``, 38 columns) on the command line, through
the real entry point: recognised by their header or named by ``--format rgblimp``; a bad file
exits 2 with one line. The files come from the excerpt in the repository
(validation/vehicles/data/rgblimp/, zhu-yj/ABNODE, MIT licence, copyright 2024 zhu-yj)."""
import pytest

from validation.cli import main
from validation.vehicles.rgblimp_data import EXCERPT_FOLDER, SOURCE_COLUMNS

SPIRAL = EXCERPT_FOLDER / "data_117.csv"
STRAIGHT = EXCERPT_FOLDER / "data_121.csv"


def _one_error_line(capsys, command):
    """The whole stderr of a failed command: exactly one line, starting with the command's name."""
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1 and captured.err.startswith(f"flightgp {command}: error: ")
    assert "Traceback" not in captured.err
    return captured.err


def _source_lines(n_rows=3):
    """The header and the first ``n_rows`` data lines of the source's flight 121, as in the file."""
    return STRAIGHT.read_text(encoding="utf-8").splitlines()[:n_rows + 1]


def _with_cell(lines, row, column, text):
    """``lines`` with the cell of data ``row`` (1-based) in source ``column`` replaced by ``text``."""
    cells = lines[row].split(",")
    cells[SOURCE_COLUMNS.index(column)] = text
    return lines[:row] + [",".join(cells)] + lines[row + 1:]


@pytest.mark.parametrize("extra", [[], ["--format", "rgblimp"], ["--vehicle", "rgblimp"]])
def test_inspect_reads_a_source_file_as_it_is(capsys, extra):
    assert main(["inspect", str(SPIRAL), *extra]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"{SPIRAL}: valid recording of rgblimp"
    assert lines[1] == "1081 samples, 0 .. 18 s (duration 18 s), sample time 0.0166667 s (60 Hz)"
    assert lines[3].split() == ["time", "time", "s", "0", "18"]
    assert lines[4].split() == ["thrust_left", "input", "N", "0.01372", "0.01372"]
    assert lines[8].split() == ["gondola_z", "input", "m", "0.238", "0.238"]
    assert [line.split()[:3] for line in lines[9:]][-1] == ["R", "output", "rad/s"]


@pytest.mark.parametrize(("name", "lines", "extra", "message"), [
    ("data_5.csv", [_source_lines()[0].replace("vb_2", "vb_y")] + _source_lines()[1:], [],
     "data_5.csv, row 1, column 8 ('vb_y'): expected 'vb_2'; an RGBlimp recording has the source's 38 columns"),
    ("data_5.csv", [",".join(SOURCE_COLUMNS[:30])] + _source_lines()[1:], [],
     "data_5.csv, row 1: 30 columns, but an RGBlimp recording has the source's 38"),
    ("data_5.csv", _with_cell(_source_lines(), 2, "e_2", "NaN"), [],
     "data_5.csv, row 3, column 5 ('e_2'): 'NaN' is not a finite number"),
    ("data_5.csv", _with_cell(_source_lines(), 1, "Fl_series", ""), [],
     "data_5.csv, row 2, column 19 ('Fl_series'): empty cell"),
    ("data_5.csv", _source_lines()[:-1] + [",".join(_source_lines()[-1].split(",")[:20])], [],
     "data_5.csv, row 4: 20 fields, but the header has 38 columns"),
    ("data_5.csv", _source_lines(1), [], "data_5.csv: 1 data row(s); a recording needs at least two samples"),
    ("data_5.csv", _with_cell(_source_lines(), 2, "e_3", "37.3"), [],
     "data_5.csv, row 3, column 6 ('e_3'): |e_3| = 37.3 exceeds the plausible"),
    ("flight.csv", _source_lines(), [], "flight.csv: an RGBlimp recording is named data_N.csv"),
    ("data_5.csv", [], [], "data_5.csv, row 1: the file is empty; expected a header row starting with 'time'"),
    ("data_5.csv", [], ["--format", "rgblimp"], "data_5.csv, row 1: the file is empty; expected the source's header"),
    ("data_5.csv", ["time,elevator,aileron,rudder,q", "0,0,0,0,0", "0.01,0,0,0,0"], ["--format", "rgblimp"],
     "data_5.csv, row 1: 5 columns, but an RGBlimp recording has the source's 38"),
    ("data_5.csv", _source_lines(), ["--format", "flightgp"],
     "data_5.csv, row 1, column 1 ('p_1'): the first column must be 'time' (s)"),
    ("data_5.csv", _source_lines(), ["--vehicle", "blimp"],
     "data_5.csv: a recording in the RGBlimp source's format is one of rgblimp"),
])
def test_inspect_refuses_a_bad_source_file_with_one_line_and_exit_2(tmp_path, capsys, name, lines, extra, message):
    path = tmp_path / name
    path.write_text("".join(line + "\n" for line in lines), encoding="utf-8")
    assert main(["inspect", str(path), *extra]) == 2
    assert message in _one_error_line(capsys, "inspect")


def test_train_reads_recordings_through_the_same_reader(tmp_path, capsys):
    path = tmp_path / "data_5.csv"
    path.write_text("\n".join(_with_cell(_source_lines(), 2, "wb_1", "nan")) + "\n", encoding="utf-8")
    assert main(["train", str(path), "--format", "rgblimp", "--out", str(tmp_path / "m.npz")]) == 2
    assert "data_5.csv, row 3, column 10 ('wb_1'): 'nan' is not a finite number" in _one_error_line(capsys, "train")
    assert not (tmp_path / "m.npz").exists()


def test_format_takes_only_known_formats(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["inspect", str(SPIRAL), "--format", "matlab"])
    assert exit_.value.code == 2
    assert "invalid choice: 'matlab'" in capsys.readouterr().err
