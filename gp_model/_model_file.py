"""Portable model files: one ``.npz`` holding named arrays and a JSON header, never pickle.

Layout: the array ``__header__`` is a JSON string ``{"format": "flightgp-model", "version": 1,
"type": <model type>, "meta": {...}}``; every other array is named ``<part>/<name>``, where a
part is one GP of the model (``gp0``, ``gp1``, ...). Each part's metadata names its kind,
``"gp_type"``: ``"exact"`` (:class:`~gp_model.GaussianProcess`) or ``"sparse_vfe"``
(:class:`~gp_model.SparseGaussianProcess`, which also stores its inducing inputs); files written
before sparse GPs existed have no ``gp_type`` and hold exact GPs.

Grey-box models (:class:`~gp_model.GreyBoxGP`, type ``"GreyBoxGP"``) store their residual GPs as
parts (one when shared, else one per state), their structure (``state_columns``, ``shared``,
``n_states``, ``n_inputs``, ``noise_variance``, ``n_restarts``) under ``"structure"``, and under
``"physics"`` a JSON description of the physics step they were trained with: at least ``"kind"``
(e.g. ``"blimp_rk4"``, the blimp's, docs/gp_model.md) and whatever numbers rebuild the step.
The physics callable itself is never stored; whoever loads the model rebuilds it from that
description. Files are written to a temporary file in the target folder and renamed, so a crash
never leaves half a model behind.
"""
from __future__ import annotations

import io
import json
import os
import secrets
import zipfile
from pathlib import Path

import numpy as np

from ._errors import GPNumericalError, ModelFileError
from ._gp import GaussianProcess, PerOutputGP
from ._greybox import GreyBoxGP, greybox_from_parts, greybox_to_parts
from ._narx import GPNarx, NarxStructure
from ._sparse_gp import SparseGaussianProcess

FORMAT = "flightgp-model"
VERSION = 1

#: Kinds of GP part: ``gp_type`` -> class. Each class writes a part with its ``to_arrays`` and
#: reads one back with its ``from_arrays``.
PART_TYPES = {"exact": GaussianProcess, "sparse_vfe": SparseGaussianProcess}


