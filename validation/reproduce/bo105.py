"""Reproduce the Bo105 GP-NARX paper (AHS 74th Forum, 2018), then go past its future work.

The paper's experiment, with our stand-ins (docs/vehicles.md): the Bo105 flight-test stand-in
at 80 kt flies a 3-2-1-1 on longitudinal cyclic (1 deg, 0.4 s steps, 8 s at 100 Hz); a GP-NARX
with Higdon's kernel and simulated annealing predicts pitch, roll and yaw rate from the cyclic
and the previous rates; one-step-ahead (OSAP) and free-run (FMP, Monte Carlo with
hyperparameter samples) predictions are compared with the physics reference and the flight test
by RMSE per axis, and the free run is repeated on an unseen manoeuvre (1.5 deg, 0.3 s steps).

Beyond the paper (its "future work"), measured in the same report:

- lateral cyclic and pedal inputs in the NARX structure, trained on one 3-2-1-1 per control and
  tested on an unseen multi-axis manoeuvre;
- all samples with a sparse GP (data-chosen inducing points) against the paper's subsampling;
- ARD relevance of every regressor, used to choose the lags from a wide candidate structure;
- the same pipeline on JSBSim's ``ah1s`` helicopter in hover (a model nobody here wrote).
"""
from __future__ import annotations

import time as clock
from dataclasses import replace
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from validation.core.files import write_atomically, write_json
from validation.core.manoeuvres import doublet, three_two_one_one, time_grid
from validation.core.metrics import rmse
from validation.core.plots import png_bytes
from validation.core.recordings import Recording, column_unit, write_recording
from validation.models.narx import NarxConfig, NarxPrediction, free_run, one_step, save_trained, train_narx
from validation.vehicles import get_vehicle

AXES = ("p", "q", "r")
#: The paper's manoeuvre and an unseen one (different amplitude and step time).
TRAINING_MANOEUVRE = {"amplitude_deg": 1.0, "step_time": 0.4, "start": 1.0, "duration": 8.0}
UNSEEN_MANOEUVRE = {"amplitude_deg": 1.5, "step_time": 0.3, "start": 1.0, "duration": 8.0}
#: The paper's model at our NARX step (validation.models.narx): cyclic at lags 1-2, rates at lag 1,
#: 0.1 s step, every 25th 100 Hz sample = 32 training points from 8 s.
PAPER_CONFIG = NarxConfig(inputs=("theta_1s",), outputs=AXES, input_lags=(1, 2), output_lags=(1,),
                          decimation=10, stride=25, kernel="higdon", hyperparameters="annealing")


def fly_3211(vehicle_name: str, *, input_name: str, amplitude: float, step_time: float,
             start: float, duration: float, seed: int) -> Recording:
    """A 3-2-1-1 on one input of a vehicle, other inputs at trim."""
    vehicle = get_vehicle(vehicle_name)
    time = time_grid(duration=duration, sample_time=vehicle.sample_time)
    inputs = np.zeros((len(time), len(vehicle.input_names)))
    inputs[:, vehicle.input_names.index(input_name)] = three_two_one_one(
        time, amplitude=amplitude, step_time=step_time, start=start)
    return vehicle.simulate(time, inputs, seed=seed)


def _reference_free_run(reference, recording: Recording, config: NarxConfig) -> np.ndarray:
    """The physics reference flown on the recording's inputs from trim, at the NARX times."""
    inputs = np.column_stack([recording.input(n) for n in reference.input_names])
    states = reference.simulate_states(recording.time, inputs)
    return states[:: config.decimation][:, [reference.state_names.index(a) for a in config.outputs]]


def _reference_one_step(reference, recording: Recording, config: NarxConfig) -> np.ndarray:
    """The reference's one-step prediction over one NARX step from each measured state."""
    step = config.decimation * (recording.time[1] - recording.time[0])
    phi, gamma = reference.discretisation(step)
    rows = slice(None, None, config.decimation)
    states = np.column_stack([recording.output(n) for n in reference.state_names])[rows]
    inputs = np.column_stack([recording.input(n) for n in reference.input_names])[rows]
    predicted = np.vstack([states[:1], states[:-1] @ phi.T + inputs[:-1] @ gamma.T])
    return predicted[:, [reference.state_names.index(a) for a in config.outputs]]


def _by_axis(values, axes=AXES) -> dict:
    return {axis: float(v) for axis, v in zip(axes, values)}


