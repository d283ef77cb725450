"""The fidelity scorecard: per output and model, on the held-out samples, the figures simulator
qualification speaks in (diagnosis.json's ``fidelity``, docs/diagnose.md, "fidelity").

- **RMSE** and **Theil's inequality coefficient** U (0 a perfect match, 1 no skill; Theil,
  *Applied Economic Forecasting*, 1966), as diagnosis.json's ``fit`` has them;
- **tolerance bands**: the largest error against the output's band and the share of samples
  inside it; an output *passes* when every held-out sample is inside. The default bands are the
  time-history tolerances of the helicopter full flight simulator objective tests, 14 CFR
  Part 60, Appendix C, Table C2A (14 CFR Ch. I, 1-1-19 edition) (:data:`DEFAULT_TOLERANCES`):
  test 2.c.3.b (longitudinal short-term response: +-1.5 deg pitch or +-2 deg/s pitch rate),
  2.d.3.a (lateral-directional oscillations, non-periodic responses: +-5 deg/s roll rate or
  +-5 deg roll attitude, +-4 deg/s yaw rate or +-4 deg yaw angle) and 2.c.3.a (long-term
  response: +-5 kt airspeed, applied here to the forward velocity ``u``). Other outputs have no
  default band; a tolerance file names any output's (``--tolerances``);
- **frequency-domain mismatch**: Tischler's cost ``J = (20 / n) sum W_coh [W_g (|T_m| - |T|)^2 +
  W_p (phase_m - phase)^2]`` between the frequency response of the model (``T_m``) and of the
  recording (``T``) from the input most coherent with the output, over the ``n`` = 20
  log-spaced frequencies of the band where the recording's coherence is at least 0.6, magnitude
  in dB and phase in deg, ``W_g = 1``, ``W_p = 0.01745`` and ``W_coh = (1.58 (1 - exp(-coh^2)))^2``
  (Tischler & Remple, *Aircraft and Rotorcraft System Identification*, 2nd ed., 2012, ch. 11,
  where J <= 100 counts as an acceptable and J <= 50 as a nearly indistinguishable model).
  Responses are H1 estimates, cross over auto spectral density (Welch's method, 2 s Hann
  segments, half overlapping). None where no input moves in the held-out data or the coherence
  never reaches 0.6;
- **the RGBlimp's flight score** (``pose``, the RGBlimp reference only): the source's score
  of a free run (:func:`validation.vehicles.rgblimp_data.source_score`; Zhu, Cheng & Zhang 2024)
  and the RMS 3-D position error of each model over the held-out samples, the figures the
  source and flightgp's reproductions report. The source normalises each pose column by its
  range over every flight of the kind (its ``data_info`` files), which a user's own flights do
  not come with; here the range is that of the held-out samples, so the scores rank the models
  on these flights but are not the source's numbers (``flightgp reproduce rgblimp-diagnose``
  scores with the source's ranges).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy import signal

from validation.core.errors import BadInputError, unknown_name_message
from validation.core.files import read_document
from validation.core.recordings import column_unit
from validation.diagnose.prove import MODEL_KEYS
from validation.vehicles.rgblimp_data import source_score

#: Where the default bands come from.
TOLERANCE_SOURCE = "14 CFR Part 60, Appendix C, Table C2A (1-1-19 edition)"
#: The units a band may be stated in, each as (the SI unit of the outputs it measures, its size in
#: that unit): the units Table C2A states its bands in (deg, deg/s, kt; fpm and ft for vertical
#: velocity and altitude), other common ones, and the SI units themselves (docs/conventions.md,
#: "Units and axes"). 1 kt = 1852 m / 3600 s and 1 ft = 0.3048 m exactly (international
#: nautical mile and foot).
STATED_UNITS = {
    "deg": ("rad", math.pi / 180.0), "rad": ("rad", 1.0),
    "deg/s": ("rad/s", math.pi / 180.0), "rad/s": ("rad/s", 1.0),
    "kt": ("m/s", 1852.0 / 3600.0), "ft/s": ("m/s", 0.3048), "fpm": ("m/s", 0.3048 / 60.0), "m/s": ("m/s", 1.0),
    "ft": ("m", 0.3048), "m": ("m", 1.0),
}


class Band(NamedTuple):
    """A tolerance band: ``half_width`` in the output's SI unit (docs/conventions.md, "Units and
    axes"), where it comes from (``source``, e.g. the table's test) and, where its source states
    it in another unit, the band as stated (``as_stated``, e.g. ``"2 deg/s"``; None when given in
    SI)."""

    half_width: float
    source: str
    as_stated: str | None = None


def _stated(value: float, unit: str, test: str, what: str) -> Band:
    """The band of Table C2A's ``test``, stated there as +-``value`` ``unit`` of ``what``."""
    return Band(value * STATED_UNITS[unit][1], f"{test}: +-{value:g} {unit} {what}", f"{value:g} {unit}")