def save_model(path, model, *, meta: dict | None = None, physics: dict | None = None) -> Path:
    """Write a fitted model to ``path``.

    Parameters
    ----------
    path : str or Path
        Target file; ``.npz`` is appended if missing.
    model : GaussianProcess, SparseGaussianProcess, PerOutputGP, GPNarx or GreyBoxGP
        Fitted model; the GPs of a PerOutputGP or GPNarx may be exact or sparse.
    meta : dict, optional
        Extra JSON-serialisable information stored in the header (e.g. the training recording).
    physics : dict, required for a GreyBoxGP and refused otherwise
        JSON-serialisable description of the physics step the grey-box model was trained with,
        with a string ``"kind"`` (module docstring).

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    content = model_bytes(model, meta=meta, physics=physics)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with open(temporary, "xb") as stream:
            stream.write(content)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return path


def model_bytes(model, *, meta: dict | None = None, physics: dict | None = None) -> bytes:
    """The content of :func:`save_model`'s file of ``model``, for a caller that writes the file
    itself (parameters as :func:`save_model`)."""
    gps, structure = _decompose(model)
    is_greybox = isinstance(model, GreyBoxGP)
    if is_greybox and not (isinstance(physics, dict) and isinstance(physics.get("kind"), str)):
        raise ValueError("a GreyBoxGP needs physics={'kind': ..., ...}: the description of the "
                         "physics step it was trained with (the callable itself is not stored)")
    if physics is not None and not is_greybox:
        raise ValueError(f"physics is only stored with a GreyBoxGP, not a {type(model).__name__}")
    parts, arrays = [], {}
    for i, gp in enumerate(gps):
        gp_type = next((name for name, cls in PART_TYPES.items() if type(gp) is cls), None)
        if gp_type is None:
            raise TypeError(f"cannot save a {type(gp).__name__} as part of a model")
        part_meta, part_arrays = gp.to_arrays()
        parts.append({"gp_type": gp_type, **part_meta})
        arrays.update({f"gp{i}/{name}": value for name, value in part_arrays.items()})
    header = {"format": FORMAT, "version": VERSION, "type": type(model).__name__,
              "parts": parts, "structure": structure, "meta": meta or {}}
    if is_greybox:
        header["physics"] = physics
    arrays["__header__"] = np.array(json.dumps(header))
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def read_header(path) -> dict:
    """The JSON header of a model file (format, version, type, meta; physics for a GreyBoxGP)."""
    return _open(path)[0]


def load_model(path):
    """Read a model written by :func:`save_model`.

    Returns
    -------
    GaussianProcess, SparseGaussianProcess, PerOutputGP, GPNarx or GreyBoxGP
        The model, ready to predict (factorisations are recomputed from the stored data).

    Raises
    ------
    ModelFileError
        Missing, corrupt, not a flightgp model, of another format version, or inconsistent.
    """
    header, arrays = _open(path)
    try:
        gps = []
        for i, part_meta in enumerate(header["parts"]):
            prefix = f"gp{i}/"
            part = {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}
            gp_type = part_meta.get("gp_type", "exact")
            if gp_type not in PART_TYPES:
                raise ModelFileError(f"{path}: part {i} is a GP of unknown type {gp_type!r}; this "
                                     f"flightgp reads {', '.join(PART_TYPES)}. Use the flightgp "
                                     "release that wrote it.")
            gps.append(PART_TYPES[gp_type].from_arrays(part_meta, part))
        if header["type"] in ("GaussianProcess", "SparseGaussianProcess"):
            kinds = [type(gp).__name__ for gp in gps]
            if kinds != [header["type"]]:
                raise ValueError(f"a {header['type']} file must hold one such GP, not {kinds}")
            return gps[0]
        if header["type"] == "PerOutputGP":
            return PerOutputGP(gps)
        if header["type"] == "GPNarx":
            return GPNarx(NarxStructure(**header["structure"]), PerOutputGP(gps))
        if header["type"] == "GreyBoxGP":
            physics = header.get("physics")
            if not (isinstance(physics, dict) and isinstance(physics.get("kind"), str)):
                raise ValueError("a GreyBoxGP file must describe its physics (a header 'physics' "
                                 "with a 'kind')")
            if not all(type(gp) is GaussianProcess for gp in gps):
                raise ValueError("a GreyBoxGP file holds exact GPs only")
            return greybox_from_parts(header["structure"], gps)
    except ModelFileError:
        raise
    except GPNumericalError as error:
        raise ModelFileError(f"{path}: the stored GP cannot be factorised ({error})") from None
    except (KeyError, ValueError, TypeError, AttributeError) as error:
        raise ModelFileError(f"{path}: model file is inconsistent ({type(error).__name__}: {error})") from None
    raise ModelFileError(f"{path}: unknown model type {header['type']!r}")


def _decompose(model) -> tuple[list, dict | None]:
    """The GPs of ``model`` and, for a NARX model, its structure as JSON-safe data."""
    if isinstance(model, (GaussianProcess, SparseGaussianProcess)):
        return [model], None
    if isinstance(model, PerOutputGP):
        return model.gps, None
    if isinstance(model, GreyBoxGP):
        structure, gps = greybox_to_parts(model)
        return gps, structure
    if isinstance(model, GPNarx):
        s = model.structure
        return model.model.gps, {"input_names": list(s.input_names), "output_names": list(s.output_names),
                                 "input_lags": list(s.input_lags), "output_lags": list(s.output_lags)}
    raise TypeError(f"cannot save a {type(model).__name__}")


def _open(path) -> tuple[dict, dict]:
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"{path}: no such model file")
    if not zipfile.is_zipfile(path):
        raise ModelFileError(f"{path}: not a readable .npz model file (not a zip archive)")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as error:
        raise ModelFileError(f"{path}: not a readable .npz model file ({error})") from None
    try:
        header = json.loads(str(arrays.pop("__header__")))
    except (KeyError, json.JSONDecodeError):
        raise ModelFileError(f"{path}: no flightgp header; not a flightgp model file") from None
    if not isinstance(header, dict):
        raise ModelFileError(f"{path}: the header is not a JSON object; not a flightgp model file")
    if header.get("format") != FORMAT:
        raise ModelFileError(f"{path}: not a flightgp model file (format {header.get('format')!r})")
    if header.get("version") != VERSION:
        raise ModelFileError(
            f"{path}: model file version {header.get('version')!r}; this flightgp reads version "
            f"{VERSION}. Retrain the model or use the flightgp release that wrote it."
        )
    for name, array in arrays.items():
        if array.dtype.kind in "fc" and not np.all(np.isfinite(array)):
            raise ModelFileError(f"{path}: array {name!r} holds NaN or inf; the file is corrupt")
    return header, arrays
