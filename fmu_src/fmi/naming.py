"""FMU names and files: what ``--name`` may be and where the FMU is written (build time)."""
from __future__ import annotations

import re
from pathlib import Path

from validation.core.errors import BadInputError
from validation.core.files import check_output_folder

#: An FMU name, which is also its FMI model identifier (a C identifier in the native FMUs):
#: a letter, then at most 63 letters, digits or underscores.
FMU_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}\Z")


def default_name(text: str) -> str:
    """``text`` (e.g. a model file's stem) made into an FMU name (:data:`FMU_NAME`): every run of
    other characters becomes one underscore, and a name that does not start with a letter gets
    ``model_`` in front."""
    name = re.sub(r"\W+", "_", text).strip("_") or "model"
    return name if name[0].isalpha() else f"model_{name}"


def fmu_target(out_dir, name: str) -> Path:
    """``out_dir/<name>.fmu`` after checking ``name`` (:data:`FMU_NAME`) and ``out_dir``.

    Raises
    ------
    validation.core.errors.BadInputError
        ``name`` is not an FMU name, ``out_dir`` cannot be written (e.g. it is a file), or it holds
        a ``<name>.fmu`` flightgp did not write (:func:`validation.core.files.check_output_folder`).
    """
    out_dir = Path(out_dir)
    if not FMU_NAME.match(name):
        raise BadInputError(f"FMU name {name!r} must start with a letter and hold only letters, "
                            "digits and underscores (at most 64); it becomes the FMI model identifier")
    check_output_folder(out_dir, writes=[f"{name}.fmu"])
    return out_dir / f"{name}.fmu"
