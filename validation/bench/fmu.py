"""``flightgp bench fmu``: per-step cost of the GP FMUs in fmpy against a bare pythonfmu FMU,
and of the native FMUs against the pythonfmu FMU of the same model, in fmpy and in the plain C
host (docs/benchmarks.md)."""
from __future__ import annotations

import time

import numpy as np

from validation.bench.rows import SummaryRow

#: Goals of the native FMU (docs/benchmarks.md): a step, variance included, at least this many times
#: cheaper than the pythonfmu FMU's, and under this many microseconds at 500 training points.
NATIVE_GOAL_RATIO, NATIVE_GOAL_US = 10.0, 10.0


#: ``bench fmu``'s blimp RKGP model: seconds of blimp-flight (20 Hz, true states) under random
#: piecewise-constant commands held for ``BLIMP_HOLD`` frames (the blimp RKGP FMU tests train
#: theirs the same way).
BLIMP_SECONDS, BLIMP_HOLD = 10.0, 10


#: A bare pythonfmu FMU with the rate predictor's variables that copies its inputs to its outputs:
#: the per-step overhead any pythonfmu FMU pays in fmpy, the peer of ``bench fmu``.
_BARE_FMU_SCRIPT = """
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

INPUTS = {inputs!r}
OUTPUTS = {outputs!r}


class {name}(Fmi2Slave):
    description = "bare pythonfmu FMU: outputs copy inputs (flightgp bench fmu peer)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        for name in INPUTS:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input,
                                        variability=Fmi2Variability.continuous, start=0.0))
        for name in OUTPUTS:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.output,
                                        variability=Fmi2Variability.continuous, initial="exact",
                                        start=0.0))

    def do_step(self, current_time, step_size):
        for index, name in enumerate(OUTPUTS):
            setattr(self, name, getattr(self, INPUTS[index % len(INPUTS)]))
        return True
"""


def _time_fmu_steps(fmu_path, inputs, outputs, *, n_steps: int, step: float, repeats: int = 3,
                    values=None, start_values: dict | None = None) -> float:
    """Best-of-``repeats`` wall time per communication step (s) of ``setReal(inputs)``,
    ``doStep``, ``getReal(outputs)`` in fmpy's FMU2Slave, with varying input values: ``values``
    (shape (n_steps, len(inputs)), row ``k`` set before step ``k``), by default small sines.
    ``start_values`` (Real name -> value) are set before initialisation in every repeat."""
    import shutil

    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    description = read_model_description(str(fmu_path))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    unzipdir = extract(str(fmu_path))
    try:
        fmu = FMU2Slave(guid=description.guid, unzipDirectory=unzipdir,
                        modelIdentifier=description.coSimulation.modelIdentifier, instanceName="bench")
        fmu.instantiate()
        in_refs, out_refs = [refs[n] for n in inputs], [refs[n] for n in outputs]
        if values is None:
            values = 0.01 * np.sin(np.arange(n_steps)[:, None] + np.arange(len(inputs)))
        starts = start_values or {}
        best = np.inf
        for _ in range(repeats):
            fmu.reset()
            if starts:
                fmu.setReal([refs[n] for n in starts], [float(v) for v in starts.values()])
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
            begin = time.perf_counter()
            for k in range(n_steps):  # time from the step counter, t = k h
                fmu.setReal(in_refs, values[k].tolist())
                fmu.doStep(currentCommunicationPoint=k * step, communicationStepSize=step)
                fmu.getReal(out_refs)
            best = min(best, (time.perf_counter() - begin) / n_steps)
        fmu.terminate()
        fmu.freeInstance()
    finally:
        shutil.rmtree(unzipdir, ignore_errors=True)
    return best


