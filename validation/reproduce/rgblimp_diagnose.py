"""``flightgp reproduce rgblimp-diagnose``: ``flightgp diagnose --reference rgblimp`` on real
flights of several configurations, its findings replicated across two folds, and the corrected
model scored as the source scores its models (docs/rgblimp.md, "Diagnosis").

For each chosen configuration with at least two flights present, every flight but the
highest-numbered is diagnosed and that one is held out (on the shared folder of flights
``4j+1 .. 4j+3``: diagnose ``4j+1`` and ``4j+2``, hold out ``4j+3``). The diagnosed flights are
ordered by configuration, so the two folds of :mod:`validation.diagnose.replicate` are the first
and the second flight of every configuration: two repeats of the same inputs. Each held-out
flight is then free-run from its first recorded state by the published model, the corrected
model (the named effects) and the corrected model plus diagnose's residual GPs, and scored with
:func:`validation.reproduce.rgblimp.flight_metrics` (the source's score and position RMSE).
"""
from __future__ import annotations

import time as clock
from pathlib import Path

import numpy as np

from validation.core.errors import BadInputError
from validation.core.files import json_text, write_files_atomically
from validation.core.progress import progress_bar
from validation.diagnose import diagnose, diagnosis_files
from validation.reproduce.rgblimp import flight_metrics, read_score_ranges, split_flights
from validation.vehicles.rgblimp import RGBlimpReference
from validation.vehicles.rgblimp_data import read_rgblimp_flight
from validation.vehicles.rgblimp_equations import STATE_NAMES

#: Configurations diagnosed by default: eight spread over the 35 (spirals 0-29 with the gondola
#: moved and both thrust settings, straight flights 30-34), those of the settings study
#: (docs/rgblimp.md, "Identification and RKGP").
DEFAULT_CONFIGURATIONS = (0, 6, 12, 18, 24, 27, 30, 33)
#: Folds of the replication: the two repeat flights of each configuration.
FOLDS = 2
#: The goal: the corrected model's mean held-out score at least this many times lower than the
#: published model's.
GOAL_SCORE_FACTOR = 2.0
#: The models scored on each held-out flight.
SCORED = ("physics", "corrected", "corrected_gp")


def reproduce_rgblimp_diagnose(data_dir, out_dir, *, configurations=DEFAULT_CONFIGURATIONS, seed: int = 0,
                               progress: bool = True) -> dict:
    """Diagnose, replicate and score (module docstring); writes ``out_dir/results.json``,
    ``out_dir/report.md`` and the diagnosis in ``out_dir/diagnosis/`` (all at once).

    Parameters
    ----------
    data_dir : path
        The source's ``data_N.csv`` (any subset) and ``data_info/``.
    out_dir : path
    configurations : sequence of int
        Each needs two flights present; :data:`DEFAULT_CONFIGURATIONS` by default.
    seed : int
        Seed of diagnose's residual GPs.
    progress : bool
        A progress bar over the diagnosis' fits.

    Returns
    -------
    dict
        ``results.json``: ``configurations`` (index, diagnosed and held-out files), ``findings``
        (diagnose's, with their replication), ``flights`` (per held-out flight: ``score`` and
        ``position_rmse_m`` of each of :data:`SCORED`), ``summary`` (means and the ratio of
        the published model's mean score to the corrected model's), ``goal`` and ``seconds``.

    Raises
    ------
    BadInputError
        As :func:`validation.reproduce.rgblimp.split_flights` and
        :func:`validation.diagnose.diagnose`; fewer than two configurations' flights to fold.
    """
    started = clock.perf_counter()
    data_dir = Path(data_dir)
    splits = split_flights(data_dir, configurations=configurations)
    ranges = read_score_ranges(data_dir)
    diagnosed = [data_dir / f"data_{n}.csv" for split in splits for n in split.fit]
    held_out = [data_dir / f"data_{split.test}.csv" for split in splits]
    if len(diagnosed) < FOLDS:
        raise BadInputError(f"{len(diagnosed)} diagnosed flight(s); the replication needs {FOLDS}")
    with progress_bar("diagnose rgblimp", enabled=progress, unit="fit") as update:
        diagnosis = diagnose(diagnosed, reference="rgblimp", holdout=held_out, seed=seed, folds=FOLDS,
                             progress=update)
    held_out_recordings = [read_rgblimp_flight(p).recording for p in held_out]
    with_gp = _corrected_gp_states(diagnosis, held_out_recordings)
    flights = []
    for split, path, recording, gp_states in zip(splits, held_out, held_out_recordings, with_gp):
        predicted = {"physics": RGBlimpReference().simulate_states(recording.time, recording.inputs,
                                                                   initial_state=recording.outputs[0]),
                     "corrected": diagnosis.corrected.replay_states(recording),
                     "corrected_gp": gp_states}
        metrics = {name: flight_metrics(states, recording.outputs, ranges[split.kind])
                   for name, states in predicted.items()}
        flights.append({"configuration": split.configuration, "test": path.name,
                        **{key: {name: metrics[name][key] for name in SCORED}
                           for key in ("score", "position_rmse_m", "final_position_error_m", "yaw_rmse_rad")}})
    results = {"configurations": [{"index": s.configuration, "diagnosed": [f"data_{n}.csv" for n in s.fit],
                                   "held_out": f"data_{s.test}.csv"} for s in splits],
               "findings": diagnosis.as_dict()["findings"], "flights": flights,
               "summary": _summary(flights), "seconds": clock.perf_counter() - started}
    results["goal"] = {"score_factor": GOAL_SCORE_FACTOR,
                       "met": bool(results["summary"]["score_ratio_physics_to_corrected"] >= GOAL_SCORE_FACTOR)}
    out_dir = Path(out_dir)
    files = diagnosis_files(diagnosis, out_dir / "diagnosis")
    files[out_dir / "results.json"] = json_text(results)
    files[out_dir / "report.md"] = format_results(results)
    write_files_atomically(files)
    return results