def reproduce_bo105(out_dir, *, seed: int = 0, n_runs: int = 1000, beyond: bool = True,
                    progress: bool = True) -> dict:
    """Run the experiment, write figures, recordings, models and ``results.json`` to ``out_dir``.

    Parameters
    ----------
    out_dir : path
    seed : int, default 0
        Seeds the flight tests (training: ``seed``, unseen: ``seed + 1``), the annealing and
        the Monte Carlo free runs.
    n_runs : int, default 1000
        Monte Carlo runs R of the free runs.
    beyond : bool, default True
        Also run the beyond-the-paper studies.
    progress : bool
        Progress bars on stderr.

    Returns
    -------
    dict
        The content of ``results.json``.
    """
    out_dir = Path(out_dir)
    config = PAPER_CONFIG
    reference = get_vehicle("bo105-80kt")
    flights = _training_and_unseen(seed)
    for name, recording in flights.items():
        write_recording(out_dir / f"flight_test_{name}.csv", recording)

    started = clock.perf_counter()
    trained = train_narx([flights["training"]], config, seed=seed, progress=progress)
    training_s = clock.perf_counter() - started
    save_trained(out_dir / "bo105_gp_narx.npz", trained)  # with the flights' vehicle and speed

    osap = one_step(trained, flights["training"])
    fmp = free_run(trained, flights["training"], n_runs=n_runs, seed=seed, progress=progress)
    fmp_unseen = free_run(trained, flights["unseen"], n_runs=n_runs, seed=seed, progress=progress)
    first = osap.first
    ref_osap = _reference_one_step(reference, flights["training"], config)
    ref_fmp = _reference_free_run(reference, flights["training"], config)
    ref_unseen = _reference_free_run(reference, flights["unseen"], config)

    results = {
        "case": "Bo105 80 kt flight-test stand-in, 3-2-1-1 on theta_1s "
                f"({TRAINING_MANOEUVRE['amplitude_deg']} deg, {TRAINING_MANOEUVRE['step_time']} s steps)",
        "units": "RMSE in rad/s against the flight-test stand-in at the 0.1 s NARX samples; "
                 "coverage95 as a fraction of samples inside the 95 % band",
        "config": {**config.to_json(), "training_points": int(len(trained.model.model.gps[0].X_train_)),
                   "n_runs": n_runs, "seed": seed, "training_s": training_s},
        "osap": {"gp": _by_axis(osap.rmse()),
                 "reference": _by_axis(rmse(osap.measured[first:], ref_osap[first:], axis=0))},
        "fmp": {"gp": _by_axis(fmp.rmse()),
                "reference": _by_axis(rmse(fmp.measured[first:], ref_fmp[first:], axis=0))},
        "coverage95": _by_axis(fmp.coverage()),
        "unseen": {
            "manoeuvre": UNSEEN_MANOEUVRE,
            "fmp": {"gp": _by_axis(fmp_unseen.rmse()),
                    "reference": _by_axis(rmse(fmp_unseen.measured[first:], ref_unseen[first:], axis=0))},
            "coverage95": _by_axis(fmp_unseen.coverage()),
        },
        "relevance": trained.model.relevance(),
    }
    figures = {
        "osap.png": ("One-step-ahead prediction (OSAP), training manoeuvre", osap, ref_osap, True),
        "fmp.png": ("Full-model prediction (FMP, free run), training manoeuvre", fmp, ref_fmp, True),
        "fmp_unseen.png": ("Full-model prediction (FMP), unseen manoeuvre", fmp_unseen, ref_unseen, False),
    }
    for file_name, (title, prediction, ref, show_training) in figures.items():
        figure = paper_figure(prediction, ref, title=f"Bo105 80 kt: {title}",
                              training_time=trained.training_time if show_training else None)
        write_atomically(out_dir / file_name, png_bytes(figure))
    if beyond:
        results["beyond"] = beyond_the_paper(out_dir, seed=seed, n_runs=n_runs, progress=progress)
    write_json(out_dir / "results.json", results)
    return results


