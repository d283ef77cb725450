"""``flightgp reproduce rgblimp-diagnose``: ``flightgp diagnose --reference rgblimp`` on real
flights of several configurations, its corrections chosen on validation flights and tested on
flights the diagnosis never sees, scored as the source scores its models (docs/rgblimp.md,
"Diagnosis").

Three flights per chosen configuration, the lowest-numbered three present (on the shared folder
of flights ``4j+1 .. 4j+3``): the first is diagnosed, the second is the diagnosis' held-out
flight, which decides which findings carry over and so enter the corrected model
(:mod:`validation.diagnose.carry_over`: a validation flight), and the third is the test flight.

Each configuration is diagnosed on its own by default (a configuration is a set-up of the
vehicle: the gondola's position and the thrust), the diagnoses side by side in ``workers``
processes; ``pooled=True`` diagnoses every chosen configuration's flight at once instead (the
vehicle-level question: one correction for every set-up). Each test flight is then free-run
from its first recorded state by the published model, the model with every named effect and
the corrected model of its diagnosis, and scored with
:func:`validation.reproduce.rgblimp.flight_metrics` (the source's score and position RMSE). The
residual GPs of the diagnosis are not scored here: they model the diagnosed flights' residual
and are not carried to other flights.
"""
from __future__ import annotations

import multiprocessing
import os
import sys
import time as clock
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from validation.core.errors import BadInputError
from validation.core.files import json_text, write_files_atomically
from validation.core.progress import progress_bar
from validation.diagnose import diagnose, diagnosis_files
from validation.diagnose.pipeline import stage_count
from validation.reproduce.rgblimp import flight_metrics, read_score_ranges, split_flights
from validation.vehicles.effect_vehicle import EffectVehicle
from validation.vehicles.fmu_reference import available_cores
from validation.vehicles.rgblimp import RGBlimpReference
from validation.vehicles.rgblimp_data import read_rgblimp_flight

#: Configurations diagnosed by default: eight spread over the 35 (spirals 0-29 with the gondola
#: moved and both thrust settings, straight flights 30-34), those of the settings study
#: (docs/rgblimp.md, "Identification and RKGP").
DEFAULT_CONFIGURATIONS = (0, 6, 12, 18, 24, 27, 30, 33)
#: The goal: the corrected model's score on a test flight at least this many times lower than the
#: published model's, on at least :data:`GOAL_FLIGHTS` of the default eight, and a lower mean
#: position RMSE.
GOAL_SCORE_FACTOR, GOAL_FLIGHTS = 1.5, 6
#: The models scored on each test flight.
SCORED = ("physics", "all_named", "corrected")


