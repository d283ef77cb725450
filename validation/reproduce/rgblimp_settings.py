"""The validation-flight study behind the RGBlimp reproduction's settings (docs/rgblimp.md,
"Identification and RKGP").

:mod:`validation.reproduce.rgblimp` tests each configuration on its highest-numbered flight
present. This study never reads that flight: for every configuration with at least three flights
present it fits on the lowest-numbered one and validates on the next (on a folder that holds flights
``4j+1 .. 4j+3``: fit on ``4j+1``, validate on ``4j+2``), with the reproduction's
own procedure (a global identification on the fitting flights of every configuration,
:func:`validation.reproduce.rgblimp.fit_global`, then per configuration the identified model
started from it and drawn toward it (:func:`validation.reproduce.rgblimp.identify_all_configurations`) and
its RKGP; free runs
of the whole validation flight, the RKGP's mean only). Candidates that share the identification
settings share the identified models. Each candidate changes
one setting of the chosen one (:data:`validation.reproduce.rgblimp.DEFAULT_SETUP`); the table is
the mean over configurations of the source's score and of the position RMSE, identified model
and RKGP, with the published model's for scale.
"""
from __future__ import annotations

import time as clock
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from validation.core.errors import BadInputError
from validation.core.progress import progress_bar
from validation.models.rgblimp_greybox import continuous_states, fit_rkgp, physics_step
from validation.models.rgblimp_identification import IDENTIFIED_PARAMETERS, STATE_SCALE, RGBlimpModel
from validation.reproduce.rgblimp import (
    DEFAULT_SETUP,
    Split,
    fit_global,
    flight_metrics,
    identify_all_configurations,
    read_score_ranges,
)
from validation.vehicles.rgblimp_data import flights_by_configuration, read_rgblimp_flight

#: The chosen settings and their one-setting variants: name -> RGBlimpSetup.
CANDIDATES = {
    "chosen": DEFAULT_SETUP,
    "no wind": replace(DEFAULT_SETUP, identified_parameters=tuple(
        n for n in IDENTIFIED_PARAMETERS if not n.startswith("wind"))),
    "segments 3 s": replace(DEFAULT_SETUP, segment_duration=3.0),
    "segments 12 s": replace(DEFAULT_SETUP, segment_duration=12.0),
    "recorded training states": replace(DEFAULT_SETUP, smoothing=None),
    "smoothing 21 samples": replace(DEFAULT_SETUP, smoothing=(21, 2)),
    "300 training points": replace(DEFAULT_SETUP, training_points=300),
    "noise floor 1e-2": replace(DEFAULT_SETUP, min_noise_variance=1e-2),
    "not drawn toward the vehicle": replace(DEFAULT_SETUP, shrinkage=None),
    "shrinkage 0.5": replace(DEFAULT_SETUP, shrinkage=0.5),
}
#: The models each candidate is scored on.
SCORED = ("physics", "identified", "rkgp")


def validation_splits(data_dir, *, configurations=None) -> list[Split]:
    """Fit on the lowest-numbered flight, validate on the next, of every configuration with at
    least three flights present (the highest-numbered, the reproduction's test flight, unread).

    Raises
    ------
    BadInputError
        No configuration (or a requested one) has three flights.
    """
    present = flights_by_configuration(data_dir)
    chosen = sorted(present) if configurations is None else sorted({int(j) for j in configurations})
    splits = [Split(j, (present[j][0],), present[j][1]) for j in chosen if len(present.get(j, ())) >= 3]
    missing = [j for j in chosen if len(present.get(j, ())) < 3]
    if (configurations is not None and missing) or not splits:
        raise BadInputError(f"{data_dir}: the settings study needs three flights of a configuration (fit, "
                            f"validate, and the test flight it leaves unread); too few for configuration(s) "
                            f"{missing or sorted(present)}")
    return splits