def paper_figure(prediction: NarxPrediction, reference: np.ndarray | None, *, title: str,
                 training_time=None, axes=AXES) -> Figure:
    """The paper's style: flight test, physics model, GP mean, 95 % band, training points as
    diamonds; one panel per rate."""
    figure = Figure(figsize=(8, 2.3 * len(axes) + 0.4), layout="constrained")
    FigureCanvasAgg(figure)
    panels = figure.subplots(len(axes), 1, sharex=True, squeeze=False)[:, 0]
    band = 1.96 * np.sqrt(prediction.var)
    for j, (panel, axis) in enumerate(zip(panels, axes)):
        panel.plot(prediction.time, prediction.measured[:, j], "k", lw=1, label="flight test (stand-in)")
        if reference is not None:
            panel.plot(prediction.time, reference[:, j], "--", color="tab:orange", label="physics model")
        panel.plot(prediction.time, prediction.mean[:, j], color="tab:blue", label="GP mean")
        panel.fill_between(prediction.time, prediction.mean[:, j] - band[:, j],
                           prediction.mean[:, j] + band[:, j], color="tab:blue", alpha=0.25,
                           label="GP 95 % band")
        if training_time is not None and len(training_time):
            index = np.searchsorted(prediction.time, training_time)
            index = index[index < len(prediction.time)]
            panel.plot(prediction.time[index], prediction.measured[index, j], "D", ms=4,
                       color="tab:green", label="training points")
        panel.set_ylabel(f"{axis} [{column_unit(axis)}]")
        panel.grid(True, alpha=0.3)
    panels[0].legend(fontsize="small", ncol=3, loc="upper right")
    panels[-1].set_xlabel("time [s]")
    figure.suptitle(title)
    return figure


def beyond_the_paper(out_dir: Path, *, seed: int, n_runs: int, progress: bool) -> dict:
    """The paper's future work, each measured on data the model did not see."""
    results = {}
    reference = get_vehicle("bo105-80kt")
    # (1) Lateral cyclic and pedal: one 3-2-1-1 per control for training; an unseen manoeuvre
    # with doublets on all three controls for testing.
    controls = ("theta_1s", "theta_1c", "theta_0T")
    training = [fly_3211("bo105-80kt-flight", input_name=c, amplitude=np.radians(1.0), step_time=0.4,
                         start=1.0, duration=8.0, seed=seed + 10 + i) for i, c in enumerate(controls)]
    multi_axis = _multi_axis_doublets(seed=seed + 20)
    write_recording(out_dir / "flight_test_multi_axis.csv", multi_axis)
    config = replace(PAPER_CONFIG, inputs=controls)
    trained = train_narx(training, config, seed=seed, progress=progress)
    prediction = free_run(trained, multi_axis, n_runs=n_runs, seed=seed, progress=progress)
    paper_only = train_narx(training[:1], PAPER_CONFIG, seed=seed, progress=progress)
    paper_prediction = free_run(paper_only, multi_axis, n_runs=n_runs, seed=seed, progress=progress)
    ref = _reference_free_run(reference, multi_axis, config)
    results["lateral_and_pedal_inputs"] = {
        "test": "unseen multi-axis doublets on theta_1s, theta_1c, theta_0T",
        "fmp": {"gp_all_controls": _by_axis(prediction.rmse()),
                "gp_longitudinal_only": _by_axis(paper_prediction.rmse()),
                "reference": _by_axis(rmse(prediction.measured[prediction.first:], ref[prediction.first:], axis=0))},
        "coverage95": _by_axis(prediction.coverage()),
    }
    write_atomically(out_dir / "fmp_multi_axis.png", png_bytes(paper_figure(
        prediction, ref, title="Bo105 80 kt, unseen multi-axis doublets: GP-NARX with lateral cyclic and pedal")))
    results["relevance_lag_selection"] = _lag_selection(seed=seed, n_runs=n_runs, progress=progress)
    results["sparse_all_samples"] = _sparse_all_samples(seed=seed, n_runs=n_runs, progress=progress)
    results["jsbsim_ah1s"] = _jsbsim_ah1s(out_dir, seed=seed, n_runs=n_runs, progress=progress)
    return results


#: The ah1s in hover is attitude-commanded by its AFCS: pitch rate is a fast (about 3 Hz)
#: transient and the AFCS feeds back attitude, so the NARX runs at 0.02 s and feeds back the
#: attitudes too. JSBSim has no sensor noise, so a short step does not drown in it.
AH1S_CONFIG = NarxConfig(inputs=("longitudinal_cyclic",), outputs=("p", "q", "r", "phi", "theta"),
                         input_lags=(1, 2), output_lags=(1, 2), decimation=2, stride=10)