def reproduce_rgblimp_diagnose(data_dir, out_dir, *, configurations=DEFAULT_CONFIGURATIONS, seed: int = 0,
                               pooled: bool = False, workers: int | None = None, progress: bool = True,
                               figures: bool = True) -> dict:
    """Diagnose, validate and test (module docstring); writes ``out_dir/results.json``,
    ``out_dir/report.md`` and each diagnosis in ``out_dir/diagnosis/`` (``configuration_<j>/``
    per configuration; the pooled one in ``diagnosis/`` itself), all at once.

    Parameters
    ----------
    data_dir : path
        The source's ``data_N.csv`` (any subset) and ``data_info/``.
    out_dir : path
    configurations : sequence of int
        Each needs three flights present; :data:`DEFAULT_CONFIGURATIONS` by default.
    seed : int
        Seed of diagnose's residual GPs.
    pooled : bool
        One diagnosis of every configuration's flight at once instead of one per configuration.
    workers : int, optional
        Processes that diagnose configurations side by side (default: the cores this process may
        use, at most the number of configurations; 1 runs them here).
    progress : bool
        A progress bar over the configurations (over the diagnosis' stages when pooled).
    figures : bool
        Each diagnosis' PNGs of its held-out flight (without: none, and its report names none).

    Returns
    -------
    dict
        ``results.json``: ``configurations`` (index, diagnosed, validation and test files),
        ``diagnoses`` (per diagnosis: its ``configurations``, ``folder`` and ``findings``),
        ``flights`` (per test flight: ``score`` and ``position_rmse_m`` of each of
        :data:`SCORED`), ``summary`` (means, the ratio of the published model's mean score to the
        corrected model's, and the flights where the corrected model's score is
        :data:`GOAL_SCORE_FACTOR` times lower), ``goal``, ``pooled`` and ``seconds``.

    Raises
    ------
    BadInputError
        As :func:`validation.reproduce.rgblimp.split_flights` and
        :func:`validation.diagnose.diagnose`; a chosen configuration with fewer than three flights.
    """
    started = clock.perf_counter()
    data_dir, out_dir = Path(data_dir), Path(out_dir)
    splits = split_flights(data_dir, configurations=configurations)
    short = [split.configuration for split in splits if len(split.fit) < 2]
    if short:
        raise BadInputError(f"{data_dir}: configuration(s) {', '.join(map(str, short))} have fewer than three flights; "
                            "the diagnosis needs one to diagnose, one to validate and one to test")
    ranges = read_score_ranges(data_dir)
    groups = [splits] if pooled else [[split] for split in splits]
    folders = [out_dir / "diagnosis"] if pooled else [out_dir / "diagnosis" / f"configuration_{split.configuration}"
                                                      for split in splits]
    jobs = [([data_dir / f"data_{s.fit[0]}.csv" for s in group], [data_dir / f"data_{s.fit[1]}.csv" for s in group],
             folder, seed) for group, folder in zip(groups, folders)]
    workers = min(workers or available_cores(), len(jobs))
    with progress_bar("diagnose rgblimp", enabled=progress, total=stage_count() if pooled else len(jobs),
                      unit="stage" if pooled else "configuration") as update:
        if pooled or workers == 1:
            outcomes = []
            for job in jobs:
                outcomes.append(_diagnose(*job, figures=figures, progress=update if pooled else None))
                if update and not pooled:
                    update(1)
        else:
            with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
                outcomes = []
                for outcome in pool.map(_diagnose, *zip(*jobs), [True] * len(jobs), [figures] * len(jobs)):
                    outcomes.append(outcome)
                    if update:
                        update(1)
    files, diagnoses, flights = {}, [], []
    for group, folder, (diagnosis, named, corrected, written) in zip(groups, folders, outcomes):
        files.update(written)
        diagnoses.append({"configurations": [s.configuration for s in group],
                          "folder": str(folder.relative_to(out_dir)), "findings": diagnosis["findings"]})
        for split in group:
            flights.append(_test_flight(data_dir / f"data_{split.test}.csv", split, ranges,
                                        EffectVehicle("rgblimp", named), EffectVehicle("rgblimp", corrected)))
    results = {"configurations": [{"index": s.configuration, "diagnosed": f"data_{s.fit[0]}.csv",
                                   "validation": f"data_{s.fit[1]}.csv", "test": f"data_{s.test}.csv"}
                                  for s in splits],
               "pooled": pooled, "diagnoses": diagnoses, "flights": flights,
               "summary": _summary(flights), "seconds": clock.perf_counter() - started}
    summary = results["summary"]
    results["goal"] = {"score_factor": GOAL_SCORE_FACTOR, "flights": GOAL_FLIGHTS,
                       "met": bool(summary["corrected_factor_flights"] >= GOAL_FLIGHTS
                                   and summary["mean_position_rmse_m"]["corrected"]
                                   < summary["mean_position_rmse_m"]["physics"])}
    files[out_dir / "results.json"] = json_text(results)
    files[out_dir / "report.md"] = format_results(results)
    write_files_atomically(files)
    return results


def _diagnose(diagnosed, validation, folder, seed, one_thread=False, figures=True, *, progress=None) -> tuple:
    """One diagnosis (in this process or a worker): diagnosis.json's content, every named effect,
    the corrected model's effects and the diagnosis' files under ``folder`` (its PNGs with
    ``figures``). ``one_thread``: a worker beside others, one BLAS and one XLA thread (threads of
    several workers fight over the cores)."""
    if not one_thread:
        diagnosis = diagnose(diagnosed, reference="rgblimp", holdout=validation, seed=seed, progress=progress)
    else:
        from threadpoolctl import threadpool_limits

        if "jax" not in sys.modules:  # read when JAX starts
            os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false "
                                       "intra_op_parallelism_threads=1").strip()
        with threadpool_limits(1):
            diagnosis = diagnose(diagnosed, reference="rgblimp", holdout=validation, seed=seed)
    return (diagnosis.as_dict(), diagnosis.named_effects, diagnosis.corrected.effects,
            diagnosis_files(diagnosis, folder, figures=figures))


