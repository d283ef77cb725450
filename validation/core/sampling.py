"""The sampling rule of time histories: one test of even sampling, the nominal step of a
jittered one, and the argument check every vehicle's ``simulate`` uses.

Time comes from an integer step counter, ``t = t0 + k*h`` (docs/conventions.md, "Time"), so an
evenly sampled history differs from its nominal grid only by the rounding of that product;
motion-capture recordings may be unevenly sampled, and say so in their sidecar.
"""
from __future__ import annotations

import numpy as np

from validation.core.errors import BadInputError

# Relative tolerance on equal time steps (1e-6 of the step); float rounding of t0 + k*h on top.
_STEP_RTOL = 1e-6


def uneven_steps(time: np.ndarray) -> np.ndarray:
    """Indices ``k`` of the intervals ``time[k+1] - time[k]`` that differ from the median interval
    by more than 1e-6 of it plus a few ulps of the times (``t0 + k*h`` grids are rounded): the one
    test of even sampling (recording files, vehicle simulations, diagnose). ``time`` (n,), n >= 2,
    strictly increasing; empty when evenly sampled."""
    step = np.diff(time)
    nominal = float(np.median(step))
    tolerance = _STEP_RTOL * nominal + 4 * np.spacing(np.maximum(abs(time[:-1]), abs(time[1:])))
    return np.flatnonzero(abs(step - nominal) > tolerance)


def nominal_step(time: np.ndarray) -> float:
    """Nominal sample interval of a recording, s: its span over its number of nominal
    intervals, each actual interval counted as ``round(h_k / median h)`` of them (so a dropped
    frame counts twice). Exact on an even grid; with frame-timing jitter of sd ``s`` it is off
    by about ``sqrt(2) s / (n - 1)`` only, where the median interval alone is off by about
    ``sqrt(pi/2) sqrt(2) s / sqrt(n)`` (the sample median's asymptotic standard error for a
    normal law), 1 % at 20 Hz with 4 ms jitter over 20 s."""
    steps = np.diff(time)
    counts = np.maximum(1.0, np.round(steps / np.median(steps)))
    return float((time[-1] - time[0]) / counts.sum())


def check_history(time, inputs, input_names, *, evenly_sampled: bool = True):
    """Validate a ``simulate`` call's arguments; the one check every vehicle uses.

    Parameters
    ----------
    time : array_like, shape (n,)
        Sample times, s; at least 2, finite, strictly increasing, and (if ``evenly_sampled``)
        evenly spaced (:func:`validation.core.recordings.uneven_steps`: to 1e-6 of the median step, far
        above the rounding of ``t0 + k*h`` grids, far below any real irregularity).
    inputs : array_like, shape (n, len(input_names))
    input_names : sequence of str
        Column names, for messages.

    Returns
    -------
    time : ndarray, shape (n,)
    inputs : ndarray, shape (n, n_inputs)
    step : float
        Mean sample interval, s.
    """
    time = np.asarray(time, dtype=float)
    inputs = np.asarray(inputs, dtype=float)
    n_inputs = len(input_names)
    if time.ndim != 1 or len(time) < 2:
        raise BadInputError(f"time must be a 1-D array of at least 2 samples, got shape {time.shape}")
    if inputs.shape != (len(time), n_inputs):
        raise BadInputError(f"inputs must have shape ({len(time)}, {n_inputs}), one row per time sample "
                            f"with columns {', '.join(input_names)}; got shape {inputs.shape}")
    if not np.all(np.isfinite(time)):
        raise BadInputError(f"time has a non-finite value at sample {int(np.argmin(np.isfinite(time)))}")
    bad = np.argwhere(~np.isfinite(inputs))
    if len(bad):
        row, column = bad[0]
        raise BadInputError(f"inputs have a non-finite value at row {row}, column {input_names[column]!r}")
    steps = np.diff(time)
    step = (time[-1] - time[0]) / (len(time) - 1)
    if np.any(steps <= 0):
        worst = int(np.argmin(steps))
        raise BadInputError(f"time must be strictly increasing; it goes from {time[worst]:.9g} s to "
                            f"{time[worst + 1]:.9g} s at sample {worst}")
    uneven = uneven_steps(time) if evenly_sampled else ()
    if len(uneven):
        raise BadInputError(f"time must be evenly spaced; the step at sample {uneven[0]} is "
                            f"{steps[uneven[0]]:.9g} s against a usual {np.median(steps):.9g} s")
    return time, inputs, float(step)


def sampling_metadata(time: np.ndarray) -> dict:
    """The sidecar keys that describe how ``time`` (n,) is sampled: ``{"sample_time": h}`` when
    evenly sampled (:func:`uneven_steps`), else ``{"uneven_sampling": true,
    "sample_time_nominal": h}`` with ``h`` the :func:`nominal_step` (docs/conventions.md,
    "Recording files")."""
    if not len(uneven_steps(time)):
        return {"sample_time": float((time[-1] - time[0]) / (len(time) - 1))}
    return {"uneven_sampling": True, "sample_time_nominal": nominal_step(time)}
