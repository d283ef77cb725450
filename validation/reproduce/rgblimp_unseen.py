"""A configuration never flown: the rollout-trained hybrid of the whole vehicle, fitted without a
configuration's flights, predicting that configuration's test flight (``flightgp reproduce
rgblimp-unseen``; docs/rgblimp.md, "A configuration never flown").

This is the question a user of the RGBlimp asks with a new gondola position or thrust setting:
how well does the model fly a configuration it has no recording of? The configurations are
dealt into ``folds`` folds (configuration ``c`` of the list into fold ``i mod folds``, so every
fold holds spiral and straight configurations). For each fold, with its configurations' flights
unread:

- **vehicle physics**: the coefficients identified on every other configuration's fitting
  flights at once (:func:`validation.reproduce.rgblimp.fit_global` without its RKGP);
- **vehicle hybrid**: one sparse-GP correction AND one set of refined coefficients shared by every
  other configuration, fitted through their free runs
  (:func:`~validation.models.rgblimp_rollout.fit_rollout_global` with ``shared_physics``): its
  inputs include both thrusts and the gondola position, so it can be run on the held-out ones.

Each held-out configuration's test flight (the same split as ``reproduce rgblimp``: fit on all but
the highest-numbered flight present, test on that one) is then free-run by both, and by the
configuration's own identified model (which did see its fitting flights: the bar the issue sets,
higher than an unseen model can be expected to clear). With 35 folds this is
leave-one-configuration-out; fewer folds leave more out and are stricter (the default, 5, leaves
7 configurations out at a time, and costs 5 global fits instead of 35).
"""
from __future__ import annotations

import dataclasses
import time as clock
from pathlib import Path

import numpy as np

from validation.core.errors import BadInputError
from validation.core.files import json_text, write_files_atomically
from validation.core.progress import progress_bar
from validation.models.rgblimp_rollout import TUNED_COEFFICIENTS, fit_rollout_global
from validation.reproduce.rgblimp import (
    DEFAULT_SETUP,
    RGBlimpSetup,
    fit_global,
    flight_metrics,
    free_runs,
    identify_configuration,
    read_score_ranges,
    split_flights,
)
from validation.vehicles.rgblimp_data import read_rgblimp_flight

#: Folds of configurations (module docstring).
DEFAULT_FOLDS = 5
#: The models free-run on each held-out test flight.
UNSEEN_MODELS = ("identified", "vehicle_physics", "vehicle_hybrid")
#: The issue's goal: the unseen hybrid better than the identified model on at least this share.
GOAL_BEATS_IDENTIFIED_SHARE = 25 / 35


def fold_of(configurations, folds: int) -> dict:
    """configuration -> fold, the ``i``-th configuration of ``configurations`` in fold ``i mod folds``."""
    return {c: i % folds for i, c in enumerate(configurations)}


def study_unseen(data_dir, out_dir, *, folds: int = DEFAULT_FOLDS, configurations=None,
                 setup: RGBlimpSetup = DEFAULT_SETUP, progress: bool = True) -> dict:
    """Fit the vehicle models without each fold and free-run its configurations' test flights;
    write ``results.json`` and ``report.md`` to ``out_dir`` (module docstring).

    Parameters
    ----------
    data_dir : path
        The source's ``data_N.csv`` and ``data_info/``.
    out_dir : path
    folds : int
        At least 2 and at most the number of configurations.
    configurations : sequence of int, optional
        Default: every one with two flights present.
    setup : RGBlimpSetup
        The identification's and the hybrid's settings (those of ``reproduce rgblimp``).
    progress : bool

    Returns
    -------
    dict
        The content of ``results.json``: per configuration each model's ``score``,
        ``position_rmse_m`` and the vehicle hybrid's ``coverage95_position``; the summary and goal.
    """
    started = clock.perf_counter()
    splits = split_flights(data_dir, configurations=configurations)
    if not 2 <= folds <= len(splits):
        raise BadInputError(f"--folds must be between 2 and the {len(splits)} configurations, got {folds}")
    ranges = read_score_ranges(data_dir, kinds=sorted({s.kind for s in splits}))
    flights = {n: read_rgblimp_flight(Path(data_dir) / f"data_{n}.csv")
               for n in sorted({n for s in splits for n in (*s.fit, s.test)})}
    fold = fold_of([s.configuration for s in splits], folds)
    entries, fold_records = [], []
    with progress_bar("rgblimp unseen configurations", enabled=progress, total=folds, unit="fold") as update:
        for k in range(folds):
            held = [s for s in splits if fold[s.configuration] == k]
            seen = [s for s in splits if fold[s.configuration] != k]
            tick = clock.perf_counter()
            vehicle, _ = fit_global([flights[n] for s in seen for n in s.fit], setup, seed=0, with_rkgp=False)
            identified_seconds = clock.perf_counter() - tick
            hybrid = fit_rollout_global([([flights[n] for n in s.fit], vehicle.model) for s in seen],
                                        setup=setup.global_rollout, shared_physics=True)[0]
            fold_records.append({"fold": k, "held_out": [s.configuration for s in held],
                                 "identification_seconds": identified_seconds,
                                 "hybrid_fit_seconds": hybrid.fit_seconds, "hybrid_iterations": hybrid.iterations,
                                 "vehicle_physics": {n: vehicle.model.value(n) for n in TUNED_COEFFICIENTS},
                                 "vehicle_hybrid_physics": {n: hybrid.physics.value(n) for n in TUNED_COEFFICIENTS}})
            for split in held:
                own = identify_configuration([flights[n] for n in split.fit], vehicle.model, setup=setup)
                test = flights[split.test].recording
                models = {"identified": own.model, "vehicle_physics": vehicle.model, "vehicle_hybrid": hybrid}
                predicted, sd, _ = free_runs(test.outputs, test.inputs, models)
                metrics = {name: flight_metrics(predicted[name], test.outputs, ranges[split.kind],
                                                position_sd=sd[name][:, :3] if name in sd else None)
                           for name in models}
                entries.append({"index": split.configuration, "kind": split.kind, "fold": k,
                                "test": f"data_{split.test}.csv",
                                "score": {n: metrics[n]["score"] for n in models},
                                "position_rmse_m": {n: metrics[n]["position_rmse_m"] for n in models},
                                "coverage95_position": metrics["vehicle_hybrid"]["coverage95_position"]})
            if update:
                update(1, fold=k)
    entries.sort(key=lambda e: e["index"])
    results = {"case": "RGBlimp: each configuration's test flight free-run by vehicle models fitted without its "
                       "flights (folds of configurations)",
               "folds": folds, "fold_of_configuration": {str(c): k for c, k in fold.items()},
               "models": {"identified": "the configuration's own identified model (saw its fitting flights)",
                          "vehicle_physics": "coefficients identified on every other fold's fitting flights",
                          "vehicle_hybrid": "one correction and one set of refined coefficients fitted through "
                                            "the free runs of every other fold's fitting flights"},
               "rollout_setup": dataclasses.asdict(setup.global_rollout),
               "configurations": entries, "fold_fits": fold_records}
    results["summary"] = summarise_unseen(entries)
    results["seconds"] = clock.perf_counter() - started
    write_files_atomically({Path(out_dir) / "results.json": json_text(results),
                            Path(out_dir) / "report.md": format_unseen(results)})
    return results


