"""``flightgp bench cosim``: the GP rate-predictor FMU's stepping loop in fmpy against simulated
time, and the co-simulation next to the reference FMU against the reference FMU alone
(docs/benchmarks.md)."""
from __future__ import annotations

import time

import numpy as np

from validation.bench.rows import SummaryRow

#: Goal of ``bench cosim`` (docs/benchmarks.md): the 8 s 3-2-1-1 co-simulation at least this many times
#: faster than real time.
COSIM_GOAL_REAL_TIME = 200.0
#: Goal of the pythonfmu GP FMU, x real time: a Python FMU pays pythonfmu's per-call overhead.
COSIM_GOAL_REAL_TIME_PYTHONFMU = 50.0
#: The summary ids of the co-simulated models, in the order ``run`` flies them.
MODEL_IDS = ("paper", "single")
#: The GP FMUs stepped per model: kind (the summary id's part) -> (which FMU, ``parallel``). The
#: native FMU computes its free run on two threads (``parallel = true``) and, as a second row, on
#: one; the pythonfmu FMU has the parameter but runs on one thread either way.
STEPPED = {"pythonfmu": ("pythonfmu", False), "native": ("native", True), "native_one_thread": ("native", False)}


def run(*, seed: int = 0, repeats: int = 3, progress: bool = True) -> dict:
    """Real-time factor of the GP rate-predictor FMU in fmpy as a simulator runs it: loaded once,
    then the stepping loop (``setReal`` of the cyclic input, ``doStep``, ``getReal`` of every
    output) in free-run mode along the 8 s 80 kt 3-2-1-1 at the NARX step, ``repeats`` times
    (:func:`validation.bench.fmu.time_stepping`); the factor is the simulated time over the
    median loop. Loading (extraction, instantiation, initialisation) is timed separately, and
    so is the whole co-simulation next to the Bo105 reference FMU (``flightgp cosim``, best of
    ``repeats``; the reference FMU alone in the same loop is the peer). For the pythonfmu and
    the native GP FMU of two models: the paper's (32 points, 400 annealing samples) and one with
    a single (maximum-likelihood) hyperparameter set; the native FMU on its fast path, on two
    threads and on one (:data:`STEPPED`). The co-simulation next to the reference runs each FMU
    as ``flightgp cosim`` does (one thread).

    Returns
    -------
    dict
        ``{"simulated_s", "goal_real_time", "rows": [{"model", "fmu", "loop_s" (per repeat),
        "real_time_factor", "load_s", "cosim_s", "cosim_real_time_factor", "over_reference_alone",
        "goal_real_time", "goal_met"}], "reference_alone_s", "repeats"}``.
    """
    import tempfile
    from dataclasses import replace
    from pathlib import Path

    from fmu_src import build_bo105_reference_fmu, build_native_rate_predictor_fmu, build_rate_predictor_fmu
    from validation.bench.fmu import time_stepping
    from validation.cosim.cosimulation import cosimulate, simulate
    from validation.models.narx import save_trained, train_narx
    from validation.reproduce.bo105 import PAPER_CONFIG, TRAINING_MANOEUVRE, fly_3211

    recording = fly_3211("bo105-80kt-flight", input_name="theta_1s",
                         amplitude=np.radians(TRAINING_MANOEUVRE["amplitude_deg"]),
                         step_time=TRAINING_MANOEUVRE["step_time"], start=1.0, duration=8.0, seed=seed)
    simulated = float(recording.time[-1] - recording.time[0])
    models = (("paper: 32 points, 400 samples", PAPER_CONFIG, {}),
              ("32 points, 1 sample (max. likelihood)",
               replace(PAPER_CONFIG, hyperparameters="maximum_likelihood"), {"n_restarts": 0}))
    rows_01 = slice(None, None, PAPER_CONFIG.decimation)  # the recording (100 Hz) on the 0.1 s NARX grid
    theta = recording.input("theta_1s")[rows_01]
    outputs = [n for o in PAPER_CONFIG.outputs for n in (o, f"{o}_lower", f"{o}_upper")]
    rows = []
    with tempfile.TemporaryDirectory(prefix="flightgp-bench-cosim-") as scratch:
        scratch = Path(scratch)
        reference = build_bo105_reference_fmu(80, scratch, name="bench_reference")
        reference_alone = _best_time(lambda: simulate(
            reference, time=recording.time[rows_01] - recording.time[0],
            inputs={c: recording.input(c)[rows_01] for c in recording.input_names}, outputs=["p", "q", "r"]),
            repeats=repeats)
        for index, (label, config, options) in enumerate(models):
            trained = train_narx([recording], config, seed=seed, progress=progress, **options)
            path = save_trained(scratch / f"model_{index}.npz", trained)
            fmus = {kind: build(path, scratch, name=f"bench_{kind}_{index}") for kind, build
                    in (("pythonfmu", build_rate_predictor_fmu), ("native", build_native_rate_predictor_fmu))}
            cosim_s = {kind: _best_time(lambda fmu=fmu: cosimulate(fmu, recording, reference_fmu=reference),
                                        repeats=repeats) for kind, fmu in fmus.items()}
            for kind, (built, parallel) in STEPPED.items():
                stepping = time_stepping(fmus[built], ["theta_1s"], outputs, n_steps=len(theta) - 1,
                                         step=trained.step, repeats=repeats, values=theta[:-1, None],
                                         start_values={"free_run": True, "parallel": parallel})
                factor = simulated / float(np.median(stepping.loop_s))
                rows.append({"model": label, "fmu": kind, "loop_s": list(stepping.loop_s),
                             "real_time_factor": factor, "load_s": stepping.load_s, "cosim_s": cosim_s[built],
                             "cosim_real_time_factor": simulated / cosim_s[built],
                             "over_reference_alone": cosim_s[built] / reference_alone,
                             "goal_real_time": _goal(kind), "goal_met": factor >= _goal(kind)})
    return {"simulated_s": simulated, "goal_real_time": COSIM_GOAL_REAL_TIME,
            "reference_alone_s": reference_alone, "rows": rows, "repeats": repeats}


