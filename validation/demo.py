"""``flightgp demo``: the built-in Bo105 case, end to end as far as flightgp goes today.

1. Fly the Bo105 flight-test stand-in at 80 kt through a 1 deg, 0.4 s 3-2-1-1 on longitudinal
   cyclic (the Bo105 GP-NARX paper's manoeuvre) and replay the physics reference on the same
   inputs; write both recordings.
2. Train a Gaussian process on 32 points (every 25th sample, as the paper) that predicts the
   next pitch rate from the current cyclic and pitch rate, with Higdon's kernel and simulated
   annealing over its hyperparameters.
3. Compare one-step-ahead predictions of the GP and of the physics reference with the flight
   test by RMSE, plot them with the GP's 95 % band, and write ``summary.json``.

The full chain of the product (GP-NARX on p, q, r with free-run prediction, FMU export and
co-simulation) replaces step 2-3 as those issues land; until then this is a small GP example
on the real case, and it says so when it runs.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from gp_model import GaussianProcess, HigdonKernel, anneal_hyperparameters, save_model

from .files import write_atomically, write_json
from .manoeuvres import three_two_one_one, time_grid
from .plots import png_bytes
from .recordings import write_recording
from .vehicles import get_vehicle

#: The demo's manoeuvre (DESIGN.md, "Physics facts": 80 kt, +/-1 deg theta_1s 3-2-1-1).
SPEED_KT, AMPLITUDE_RAD, STEP_TIME_S, START_S, DURATION_S = 80, np.radians(1.0), 0.4, 1.0, 8.0
#: Every 25th sample for training, as in the Bo105 GP-NARX paper (32 points from 8 s at 100 Hz).
TRAINING_STRIDE = 25


def _one_step_design(recording, *, output: str, control: str):
    """Regressors ``[u(k), y(k)]`` and targets ``y(k+1)`` from a recording, shapes (n-1, 2), (n-1,)."""
    y, u = recording.output(output), recording.input(control)
    return np.column_stack([u[:-1], y[:-1]]), y[1:]


def _reference_one_step(reference_vehicle, recording, *, output: str) -> np.ndarray:
    """The reference's one-step-ahead prediction of ``output`` from each measured state.

    Uses the exact discretisation ``x(k+1) = Phi x(k) + Gamma u(k)`` of the linear model with the
    flight test's measured state at ``k`` (all eight states are recorded).
    """
    states = np.column_stack([recording.output(name) for name in reference_vehicle.state_names])
    inputs = np.column_stack([recording.input(name) for name in reference_vehicle.input_names])
    phi, gamma = reference_vehicle.discretisation(recording.time[1] - recording.time[0])
    predicted = states[:-1] @ phi.T + inputs[:-1] @ gamma.T
    return predicted[:, reference_vehicle.state_names.index(output)]


def run_demo(out_dir, *, seed: int = 0, progress: bool = True) -> dict:
    """Run the demo into ``out_dir``; returns the summary written to ``summary.json``."""
    out_dir = Path(out_dir)
    flight = get_vehicle(f"bo105-{SPEED_KT}kt-flight")
    reference = get_vehicle(f"bo105-{SPEED_KT}kt")
    time = time_grid(duration=DURATION_S, sample_time=flight.sample_time)
    inputs = np.zeros((len(time), len(flight.input_names)))
    inputs[:, flight.input_names.index("theta_1s")] = three_two_one_one(
        time, amplitude=AMPLITUDE_RAD, step_time=STEP_TIME_S, start=START_S)
    flight_test = flight.simulate(time, inputs, seed=seed)
    replay = reference.simulate(time, inputs)
    write_recording(out_dir / "flight_test.csv", flight_test)
    write_recording(out_dir / "reference.csv", replay)

    X, y = _one_step_design(flight_test, output="q", control="theta_1s")
    train = np.arange(0, len(X), TRAINING_STRIDE)
    gp = GaussianProcess(HigdonKernel(1.0, [0.5, 0.5]), noise_variance=1e-2).fit(X[train], y[train])
    annealing = anneal_hyperparameters(gp, n_samples=400, seed=seed, progress=progress)
    save_model(out_dir / "pitch_rate_gp.npz", gp, meta={"regressors": ["theta_1s(k)", "q(k)"],
                                                        "target": "q(k+1)", "seed": seed})
    mean, var = gp.predict(X, return_var=True, include_noise=True)
    physics = _reference_one_step(reference, flight_test, output="q")
    held_out = np.setdiff1d(np.arange(len(X)), train)
    band = 1.96 * np.sqrt(var)
    summary = {
        "case": f"Bo105 {SPEED_KT} kt, {np.degrees(AMPLITUDE_RAD):g} deg theta_1s 3-2-1-1, "
                f"{STEP_TIME_S} s steps, seed {seed}",
        "training_points": int(len(train)),
        "annealing_stages": len(annealing.zeta_schedule),
        "one_step_rmse_q_rad_s": {
            "gp": float(np.sqrt(np.mean((mean[held_out] - y[held_out]) ** 2))),
            "reference": float(np.sqrt(np.mean((physics[held_out] - y[held_out]) ** 2))),
        },
        "coverage95_q": float(np.mean(np.abs(mean[held_out] - y[held_out]) <= band[held_out])),
        "note": "small GP example (one-step pitch rate); the GP-NARX, free run and FMU chain "
                "arrive with the later issues",
    }
    write_atomically(out_dir / "pitch_rate.png", png_bytes(
        _figure(time[1:], y, mean, band, physics, train)))
    write_json(out_dir / "summary.json", summary)
    return summary


def _figure(time, measured, mean, band, physics, train) -> Figure:
    figure = Figure(figsize=(8, 4), layout="constrained")
    FigureCanvasAgg(figure)
    axis = figure.subplots()
    axis.plot(time, measured, "k", lw=1, label="flight test (stand-in)")
    axis.plot(time, physics, "--", color="tab:orange", label="physics reference (one step)")
    axis.plot(time, mean, color="tab:blue", label="GP mean (one step)")
    axis.fill_between(time, mean - band, mean + band, color="tab:blue", alpha=0.25, label="GP 95 %")
    axis.plot(time[train], measured[train], "D", ms=4, color="tab:green", label="training points")
    axis.set(xlabel="time [s]", ylabel="pitch rate q [rad/s]",
             title="Bo105 80 kt, 3-2-1-1 on longitudinal cyclic: one-step-ahead pitch rate")
    axis.grid(True, alpha=0.3)
    axis.legend(fontsize="small")
    return figure
