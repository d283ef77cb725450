"""The validation-flight study that fixed the blimp RKGP's settings before the held-out flights
were looked at (docs/reproductions.md, "Blimp RKGP").

The RKGP of :mod:`validation.models.blimp_greybox` has three settings that decide whether its
residual GPs learn the physics' error or the motion capture's noise: the training states (the
recorded ones, or poses re-fitted by a local polynomial of some window and degree), the command
lags the GPs see, and the state filter's process noise that gives the one-second predictions
their start. Each candidate changes one setting of the chosen configuration
(:data:`validation.models.blimp_greybox.SMOOTHING_WINDOW`, ``SMOOTHING_ORDER``,
``COMMAND_LAGS``, ``PROCESS_NOISE_SD``); every candidate is fitted on campaign seed 0's
training flights and scored on a validation flight of its own seed
(:data:`VALIDATION_FLIGHT`), which is neither a training nor a held-out flight of any seed: the
Table I metric (RMSE at the one-second horizon against the recording, from the filtered start
states of :data:`N_STARTS` random frames), RKGP and, from the same starts, the identified RK.
"""
from __future__ import annotations

import time as clock
from dataclasses import asdict, dataclass, replace

import numpy as np

from validation.core.progress import progress_bar
from validation.models.blimp_greybox import (
    COMMAND_LAGS,
    PROCESS_NOISE_SD,
    SMOOTHING_ORDER,
    SMOOTHING_WINDOW,
    filtered_states,
    fit_greybox,
    step_inputs,
)
from validation.models.blimp_identification import identify_parameters, physics_step, simulate_segments
from validation.reproduce.blimp_prediction import (
    DEFAULT_SETUP,
    HORIZON_FRAMES,
    QUICK_SETUP,
    RK_MAX_STEP,
    fly_flights,
    horizon_rmse,
    random_command_flight,
    start_frames,
)

#: SeedSequence of the validation flight (campaign flights are ``[s, 0, i]`` and ``[s, 1, i]``).
VALIDATION_FLIGHT = (0, 6, 0)
#: Length of the validation flight, s, and the random start frames scored on it.
VALIDATION_DURATION = 30.0
N_STARTS = 100


@dataclass(frozen=True)
class Candidate:
    """One configuration of the study.

    Attributes
    ----------
    name : str
    smoothing : (int, int) or None
        Window (frames) and degree of the training states' pose fit; None: the recorded states.
    command_lags : tuple of float
        Time constants of the lagged fan commands the GPs see, s.
    process_noise_scale : float
        Factor on :data:`validation.models.blimp_greybox.PROCESS_NOISE_SD`.
    """

    name: str
    smoothing: tuple | None = (SMOOTHING_WINDOW, SMOOTHING_ORDER)
    command_lags: tuple = COMMAND_LAGS
    process_noise_scale: float = 1.0


CHOSEN = Candidate("chosen")
#: The chosen configuration and its one-setting variants.
CANDIDATES = (
    CHOSEN,
    replace(CHOSEN, name="recorded states", smoothing=None),
    replace(CHOSEN, name="smoothing 9 frames quadratic", smoothing=(9, 2)),
    replace(CHOSEN, name="smoothing 17 frames quadratic", smoothing=(17, 2)),
    replace(CHOSEN, name="smoothing 21 frames cubic", smoothing=(21, 3)),
    replace(CHOSEN, name="no command lags", command_lags=()),
    replace(CHOSEN, name="one lag 0.3 s", command_lags=(0.3,)),
    replace(CHOSEN, name="two lags 0.2, 0.4 s", command_lags=(0.2, 0.4)),
    replace(CHOSEN, name="process noise x2", process_noise_scale=2.0),
    replace(CHOSEN, name="process noise x3", process_noise_scale=3.0),
    replace(CHOSEN, name="process noise x5", process_noise_scale=5.0),
)


