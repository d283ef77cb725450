"""Locate: where and at which frequencies the reference misfits the recordings.

The reference is replayed from trim on the recorded inputs; the residual is measured minus
replay, tested against the sensor noise of :mod:`validation.diagnose.noise`, on the diagnosed
(not held-out) recordings. Reported (docs/diagnose.md, the ``mismatch`` and ``locate`` sections
of diagnosis.json): time windows whose moving RMS exceeds what noise explains
(:func:`_mismatch_windows`), frequency bands where the residual's Welch PSD exceeds the noise
floor (:func:`_excess_bands`), and inputs the residual is coherent with
(:func:`_coherent_inputs`).

Unevenly sampled recordings: the moving-RMS test counts samples (its law does not depend on
their spacing); only the Welch PSD bands and the coherence, which need an even grid, are
computed on the residual linearly interpolated (inputs held) onto the nominal grid
``t_0 + k h`` (an approximation, see :func:`_on_nominal_grid`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal, stats

from validation.core.errors import BadInputError
from validation.core.recordings import column_unit, looks_like_degrees
from validation.diagnose.data import EVEN_TOLERANCE, EXCITATION_THRESHOLD, PreparedData, evenly_sampled
from validation.diagnose.noise import LOCATE_ALPHA, NOISE_ESTIMATOR
from validation.vehicles.effects import EffectModel

#: Moving-RMS window for locating mismatches, s (several periods of the 1-3 Hz rigid-body modes).
WINDOW = 0.5


@dataclass
class Location:
    """Result of :func:`locate`.

    Attributes
    ----------
    reference_replay : list of ndarray, shape (n_r, n_out)
        The reference's replay per recording (held-out ones too), outputs in
        ``data.output_names`` order.
    mismatch : list of dict
        diagnosis.json's ``mismatch``: ``output``, ``t_start``, ``t_end`` (s), ``rms_error``
        (output units), ``recording``.
    summary : dict
        diagnosis.json's ``locate``: ``noise_sd`` (per output), ``noise_estimator``, ``bands``
        (per output, ``f_low``, ``f_high`` in Hz and ``peak_ratio``), ``coherent_inputs`` (per
        output with bands), and ``spectra`` (how spectra were computed) for uneven sampling.
    """

    reference_replay: list
    mismatch: list
    summary: dict


def locate(data: PreparedData, reference: EffectModel) -> Location:
    """Replay ``reference`` without effects and locate its misfit (module docstring).

    Raises
    ------
    BadInputError
        The reference's own replay of a recording is not finite (an FMU that could not run it,
        or a model that diverges from the recorded start): no verdict can rest on it.
    """
    replay = data.simulate(reference, [])
    for name, states in zip(data.recording_names, replay):
        if not np.all(np.isfinite(states)):
            raise BadInputError(f"{reference.name} could not replay {name}: its outputs are not finite (NaN or "
                                "inf), so there is no model to diagnose; check that the model runs this recording "
                                "(--map for its columns, its start state, its platform)")
    _check_angle_units(data, replay, reference.name)
    residuals = [{n: m[:, i] - r[:, i] for i, n in enumerate(data.output_names)}
                 for m, r in zip(data.measured, replay)]
    mismatch = []
    for k, name in enumerate(data.recording_names):
        if data.held_out[k]:
            continue
        for i, output in enumerate(data.output_names):
            for t_start, t_end, rms in _mismatch_windows(data.time[k], residuals[k][output], data.noise_sd[k][i],
                                                         int(round(WINDOW * data.sample_rate))):
                mismatch.append({"output": output, "t_start": round(t_start, 4), "t_end": round(t_end, 4),
                                 "rms_error": rms, "recording": name})
    return Location(replay, mismatch, _spectra(data, residuals))


#: Correlation of recording and replay above which their ratio is read as a unit's (and not a
#: model's) difference.
UNIT_CORRELATION = 0.9


def _check_angle_units(data: PreparedData, replay: list, reference_name: str) -> None:
    """Refuse an angle or rate output whose recording moves like the reference's replay but
    about 57 times larger or smaller (degrees against radians): a unit slip the reading's
    plausibility limits miss on a small manoeuvre, and no missing physics scales a whole
    response by 57. The ratio is the least-squares gain of the recorded on the replayed changes
    from each recording's first sample; only a clear likeness (correlation above
    :data:`UNIT_CORRELATION`) is judged (:func:`~validation.core.recordings.looks_like_degrees`,
    either way round)."""
    diagnosed = [k for k in range(len(data.time)) if not data.held_out[k]]
    for i, output in enumerate(data.output_names):
        if column_unit(output) not in ("rad", "rad/s"):
            continue
        measured = np.concatenate([data.measured[k][:, i] - data.measured[k][0, i] for k in diagnosed])
        replayed = np.concatenate([replay[k][:, i] - replay[k][0, i] for k in diagnosed])
        if not (np.std(measured) > 0 and np.std(replayed) > 0):
            continue
        if np.corrcoef(measured, replayed)[0, 1] < UNIT_CORRELATION:
            continue
        gain = float(measured @ replayed / (replayed @ replayed))
        if looks_like_degrees(abs(gain)):
            raise BadInputError(f"the recorded {output} is {abs(gain):.3g} times {reference_name}'s replay of it: it "
                                f"looks like degrees; flightgp reads {column_unit(output)} "
                                "(docs/conventions.md, \"Units and axes\")")
        if looks_like_degrees(1 / abs(gain)):
            raise BadInputError(f"{reference_name}'s replay of {output} is {1 / abs(gain):.3g} times the recorded "
                                f"{output}: the reference's {output} looks like degrees; flightgp reads "
                                f"{column_unit(output)} (docs/conventions.md, \"Units and axes\")")


def _spectra(data: PreparedData, residuals: list) -> dict:
    """diagnosis.json's ``locate`` (:class:`Location`): bands and coherent inputs per output."""
    summary = {"noise_sd": data.typical_noise_sd, "noise_estimator": NOISE_ESTIMATOR,
               "bands": {}, "coherent_inputs": {}}
    if not data.even:
        summary["spectra"] = f"on the nominal {data.step:.6g} s grid (residuals interpolated linearly, inputs held)"
    diagnosed = [k for k in range(len(data.time)) if not data.held_out[k]]
    on_grid = [({n: _on_nominal_grid(data.time[k], data.inputs[k][:, data.input_names.index(n)], data.step,
                                     held=True) for n in data.excited},
                {n: _on_nominal_grid(data.time[k], residuals[k][n], data.step) for n in data.output_names})
               for k in diagnosed]
    for i, name in enumerate(data.output_names):
        bands = _excess_bands([grid_residuals[name] for _, grid_residuals in on_grid],
                              [data.noise_sd[k][i] for k in diagnosed], data.sample_rate)
        if bands:
            summary["bands"][name] = [{"f_low": lo, "f_high": hi, "peak_ratio": ratio} for lo, hi, ratio in bands]
            summary["coherent_inputs"][name] = _coherent_inputs(on_grid, name, data.excited, data.sample_rate)
    return summary