def summarise_unseen(entries: list[dict]) -> dict:
    """Means, how often the vehicle hybrid beats each other model in score, and the goal."""
    n = len(entries)
    mean = {key: {name: float(np.mean([e[key][name] for e in entries])) for name in UNSEEN_MODELS}
            for key in ("score", "position_rmse_m")}
    beats = {other: int(sum(e["score"]["vehicle_hybrid"] < e["score"][other] for e in entries))
             for other in ("identified", "vehicle_physics")}
    needed = int(np.ceil(GOAL_BEATS_IDENTIFIED_SHARE * n - 1e-9))
    coverage = [e["coverage95_position"] for e in entries]
    return {"n_configurations": n, "mean_score": mean["score"], "mean_position_rmse_m": mean["position_rmse_m"],
            "vehicle_hybrid_beats_in_score": beats,
            "vehicle_hybrid_mean_coverage95_position": float(np.mean(coverage)),
            "vehicle_hybrid_coverage_in_0.85_0.99": int(sum(0.85 <= c <= 0.99 for c in coverage)),
            "goal_beats_identified": {"target": f"vehicle hybrid's score below the identified model's on at least "
                                                f"{needed} of {n}",
                                      "needed": needed, "measured": f"{beats['identified']} of {n}",
                                      "met": beats["identified"] >= needed}}


def format_unseen(results: dict) -> str:
    """``report.md``: the summary and the per-configuration table."""
    s = results["summary"]
    lines = [f"# RGBlimp: configurations never flown ({results['folds']} folds of configurations)", "",
             "| model | mean score | mean position RMSE, m |", "|---|---:|---:|"]
    lines += [f"| {name} | {s['mean_score'][name]:.5f} | {s['mean_position_rmse_m'][name]:.3f} |"
              for name in UNSEEN_MODELS]
    goal = s["goal_beats_identified"]
    lines += ["", f"The vehicle hybrid beats the configuration's own identified model in score on "
                  f"{goal['measured']} test flights (goal: at least {goal['needed']}; "
                  f"{'met' if goal['met'] else 'missed'}), the vehicle physics on "
                  f"{s['vehicle_hybrid_beats_in_score']['vehicle_physics']} of {s['n_configurations']}. "
                  f"Mean 95 % coverage of positions {s['vehicle_hybrid_mean_coverage95_position']:.3f} "
                  f"({s['vehicle_hybrid_coverage_in_0.85_0.99']} of {s['n_configurations']} in 0.85-0.99).", "",
              "| configuration | fold | identified | vehicle physics | vehicle hybrid | coverage |",
              "|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {e['index']} | {e['fold']} | {e['score']['identified']:.5f} | {e['score']['vehicle_physics']:.5f} | "
              f"{e['score']['vehicle_hybrid']:.5f} | {e['coverage95_position']:.3f} |"
              for e in results["configurations"]]
    lines += ["", f"Total {results['seconds'] / 60:.1f} min."]
    return "\n".join(lines) + "\n"