def _test_flight(path: Path, split, ranges: dict, all_named: EffectVehicle, corrected: EffectVehicle) -> dict:
    """The test flight's free runs of :data:`SCORED`, scored as the source scores."""
    recording = read_rgblimp_flight(path).recording
    predicted = {"physics": RGBlimpReference().simulate_states(recording.time, recording.inputs,
                                                               initial_state=recording.outputs[0]),
                 "all_named": all_named.replay_states(recording),
                 "corrected": corrected.replay_states(recording)}
    metrics = {name: flight_metrics(states, recording.outputs, ranges[split.kind])
               for name, states in predicted.items()}
    return {"configuration": split.configuration, "test": path.name,
            **{key: {name: metrics[name][key] for name in SCORED}
               for key in ("score", "position_rmse_m", "final_position_error_m", "yaw_rmse_rad")}}


def _summary(flights: list[dict]) -> dict:
    """Means over the test flights, the score ratio and the flights that meet the goal's factor."""
    mean = {key: {name: float(np.mean([f[key][name] for f in flights])) for name in SCORED}
            for key in ("score", "position_rmse_m")}
    return {"mean_score": mean["score"], "mean_position_rmse_m": mean["position_rmse_m"],
            "score_ratio_physics_to_corrected": mean["score"]["physics"] / mean["score"]["corrected"],
            "corrected_better_flights": sum(f["score"]["corrected"] < f["score"]["physics"] for f in flights),
            "corrected_factor_flights": sum(GOAL_SCORE_FACTOR * f["score"]["corrected"] <= f["score"]["physics"]
                                            for f in flights)}


def format_results(results: dict) -> str:
    """``report.md``: the findings, then the test flights' scores."""
    summary = results["summary"]
    configurations = results["configurations"]
    lines = ["# RGBlimp diagnosis on real flights", "",
             "Diagnosed: " + ", ".join(c["diagnosed"] for c in configurations) + "; validation (held out by the "
             "diagnosis, choosing what carries over): " + ", ".join(c["validation"] for c in configurations)
             + "; test (never seen by the diagnosis): " + ", ".join(c["test"] for c in configurations) + ".", "",
             "## Findings", ""]
    for diagnosis in results["diagnoses"]:
        lines += [f"### Configuration{'s' if len(diagnosis['configurations']) > 1 else ''} "
                  f"{', '.join(map(str, diagnosis['configurations']))} ({diagnosis['folder']}/)", ""]
        lines += [f"- {finding['statement']}" for finding in diagnosis["findings"]] or ["- none"]
        lines.append("")
    lines += ["", "## Test flights (the source's score; position RMSE, m)", "",
              "| flight | published model | every named effect | corrected |", "|---|---|---|---|"]
    for flight in results["flights"]:
        lines.append(f"| {flight['test']} | " + " | ".join(
            f"{flight['score'][n]:.4g}; {flight['position_rmse_m'][n]:.3f}" for n in SCORED) + " |")
    lines.append("| mean | " + " | ".join(f"{summary['mean_score'][n]:.4g}; {summary['mean_position_rmse_m'][n]:.3f}"
                                          for n in SCORED) + " |")
    goal = results["goal"]
    lines += ["", f"Published model / corrected model, mean score: {summary['score_ratio_physics_to_corrected']:.2f}x. "
              f"The corrected model beats the published one on {summary['corrected_better_flights']} of "
              f"{len(results['flights'])} test flights, by {goal['score_factor']:g}x or more on "
              f"{summary['corrected_factor_flights']} (goal: {goal['flights']}, and a lower mean position RMSE: "
              f"{'met' if goal['met'] else 'missed'}).", ""]
    return "\n".join(lines)