def run(*, n_steps: int = 2000, seed: int = 0, progress: bool = True) -> dict:
    """Per-step cost in fmpy of the Bo105 GP rate-predictor FMU (the paper's model: 32
    training points, Higdon kernel, 400 annealing samples per output) against a bare pythonfmu
    FMU with the same variables, both built and timed in this run.

    Then the native FMUs against the pythonfmu FMU of the same model, timed in fmpy and
    in the plain C host: the rate predictor of the paper's model and of :data:`NATIVE_MODELS`
    (:func:`_native_rows`, key ``"native"``), and the blimp RKGP (:func:`blimp_rkgp_row`, key
    ``"blimp"``).

    Returns
    -------
    dict
        ``{"steps", "gp_us_per_step", "bare_us_per_step", "gp_over_bare", "goal_ratio",
        "goal_met", "training_points", "hyperparameter_samples", "real_time_factor_at_narx_step",
        "native_us_per_step", "native_over_bare", "gp_over_native", "native", "native_goal_ratio",
        "native_goal_us_at_500", "blimp"}``.
    """
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    from fmu_src import build_rate_predictor_fmu
    from validation.models.narx import save_trained, train_narx
    from validation.reproduce.bo105 import PAPER_CONFIG, TRAINING_MANOEUVRE, fly_3211

    recording = fly_3211("bo105-80kt-flight", input_name="theta_1s",
                         amplitude=np.radians(TRAINING_MANOEUVRE["amplitude_deg"]),
                         step_time=TRAINING_MANOEUVRE["step_time"], start=1.0, duration=8.0, seed=seed)
    trained = train_narx([recording], PAPER_CONFIG, seed=seed, progress=progress)
    inputs = [*PAPER_CONFIG.inputs, *(f"{o}_prev" for o in PAPER_CONFIG.outputs)]
    outputs = [n for o in PAPER_CONFIG.outputs for n in (o, f"{o}_lower", f"{o}_upper")]
    with tempfile.TemporaryDirectory(prefix="flightgp-bench-fmu-") as scratch:
        scratch = Path(scratch)
        gp_fmu = build_rate_predictor_fmu(save_trained(scratch / "gp.npz", trained), scratch,
                                          name="bench_gp_rate_predictor")
        script = scratch / "bench_bare_fmu.py"
        script.write_text(_BARE_FMU_SCRIPT.format(inputs=inputs, outputs=outputs, name="bench_bare_fmu"))
        subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(script), "-d", str(scratch)],
                       check=True, capture_output=True)
        step = trained.step
        bare = _time_fmu_steps(scratch / "bench_bare_fmu.fmu", inputs, outputs, n_steps=n_steps, step=step)
        gp = _time_fmu_steps(gp_fmu, inputs, outputs, n_steps=n_steps, step=step)
        native = _native_rows(scratch, scratch / "gp.npz", gp, inputs, outputs, n_steps=n_steps, step=step,
                              seed=seed, progress=progress)
        blimp = blimp_rkgp_row(scratch, n_steps=n_steps, seed=seed)
    samples = [len(g.theta_samples_) for g in trained.model.model.gps]
    return {"steps": n_steps, "gp_us_per_step": gp * 1e6, "bare_us_per_step": bare * 1e6,
            "gp_over_bare": gp / bare, "goal_ratio": FMU_GOAL_RATIO, "goal_met": gp / bare <= FMU_GOAL_RATIO,
            "training_points": int(len(trained.model.model.gps[0].X_train_)),
            "hyperparameter_samples": samples,
            "real_time_factor_at_narx_step": step / gp, "narx_step_s": step,
            "native_us_per_step": native[0]["native_us_per_step"], "native_over_bare":
                native[0]["native_us_per_step"] / (bare * 1e6),
            "gp_over_native": gp * 1e6 / native[0]["native_us_per_step"], "native": native,
            "native_goal_ratio": NATIVE_GOAL_RATIO, "native_goal_us_at_500": NATIVE_GOAL_US, "blimp": blimp}


#: Goal of ``bench fmu`` (docs/benchmarks.md): the GP adds at most this factor to the bare FMU's step cost.
FMU_GOAL_RATIO = 3.0


#: ``bench fmu``'s native comparison besides the paper's model: label, changes to
#: ``PAPER_CONFIG``, training rows (None: the paper's 3-2-1-1 at stride 25, 32 points).
NATIVE_MODELS = (
    ("32 points, 1 sample (max. likelihood)", {"hyperparameters": "maximum_likelihood"}, None),
    ("500 points, 1 sample (max. likelihood)", {"hyperparameters": "maximum_likelihood", "stride": 1}, 500),
    ("500 points, 50 inducing (sparse)", {"hyperparameters": "maximum_likelihood", "stride": 1,
                                          "n_inducing": 50}, 500),
)
#: The summary ids of the paper's model and of :data:`NATIVE_MODELS`, in that order.
NATIVE_IDS = ("paper", "single", "n500", "sparse50")
#: Real-time factor a native rate-predictor step must allow in the C host (the co-simulation
#: goal, :data:`validation.bench.cosim.COSIM_GOAL_REAL_TIME`): its per-step goal is the
#: model's step over this.
NATIVE_GOAL_REAL_TIME = 200.0