def _on_nominal_grid(time: np.ndarray, values: np.ndarray, step: float, *, held: bool = False) -> np.ndarray:
    """``values`` (n,) sampled at ``time`` (n,), brought onto the grid ``time[0] + k step``
    covering it, shape (m,); unchanged when ``time`` is evenly sampled already.

    Residuals are interpolated linearly; inputs (``held``) keep their zero-order hold (the row
    acting at each grid time). Linear interpolation is an approximation for white noise: a grid
    value between samples at fractions ``w, 1 - w`` has variance ``(w^2 + (1 - w)^2) sigma^2``,
    at least half of ``sigma^2`` (about 0.9 of it for 4 ms jitter at 20 Hz), and neighbours that
    share a sample correlate; so spectra on the grid sit a little below the white floor
    ``2 sigma^2 / fs`` at high frequencies, which makes :func:`_excess_bands` slightly
    conservative there, and phases are off by at most the jitter.
    """
    if evenly_sampled(time):
        return values
    grid = time[0] + step * np.arange(int(math.floor((time[-1] - time[0]) / step + 1e-6)) + 1)
    if held:
        rows = np.searchsorted(time, grid + EVEN_TOLERANCE * step, side="right") - 1
        return values[np.clip(rows, 0, len(values) - 1)]
    return np.interp(grid, time, values)


def _moving_mean_square(residual: np.ndarray, width: int) -> np.ndarray:
    """Centred moving mean of ``residual**2`` over ``width`` samples, shape like ``residual``."""
    kernel = np.ones(width) / width
    return np.convolve(residual**2, kernel, mode="same")