#: Default tolerance bands, output -> :class:`Band` (half-width in SI, computed from the table's
#: deg, deg/s and kt).
DEFAULT_TOLERANCES = {
    "q": _stated(2.0, "deg/s", "2.c.3.b", "pitch rate"),
    "theta": _stated(1.5, "deg", "2.c.3.b", "pitch"),
    "p": _stated(5.0, "deg/s", "2.d.3.a", "roll rate"),
    "phi": _stated(5.0, "deg", "2.d.3.a", "roll attitude"),
    "r": _stated(4.0, "deg/s", "2.d.3.a", "yaw rate"),
    "psi": _stated(4.0, "deg", "2.d.3.a", "yaw angle"),
    "u": _stated(5.0, "kt", "2.c.3.a", "airspeed"),
}
#: Tischler's cost: frequency points, weights and the coherence a point needs (Tischler &
#: Remple 2012, ch. 11).
N_FREQUENCIES = 20
MAGNITUDE_WEIGHT, PHASE_WEIGHT = 1.0, 0.01745
MIN_COHERENCE = 0.6
#: Welch segment length, s: 2 s gives about 19 half-overlapping segments in 20 s, so the coherence
#: of noise alone stays far below 0.6 (its estimate is biased upward when few segments are averaged).
SEGMENT_SECONDS = 2.0


def read_tolerances(path) -> dict:
    """A tolerance file: JSON ``{"q": 0.03, ...}``, half-widths in each output's SI unit
    (docs/conventions.md, "Units and axes"), as output -> :class:`Band`; BadInputError for a
    missing or malformed file or a band that is not a positive number."""
    path = Path(path)
    content = read_document(path, what="tolerance file")
    if not isinstance(content, dict):
        raise BadInputError(f"{path}: a tolerance file maps outputs to band half-widths, e.g. {{\"q\": 0.035}}")
    for name, value in content.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            raise BadInputError(f"{path}: the band of {name!r} must be a positive number in {column_unit(name)}, "
                                f"got {value!r}")
    return {name: Band(float(value), path.name) for name, value in content.items()}


def check_tolerance_outputs(tolerances: dict | None, output_names) -> None:
    """Refuse a tolerance file's output that the diagnosed recordings do not hold (it would be
    dropped while the report credits the file), naming the nearest output they do hold.

    Parameters
    ----------
    tolerances : dict or None
        Output -> :class:`Band`, as :func:`read_tolerances` returns.
    output_names : sequence of str
        The outputs diagnosed.
    """
    for name, band in (tolerances or {}).items():
        if name not in output_names:
            raise BadInputError(f"{band.source}: {unknown_name_message(name, output_names, what='output')} "
                                "(the outputs of the diagnosed recordings)")


#: The pose outputs the RGBlimp's flight score weighs, in its order.
POSE_OUTPUTS = ("x", "y", "z", "phi", "theta", "psi")