def study_settings(data_dir, *, configurations=None, candidates=None, seed: int = 0,
                   progress: bool = False) -> dict:
    """Score each candidate setup on the validation flights.

    Parameters
    ----------
    data_dir : path
        The source's ``data_N.csv`` and ``data_info/``.
    configurations : sequence of int, optional
        Default every configuration with three flights present.
    candidates : dict, optional
        name -> RGBlimpSetup; default :data:`CANDIDATES`.
    seed : int
        Seed of the GPs' hyperparameter search.
    progress : bool

    Returns
    -------
    dict
        ``splits`` (fit and validation flight per configuration) and ``candidates``: per
        candidate its setup, the mean over configurations of each model's ``score`` and
        ``position_rmse_m``, per configuration the same, and the wall time.
    """
    candidates = CANDIDATES if candidates is None else candidates
    splits = validation_splits(data_dir, configurations=configurations)
    ranges = read_score_ranges(data_dir, kinds=sorted({s.kind for s in splits}))
    flights = {n: read_rgblimp_flight(Path(data_dir) / f"data_{n}.csv")
               for s in splits for n in (*s.fit, s.test)}
    fitting = [flights[n] for s in splits for n in s.fit]
    scored, globals_, alone_, identified_, physics_ = {}, {}, {}, {}, {}
    with progress_bar("rgblimp settings", enabled=progress, total=len(candidates) * len(splits),
                      unit="fit") as update:
        for name, setup in candidates.items():
            began = clock.perf_counter()
            key = (setup.identified_parameters, setup.segment_duration, setup.max_segments,
                   setup.global_max_segments, setup.max_iterations)  # everything the global fit uses
            if key not in globals_:
                globals_[key] = fit_global(fitting, setup, seed=seed, with_rkgp=False)[0]
            if (key, setup.shrinkage) not in identified_:  # the configurations are drawn toward each other
                groups = [[flights[n] for n in s.fit] for s in splits]
                if key not in alone_:  # the first fits do not depend on the shrinkage
                    alone_[key] = identify_all_configurations(groups, globals_[key].model,
                                                              setup=replace(setup, shrinkage=None))
                results = identify_all_configurations(groups, globals_[key].model, setup=setup, alone=alone_[key])
                identified_[key, setup.shrinkage] = {}
                for split, result in zip(splits, results):
                    test = flights[split.test].recording
                    identified_[key, setup.shrinkage][split] = result.model, flight_metrics(
                        result.model.simulate(test.outputs[0], test.inputs), test.outputs, ranges[split.kind])
            per_configuration = []
            for split in splits:
                fitting_flights = [flights[n] for n in split.fit]
                test = flights[split.test].recording
                if split not in physics_:  # no setting changes the published model's run
                    physics_[split] = flight_metrics(RGBlimpModel().simulate(test.outputs[0], test.inputs),
                                                     test.outputs, ranges[split.kind])
                model, identified_metrics = identified_[key, setup.shrinkage][split]
                rkgp = fit_rkgp(fitting_flights, model, n_points=setup.training_points,
                                min_noise_variance=setup.min_noise_variance, smoothing=setup.smoothing, seed=seed)
                start = continuous_states(test.outputs[:1])[0]
                metrics = {"physics": physics_[split], "identified": identified_metrics,
                           "rkgp": flight_metrics(rkgp.rollout(start, test.inputs[:-1], physics_step(model)),
                                                  test.outputs, ranges[split.kind])}
                per_configuration.append(_scored(split, metrics, SCORED))
                if update:
                    update(1, candidate=name)
            scored[name] = {**_candidate(setup, per_configuration, SCORED), "seconds": clock.perf_counter() - began}
    return _study(splits, scored)


def _scored(split: Split, metrics: dict, models) -> dict:
    """One configuration's row of a study: its ``score`` and ``position_rmse_m`` per model."""
    return {"index": split.configuration,
            **{key: {m: metrics[m][key] for m in models} for key in ("score", "position_rmse_m")}}


def _candidate(setup, per_configuration: list, models) -> dict:
    """One candidate of a study: its setup (a dataclass), the means over configurations and the rows."""
    return {"setup": {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(setup).items()},
            **{f"mean_{k}": {m: float(np.mean([e[k][m] for e in per_configuration])) for m in models}
               for k in ("score", "position_rmse_m")},
            "configurations": per_configuration}


def _study(splits, scored: dict) -> dict:
    """A study's results: the splits, what the means are over, and each candidate."""
    return {"splits": [{"index": s.configuration, "fit": [f"data_{n}.csv" for n in s.fit],
                        "validation": f"data_{s.test}.csv"} for s in splits],
            "metric": "mean over configurations of a free run of the whole validation flight from its first "
                      "recorded state: the source's score and the position RMSE (m)",
            "candidates": scored}


def format_settings(results: dict) -> str:
    """The study as a plain-text table."""
    lines = [f"RGBlimp settings on {len(results['splits'])} validation flights (fit on one flight per "
             "configuration, free run of the next): means over configurations",
             f"{'candidate':28}{'score ident.':>13}{'score RKGP':>12}{'pos ident. m':>14}{'pos RKGP m':>12}"]
    for name, entry in results["candidates"].items():
        lines.append(f"{name:28}{entry['mean_score']['identified']:13.5f}{entry['mean_score']['rkgp']:12.5f}"
                     f"{entry['mean_position_rmse_m']['identified']:14.3f}{entry['mean_position_rmse_m']['rkgp']:12.3f}")
    first = next(iter(results["candidates"].values()))
    lines.append(f"{'published model':28}{first['mean_score']['physics']:13.5f}{'':12}"
                 f"{first['mean_position_rmse_m']['physics']:14.3f}")
    return "\n".join(lines)


#: The rollout-trained hybrid's chosen settings and the variants the validation flights compared
#: (docs/rgblimp.md, "Rollout-trained hybrid"): name -> RolloutSetup.
HYBRID_CANDIDATES = {
    "chosen": DEFAULT_SETUP.rollout,
    "physics not tuned": replace(DEFAULT_SETUP.rollout, tune_physics=False),
    "segments 6 s": replace(DEFAULT_SETUP.rollout, segment_duration=6.0),
    "prior weight 1": replace(DEFAULT_SETUP.rollout, prior_weight=1.0),
    "8 inducing inputs": replace(DEFAULT_SETUP.rollout, inducing_points=8),
    "loss scales of the identification": replace(DEFAULT_SETUP.rollout, state_scale=STATE_SCALE),
}