def _corrected_gp_states(diagnosis, recordings) -> list[np.ndarray]:
    """Per held-out recording, the corrected model plus residual GPs (diagnose's held-out
    traces, concatenated over the held-out recordings in order, split back), shape (n_r, 12)."""
    traces = diagnosis.holdout_traces
    stacked = np.column_stack([traces[name]["corrected_gp"] for name in STATE_NAMES])
    edges = np.cumsum([len(r.time) for r in recordings])[:-1]
    return np.split(stacked, edges)


def _summary(flights: list[dict]) -> dict:
    """Means over the held-out flights and the score ratios."""
    mean = {key: {name: float(np.mean([f[key][name] for f in flights])) for name in SCORED}
            for key in ("score", "position_rmse_m")}
    return {"mean_score": mean["score"], "mean_position_rmse_m": mean["position_rmse_m"],
            "score_ratio_physics_to_corrected": mean["score"]["physics"] / mean["score"]["corrected"],
            "score_ratio_physics_to_corrected_gp": mean["score"]["physics"] / mean["score"]["corrected_gp"],
            "corrected_better_flights": sum(f["score"]["corrected"] < f["score"]["physics"] for f in flights)}


def format_results(results: dict) -> str:
    """``report.md``: the findings with their replication, then the held-out scores."""
    summary = results["summary"]
    lines = ["# RGBlimp diagnosis on real flights", "",
             "Diagnosed: " + ", ".join(f for c in results["configurations"] for f in c["diagnosed"]) + "; held out: "
             + ", ".join(c["held_out"] for c in results["configurations"]) + ".", "", "## Findings", ""]
    lines += [f"- {finding['statement']}" for finding in results["findings"]] or ["- none"]
    lines += ["", "## Held-out free runs (the source's score; position RMSE, m)", "",
              "| flight | physics | corrected | corrected + GP |", "|---|---|---|---|"]
    for flight in results["flights"]:
        lines.append(f"| {flight['test']} | " + " | ".join(
            f"{flight['score'][n]:.4g}; {flight['position_rmse_m'][n]:.3f}" for n in SCORED) + " |")
    lines.append("| mean | " + " | ".join(f"{summary['mean_score'][n]:.4g}; {summary['mean_position_rmse_m'][n]:.3f}"
                                          for n in SCORED) + " |")
    verdict = "met" if results["goal"]["met"] else "missed"
    lines += ["", f"Published model / corrected model, mean score: {summary['score_ratio_physics_to_corrected']:.2f}x "
              f"(goal {results['goal']['score_factor']:g}x: {verdict}); with the residual GPs "
              f"{summary['score_ratio_physics_to_corrected_gp']:.2f}x. The corrected model beats the published "
              f"one on {summary['corrected_better_flights']} of {len(results['flights'])} held-out flights.", ""]
    return "\n".join(lines)
