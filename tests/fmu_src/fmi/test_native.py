"""The native FMUs' compile (fmu_src/fmi/native.py, compile_shared_library) and its object cache."""
from __future__ import annotations

import ctypes
import subprocess

import pytest

from fmu_src.fmi import native
from fmu_src.fmi.native import CACHE_VARIABLE, compile_shared_library

#: Two files including one header; exported despite -fvisibility=hidden, so ctypes can call them.
SOURCES = {"value.c": b'#include "value.h"\nEXPORT int value(void) { return VALUE; }\n',
           "twice.c": b'#include "value.h"\nEXPORT int twice(void) { return 2 * VALUE; }\n',
           "value.h": b'#define VALUE 7\n#define EXPORT __attribute__((visibility("default")))\n'
                      b"EXPORT int value(void);\nEXPORT int twice(void);\n"}


def _values(binary: bytes, path) -> tuple[int, int]:
    """value() and twice() of a library compiled from (a variant of) SOURCES."""
    path.write_bytes(binary)
    library = ctypes.CDLL(str(path))
    return library.value(), library.twice()


def _compiles(monkeypatch) -> list:
    """The gcc commands that compile a file (``-c``) from here on."""
    commands, run = [], subprocess.run

    def recording(command, *args, **kwargs):
        if "-c" in command:
            commands.append(command)
        return run(command, *args, **kwargs)

    monkeypatch.setattr(native.subprocess, "run", recording)
    return commands


def test_without_the_cache_variable_every_file_is_compiled_each_time(monkeypatch, tmp_path):
    monkeypatch.delenv(CACHE_VARIABLE, raising=False)
    compiles = _compiles(monkeypatch)
    for index in range(2):
        assert _values(compile_shared_library(SOURCES, "plain"), tmp_path / f"plain_{index}.so") == (7, 14)
    assert len(compiles) == 4


def test_identical_code_is_compiled_once_and_any_change_compiles_anew(monkeypatch, tmp_path):
    """Two builds of the same sources compile each file once, the second (under another name)
    taking the kept objects: the same library. A changed header recompiles both files that
    include it, with its new value; other flags recompile; a failed compile keeps nothing."""
    cache = tmp_path / "cache"
    monkeypatch.setenv(CACHE_VARIABLE, str(cache))
    compiles = _compiles(monkeypatch)
    first = compile_shared_library(SOURCES, "first")
    assert len(compiles) == 2 and len(list(cache.glob("*.o"))) == 2
    second = compile_shared_library(SOURCES, "second")
    assert len(compiles) == 2 and second == first
    assert _values(second, tmp_path / "second.so") == (7, 14)
    changed = compile_shared_library({**SOURCES, "value.h": SOURCES["value.h"].replace(b"7", b"8")}, "changed")
    assert len(compiles) == 4 and _values(changed, tmp_path / "changed.so") == (8, 16)
    compile_shared_library(SOURCES, "other_flags", extra_flags=("-O0",))
    assert len(compiles) == 6 and len(list(cache.glob("*.o"))) == 6
    broken = {**SOURCES, "value.c": SOURCES["value.c"].replace(b"{ return", b"{ int unused; return")}
    with pytest.raises(RuntimeError, match="unused"):
        compile_shared_library(broken, "broken", extra_flags=("-Werror",))
    assert len(compiles) == 7 and len(list(cache.glob("*.o"))) == 6 and not list(cache.glob("*.partial"))


def test_a_cache_folder_that_cannot_be_written_does_not_fail_the_build(monkeypatch, tmp_path):
    """The cache only saves time: named at a path under a file (no folder can be made there),
    every file is compiled and the library is built as without it, nothing left behind."""
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv(CACHE_VARIABLE, str(blocker / "cache"))
    compiles = _compiles(monkeypatch)
    for index in range(2):
        assert _values(compile_shared_library(SOURCES, "uncached"), tmp_path / f"uncached_{index}.so") == (7, 14)
    assert len(compiles) == 4 and blocker.read_text() == "not a folder"