def choose_settings(*, candidates=CANDIDATES, quick: bool = False, progress: bool = False) -> dict:
    """Score each candidate on the validation flight.

    Parameters
    ----------
    candidates : sequence of Candidate
    quick : bool
        Seed 0's quick training flight, a 15 s validation flight and 20 starts (for tests).
    progress : bool

    Returns
    -------
    dict
        ``setup`` and ``candidates``: per candidate its settings, the RKGP's and the RK's
        ``{group: RMSE}`` at the horizon, their ratio on position and velocity, and the fit time.
    """
    setup = QUICK_SETUP if quick else DEFAULT_SETUP
    training, _ = fly_flights(replace(setup, held_out_flights=0), seed=0)
    validation = random_command_flight(VALIDATION_DURATION / (2 if quick else 1), list(VALIDATION_FLIGHT))
    recordings = [flight.recording for flight in training]
    identified = identify_parameters(recordings, max_step=RK_MAX_STEP, max_iterations=setup.identification_iterations)
    rk = physics_step(identified.params, max_step=RK_MAX_STEP)
    frames = start_frames([validation], 20 if quick else N_STARTS, np.random.default_rng(list(VALIDATION_FLIGHT)))
    window = np.arange(HORIZON_FRAMES + 1)
    recorded = np.stack([validation.recording.outputs[k + window] for _, k in frames])
    scored = {}
    fitted = {}
    with progress_bar("blimp settings: candidates", enabled=progress, total=len(candidates),
                      unit="candidate") as update:
        for candidate in candidates:
            key = (candidate.smoothing, candidate.command_lags)
            began = clock.perf_counter()
            if key not in fitted:  # the process-noise variants share the chosen model
                fitted[key] = fit_greybox(recordings, rk, command_lags=candidate.command_lags,
                                          smoothing=candidate.smoothing)
            seconds = clock.perf_counter() - began
            model = fitted[key]
            inputs = step_inputs(validation.recording, command_lags=candidate.command_lags)

            def rkgp_step(states, step_inputs_, model=model):
                return model.predict_one_step(states, step_inputs_, rk)[0]

            estimate = filtered_states(validation.recording, rkgp_step, command_lags=candidate.command_lags,
                                       process_noise_sd=candidate.process_noise_scale * np.asarray(PROCESS_NOISE_SD))
            starts = np.stack([estimate[k] for _, k in frames])
            segments = np.stack([inputs[k + window[:-1]] for _, k in frames])
            rkgp = horizon_rmse(model.rollout(starts, segments, rk), recorded)
            physics = horizon_rmse(np.concatenate([starts[:, None], simulate_segments(rk, starts, segments)], axis=1),
                                   recorded)
            scored[candidate.name] = {
                **asdict(candidate), "RKGP": rkgp, "RK": physics,
                "RK_over_RKGP": {g: physics[g] / rkgp[g] for g in ("position", "velocity")},
                "fit_seconds": seconds}
            if update:
                update(1)
    return {"setup": {"training": "campaign seed 0's training flights" + (" (quick setup)" if quick else ""),
                      "validation_flight": f"SeedSequence({list(VALIDATION_FLIGHT)}), "
                                           f"{validation.recording.time[-1]:g} s",
                      "n_starts": len(frames), "metric": "Table I: RMSE at 1 s against the recording from "
                                                         "the candidate's filtered start states"},
            "candidates": scored}


def format_settings(results: dict) -> str:
    """The study as a plain-text table (position and velocity at the one-second horizon)."""
    lines = [f"blimp RKGP settings on the validation flight ({results['setup']['validation_flight']}, "
             f"{results['setup']['n_starts']} starts): RMSE at 1 s",
             f"{'candidate':32}{'RKGP pos m':>12}{'RKGP vel m/s':>14}{'RK pos m':>10}{'RK vel m/s':>12}"
             f"{'RK/RKGP pos':>13}{'vel':>7}"]
    for name, entry in results["candidates"].items():
        lines.append(f"{name:32}{entry['RKGP']['position']:12.4f}{entry['RKGP']['velocity']:14.4f}"
                     f"{entry['RK']['position']:10.4f}{entry['RK']['velocity']:12.4f}"
                     f"{entry['RK_over_RKGP']['position']:12.2f}x{entry['RK_over_RKGP']['velocity']:6.2f}x")
    return "\n".join(lines)
