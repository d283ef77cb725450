"""What the models inside flightgp's pythonfmu FMUs share: model files, GP kernel rows and the
training envelope. numpy and the standard library only.

Every pythonfmu FMU carries a copy of this file, under a name unique to the FMU
(:mod:`fmu_src.fmi.pythonfmu`): a simulator host has no flightgp.

Model files
-----------
An FMU's model travels in ``model.npz`` next to its code, written by ``numpy.savez`` from the
model's ``pack_model`` and read without pickle (:func:`read_model_file`). Every one starts with
:func:`model_header`, a ``format`` name and a ``version``, which :func:`check_header` checks; a
GP model stores its arrays per part (an output, or a group of outputs), prefixed ``"<part>/"``,
read by :func:`read_part`.
"""
from __future__ import annotations

import numpy as np

#: A model input counts as outside the training envelope when it leaves the training range by
#: more than this fraction of the range on either side (docs/fmus.md, "Sampling, status and state").
ENVELOPE_MARGIN = 0.1


class ModelFormatError(ValueError):
    """The model file is not the FMU's model of this version, or is inconsistent."""


def model_header(format_name: str, version: int) -> dict:
    """The arrays that open every FMU model file: its ``format`` name and ``version``."""
    return {"format": np.array(format_name), "version": np.array(int(version))}


def read_model_file(path) -> dict:
    """Every array of the ``.npz`` model file at ``path``, by name (never unpickles)."""
    with np.load(path, allow_pickle=False) as npz:
        return {name: npz[name] for name in npz.files}


def check_header(arrays: dict, *, format_name: str, version: int) -> None:
    """Raise :class:`ModelFormatError` unless ``arrays`` open with :func:`model_header`
    ``(format_name, version)``."""
    found = (str(arrays.get("format")), int(arrays.get("version", -1)))
    if found != (format_name, version):
        raise ModelFormatError(f"not a {format_name} model file of version {version} (format {found[0]!r}, "
                               f"version {found[1]}); rebuild the FMU with this flightgp")


def read_part(arrays: dict, prefix: str, dimensions: dict) -> dict:
    """One part's arrays, ``arrays[prefix + name]`` for each ``name`` of ``dimensions``, as
    C-ordered float arrays with the number of dimensions ``dimensions[name]``, all finite.

    Raises
    ------
    ModelFormatError
        An array is missing, has another number of dimensions, or is not finite.
    """
    try:
        part = {name: np.array(arrays[prefix + name], dtype=float, order="C") for name in dimensions}
    except KeyError as error:
        raise ModelFormatError(f"the model file lacks the array {error}") from None
    for name, ndim in dimensions.items():
        if part[name].ndim != ndim:
            raise ModelFormatError(f"{prefix}{name} has {part[name].ndim} dimensions, expected {ndim}")
        if not np.isfinite(part[name]).all():
            raise ModelFormatError(f"{prefix}{name} holds values that are not finite")
    return part


def freeze(arrays) -> None:
    """Make every array of ``arrays`` read-only: a loaded model is shared by every instance of
    the FMU in a process."""
    for value in arrays:
        if isinstance(value, np.ndarray):
            value.flags.writeable = False


def kernel_rows(xs: np.ndarray, basis: np.ndarray, kernel_weights: np.ndarray,
                log_signal_variance: np.ndarray) -> np.ndarray:
    """``k_r(x, b) = sigma_f,r^2 exp(-sum_i w_r,i (x_i - b_i)^2)`` for each hyperparameter row r:
    the squared-exponential kernel with one length scale per input (Rasmussen & Williams 2006,
    eq. 5.1, with ``w_i = 1 / (2 l_i^2)``).

    Parameters
    ----------
    xs : ndarray, shape (d,)
        Standardised input.
    basis : ndarray, shape (m, d)
    kernel_weights : ndarray, shape (R, d)
    log_signal_variance : ndarray, shape (R,)

    Returns
    -------
    ndarray, shape (R, m)
    """
    squared = (xs - basis) ** 2  # (m, d)
    return np.exp(log_signal_variance[:, None] - kernel_weights @ squared.T)


class Envelope:
    """The training range of a model's inputs, widened by :data:`ENVELOPE_MARGIN` of the range
    on each side; an FMU warns when an input leaves it.

    Parameters
    ----------
    low, high : ndarray, shape (d,)
        Training range of each input, physical units.
    names : sequence of str
        Input names, for messages.
    """

    def __init__(self, low, high, names) -> None:
        self.low, self.high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
        self.names = tuple(names)
        margin = ENVELOPE_MARGIN * (self.high - self.low)
        self.lower, self.upper = self.low - margin, self.high + margin
        freeze((self.low, self.high, self.lower, self.upper))

    def outside(self, x: np.ndarray) -> list[str]:
        """One phrase per input of ``x`` (d,) outside the envelope (empty if inside)."""
        return [f"{self.names[i]} = {x[i]:.6g} (trained on {self.low[i]:.6g} .. {self.high[i]:.6g})"
                for i in np.flatnonzero((x < self.lower) | (x > self.upper))]
