"""Output paths are checked before any long work, and no command replaces a file flightgp did not
write (docs/conventions.md, "Writing files"): exit 2, one line, the user's files unchanged; a
command run again into its own folder replaces its own files."""
import os

import pytest

from validation.cli import main

#: A file of the user's, in the way of a command's output.
USERS = b"my own notes, not flightgp's\n"
NOT_WRITTEN = "exists and was not written by flightgp; choose another --out or move it"


# Each case: the user's files (relative to tmp_path), the command ({tmp} is tmp_path) and the one
# line it must end with. The recordings and models named do not exist: the output check comes
# first, so the message is about the output (and the command stops at once).
@pytest.mark.parametrize("users_files, command, message", [
    pytest.param(["taken"], ["diagnose", "{tmp}/none.csv", "--reference", "bo105-80kt", "--out", "{tmp}/taken/out"],
                 "cannot write to {tmp}/taken/out: {tmp}/taken is a file, not a folder", id="diagnose-under-a-file"),
    pytest.param(["out/report.md"], ["diagnose", "{tmp}/none.csv", "--reference", "bo105-80kt", "--out", "{tmp}/out"],
                 "{tmp}/out/report.md " + NOT_WRITTEN, id="diagnose-users-report"),
    pytest.param(["out/holdout_q.png"], ["diagnose", "{tmp}/none.csv", "--reference", "bo105-80kt",
                                         "--out", "{tmp}/out"],
                 "{tmp}/out/holdout_q.png " + NOT_WRITTEN, id="diagnose-users-plot"),
    pytest.param(["bo105.json"], ["state-space", "bo105-80kt", "--out", "{tmp}/bo105.json"],
                 "{tmp}/bo105.json " + NOT_WRITTEN, id="state-space-file"),
    pytest.param(["taken"], ["state-space", "bo105-80kt", "--out", "{tmp}/taken/bo105.json"],
                 "{tmp}/taken exists and is not a folder", id="state-space-under-a-file"),
    pytest.param(["run.json"], ["record", "--vehicle", "bo105-80kt", "--input", "theta_1s", "--duration", "2",
                                "--out", "{tmp}/run.csv"],
                 "{tmp}/run.json " + NOT_WRITTEN, id="record-sidecar"),
    pytest.param(["model.npz"], ["train", "{tmp}/none.csv", "--out", "{tmp}/model.npz"],
                 "{tmp}/model.npz " + NOT_WRITTEN, id="train"),
    pytest.param(["p.png"], ["predict", "{tmp}/none.npz", "{tmp}/none.csv", "--plot", "--out", "{tmp}/p.csv"],
                 "{tmp}/p.png " + NOT_WRITTEN, id="predict-plot"),
    pytest.param(["out/bo105_80kt_reference.fmu"], ["build-fmu", "--reference", "bo105-80kt", "--out", "{tmp}/out"],
                 "{tmp}/out/bo105_80kt_reference.fmu " + NOT_WRITTEN, id="build-fmu"),
    pytest.param(["out/scorecard.txt"], ["diagnose-bench", "--cases", "delay-theta_1s-60ms", "--out", "{tmp}/out"],
                 "{tmp}/out/scorecard.txt " + NOT_WRITTEN, id="diagnose-bench"),
    pytest.param(["out/junit.xml"], ["qtg", "{tmp}/none.toml", "--reference", "bo105-80kt", "--out", "{tmp}/out"],
                 "{tmp}/out/junit.xml " + NOT_WRITTEN, id="qtg"),
    pytest.param(["out/gp.json"], ["bench", "gp", "--out-dir", "{tmp}/out", "--summary", "{tmp}/bench.json"],
                 "{tmp}/out/gp.json " + NOT_WRITTEN, id="bench"),
    # demo and reproduce write many files: their folder holds flightgp's files only
    pytest.param(["out/notes.txt"], ["demo", "--out", "{tmp}/out"], "{tmp}/out/notes.txt " + NOT_WRITTEN, id="demo"),
    pytest.param(["out/notes.txt"], ["reproduce", "bo105", "--out", "{tmp}/out"],
                 "{tmp}/out/notes.txt " + NOT_WRITTEN, id="reproduce"),
])
def test_an_output_that_cannot_or_must_not_be_written_exits_2_first(tmp_path, capsys, users_files, command,
                                                                     message):
    for name in users_files:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(USERS)
    assert main([part.format(tmp=tmp_path) for part in command]) == 2
    err = capsys.readouterr().err
    assert err == f"flightgp {command[0]}: error: {message.format(tmp=tmp_path)}\n"
    assert all((tmp_path / name).read_bytes() == USERS for name in users_files)  # byte for byte
    written = {path.name for path in tmp_path.rglob("*") if path.is_file()} - {os.path.basename(n) for n in users_files}
    assert not written  # nothing else written: no temporary, no list of files


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes into any folder")
def test_a_folder_without_write_permission_exits_2_at_once(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        assert main(["diagnose", str(tmp_path / "none.csv"), "--reference", "bo105-80kt", "--out", str(locked)]) == 2
    finally:
        locked.chmod(0o700)
    assert capsys.readouterr().err == f"flightgp diagnose: error: cannot write to {locked}: Permission denied\n"


@pytest.mark.parametrize("command, outputs", [
    (["state-space", "bo105-80kt", "--out", "{tmp}/out/bo105.json"], ["bo105.json"]),
    (["record", "--vehicle", "bo105-80kt", "--input", "theta_1s", "--duration", "2", "--out", "{tmp}/out/run.csv"],
     ["run.csv", "run.json"]),
])
def test_a_command_run_again_into_its_own_folder_replaces_its_files_and_keeps_the_users(tmp_path, command, outputs):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_bytes(USERS)  # the user's, but no name the command writes
    argv = [part.format(tmp=tmp_path) for part in command]
    assert main(argv) == 0
    first = {name: ((out / name).read_bytes(), (out / name).stat().st_ino) for name in outputs}
    assert main(argv) == 0
    again = {name: ((out / name).read_bytes(), (out / name).stat().st_ino) for name in outputs}
    assert all(again[name][0] == first[name][0] and again[name][1] != first[name][1] for name in outputs)  # replaced
    assert (out / "notes.txt").read_bytes() == USERS


def test_a_file_flightgp_wrote_and_the_user_changed_is_kept(tmp_path, capsys):
    out = tmp_path / "bo105.json"
    assert main(["state-space", "bo105-80kt", "--out", str(out)]) == 0
    out.write_bytes(out.read_bytes() + USERS)
    assert main(["state-space", "bo105-80kt", "--out", str(out)]) == 2
    assert capsys.readouterr().err.endswith(
        f"error: {out} was changed since flightgp wrote it; choose another --out or move it\n")
    assert out.read_bytes().endswith(USERS)