def _best_time(call, *, repeats: int = 3) -> float:
    """Best wall-clock seconds of ``call()`` over ``repeats`` calls."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - start)
    return best


def format_table(report: dict) -> str:
    """The ``bench cosim`` report as a table."""
    return "\n".join([
        f"GP rate-predictor FMU in fmpy, free run along the {report['simulated_s']:g} s 80 kt 3-2-1-1: the "
        f"stepping loop, {report.get('repeats', 3)} runs (x real time at the median); loading timed apart; the "
        f"co-simulation next to the Bo105 reference FMU (best of {report.get('repeats', 3)}; reference FMU alone "
        f"{report['reference_alone_s'] * 1e3:.0f} ms); goal >= {report['goal_real_time']:g}x real time native, "
        f">= {COSIM_GOAL_REAL_TIME_PYTHONFMU:g}x pythonfmu",
        f"{'model':<40} {'GP FMU':<17} {'loop s (runs)':>24} {'x real time':>12} {'load s':>7} {'cosim s':>8} "
        f"{'x ref.':>7} {'met':>4}",
        *(f"{r['model']:<40} {r['fmu']:<17} {' '.join(f'{t:.3f}' for t in r['loop_s']):>24} "
          f"{r['real_time_factor']:12.1f} {r['load_s']:7.3f} {r['cosim_s']:8.3f} {r['over_reference_alone']:7.1f} "
          f"{'yes' if r['goal_met'] else 'no':>4}" for r in report["rows"]),
    ])


def _goal(kind: str) -> float:
    """The real-time goal of a GP FMU of ``kind`` (a key of :data:`STEPPED`)."""
    return COSIM_GOAL_REAL_TIME_PYTHONFMU if kind == "pythonfmu" else COSIM_GOAL_REAL_TIME


def summary_rows(report: dict) -> list[SummaryRow]:
    """Headline rows: each model's native and pythonfmu co-simulation against real time."""
    models = list(dict.fromkeys(r["model"] for r in report["rows"]))
    return [SummaryRow(f"cosim.{MODEL_IDS[models.index(r['model'])]}.{r['fmu']}.realtime",
                       f"{r['fmu']} GP FMU stepping in fmpy, free run, {r['model']}", r["real_time_factor"],
                       "x real time", r.get("goal_real_time", _goal(r["fmu"])),
                       note=f"median of {len(r['loop_s'])}; load {r['load_s']:.3f} s; next to the reference FMU "
                            f"{r['cosim_real_time_factor']:.1f}x (the FMU's defaults)") for r in report["rows"]]