def scorecard(traces: dict, fit: dict, holdout_inputs: list, *, step: float, tolerances: dict | None = None,
              pose_score: bool = False) -> dict:
    """diagnosis.json's ``fidelity`` (module docstring).

    Parameters
    ----------
    traces : dict
        Per output the held-out ``measured`` and model traces (:class:`validation.diagnose.prove.Proof`).
    fit : dict
        diagnosis.json's ``fit`` (RMSE and Theil's U per model).
    holdout_inputs : list of (ndarray (n_r, n_inputs), ndarray bool (n_r,), tuple of str)
        Per held-out recording: its inputs, its held-out mask and the input names.
    step : float
        Sample interval, s.
    tolerances : dict, optional
        Output -> :class:`Band`; default :data:`DEFAULT_TOLERANCES`; outputs a file does not
        name keep their default.
    pose_score : bool
        Add the RGBlimp's flight score (:func:`pose_scores`), where the traces hold the pose.

    Returns
    -------
    dict
        ``tolerance_source`` and ``outputs``: per output ``tolerance`` (half-width in SI or
        None), ``tolerance_source``, ``tolerance_as_stated`` (the band in its source's unit, e.g.
        ``"2 deg/s"``; None when given in SI or without a band) and, per model (``reference``,
        ``corrected``, ``corrected_gp``), ``rmse``, ``theil``, ``max_error``, ``inside_share``
        and ``passes`` (None without a band) and ``frequency_cost`` (None without a coherent
        input), plus the ``input`` the frequency responses are taken from; with ``pose_score``,
        ``pose`` (:func:`pose_scores`).
    """
    bands = {**DEFAULT_TOLERANCES, **(tolerances or {})}
    outputs = {}
    for name, trace in traces.items():
        band = bands.get(name)
        entry = {"tolerance": band.half_width if band else None, "tolerance_source": band.source if band else None,
                 "tolerance_as_stated": band.as_stated if band else None}
        input_name, responses = _frequency_costs(trace, holdout_inputs, step)
        entry["frequency_input"] = input_name
        for key in MODEL_KEYS:
            error = np.abs(trace[key] - trace["measured"])
            inside = float(np.mean(error <= band.half_width)) if band else None
            entry[key] = {"rmse": fit[f"rmse_{key}"][name], "theil": fit[f"theil_{key}"][name],
                          "max_error": float(np.max(error)), "inside_share": inside,
                          "passes": (inside == 1.0) if band else None, "frequency_cost": responses.get(key)}
        outputs[name] = entry
    card = {"tolerance_source": TOLERANCE_SOURCE if tolerances is None else "tolerance file and " + TOLERANCE_SOURCE,
            "outputs": outputs}
    pose = pose_scores(traces) if pose_score else None
    if pose is not None:
        card["pose"] = pose
    return card


def pose_scores(traces: dict) -> dict | None:
    """The RGBlimp's flight score of every model on the held-out samples (module docstring).

    Parameters
    ----------
    traces : dict
        As for :func:`scorecard`; the six :data:`POSE_OUTPUTS` in m and rad.

    Returns
    -------
    dict or None
        ``ranges`` (pose output -> its range over the held-out samples, m or rad),
        ``ranges_from`` (in words) and per model (``reference``, ``corrected``,
        ``corrected_gp``) ``score`` and ``position_rmse_m``; None where the traces lack a pose
        output or one does not move.
    """
    if not all(name in traces for name in POSE_OUTPUTS):
        return None
    measured = np.column_stack([traces[name]["measured"] for name in POSE_OUTPUTS])
    ranges = np.ptp(measured, axis=0)
    if not np.all(ranges > 0):
        return None
    result = {"ranges": {name: float(r) for name, r in zip(POSE_OUTPUTS, ranges)},
              "ranges_from": "the held-out samples (the source takes every flight of the kind)"}
    for key in MODEL_KEYS:
        predicted = np.column_stack([traces[name][key] for name in POSE_OUTPUTS])
        distance = np.linalg.norm(predicted[:, :3] - measured[:, :3], axis=1)
        result[key] = {"score": source_score(predicted, measured, ranges),
                       "position_rmse_m": float(np.sqrt(np.mean(distance**2)))}
    return result