def _native_rows(scratch, paper_model, paper_gp_s: float, inputs, outputs, *, n_steps: int, step: float,
                 seed: int, progress: bool) -> list:
    """Per-step cost of native rate-predictor FMUs (:mod:`fmu_src.rate_predictor.native`) next to the pythonfmu
    FMU of the same model: the paper's model (``paper_model``, whose pythonfmu FMU took
    ``paper_gp_s`` per step) and :data:`NATIVE_MODELS`. The native FMU is timed in fmpy (the same
    ``setReal`` + ``doStep`` + ``getReal`` through ctypes as the pythonfmu FMUs) and in the plain C
    host (:func:`validation.cosim.hosts.simulate_in_c_host`: the same three calls without Python).

    Returns
    -------
    list of dict
        ``{"model", "training_points", "basis_points", "hyperparameter_samples",
        "pythonfmu_us_per_step", "native_us_per_step", "native_c_host_us_per_step",
        "pythonfmu_over_native", "pythonfmu_over_native_c_host"}`` per model, the paper's first.
    """
    from dataclasses import replace

    from fmu_src import build_native_rate_predictor_fmu, build_rate_predictor_fmu
    from validation.cosim.hosts import simulate_in_c_host
    from validation.models.narx import load_trained, save_trained, train_narx
    from validation.reproduce.bo105 import PAPER_CONFIG, TRAINING_MANOEUVRE, fly_3211

    values = 0.01 * np.sin(np.arange(n_steps + 1)[:, None] + np.arange(len(inputs)))
    signals = dict(zip(inputs, values.T))
    models = [("paper: 32 points, 400 samples (annealing)", paper_model, paper_gp_s)]
    for label, changes, rows in NATIVE_MODELS:
        config = replace(PAPER_CONFIG, **changes)
        # rows regressor rows at stride 1: a recording of rows + max_lag NARX steps of samples
        duration = (8.0 if rows is None else
                    (rows + config.structure().max_lag * config.decimation - 1) * 0.01)
        recording = fly_3211("bo105-80kt-flight", input_name="theta_1s",
                             amplitude=np.radians(TRAINING_MANOEUVRE["amplitude_deg"]),
                             step_time=TRAINING_MANOEUVRE["step_time"], start=1.0, duration=duration, seed=seed)
        trained = train_narx([recording], config, seed=seed, progress=progress, n_restarts=0)
        path = save_trained(scratch / f"native_{len(models)}.npz", trained)
        python_fmu = build_rate_predictor_fmu(path, scratch, name=f"bench_python_{len(models)}")
        models.append((label, path, _time_fmu_steps(python_fmu, inputs, outputs, n_steps=n_steps, step=step)))
    result = []
    for index, (label, path, python_s) in enumerate(models):
        fmu = build_native_rate_predictor_fmu(path, scratch, name=f"bench_native_{index}")
        native_s = _time_fmu_steps(fmu, inputs, outputs, n_steps=n_steps, step=step)
        c_host_us = simulate_in_c_host(fmu, step_size=step, n_steps=n_steps, inputs=signals, outputs=outputs,
                                       repeats=3)["us_per_step"]
        gps = load_trained(path).model.model.gps
        forms = gps[0].predictive_forms(use_samples=True)
        result.append({"model": label, "training_points": int(len(gps[0].X_train_)),
                       "basis_points": int(len(forms[0].basis)), "hyperparameter_samples": len(forms),
                       "pythonfmu_us_per_step": python_s * 1e6, "native_us_per_step": native_s * 1e6,
                       "native_c_host_us_per_step": c_host_us, "pythonfmu_over_native": python_s / native_s,
                       "pythonfmu_over_native_c_host": python_s * 1e6 / c_host_us})
    return result


