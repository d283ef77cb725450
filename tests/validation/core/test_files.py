"""Writing files: never over a file flightgp did not write, each folder's list of the files
flightgp wrote kept with them, and output folders checked without writing anything
(docs/conventions.md, "Writing files")."""
import hashlib
import json
import os

import pytest

from validation.core.errors import BadInputError
from validation.core.files import WRITTEN_LIST, check_output_folder, write_files_atomically, written_files


def test_a_file_flightgp_did_not_write_is_refused_and_nothing_is_written(tmp_path):
    (tmp_path / "b.txt").write_bytes(b"the user's")
    with pytest.raises(BadInputError, match=f"^{tmp_path / 'b.txt'} exists and was not written by flightgp"):
        write_files_atomically({tmp_path / "a.txt": "a", tmp_path / "b.txt": "b"})
    assert sorted(os.listdir(tmp_path)) == ["b.txt"]  # no a.txt, no temporary, no list
    assert (tmp_path / "b.txt").read_bytes() == b"the user's"


def test_flightgp_replaces_its_own_files_as_it_wrote_them_and_lists_only_those_that_exist(tmp_path):
    write_files_atomically({tmp_path / "a.txt": "a", tmp_path / "b.txt": b"b"})
    assert written_files(tmp_path) == {"a.txt": [hashlib.sha256(b"a").hexdigest()],
                                       "b.txt": [hashlib.sha256(b"b").hexdigest()]}
    (tmp_path / "b.txt").unlink()
    write_files_atomically({tmp_path / "a.txt": "again"})
    assert list(json.loads((tmp_path / WRITTEN_LIST).read_text())["files"]) == ["a.txt"]
    assert (tmp_path / "a.txt").read_text() == "again"
    (tmp_path / "b.txt").write_text("the user's, under a name flightgp once used")
    with pytest.raises(BadInputError, match="b.txt exists and was not written by flightgp"):
        write_files_atomically({tmp_path / "b.txt": "b"})
    (tmp_path / "a.txt").write_text("again, and the user's notes")
    with pytest.raises(BadInputError, match=f"^{tmp_path / 'a.txt'} was changed since flightgp wrote it; choose"):
        write_files_atomically({tmp_path / "a.txt": "a"})
    assert (tmp_path / "a.txt").read_text() == "again, and the user's notes"


def test_a_write_cut_short_after_the_list_leaves_files_flightgp_can_write_again(tmp_path, monkeypatch):
    """The list is renamed into place before the files it names and keeps a replaced file's
    former content: a write stopped between the two leaves a file flightgp can replace."""
    write_files_atomically({tmp_path / "a.txt": "first"})
    replace, calls = os.replace, []

    def second_fails(source, target):
        calls.append(target)
        if len(calls) == 2:
            raise OSError("disk full")
        replace(source, target)

    monkeypatch.setattr("validation.core.files.os.replace", second_fails)
    with pytest.raises(OSError, match="disk full"):
        write_files_atomically({tmp_path / "a.txt": "second"})
    monkeypatch.undo()
    assert (tmp_path / "a.txt").read_text() == "first"
    write_files_atomically({tmp_path / "a.txt": "third"})
    assert (tmp_path / "a.txt").read_text() == "third"


def test_check_output_folder_refuses_only_files_it_will_write_and_writes_nothing(tmp_path):
    (tmp_path / "notes.txt").write_text("the user's")
    (tmp_path / "plots").mkdir()
    (tmp_path / ".hidden").write_text("the user's")
    assert check_output_folder(tmp_path, writes=["report.md", "*.png", "plots"]) == tmp_path
    with pytest.raises(BadInputError, match="notes.txt exists and was not written by flightgp"):
        check_output_folder(tmp_path, writes=["*"])
    new = tmp_path / "new" / "deeper"
    assert check_output_folder(new, writes=["*"]) == new and not (tmp_path / "new").exists()
    assert sorted(os.listdir(tmp_path)) == [".hidden", "notes.txt", "plots"]