def _frequency_costs(trace: dict, holdout_inputs: list, step: float) -> tuple[str | None, dict]:
    """:func:`frequency_costs` on the held-out samples of every recording, end to end."""
    if not holdout_inputs:
        return None, {}
    inputs = np.concatenate([inputs[mask] for inputs, mask, _ in holdout_inputs])
    return frequency_costs(inputs, holdout_inputs[0][2], trace["measured"],
                           {key: trace[key] for key in MODEL_KEYS}, step=step)


def frequency_costs(inputs: np.ndarray, input_names, measured: np.ndarray, models: dict, *,
                    step: float) -> tuple[str | None, dict]:
    """Tischler's frequency-domain cost J of each model's output against the measured one (module
    docstring), from the input most coherent with the measurement.

    Parameters
    ----------
    inputs : ndarray, shape (n, n_inputs)
        The inputs, evenly sampled every ``step`` s, in their own units.
    input_names : sequence of str, length n_inputs
    measured : ndarray, shape (n,)
        The measured output, in its SI unit.
    models : dict of str -> ndarray, shape (n,)
        Each model's output at the same samples.
    step : float
        Sample interval, s.

    Returns
    -------
    input_name : str or None
        The input the responses are taken from (None when no input moves).
    costs : dict of str -> float
        J per model (dimensionless; J <= 100 acceptable, J <= 50 nearly indistinguishable);
        empty when no input moves or the coherence never reaches :data:`MIN_COHERENCE` over two
        frequencies.
    """
    best = (None, None, -1.0)
    for column in range(inputs.shape[1]):
        x = inputs[:, column]
        if np.ptp(x) <= 0:
            continue
        frequencies, coherence = _spectra(x, measured, step)[::2]
        score = float(np.mean(coherence[1:])) if len(coherence) > 1 else 0.0
        if score > best[2]:
            best = (input_names[column], column, score)
    if best[1] is None:
        return None, {}
    x = inputs[:, best[1]]
    frequencies, response, coherence = _spectra(x, measured, step)
    band = frequencies[(coherence >= MIN_COHERENCE) & (frequencies > 0)]
    if len(band) < 2:
        return best[0], {}
    points = np.geomspace(band.min(), band.max(), N_FREQUENCIES)
    measured_response = _at(frequencies, response, points)
    weight = (1.58 * (1 - np.exp(-np.interp(points, frequencies, coherence) ** 2))) ** 2
    costs = {}
    for key, predicted in models.items():
        ratio = _at(frequencies, _spectra(x, predicted, step)[1], points) / measured_response
        magnitude_error = 20 * np.log10(np.maximum(np.abs(ratio), 1e-300))  # dB
        phase_error = np.degrees(np.angle(ratio))  # deg, within +-180
        costs[key] = float(20.0 / N_FREQUENCIES * np.sum(
            weight * (MAGNITUDE_WEIGHT * magnitude_error**2 + PHASE_WEIGHT * phase_error**2)))
    return best[0], costs


def _spectra(x: np.ndarray, y: np.ndarray, step: float):
    """Frequencies (Hz), the H1 response ``G_xy / G_xx`` and the coherence of y with x."""
    segment = int(min(len(x), max(16, round(SEGMENT_SECONDS / step))))
    frequencies, pxx = signal.welch(x, fs=1.0 / step, nperseg=segment)
    _, pxy = signal.csd(x, y, fs=1.0 / step, nperseg=segment)
    with np.errstate(divide="ignore", invalid="ignore"):  # a flat output has no coherence: 0
        _, coherence = signal.coherence(x, y, fs=1.0 / step, nperseg=segment)
        response = np.where(pxx > 0, pxy / pxx, 0.0)
    return frequencies, response, np.nan_to_num(coherence)


def _at(frequencies: np.ndarray, response: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The complex ``response`` interpolated (real and imaginary parts) at ``points``, Hz; the
    cost compares model and measurement by their ratio, so that phases never differ by a
    whole turn."""
    return np.interp(points, frequencies, response.real) + 1j * np.interp(points, frequencies, response.imag)