def blimp_rkgp_row(scratch, *, n_steps: int, seed: int = 0) -> dict:
    """Per-step cost of the native blimp RKGP FMU (:func:`fmu_src.build_native_blimp_rkgp_fmu`)
    against the pythonfmu blimp RKGP FMU (:func:`fmu_src.build_blimp_rkgp_fmu`), both built
    in ``scratch`` from one small grey-box model trained here as the FMU tests do:
    :data:`BLIMP_SECONDS` of ``blimp-flight`` (mocap off, 20 Hz) under random commands, a shared GP
    on the RK4 physics leaving out position and yaw (200 training pairs, maximum likelihood
    without restarts: about a second). Timed by :func:`time_blimp_rkgp_fmus` on the training
    commands from the training start state (inside the envelope).

    Returns
    -------
    dict
        :func:`time_blimp_rkgp_fmus`'s, with ``"model"`` and ``"training_pairs"``.
    """
    from pathlib import Path

    from fmu_src import build_blimp_rkgp_fmu, build_native_blimp_rkgp_fmu
    from gp_model import GreyBoxGP, save_model
    from validation.models.blimp_greybox import BlimpStepDescription
    from validation.models.blimp_identification import physics_step, recording_arrays
    from validation.vehicles.blimp import BlimpParameters
    from validation.vehicles.blimp_flight import BlimpFlightTest

    scratch = Path(scratch)
    time_ = np.arange(int(round(BLIMP_SECONDS / BlimpFlightTest.sample_time)) + 1) * BlimpFlightTest.sample_time
    rng = np.random.default_rng(seed)
    levels = lambda low, high: np.repeat(  # noqa: E731
        rng.uniform(low, high, len(time_) // BLIMP_HOLD + 1), BLIMP_HOLD)[:len(time_)]
    commands = np.column_stack([levels(0.2, 0.8), levels(-0.2, 0.4), levels(-0.6, 0.6)])
    states, step_inputs = recording_arrays(BlimpFlightTest(mocap=False).simulate(time_, commands, seed=seed))
    params = BlimpParameters()
    model = GreyBoxGP(state_columns=(3, 4, 6, 7, 8, 9, 10, 11), n_restarts=0).fit_trajectories(
        [(states, step_inputs)], physics_step(params))
    path = save_model(scratch / "blimp_rkgp.npz", model, physics=BlimpStepDescription(params).as_dict())
    row = time_blimp_rkgp_fmus(build_blimp_rkgp_fmu(path, scratch, name="bench_blimp_python"),
                               build_native_blimp_rkgp_fmu(path, scratch, name="bench_blimp_native"),
                               commands, states[0], n_steps=n_steps)
    pairs = int(len(states) - 1)
    return {"model": f"blimp RKGP: {pairs} pairs, shared GP, 1 sample (max. likelihood)",
            "training_pairs": pairs, **row}


def time_blimp_rkgp_fmus(python_fmu, native_fmu, commands, start, *, n_steps: int) -> dict:
    """Per-step cost of a pythonfmu and a native blimp RKGP FMU of one model flying ``commands``
    (shape (n + 1, 3), one row per 20 Hz frame) from the state ``start`` (12,), for
    ``min(n_steps, n)`` steps: ``setReal`` + ``doStep`` + ``getReal`` (3 commands in, 12 states
    and 12 sds out), best of 3, in fmpy (both FMUs) and in the plain C host
    (:func:`validation.cosim.hosts.simulate_in_c_host`, the native one).

    Returns
    -------
    dict
        ``{"steps", "pythonfmu_us_per_step", "native_us_per_step", "native_c_host_us_per_step",
        "pythonfmu_over_native", "pythonfmu_over_native_c_host"}``.
    """
    from validation.cosim.hosts import simulate_in_c_host
    from validation.vehicles.blimp import INPUT_NAMES, STATE_NAMES
    from validation.vehicles.blimp_flight import BlimpFlightTest

    h, commands = BlimpFlightTest.sample_time, np.asarray(commands, dtype=float)
    steps = min(n_steps, len(commands) - 1)
    outputs = [*STATE_NAMES, *(f"{s}_sd" for s in STATE_NAMES)]
    starts = {f"{s}_start": float(v) for s, v in zip(STATE_NAMES, start)}
    python_us, native_us = (_time_fmu_steps(fmu, INPUT_NAMES, outputs, n_steps=steps, step=h,
                                            values=commands[:steps], start_values=starts) * 1e6
                            for fmu in (python_fmu, native_fmu))
    c_host_us = simulate_in_c_host(native_fmu, step_size=h, n_steps=steps, outputs=outputs, start_values=starts,
                                   inputs=dict(zip(INPUT_NAMES, commands[:steps + 1].T)),
                                   repeats=3)["us_per_step"]
    return {"steps": steps, "pythonfmu_us_per_step": python_us, "native_us_per_step": native_us,
            "native_c_host_us_per_step": c_host_us, "pythonfmu_over_native": python_us / native_us,
            "pythonfmu_over_native_c_host": python_us / c_host_us}


def format_table(report: dict) -> str:
    """The ``bench fmu`` report as a table."""
    blimp = report.get("blimp")
    native = [
        "",
        f"Native (C) FMUs vs the pythonfmu FMU of the same model, us per step (fmpy: the same calls "
        f"through ctypes; C host: the same calls from C, no Python); goals: >= "
        f"{report['native_goal_ratio']:g}x cheaper, < {report['native_goal_us_at_500']:g} us at 500 points",
        f"{'model':<42} {'basis':>5} {'S':>4} {'pythonfmu':>10} {'native':>8} {'C host':>8} {'ratio':>7} "
        f"{'ratio C':>8}",
        *(f"{r['model']:<42} {r['basis_points']:>5} {r['hyperparameter_samples']:>4} "
          f"{r['pythonfmu_us_per_step']:>10.1f} {r['native_us_per_step']:>8.1f} "
          f"{r['native_c_host_us_per_step']:>8.2f} {r['pythonfmu_over_native']:>6.1f}x "
          f"{r['pythonfmu_over_native_c_host']:>7.1f}x" for r in report.get("native", [])),
        *([f"{'blimp RKGP (shared GP, RK4 physics)':<42} {blimp['training_pairs']:>5} {1:>4} "
           f"{blimp['pythonfmu_us_per_step']:>10.1f} {blimp['native_us_per_step']:>8.1f} "
           f"{blimp['native_c_host_us_per_step']:>8.2f} {blimp['pythonfmu_over_native']:>6.1f}x "
           f"{blimp['pythonfmu_over_native_c_host']:>7.1f}x",
           f"(blimp RKGP: 3 commands in, 12 states and 12 sds out, {blimp['steps']} steps of its training "
           "flight at 20 Hz)"] if blimp else []),
    ] if report.get("native") or blimp else []
    return "\n".join([
        f"Rate-predictor FMU step cost in fmpy (setReal + doStep + getReal, best of 3 x "
        f"{report['steps']} steps) vs a bare pythonfmu FMU with the same variables; "
        f"{report['training_points']} training points, {report['hyperparameter_samples'][0]} "
        "hyperparameter samples per output",
        f"{'GP FMU us/step':>15} {'bare us/step':>13} {'ratio':>8} {'goal':>7} {'met':>4} {'x real time':>12}",
        f"{report['gp_us_per_step']:15.1f} {report['bare_us_per_step']:13.1f} "
        f"{report['gp_over_bare']:7.1f}x {'<=' + format(report['goal_ratio'], 'g') + 'x':>7} "
        f"{'yes' if report['goal_met'] else 'no':>4} {report['real_time_factor_at_narx_step']:12.0f}",
        *native,
    ])


def summary_rows(report: dict) -> list[SummaryRow]:
    """Headline rows: the pythonfmu GP FMU against the bare one; each native rate predictor in
    the C host (the paper's model against the step that :data:`NATIVE_GOAL_REAL_TIME` x real
    time allows, the others as a ratio to their pythonfmu FMU, at 500 points also in us); the
    blimp RKGP."""
    rows = [SummaryRow("fmu.pythonfmu.gp_over_bare", "pythonfmu GP FMU step vs bare pythonfmu FMU",
                       report["gp_over_bare"], "x the cost", report["goal_ratio"], at_least=False)]
    budget_us = report["narx_step_s"] * 1e6 / NATIVE_GOAL_REAL_TIME
    for key, row in zip(NATIVE_IDS, report.get("native", [])):
        cheaper = f"{row['pythonfmu_over_native_c_host']:.1f}x cheaper than pythonfmu"
        if key == "paper":
            rows.append(SummaryRow("fmu.paper.native.step_us", f"native FMU step in the C host, {row['model']}",
                                   row["native_c_host_us_per_step"], "us", budget_us, at_least=False, note=cheaper))
            continue
        rows.append(SummaryRow(f"fmu.{key}.native.speedup", f"native vs pythonfmu FMU step, {row['model']}",
                               row["pythonfmu_over_native_c_host"], "x", report["native_goal_ratio"],
                               note=f"{row['native_c_host_us_per_step']:.1f} us (C host)"))
        if row["training_points"] >= 500:
            rows.append(SummaryRow(f"fmu.{key}.native.step_us", f"native FMU step in the C host, {row['model']}",
                                   row["native_c_host_us_per_step"], "us", report["native_goal_us_at_500"],
                                   at_least=False))
    blimp = report.get("blimp")
    if blimp:
        rows.append(SummaryRow("fmu.blimp_rkgp.native.speedup",
                               f"native vs pythonfmu FMU step, blimp RKGP, {blimp['training_pairs']} pairs",
                               blimp["pythonfmu_over_native_c_host"], "x", report["native_goal_ratio"],
                               note=f"{blimp['native_c_host_us_per_step']:.1f} us (C host)"))
    return rows
