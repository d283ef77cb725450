"""Writing output files atomically: temporary files in the target folders, then renames, so a
crash or a bad input never leaves half a file where a good one was; and never over a file
flightgp did not write: each folder's list of the files flightgp wrote there (:data:`WRITTEN_LIST`)
is kept up to date in the same step (docs/conventions.md, "Writing files")."""
from __future__ import annotations

import fnmatch
import hashlib
import json
import os
import secrets
from pathlib import Path

from validation.core.errors import BadInputError

#: The list of the files flightgp wrote in a folder, with the SHA-256 of their content, kept in
#: that folder; flightgp replaces an existing file only if this list names it with its content.
WRITTEN_LIST = ".flightgp-written.json"


def check_output_folder(path, *, writes=()) -> Path:
    """``path`` as a Path, after checking that a command can write its files there: call it
    before any long work, so the user learns of a bad ``--out`` at once.

    A small temporary file is created and removed in the folder, or, while it is missing, in the
    nearest folder above it that exists (where it will be created); nothing is left behind.

    Parameters
    ----------
    path : str or Path
        The output folder (of a file output, its parent folder).
    writes : iterable of str
        Names of the files the command will write directly in ``path``, or shell patterns of
        them (``holdout_*.png``; ``*`` claims every file of the folder). A file that matches and
        that flightgp did not write, or that was changed since (:data:`WRITTEN_LIST`), is
        refused. Hidden files never match a pattern.

    Returns
    -------
    Path

    Raises
    ------
    validation.core.errors.BadInputError
        ``path`` is a file, cannot be created or cannot be written to ("cannot write to DIR:
        Permission denied"), or holds a file of ``writes`` that flightgp did not write or that
        was changed since.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise BadInputError(f"{path} exists and is not a folder")
    existing = next(folder for folder in (path, *path.parents) if folder.exists())
    if not existing.is_dir():
        raise BadInputError(f"cannot write to {path}: {existing} is a file, not a folder")
    probe = _temporary_path(existing / "flightgp-write-check")
    try:
        probe.open("x").close()
        probe.unlink()
    except OSError as error:
        raise BadInputError(f"cannot write to {path}: {error.strerror or error}") from None
    if existing != path:
        return path  # a new folder: nothing in it to refuse
    patterns = tuple(writes)
    names = [entry.name for entry in os.scandir(path) if not entry.name.startswith(".") and not entry.is_dir()
             and any(entry.name == pattern or fnmatch.fnmatchcase(entry.name, pattern) for pattern in patterns)]
    _checked_digests(path, sorted(names))
    return path


def written_files(folder) -> dict:
    """The files flightgp wrote in ``folder`` as its :data:`WRITTEN_LIST` says (empty when it is
    missing or unreadable): ``{name: [SHA-256, ...]}``, the hex digests of the content flightgp
    last wrote there and, after a replacement, of the content before it (a write cut short
    between the list and the file leaves that one)."""
    try:
        content = json.loads((Path(folder) / WRITTEN_LIST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    files = content.get("files") if isinstance(content, dict) else None
    if not isinstance(files, dict):
        return {}
    return {name: digests for name, digests in files.items() if isinstance(digests, list)}


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _checked_digests(folder: Path, names) -> dict:
    """``{name: SHA-256}`` of those of the files ``names`` of ``folder`` that exist, after checking
    that flightgp wrote each as it is now: BadInputError naming the first that it did not write or
    that was changed since (a folder of that name is left to the writer, which refuses it)."""
    existing = [name for name in names if (folder / name).exists() and not (folder / name).is_dir()]
    if not existing:
        return {}
    written = written_files(folder)  # read after the files: the list is renamed into place before them
    digests = {}
    for name in existing:
        if name not in written:
            raise BadInputError(f"{folder / name} exists and was not written by flightgp; "
                                "choose another --out or move it")
        digests[name] = _file_digest(folder / name)
        if digests[name] not in written[name]:
            raise BadInputError(f"{folder / name} was changed since flightgp wrote it; "
                                "choose another --out or move it")
    return digests


def _written_list(folder: Path, new: dict, current: dict) -> str:
    """The text of ``folder``'s :data:`WRITTEN_LIST` once the files of digests ``new`` (``{name:
    SHA-256}``) replace those of digests ``current``: the files it lists that still exist, and the
    new ones with their new and current digests."""
    files = {name: digests for name, digests in written_files(folder).items() if (folder / name).exists()}
    for name, digest in new.items():
        files[name] = [digest] if current.get(name, digest) == digest else [digest, current[name]]
    return json_text({"format": "flightgp-written", "version": 1,
                      "about": "the files flightgp wrote in this folder and the SHA-256 of their content; "
                               "it replaces no other file (flightgp docs/conventions.md, Writing files)",
                      "files": dict(sorted(files.items()))})


def _temporary_path(path: Path) -> Path:
    """The temporary file that ``path`` is written to before the rename: ``.NAME.<pid>.<random>.tmp``."""
    return path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")


def write_files_atomically(files: dict) -> list[Path]:
    """Write several files as one step: every file's content goes to a temporary file next to
    it first, and only when all are written are they renamed into place, each folder's
    :data:`WRITTEN_LIST` (updated with the new files) before the files it names.

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
    validation.core.errors.BadInputError
        A file of ``files`` exists and flightgp did not write it, or not as it is now (its folder's
        :data:`WRITTEN_LIST` does not name it with this content); nothing is written.
    OSError
        Naming the target path (not the temporary file) when a folder cannot be created or a
        file cannot be written; no target has been touched then, and no temporary is left.
    """
    targets = {Path(path): data for path, data in files.items()}
    folders, spelled = {}, {}  # one list per folder, however its paths are spelled
    for path, data in targets.items():
        folder = spelled.setdefault(os.path.abspath(path.parent), path.parent)
        folders.setdefault(folder, {})[path.name] = _digest(data.encode("utf-8") if isinstance(data, str) else data)
    lists = {folder / WRITTEN_LIST: _written_list(folder, new, _checked_digests(folder, new))
             for folder, new in folders.items()}
    temporaries = {}
    try:
        for path, data in {**targets, **lists}.items():
            temporary = _temporary_path(path)
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                binary = isinstance(data, bytes)
                # Not tempfile.mkstemp: its files are private (0600); these get the umask mode.
                with open(temporary, "xb" if binary else "x",
                          **({} if binary else {"newline": "", "encoding": "utf-8"})) as stream:
                    temporaries[path] = temporary
                    stream.write(data)
            except OSError as error:
                raise OSError(error.errno, error.strerror, str(path)) from None
        for path in targets:
            if path.is_dir():
                raise IsADirectoryError(21, "Is a directory", str(path))
        for path in [*lists, *targets]:  # the lists first: they name each file's new and former content
            os.replace(temporaries[path], path)
    except BaseException:
        for temporary in temporaries.values():
            temporary.unlink(missing_ok=True)
        raise
    return list(targets)


def write_atomically(path, data: str | bytes) -> Path:
    """Write one file via a temporary file and a rename (see :func:`write_files_atomically`)."""
    return write_files_atomically({path: data})[0]


def json_text(data) -> str:
    """``data`` as the project's JSON files hold it: indented by two spaces, a final newline."""
    return json.dumps(data, indent=2) + "\n"


def write_json(path, data) -> Path:
    """Write ``data`` as indented JSON (:func:`json_text`), atomically; returns the path."""
    return write_atomically(path, json_text(data))


def read_document(path, *, what: str, syntax: str = "JSON"):
    """The content of the JSON (or TOML) file a user gave, ``path``; :class:`BadInputError`
    naming the file and ``what`` it should be (``"tolerance file"``) when it is missing, a
    folder, not UTF-8 text or not valid ``syntax``: ``"no such tolerance file"``, ``"not a
    JSON tolerance file (<the parser's words>)"``.

    Parameters
    ----------
    path : path
    what : str
        What the file is, for the messages.
    syntax : {"JSON", "TOML"}
    """
    import tomllib

    from validation.core.errors import BadInputError

    path = Path(path)
    parse = {"JSON": json.loads, "TOML": tomllib.loads}[syntax]
    try:
        return parse(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise BadInputError(f"{path}: no such {what}") from None
    except IsADirectoryError:
        raise BadInputError(f"{path}: a folder, not a {what}") from None
    except ValueError as error:  # JSON's and TOML's decode errors and UnicodeDecodeError are ValueErrors
        raise BadInputError(f"{path}: not a {syntax} {what} ({error})") from None