def _jsbsim_ah1s(out_dir: Path, *, seed: int, n_runs: int, progress: bool) -> dict:
    """The same pipeline on JSBSim's ah1s in hover (a model nobody here wrote). There is no
    physics reference to compare with, so the baseline is "no response" (the rates' RMS about
    their mean): ``explained = 1 - (RMSE / RMS)^2``."""
    flights = {name: fly_3211("jsbsim:ah1s", input_name="longitudinal_cyclic", amplitude=amplitude,
                              step_time=step_time, start=1.0, duration=8.0, seed=seed)
               for name, amplitude, step_time in (("training", 0.1, 0.4), ("unseen", 0.15, 0.3))}
    trained = train_narx([flights["training"]], AH1S_CONFIG, seed=seed, progress=progress)
    results = {"config": AH1S_CONFIG.to_json(),
               "manoeuvres": {"training": "3-2-1-1, 0.1 of full longitudinal cyclic, 0.4 s steps",
                              "unseen": "3-2-1-1, 0.15 of full longitudinal cyclic, 0.3 s steps"}}
    for name, recording in flights.items():
        prediction = free_run(trained, recording, n_runs=n_runs, seed=seed, progress=progress)
        rms = prediction.measured[prediction.first:, :3].std(axis=0)
        rates_rmse = prediction.rmse()[:3]
        results[name] = {"fmp_rmse": _by_axis(rates_rmse), "rate_rms": _by_axis(rms),
                         "explained": _by_axis(1.0 - (rates_rmse / rms) ** 2),
                         "coverage95": _by_axis(prediction.coverage()[:3])}
        if name == "unseen":
            write_atomically(out_dir / "fmp_ah1s_unseen.png", png_bytes(paper_figure(
                prediction, None, title="JSBSim ah1s hover, unseen 3-2-1-1: GP-NARX free run",
                axes=AH1S_CONFIG.outputs)))
    return results


def _multi_axis_doublets(*, seed: int) -> Recording:
    vehicle = get_vehicle("bo105-80kt-flight")
    time = time_grid(duration=10.0, sample_time=vehicle.sample_time)
    inputs = np.zeros((len(time), len(vehicle.input_names)))
    for start, name in ((1.0, "theta_1s"), (4.0, "theta_1c"), (7.0, "theta_0T")):
        inputs[:, vehicle.input_names.index(name)] = doublet(time, amplitude=np.radians(1.0),
                                                             step_time=0.5, start=start)
    return vehicle.simulate(time, inputs, seed=seed)


#: Inducing points of the all-samples sparse GP (Titsias VFE; chosen by greedy variance).
SPARSE_INDUCING_POINTS = 40


def _sparse_all_samples(*, seed: int, n_runs: int, progress: bool) -> dict:
    """Every sample of the training manoeuvre (about 780 regressor rows) through a sparse GP,
    against the paper's every 25th sample through an exact GP; same kernel and annealing."""
    flights = _training_and_unseen(seed)
    configs = {"exact_every_25th": PAPER_CONFIG,
               "sparse_all_samples": replace(PAPER_CONFIG, stride=1, n_inducing=SPARSE_INDUCING_POINTS)}
    results = {"inducing_points": SPARSE_INDUCING_POINTS}
    for name, config in configs.items():
        started = clock.perf_counter()
        trained = train_narx([flights["training"]], config, seed=seed, progress=progress)
        seconds = clock.perf_counter() - started
        results[name] = {"training_rows": int(len(trained.model.model.gps[0].X_train_)),
                         "training_s": seconds}
        for flight, recording in flights.items():
            prediction = free_run(trained, recording, n_runs=n_runs, seed=seed, progress=progress)
            results[name][f"{flight}_fmp_rmse"] = _by_axis(prediction.rmse())
            results[name][f"{flight}_coverage95"] = _by_axis(prediction.coverage())
    return results


def _training_and_unseen(seed: int) -> dict:
    """The paper's training and unseen manoeuvres on the flight-test stand-in."""
    return {name: fly_3211("bo105-80kt-flight", input_name="theta_1s", seed=seed + offset,
                           amplitude=np.radians(manoeuvre["amplitude_deg"]),
                           **{k: v for k, v in manoeuvre.items() if k != "amplitude_deg"})
            for offset, (name, manoeuvre) in enumerate((("training", TRAINING_MANOEUVRE),
                                                        ("unseen", UNSEEN_MANOEUVRE)))}


