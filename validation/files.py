"""Writing output files atomically: a temporary file in the target folder, then a rename, so a
crash or a bad input never leaves half a file where a good one was (DESIGN.md, "Conventions")."""
from __future__ import annotations

import json
import os
import secrets
from pathlib import Path


def write_atomically(path, data: str | bytes) -> Path:
    """Write ``data`` (text or bytes) to ``path`` via a temporary file and a rename.

    The folder is created if needed. Readers see the old file or the whole new one, never a
    partial write; the temporary file is removed if anything fails. The file gets the usual
    umask permissions (``tempfile.mkstemp`` would make it private).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    binary = isinstance(data, bytes)
    try:
        with open(temporary, "xb" if binary else "x",
                  **({} if binary else {"newline": "", "encoding": "utf-8"})) as stream:
            stream.write(data)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return path


def write_json(path, data) -> Path:
    """Write ``data`` as indented JSON, atomically; returns the path."""
    return write_atomically(path, json.dumps(data, indent=2) + "\n")
