"""Table II of the blimp RKGP paper: do sampled RKGP trajectories spread like real ones?

Ko, Klein, Fox & Haehnel (ICRA 2007), sec. IV-C: one start and one command sequence, flown
repeatedly by the real blimp and sampled from the RKGP model; the end points' spread is
compared. Here: the first :attr:`Table2Setup.horizon_frames` commands of the seed's first
held-out flight, flown :attr:`Table2Setup.stand_in_runs` times by the stand-in (each run
seeded differently: buoyancy drift, frame-time jitter and marker noise differ) from rest at
the origin, as every stand-in flight starts. RKGP starts at rest (zero velocities and rates) in
the mean recorded first pose of those runs (what the experimenter measures of the common
start), fans at rest, nominal frame interval, and is rolled out:

- ``rkgp_sampled_noise``: each step's residual drawn from the latent GP conditioned on the
  residuals already drawn along the rollout, plus independent observation noise
  (:meth:`gp_model.GreyBoxGP.sample_rollouts` with ``include_noise``: Ko et al.'s "with noise");
- ``rkgp_sampled``: the same draws without the observation noise (latent function only);
- ``rkgp_mean``: the mean rollout (no spread by construction);
- ``rkgp_propagated``: the mean rollout's first-order propagated standard deviations
  (:meth:`gp_model.GreyBoxGP.propagate`), for comparison with the samples.

Calibrated rows (``rkgp_calibrated_noise``, ``rkgp_calibrated``): the same draws from a posterior
whose covariance and noise variance are scaled by ``c**2`` (``GreyBoxGP.sample_rollouts``'s
``spread_scale``), with ``c`` chosen on validation repeats the table never sees
(:func:`calibrate_spread`): other commands of the same distribution, flown by the stand-in with
other seeds, where ``c`` makes the sampled-with-noise spread equal the stand-in's. This is the
rollout-trained RGBlimp hybrid's treatment of its bands (docs/rgblimp.md, "The hybrid's
settings, chosen on validation flights"): the band's size is calibrated on validation flights,
its shape is the model's.

Spread of a set of end points: standard deviation (ddof 0) of x, y, z and yaw (yaw deviations
wrapped to [-pi, pi) about the stand-in's circular mean) and the mean Euclidean distance of the
end positions from their mean; offset: distance of the set's mean end position from the stand-in
runs' mean end position. The stand-in's end points are the recorded ones (mocap, as Ko et al.).
"""
from __future__ import annotations

import time as clock
from dataclasses import asdict, dataclass

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from gp_model import GreyBoxGP
from validation.core.progress import progress_bar
from validation.models.blimp_greybox import COMMAND_LAGS, lagged_commands
from validation.models.blimp_identification import recording_arrays
from validation.reproduce.blimp_prediction import random_commands
from validation.vehicles.blimp import SAMPLE_TIME
from validation.vehicles.blimp_flight import BlimpFlightTest

ROWS = ("stand_in", "rkgp_sampled_noise", "rkgp_sampled", "rkgp_mean")
#: Rows drawn at the calibrated spread scale.
CALIBRATED_ROWS = ("rkgp_calibrated_noise", "rkgp_calibrated")
#: SeedSequence key of the calibration's validation repeats: commands ``[seed, 7]``, stand-in
#: run i ``[seed, 7, i]``, samples ``[seed, 7]`` (the table's own keys are ``[seed, 3, ...]``).
CALIBRATION_KEY = 7
#: Calibration stops when the validation spread ratio is within this of 1, or after
#: :data:`CALIBRATION_ITERATIONS` rescalings.
CALIBRATION_TOLERANCE = 0.02
CALIBRATION_ITERATIONS = 6


@dataclass(frozen=True)
class Table2Setup:
    """Sizes of the Table II experiment.

    Attributes
    ----------
    horizon_frames : int
        Length of the fixed command sequence, mocap frames (40: 2 s at 20 Hz; long enough for
        the fans to spin up and the end points to spread).
    stand_in_runs : int
        Repeated stand-in runs (the paper's twenty).
    n_samples : int
        Sampled RKGP rollouts.
    """

    horizon_frames: int = 40
    stand_in_runs: int = 20
    n_samples: int = 100


DEFAULT_SETUP = Table2Setup()
QUICK_SETUP = Table2Setup(stand_in_runs=8, n_samples=20)