def _mismatch_windows(time, residual, noise_sd, width) -> list:
    """Windows where the moving mean square exceeds the noise: under white noise of variance
    sigma^2 a window's mean square is sigma^2 chi2(W)/W; exceeding its 1 - LOCATE_ALPHA
    quantile marks a mismatch. Adjacent marked samples merge into one window. ``width`` counts
    samples (about :data:`WINDOW` s at the nominal rate): the law counts samples whatever their
    spacing, so unevenly sampled recordings are tested on their own samples, not resampled."""
    width = max(3, min(width, len(residual)))
    limit = noise_sd**2 * stats.chi2.isf(LOCATE_ALPHA, width) / width
    marked = _moving_mean_square(residual, width) > limit
    edges = np.flatnonzero(np.diff(np.concatenate(([0], marked.astype(int), [0]))))
    spans = []
    for start, stop in zip(edges[::2], edges[1::2]):
        if spans and start - spans[-1][1] < width:  # gaps shorter than a window: one mismatch
            spans[-1][1] = stop
        else:
            spans.append([start, stop])
    return [(float(time[start]), float(time[stop - 1]), float(np.sqrt(np.mean(residual[start:stop] ** 2))))
            for start, stop in spans]


def _welch_segment(n: int, fs: float) -> int:
    """Welch segment length: about 2.56 s (0.4 Hz resolution at any rate), at most n // 4."""
    return int(max(16, min(2 ** round(math.log2(2.56 * fs)), n // 4)))


def _excess_bands(residuals, noise_sds, fs) -> list:
    """Frequency bands where the residual PSD exceeds the white-noise floor ``2 sigma^2 / fs``.

    Welch's averaged periodogram (Welch, IEEE Trans. Audio Electroacoust. 15(2), 1967), Hann
    windows with 50 % overlap; its estimate is taken as ``PSD chi2(2K)/2K`` for K segments
    (Bendat & Piersol, *Random Data*, 4th ed., 2010, sec. 8.5, ignoring the overlap's
    correlation); a bin is above noise when it exceeds the ``1 - LOCATE_ALPHA`` quantile.
    Returns ``[(f_low, f_high, peak PSD / floor)]`` in Hz.
    """
    n_min = min(len(r) for r in residuals)
    nperseg = _welch_segment(n_min, fs)
    psds, floors, segments = [], [], 0
    for residual, sd in zip(residuals, noise_sds):
        frequency, psd = signal.welch(residual, fs=fs, nperseg=nperseg)
        psds.append(psd)
        floors.append(2 * sd**2 / fs)
        segments += max(1, 2 * len(residual) // nperseg - 1)
    ratio = np.mean(psds, axis=0) / np.mean(floors)
    limit = stats.chi2.isf(LOCATE_ALPHA, 2 * segments) / (2 * segments)
    above = ratio > limit
    bands = []
    edges = np.flatnonzero(np.diff(np.concatenate(([0], above.astype(int), [0]))))
    for start, stop in zip(edges[::2], edges[1::2]):
        bands.append((float(frequency[start]), float(frequency[stop - 1]), float(ratio[start:stop].max())))
    return bands


def _coherent_inputs(signals, output, excited, fs) -> list:
    """Inputs the residual of ``output`` is coherent with (magnitude-squared coherence,
    Welch-averaged, scipy.signal.coherence). Under independence and K segments the estimate's
    null distribution gives ``P(C > c) = (1 - c)^(K-1)`` (Carter, Proc. IEEE 75(2), 1987); the
    threshold is its ``LOCATE_ALPHA``-quantile. Only bins where the input carries at least 1 %
    of its peak power count. ``signals`` holds ``(inputs, residuals)`` per diagnosed recording,
    dicts of name -> ndarray (m,) on one even grid of rate ``fs`` Hz (:func:`_on_nominal_grid`).
    Returns ``[{"input", "coherence", "frequency"}]`` above threshold."""
    found = []
    for name in excited:
        best = (0.0, 0.0)
        for inputs, residuals in signals:
            u = inputs[name]
            if np.ptp(u) <= EXCITATION_THRESHOLD:
                continue
            residual = residuals[output]
            nperseg = _welch_segment(len(u), fs)
            with np.errstate(invalid="ignore", divide="ignore"):  # segments where u is constant
                frequency, coherence = signal.coherence(u, residual, fs=fs, nperseg=nperseg)
            coherence = np.nan_to_num(coherence)
            _, power = signal.welch(u, fs=fs, nperseg=nperseg)
            segments = max(2, 2 * len(u) // nperseg - 1)
            limit = 1 - LOCATE_ALPHA ** (1 / (segments - 1))
            useful = (power >= 0.01 * power.max()) & (frequency > 0)  # not the mean (bias, drift)
            if useful.any():
                k = int(np.argmax(np.where(useful, coherence, 0.0)))
                if coherence[k] > limit and coherence[k] > best[0]:
                    best = (float(coherence[k]), float(frequency[k]))
        if best[0] > 0:
            found.append({"input": name, "coherence": round(best[0], 3), "frequency": round(best[1], 3)})
    return sorted(found, key=lambda item: -item["coherence"])