def study_hybrid_settings(data_dir, *, configurations=None, candidates=None, seed: int = 0,
                          setup=DEFAULT_SETUP, progress: bool = False) -> dict:
    """Score each candidate setup of the rollout-trained hybrid on the validation flights.

    The splits are :func:`validation_splits`' (fit on ``4j+1``, validate on ``4j+2``); the
    identified model each hybrid starts from is the reproduction's (a global identification on
    the fitting flights, then one per configuration started from it, with
    :data:`validation.reproduce.rgblimp.DEFAULT_SETUP`), shared by the candidates.

    Parameters
    ----------
    data_dir : path
    configurations : sequence of int, optional
    candidates : dict, optional
        name -> :class:`~validation.models.rgblimp_rollout.RolloutSetup`; default
        :data:`HYBRID_CANDIDATES`.
    seed : int
        Ignored by the identification; the hybrid's own seed is the candidate's.
    setup : RGBlimpSetup
        The identification's settings (default the reproduction's).
    progress : bool

    Returns
    -------
    dict
        ``splits``, and per candidate its setup, the mean over configurations of the ``score``
        and ``position_rmse_m`` of the published, identified and hybrid models, how often the
        hybrid beats the identified model, per configuration the same, and the mean fit time.
    """
    from validation.models.rgblimp_rollout import fit_rollout

    candidates = HYBRID_CANDIDATES if candidates is None else candidates
    splits = validation_splits(data_dir, configurations=configurations)
    ranges = read_score_ranges(data_dir, kinds=sorted({s.kind for s in splits}))
    flights = {n: read_rgblimp_flight(Path(data_dir) / f"data_{n}.csv")
               for s in splits for n in (*s.fit, s.test)}
    fitting = [flights[n] for s in splits for n in s.fit]
    global_model = fit_global(fitting, setup, seed=seed, with_rkgp=False)[0].model
    results = identify_all_configurations([[flights[n] for n in s.fit] for s in splits], global_model, setup=setup)
    identified, baseline = {}, {}
    for split, result in zip(splits, results):
        test = flights[split.test].recording
        model = identified[split] = result.model
        baseline[split] = {name: flight_metrics(m.simulate(test.outputs[0], test.inputs), test.outputs,
                                                ranges[split.kind])
                           for name, m in (("physics", RGBlimpModel()), ("identified", model))}
    scored = {}
    models = ("physics", "identified", "hybrid")
    with progress_bar("rgblimp hybrid settings", enabled=progress, total=len(candidates) * len(splits),
                      unit="fit") as update:
        for name, rollout_setup in candidates.items():
            per_configuration, seconds = [], []
            for split in splits:
                test = flights[split.test].recording
                hybrid = fit_rollout([flights[n] for n in split.fit], identified[split], setup=rollout_setup)
                seconds.append(hybrid.fit_seconds)
                metrics = {**baseline[split], "hybrid": flight_metrics(
                    hybrid.simulate(test.outputs[0], test.inputs), test.outputs, ranges[split.kind])}
                per_configuration.append(_scored(split, metrics, models))
                if update:
                    update(1, candidate=name)
            scored[name] = {**_candidate(rollout_setup, per_configuration, models),
                            "hybrid_beats_identified": int(sum(e["score"]["hybrid"] < e["score"]["identified"]
                                                               for e in per_configuration)),
                            "mean_fit_seconds": float(np.mean(seconds))}
    return _study(splits, scored)


def format_hybrid_settings(results: dict) -> str:
    """The hybrid's study as a plain-text table."""
    n = len(results["splits"])
    lines = [f"RGBlimp rollout-trained hybrid on {n} validation flights (fit on one flight per configuration, "
             "free run of the next): means over configurations",
             f"{'candidate':24}{'score ident.':>13}{'score hybrid':>13}{'pos ident. m':>14}{'pos hybrid m':>14}"
             f"{'beats ident.':>14}{'fit s':>8}"]
    for name, entry in results["candidates"].items():
        lines.append(f"{name:24}{entry['mean_score']['identified']:13.5f}{entry['mean_score']['hybrid']:13.5f}"
                     f"{entry['mean_position_rmse_m']['identified']:14.3f}"
                     f"{entry['mean_position_rmse_m']['hybrid']:14.3f}"
                     f"{entry['hybrid_beats_identified']:>9} of {n}{entry['mean_fit_seconds']:8.1f}")
    first = next(iter(results["candidates"].values()))
    lines.append(f"{'published model':24}{first['mean_score']['physics']:13.5f}{'':13}"
                 f"{first['mean_position_rmse_m']['physics']:14.3f}")
    return "\n".join(lines)