def _lag_selection(*, seed: int, n_runs: int, progress: bool) -> dict:
    """Fit a wide candidate structure, keep regressors with ARD relevance >= 2 % for some output,
    refit with the kept lags, and compare free-run RMSE on the unseen manoeuvre."""
    flights = _training_and_unseen(seed)
    training, unseen = flights["training"], flights["unseen"]
    wide = replace(PAPER_CONFIG, input_lags=(1, 2, 3, 4), output_lags=(1, 2))
    trained_wide = train_narx([training], wide, seed=seed, progress=progress)
    relevance = trained_wide.model.relevance()
    threshold = 0.02
    kept_input = tuple(lag for lag in wide.input_lags
                       if max(relevance[o][f"theta_1s(k-{lag})"] for o in AXES) >= threshold)
    kept_output = tuple(lag for lag in wide.output_lags
                        if max(relevance[o][f"{a}(k-{lag})"] for o in AXES for a in AXES) >= threshold)
    chosen = replace(wide, input_lags=kept_input or (1,), output_lags=kept_output or (1,))
    trained_chosen = train_narx([training], chosen, seed=seed, progress=progress)
    unseen_rmse = {}
    for name, trained in (("wide", trained_wide), ("chosen", trained_chosen)):
        unseen_rmse[name] = _by_axis(free_run(trained, unseen, n_runs=n_runs, seed=seed).rmse())
    return {"threshold": threshold, "candidate_lags": {"input": list(wide.input_lags),
                                                       "output": list(wide.output_lags)},
            "relevance": relevance,
            "chosen_lags": {"input": list(chosen.input_lags), "output": list(chosen.output_lags)},
            "unseen_fmp_rmse": unseen_rmse}


def format_results(results: dict) -> str:
    """The paper's Tables 1-4 in one table: RMSE per axis, GP vs physics reference."""
    lines = [results["case"], results["units"], "",
             f"{'':28}{'p':>9}{'q':>9}{'r':>9}"]

    def row(label, values):
        lines.append(f"{label:28}" + "".join(f"{values[a]:9.4f}" for a in AXES))

    row("OSAP  GP", results["osap"]["gp"])
    row("OSAP  physics reference", results["osap"]["reference"])
    row("FMP   GP", results["fmp"]["gp"])
    row("FMP   physics reference", results["fmp"]["reference"])
    row("FMP   GP 95 % coverage", results["coverage95"])
    row("unseen FMP GP", results["unseen"]["fmp"]["gp"])
    row("unseen FMP physics ref.", results["unseen"]["fmp"]["reference"])
    row("unseen GP 95 % coverage", results["unseen"]["coverage95"])
    beyond = results.get("beyond")
    if beyond:
        lateral = beyond["lateral_and_pedal_inputs"]["fmp"]
        lines.append("")
        lines.append("beyond the paper (unseen multi-axis doublets, FMP RMSE):")
        row("  GP, all three controls", lateral["gp_all_controls"])
        row("  GP, longitudinal only", lateral["gp_longitudinal_only"])
        row("  physics reference", lateral["reference"])
        lags = beyond["relevance_lag_selection"]
        lines.append(f"lag selection by ARD relevance (>= {lags['threshold']:.0%}): chosen input lags "
                     f"{lags['chosen_lags']['input']}, output lags {lags['chosen_lags']['output']}")
        row("  unseen FMP, wide", lags["unseen_fmp_rmse"]["wide"])
        row("  unseen FMP, chosen", lags["unseen_fmp_rmse"]["chosen"])
        sparse = beyond["sparse_all_samples"]
        lines.append(f"all samples, sparse GP ({sparse['inducing_points']} inducing points, "
                     f"{sparse['sparse_all_samples']['training_rows']} rows) vs every 25th, exact:")
        row("  training FMP, sparse all", sparse["sparse_all_samples"]["training_fmp_rmse"])
        row("  training FMP, exact 25th", sparse["exact_every_25th"]["training_fmp_rmse"])
        row("  unseen FMP, sparse all", sparse["sparse_all_samples"]["unseen_fmp_rmse"])
        row("  unseen FMP, exact 25th", sparse["exact_every_25th"]["unseen_fmp_rmse"])
        ah1s = beyond["jsbsim_ah1s"]["unseen"]
        lines.append("JSBSim ah1s hover, unseen 3-2-1-1 (no physics reference; baseline = no response):")
        row("  GP FMP RMSE", ah1s["fmp_rmse"])
        row("  rate RMS (baseline RMSE)", ah1s["rate_rms"])
        row("  GP 95 % coverage", ah1s["coverage95"])
    return "\n".join(lines)
