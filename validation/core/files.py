"""Writing output files atomically: temporary files in the target folders, then renames, so a
crash or a bad input never leaves half a file where a good one was (docs/conventions.md, "Writing files")."""
from __future__ import annotations

import json
import os
import secrets
from pathlib import Path


def check_output_folder(path) -> Path:
    """``path`` as a Path, after checking it can be an output folder (missing or a folder);
    :class:`~validation.core.errors.BadInputError` when a file stands there. Call it before long
    work, so the user learns of a bad ``--out`` at once."""
    from validation.core.errors import BadInputError

    path = Path(path)
    if path.exists() and not path.is_dir():
        raise BadInputError(f"{path} exists and is not a folder")
    return path


def write_files_atomically(files: dict) -> list[Path]:
    """Write several files as one step: every file's content goes to a temporary file next to
    it first, and only when all are written are they renamed into place.

    Parameters
    ----------
    files : dict of path -> str or bytes
        Text is written as UTF-8.

    Returns
    -------
    list of Path
        The files written, in order.

    Raises
    ------
    OSError
        Naming the target path (not the temporary file) when a folder cannot be created or a
        file cannot be written; no target has been touched then, and no temporary is left.
    """
    temporaries = []
    try:
        for path, data in files.items():
            path = Path(path)
            temporary = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                binary = isinstance(data, bytes)
                # Not tempfile.mkstemp: its files are private (0600); these get the umask mode.
                with open(temporary, "xb" if binary else "x",
                          **({} if binary else {"newline": "", "encoding": "utf-8"})) as stream:
                    temporaries.append((temporary, path))
                    stream.write(data)
            except OSError as error:
                raise OSError(error.errno, error.strerror, str(path)) from None
        for _, path in temporaries:
            if path.is_dir():
                raise IsADirectoryError(21, "Is a directory", str(path))
        for temporary, path in temporaries:
            os.replace(temporary, path)
    except BaseException:
        for temporary, _ in temporaries:
            temporary.unlink(missing_ok=True)
        raise
    return [path for _, path in temporaries]


def write_atomically(path, data: str | bytes) -> Path:
    """Write one file via a temporary file and a rename (see :func:`write_files_atomically`)."""
    return write_files_atomically({path: data})[0]


def json_text(data) -> str:
    """``data`` as the project's JSON files hold it: indented by two spaces, a final newline."""
    return json.dumps(data, indent=2) + "\n"


def write_json(path, data) -> Path:
    """Write ``data`` as indented JSON (:func:`json_text`), atomically; returns the path."""
    return write_atomically(path, json_text(data))