def _wrap(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def end_point_spread(ends: np.ndarray, reference: np.ndarray) -> dict:
    """Spread of end states (R, 12) and their offset from the stand-in's end states (S, 12)."""
    yaw_centre = np.angle(np.mean(np.exp(1j * reference[:, 5])))  # circular mean of the stand-in
    yaw = _wrap(ends[:, 5] - yaw_centre)
    position = ends[:, :3]
    centre = position.mean(axis=0)
    return {"x_std_m": float(position[:, 0].std()), "y_std_m": float(position[:, 1].std()),
            "z_std_m": float(position[:, 2].std()), "yaw_std_deg": float(np.degrees(yaw.std())),
            "position_spread_m": float(np.linalg.norm(position - centre, axis=1).mean()),
            "offset_from_stand_in_m": float(np.linalg.norm(centre - reference[:, :3].mean(axis=0))),
            "yaw_offset_from_stand_in_deg": float(np.degrees(_wrap(np.angle(np.mean(np.exp(1j * yaw))))))}


@dataclass
class SpreadPaths:
    """The paths Table II compares: stand-in runs as recorded (R, H+1, 12), samples with and
    without observation noise (N, H+1, 12), the mean rollout and its propagated standard
    deviation (H+1, 12), and the calibrated samples with noise (N, H+1, 12; None without a
    calibration)."""

    stand_in: np.ndarray
    sampled_noise: np.ndarray
    sampled: np.ndarray
    mean: np.ndarray
    propagated_sd: np.ndarray
    calibrated_noise: np.ndarray | None = None


def table2(commands, model: GreyBoxGP, rk, setup: Table2Setup = DEFAULT_SETUP, *, seed: int,
           command_lags=COMMAND_LAGS, calibration: SpreadCalibration | None = None,
           progress: bool = False) -> tuple[dict, SpreadPaths]:
    """Table II (module docstring) for one seed.

    Parameters
    ----------
    commands : ndarray, shape (n, 3)
        A command sequence (at least ``horizon_frames + 1`` rows), held frame by frame.
    model : GreyBoxGP
        RKGP with inputs ``u_gondola, mu, u_tail, dt`` and the lagged commands of ``command_lags``.
    rk : callable
        Its physics step.
    setup : Table2Setup
    seed : int
        Stand-in run i is seeded ``SeedSequence([seed, 3, i])``; the samples' normals
        ``SeedSequence([seed, 3])`` (the same normals with and without noise).
    command_lags : sequence of float
    calibration : SpreadCalibration, optional
        With it, the calibrated rows too (:data:`CALIBRATED_ROWS`, drawn from the same normals)
        and ``spread_ratio_calibrated``.
    progress : bool

    Returns
    -------
    table : dict
        The ``table2`` entry of one seed in ``results.json``.
    paths : SpreadPaths
    """
    frames = setup.horizon_frames
    commands = _horizon_commands(commands, frames)
    runs = _stand_in_repeats(commands, setup.stand_in_runs, [seed, 3], label=f"seed {seed}: Table II stand-in runs",
                             progress=progress)
    start, inputs = _sampling_problem(runs, commands, command_lags)
    sample_seed = int(np.random.SeedSequence([seed, 3]).generate_state(1)[0])
    began = clock.perf_counter()
    sampled_noise = model.sample_rollouts(start, inputs, rk, n_samples=setup.n_samples, seed=sample_seed,
                                          include_noise=True)
    sampling_s = clock.perf_counter() - began
    sampled = model.sample_rollouts(start, inputs, rk, n_samples=setup.n_samples, seed=sample_seed)
    propagated = model.propagate(start, inputs, rk)
    reference = runs[:, -1]
    sd = propagated.sd[-1]
    table = {"stand_in": end_point_spread(reference, reference),
             "rkgp_sampled_noise": {**end_point_spread(sampled_noise[:, -1], reference), "seconds": sampling_s},
             "rkgp_sampled": end_point_spread(sampled[:, -1], reference),
             "rkgp_mean": end_point_spread(propagated.mean[None, -1], reference),
             "rkgp_propagated": {"x_std_m": float(sd[0]), "y_std_m": float(sd[1]), "z_std_m": float(sd[2]),
                                 "yaw_std_deg": float(np.degrees(sd[5]))},
             "setup": {**asdict(setup), "horizon_s": frames * SAMPLE_TIME, "seed": seed,
                       "commands": "the first horizon_frames commands of the seed's held-out flight 0",
                       "stand_in_start": "at rest at the origin in its static attitude (every run)",
                       "rkgp_start": "at rest in the stand-in runs' mean recorded first pose; fans at rest; "
                                     f"nominal dt {SAMPLE_TIME} s every step",
                       "stand_in_seeds": "run i: SeedSequence([seed, 3, i])",
                       "sample_seed": "SeedSequence([seed, 3]) (with and without noise)"}}
    table["spread_ratio_noise"] = (table["rkgp_sampled_noise"]["position_spread_m"]
                                   / table["stand_in"]["position_spread_m"])
    table["spread_ratio_latent"] = table["rkgp_sampled"]["position_spread_m"] / table["stand_in"]["position_spread_m"]
    calibrated_noise = None
    if calibration is not None:
        scale = calibration.spread_scale
        calibrated_noise = model.sample_rollouts(start, inputs, rk, n_samples=setup.n_samples, seed=sample_seed,
                                                 include_noise=True, spread_scale=scale)
        calibrated = model.sample_rollouts(start, inputs, rk, n_samples=setup.n_samples, seed=sample_seed,
                                           spread_scale=scale)
        table["rkgp_calibrated_noise"] = end_point_spread(calibrated_noise[:, -1], reference)
        table["rkgp_calibrated"] = end_point_spread(calibrated[:, -1], reference)
        table["calibration"] = asdict(calibration)
        table["spread_ratio_calibrated"] = (table["rkgp_calibrated_noise"]["position_spread_m"]
                                            / table["stand_in"]["position_spread_m"])
    return table, SpreadPaths(runs, sampled_noise, sampled, propagated.mean, propagated.sd, calibrated_noise)


def _horizon_commands(commands, frames: int) -> np.ndarray:
    """The first ``frames + 1`` rows of ``commands`` (n, 3); ValueError when there are fewer."""
    commands = np.asarray(commands, dtype=float)
    if frames + 1 > len(commands):
        raise ValueError(f"Table II needs {frames + 1} commands; got {len(commands)}")
    return commands[:frames + 1]


def _stand_in_repeats(commands: np.ndarray, runs: int, key: list, *, label: str, progress: bool) -> np.ndarray:
    """The stand-in flown ``runs`` times from rest at the origin under ``commands`` (H+1, 3),
    run i seeded ``SeedSequence(key + [i])``: the recorded states, shape (runs, H+1, 12)."""
    nominal_time = np.arange(len(commands)) * SAMPLE_TIME
    flown = []
    with progress_bar(label, enabled=progress, total=runs, unit="run") as update:
        for i in range(runs):
            run_seed = int(np.random.SeedSequence([*key, i]).generate_state(1)[0])
            flown.append(recording_arrays(BlimpFlightTest().simulate(nominal_time, commands, seed=run_seed))[0])
            if update:
                update(1)
    return np.stack(flown)


def _sampling_problem(runs: np.ndarray, commands: np.ndarray, command_lags) -> tuple[np.ndarray, np.ndarray]:
    """The RKGP's start (12,), at rest in the repeats' mean recorded first pose, and its inputs
    (H, 4 + 3 L): the commands, the nominal frame interval and the lagged commands."""
    frames = len(commands) - 1
    start = np.concatenate([runs[:, 0, :6].mean(axis=0), np.zeros(6)])
    dt = np.full(frames, SAMPLE_TIME)
    inputs = np.column_stack([commands[:frames], dt, lagged_commands(commands[:frames], dt,
                                                                      time_constants=command_lags)])
    return start, inputs


@dataclass(frozen=True)
class SpreadCalibration:
    """The spread scale chosen on validation repeats (:func:`calibrate_spread`).

    Attributes
    ----------
    spread_scale : float
        ``c``: the posterior's standard deviations (latent and noise) are multiplied by it.
    stand_in_spread_m : float
        The validation repeats' end-point spread, m.
    uncalibrated_spread_m, calibrated_spread_m : float
        The sampled-with-noise spread on the validation commands at scale 1 and at ``c``, m.
    rescalings : int
        Rescalings made.
    """

    spread_scale: float
    stand_in_spread_m: float
    uncalibrated_spread_m: float
    calibrated_spread_m: float
    rescalings: int


def calibrate_spread(model: GreyBoxGP, rk, setup: Table2Setup = DEFAULT_SETUP, *, seed: int,
                     command_lags=COMMAND_LAGS, progress: bool = False) -> SpreadCalibration:
    """Choose the spread scale on validation repeats that Table II never sees.

    Commands of the campaign's distribution (:func:`validation.reproduce.blimp_prediction.random_commands`,
    ``SeedSequence([seed, 7])``), ``setup.horizon_frames`` frames, flown ``setup.stand_in_runs``
    times by the stand-in (run i ``[seed, 7, i]``); the RKGP sampled ``setup.n_samples`` times
    with noise (normals ``[seed, 7]``). The scale is rescaled by the ratio of the stand-in's spread to
    the sampled one (the spread is nearly proportional to it) until they agree within
    :data:`CALIBRATION_TOLERANCE`, at most :data:`CALIBRATION_ITERATIONS` times.

    Returns
    -------
    SpreadCalibration

    Raises
    ------
    ValueError
        If the samples do not spread at all (a model without posterior variance cannot be
        calibrated).
    """
    frames = setup.horizon_frames
    time = np.arange(frames + 1) * SAMPLE_TIME
    commands = random_commands(time, np.random.default_rng(np.random.SeedSequence([seed, CALIBRATION_KEY])))
    runs = _stand_in_repeats(commands, setup.stand_in_runs, [seed, CALIBRATION_KEY],
                             label=f"seed {seed}: Table II calibration repeats", progress=progress)
    start, inputs = _sampling_problem(runs, commands, command_lags)
    sample_seed = int(np.random.SeedSequence([seed, CALIBRATION_KEY]).generate_state(1)[0])
    target = end_point_spread(runs[:, -1], runs[:, -1])["position_spread_m"]

    def sampled_spread(scale: float) -> float:
        paths = model.sample_rollouts(start, inputs, rk, n_samples=setup.n_samples, seed=sample_seed,
                                      include_noise=True, spread_scale=scale)
        return end_point_spread(paths[:, -1], runs[:, -1])["position_spread_m"]

    scale, spread = 1.0, sampled_spread(1.0)
    uncalibrated, rescalings = spread, 0
    if spread <= 0:
        raise ValueError("the RKGP's samples do not spread: there is no posterior variance to calibrate")
    while abs(spread / target - 1.0) > CALIBRATION_TOLERANCE and rescalings < CALIBRATION_ITERATIONS:
        scale *= target / spread
        spread = sampled_spread(scale)
        rescalings += 1
    return SpreadCalibration(float(scale), float(target), float(uncalibrated), float(spread), rescalings)


def table2_figure(paths: SpreadPaths) -> Figure:
    """Ko et al.'s Fig. 6 style: the end-point clouds (x-y) and the yaw tracks of the stand-in runs
    and the sampled RKGP, with the mean rollout and its propagated 2-sigma band."""
    figure = Figure(figsize=(12, 5), layout="constrained")
    FigureCanvasAgg(figure)
    track, yaw = figure.subplots(1, 2)
    t = np.arange(paths.stand_in.shape[1]) * SAMPLE_TIME
    clouds = [(paths.sampled_noise, "tab:blue", "RKGP sampled, with noise"),
              (paths.sampled, "tab:green", "RKGP sampled, latent only"),
              (paths.stand_in, "k", "stand-in runs (recorded)")]
    if paths.calibrated_noise is not None:
        clouds.insert(2, (paths.calibrated_noise, "tab:orange", "RKGP sampled, with noise, calibrated"))
    for sampled, color, label in clouds:
        for i, path in enumerate(sampled):
            track.plot(path[:, 1], path[:, 0], color=color, lw=0.5, alpha=0.2)
            yaw.plot(t, np.degrees(path[:, 5]), color=color, lw=0.5, alpha=0.2, label=label if i == 0 else None)
        track.plot(sampled[:, -1, 1], sampled[:, -1, 0], "o", color=color, ms=3.5, alpha=0.7,
                   label=f"{label} ({len(sampled)}), end points")
    mean, sd = paths.mean, paths.propagated_sd
    track.plot(mean[:, 1], mean[:, 0], color="tab:red", lw=1.5)
    track.plot(mean[-1, 1], mean[-1, 0], "*", color="tab:red", ms=14, label="RKGP mean, end point")
    yaw.plot(t, np.degrees(mean[:, 5]), color="tab:red", lw=1.5, label="RKGP mean")
    yaw.fill_between(t, np.degrees(mean[:, 5] - 2 * sd[:, 5]), np.degrees(mean[:, 5] + 2 * sd[:, 5]),
                     color="tab:red", alpha=0.15, label="RKGP propagated +-2 sd")
    track.set_xlabel("y (east) [m]")
    track.set_ylabel("x (north) [m]")
    track.set_aspect("equal", adjustable="datalim")
    yaw.set_xlabel("time from start [s]")
    yaw.set_ylabel("yaw psi [deg]")
    for panel in (track, yaw):
        panel.grid(True, alpha=0.3)
        panel.legend(fontsize="small")
    figure.suptitle(f"Blimp Table II: end points after {t[-1]:g} s from one start with one command "
                    "sequence (Ko et al. 2007, sec. IV-C)")
    return figure
