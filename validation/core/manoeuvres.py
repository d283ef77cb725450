"""Test manoeuvres on an integer step grid (``t = start_time + k * sample_time``).

Every function returns the sample times, shape (n,), s, and the signal, shape (n,), in the units
of ``amplitude`` (rad for control angles). The signal at ``time[k]`` is held until ``time[k+1]``.
A manoeuvre is zero (trim) before ``start`` and after it ends.

References: the 3-2-1-1 is the multistep of Koehler/Marchand (DLR), used in the Bo105 GP-NARX
paper (AHS 74th Forum, 2018); the doublet and the logarithmic frequency sweep follow
Tischler & Remple, *Aircraft and Rotorcraft System Identification*, 2nd ed. (2012), ch. 5.
"""
from __future__ import annotations

import numpy as np

from validation.core.errors import BadInputError

#: Most samples in one manoeuvre (about 28 h at 100 Hz; beyond it memory, not physics, runs out).
MAX_SAMPLES = 10_000_000
#: Names accepted by :func:`manoeuvre` (``flightgp record --manoeuvre``).
MANOEUVRES = ("3211", "doublet", "step", "sweep")


def time_grid(*, duration: float, sample_time: float, start_time: float = 0.0) -> np.ndarray:
    """Sample times ``start_time + k * sample_time`` for ``k = 0 .. round(duration/sample_time)``."""
    if not (np.isfinite(duration) and duration > 0):
        raise BadInputError(f"duration must be a positive number of seconds, got {duration}")
    if not (np.isfinite(sample_time) and 0 < sample_time <= duration):
        raise BadInputError(
            f"sample time must be positive and at most the duration ({duration} s), got {sample_time}"
        )
    n_steps = int(round(duration / sample_time))
    if n_steps > MAX_SAMPLES:
        raise BadInputError(f"{duration} s at {sample_time} s steps is {n_steps + 1} samples; flightgp "
                            f"handles at most {MAX_SAMPLES} in one recording")
    return start_time + np.arange(n_steps + 1) * sample_time


def _multistep(time: np.ndarray, *, start: float, step_time: float, widths, signs) -> np.ndarray:
    """Piecewise-constant steps: ``signs[i]`` held for ``widths[i] * step_time`` seconds each."""
    if not (np.isfinite(step_time) and step_time > 0):
        raise BadInputError(f"step time must be a positive number of seconds, got {step_time}")
    edges = start + step_time * np.concatenate(([0.0], np.cumsum(widths)))
    # Half a sample of tolerance so that edges on the grid are not lost to rounding.
    tolerance = 0.5 * (time[1] - time[0]) if len(time) > 1 else 0.0
    index = np.searchsorted(edges - tolerance, time, side="right") - 1
    inside = (index >= 0) & (index < len(signs))
    signal = np.zeros_like(time)
    signal[inside] = np.asarray(signs, dtype=float)[index[inside]]
    return signal


def three_two_one_one(time, *, amplitude: float, step_time: float, start: float) -> np.ndarray:
    """3-2-1-1 multistep: +A for 3 dt, -A for 2 dt, +A for 1 dt, -A for 1 dt (dt = ``step_time``)."""
    return amplitude * _multistep(time, start=start, step_time=step_time,
                                  widths=(3, 2, 1, 1), signs=(1, -1, 1, -1))


def doublet(time, *, amplitude: float, step_time: float, start: float) -> np.ndarray:
    """Doublet: +A for ``step_time``, then -A for ``step_time``."""
    return amplitude * _multistep(time, start=start, step_time=step_time, widths=(1, 1), signs=(1, -1))


def step(time, *, amplitude: float, start: float) -> np.ndarray:
    """Step of height ``amplitude`` at ``start``, held to the end."""
    return np.where(time >= start - 1e-9, amplitude, 0.0)


def frequency_sweep(time, *, amplitude: float, start: float, duration: float,
                    f_min: float = 0.1, f_max: float = 3.0) -> np.ndarray:
    """Logarithmic sine sweep from ``f_min`` to ``f_max`` Hz over ``duration`` s from ``start``.

    Phase ``phi(t) = 2 pi f_min T / ln(f_max/f_min) * ((f_max/f_min)**(t/T) - 1)``, whose
    derivative is the instantaneous frequency ``f_min (f_max/f_min)**(t/T)`` (Tischler & Remple
    2012, sec. 5.6, use a similar exponential sweep).
    """
    if not (0 < f_min < f_max):
        raise BadInputError(f"sweep needs 0 < f_min < f_max, got f_min={f_min}, f_max={f_max}")
    tau = time - start
    inside = (tau >= 0) & (tau <= duration)
    ratio = f_max / f_min
    phase = 2 * np.pi * f_min * duration / np.log(ratio) * (ratio ** (tau / duration) - 1.0)
    return np.where(inside, amplitude * np.sin(phase), 0.0)


def manoeuvre(kind: str, time, *, amplitude: float, step_time: float, start: float) -> np.ndarray:
    """The manoeuvre called ``kind`` (one of :data:`MANOEUVRES`) on ``time``.

    A ``"sweep"`` runs from ``start`` to the end of ``time``, from 0.1 Hz to 3 Hz, and ignores
    ``step_time``; a ``"step"`` ignores it too.
    """
    if kind == "3211":
        return three_two_one_one(time, amplitude=amplitude, step_time=step_time, start=start)
    if kind == "doublet":
        return doublet(time, amplitude=amplitude, step_time=step_time, start=start)
    if kind == "step":
        return step(time, amplitude=amplitude, start=start)
    if kind == "sweep":
        return frequency_sweep(time, amplitude=amplitude, start=start, duration=time[-1] - start)
    raise BadInputError(f"unknown manoeuvre {kind!r}; choose one of {', '.join(MANOEUVRES)}")
