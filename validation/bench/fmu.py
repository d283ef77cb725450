"""``flightgp bench fmu``: per-step cost of the GP FMUs in fmpy against a bare pythonfmu FMU,
and of the native FMUs against the pythonfmu FMU of the same model, in fmpy and in the plain C
host (docs/benchmarks.md)."""
from __future__ import annotations

import time
from dataclasses import dataclass

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


@dataclass(frozen=True)
class SteppingTimes:
    """Wall times of one FMU in fmpy (:func:`time_stepping`).

    Attributes
    ----------
    load_s : float
        Extraction, ``fmi2Instantiate`` and the first initialisation, s (what a simulator pays
        once).
    loop_s : tuple of float
        Per repeat, the stepping loop: ``setReal(inputs)``, ``doStep``, ``getReal(outputs)`` for
        every step, s.
    n_steps : int
    """

    load_s: float
    loop_s: tuple
    n_steps: int

    @property
    def best_step_s(self) -> float:
        """The fastest repeat's time per step, s."""
        return min(self.loop_s) / self.n_steps


def time_stepping(fmu_path, inputs, outputs, *, n_steps: int, step: float, repeats: int = 3, values=None,
                  start_values: dict | None = None) -> SteppingTimes:
    """Time an FMU in fmpy's FMU2Slave as a simulator runs it: loaded once (timed), then
    ``repeats`` times reset, initialised and stepped ``n_steps`` times (each stepping loop timed),
    with varying input values: ``values`` (shape (n_steps, len(inputs)), row ``k`` set before
    step ``k``), by default small sines. ``start_values`` (name -> value; Booleans by their
    variable's type) are set before every initialisation."""
    import shutil

    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    begin = time.perf_counter()
    description = read_model_description(str(fmu_path))
    variables = {v.name: v for v in description.modelVariables}
    unzipdir = extract(str(fmu_path))
    try:
        fmu = FMU2Slave(guid=description.guid, unzipDirectory=unzipdir,
                        modelIdentifier=description.coSimulation.modelIdentifier, instanceName="bench")
        fmu.instantiate()
        in_refs = [variables[n].valueReference for n in inputs]
        out_refs = [variables[n].valueReference for n in outputs]
        if values is None:
            values = 0.01 * np.sin(np.arange(n_steps)[:, None] + np.arange(len(inputs)))
        starts = start_values or {}
        booleans = {n: v for n, v in starts.items() if variables[n].type == "Boolean"}
        reals = {n: v for n, v in starts.items() if variables[n].type != "Boolean"}
        loops, load_s = [], None
        for _ in range(repeats):
            if load_s is not None:
                fmu.reset()
            if reals:
                fmu.setReal([variables[n].valueReference for n in reals], [float(v) for v in reals.values()])
            if booleans:
                fmu.setBoolean([variables[n].valueReference for n in booleans], [bool(v) for v in booleans.values()])
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
            if load_s is None:
                load_s = time.perf_counter() - begin
            start = time.perf_counter()
            for k in range(n_steps):  # time from the step counter, t = k h
                fmu.setReal(in_refs, values[k].tolist())
                fmu.doStep(currentCommunicationPoint=k * step, communicationStepSize=step)
                fmu.getReal(out_refs)
            loops.append(time.perf_counter() - start)
        fmu.terminate()
        fmu.freeInstance()
    finally:
        shutil.rmtree(unzipdir, ignore_errors=True)
    return SteppingTimes(load_s, tuple(loops), n_steps)


def _time_fmu_steps(fmu_path, inputs, outputs, *, n_steps: int, step: float, repeats: int = 3,
                    values=None, start_values: dict | None = None) -> float:
    """Best-of-``repeats`` wall time per communication step (s) of :func:`time_stepping`."""
    return time_stepping(fmu_path, inputs, outputs, n_steps=n_steps, step=step, repeats=repeats, values=values,
                         start_values=start_values).best_step_s


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
        "native_goal_us_at_500", "blimp", "paper_free_run"}`` (:func:`paper_free_run_rows`).
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
        free_run = paper_free_run_rows(scratch / "bench_native_0.fmu",
                                       recording.input("theta_1s")[::PAPER_CONFIG.decimation], step=step)
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
            "native_goal_ratio": NATIVE_GOAL_RATIO, "native_goal_us_at_500": NATIVE_GOAL_US, "blimp": blimp,
            "paper_free_run": free_run}


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


#: FLOPs per term of a pair block of eq. 6 in narx_model.c (tile_exponents, tile_expm1,
#: tile_accumulate), with N_Z uncertain regressors: the exponent (one add, N_Z multiply-adds),
#: in single precision on the fast path and double on the exact one; expm1 of it (expm1_single_clamped:
#: 23, expm1_clamped: 37), counting a fused multiply-add as 2; the accumulation in double (cross
#: blocks one multiply-add, own blocks three more operations for eq. 4's trace).
EXPM1_FLOPS = {"single": 23, "double": 37}
ACCUMULATE_FLOPS = {"cross": 2, "own": 6}


def free_run_flops(fmu_path) -> dict:
    """FLOPs of one free-run step of a native rate-predictor FMU in its pair blocks (eq. 6; the
    rest of a step, eqs. 1-2 and each block's set-up, is not counted), read from the FMU's
    ``model_config.h`` and ``narx_model.c``: every distinct sample's own block (symmetric: bands
    of ``OWN_BAND`` rows from the diagonal on, own_block_body) and every distinct sample pair's
    cross block (m_a x m_b).

    Returns
    -------
    dict
        ``{"terms", "fast": {"double", "single"}, "exact": {"double", "single"}}``, FLOPs.
    """
    import re
    import zipfile

    with zipfile.ZipFile(fmu_path) as archive:
        config = archive.read("sources/model_config.h").decode()
        source = archive.read("sources/narx_model.c").decode()

    def numbers(name):
        return [int(v) for v in re.search(rf"{name}\[\d+\] = {{([^}}]*)}}", config).group(1).split(",")]

    def constant(text, name):
        return int(re.search(rf"#define {name} (\d+)", text).group(1))

    m, distinct = numbers("BASIS_POINTS"), numbers("DISTINCT_SAMPLES")
    n_z = constant(config, "N_OUTPUTS") * constant(config, "N_OUTPUT_LAGS")
    band = constant(source, "OWN_BAND")
    own = sum(t * sum(min(band, mj - first) * (mj - first) for first in range(0, mj, band))
              for t, mj in zip(distinct, m))
    pairs = [(a, b) for a in range(len(m)) for b in range(a + 1, len(m))]
    counts = numbers("PAIR_COUNT") if pairs else []
    cross = sum(n * m[a] * m[b] for n, (a, b) in zip(counts, pairs))
    exponent = (own + cross) * (1 + 2 * n_z)
    accumulate = own * ACCUMULATE_FLOPS["own"] + cross * ACCUMULATE_FLOPS["cross"]
    return {"terms": own + cross,
            "fast": {"double": accumulate, "single": exponent + (own + cross) * EXPM1_FLOPS["single"]},
            "exact": {"double": exponent + accumulate + (own + cross) * EXPM1_FLOPS["double"], "single": 0}}


def machine_peak_flops() -> dict:
    """The processor's peak rate of fused multiply-adds on its widest vectors, double and single
    precision (``peak_flops.c``, compiled here with the system gcc): ``{"double", "single"}``,
    FLOP/s, and ``"isa"``."""
    import subprocess
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory(prefix="flightgp-peak-") as work:
        binary = Path(work) / "peak_flops"
        subprocess.run(["gcc", "-O2", "-std=c99", "-ffp-contract=fast", str(Path(__file__).with_name("peak_flops.c")),
                        "-o", str(binary)], check=True, capture_output=True)
        words = subprocess.run([str(binary)], check=True, capture_output=True, text=True).stdout.split()
    return {"double": float(words[1]) * 1e9, "single": float(words[3]) * 1e9, "isa": words[4]}


#: The paper model's free-run paths ``bench fmu`` times in the C host: key -> (summary id,
#: label, ``exact_moments``, ``parallel``). The fast path on two threads is the one ``bench
#: cosim`` co-simulates.
FREE_RUN_PATHS = {"fast": ("fmu.paper.native.step_us", "fast, two threads (parallel)", False, True),
                  "fast_one_thread": ("fmu.paper.native.one_thread_step_us", "fast, one thread", False, False),
                  "exact": ("fmu.paper.native.exact_step_us", "exact_moments, one thread", True, False)}


def paper_free_run_rows(fmu_path, theta_1s, *, step: float, runs: int = 3) -> dict:
    """The paper model's native FMU stepping the free run along ``theta_1s`` (the NARX grid) in
    the plain C host on each of :data:`FREE_RUN_PATHS`: ``runs`` runs each (one pass over the
    manoeuvre after loading the FMU), with the FLOPs per step (:func:`free_run_flops`) and the
    share of the machine's peak (:func:`machine_peak_flops`, one core; two threads have twice
    that) they run at: the time the step's FLOPs would take at peak over the measured time. The
    peak is that of multiply-adds alone; where additions run on units of their own beside them
    (AMD's Zen), code that mixes both can exceed it, by up to a half.

    Returns
    -------
    dict
        ``{"steps", "peak", "flops", <path>: {...}}``, each path ``{"label", "threads",
        "us_per_step": [runs], "median_us", "real_time_factor", "gflops", "share_of_peak"}``.
    """
    from validation.cosim.hosts import simulate_in_c_host

    n_steps = len(theta_1s) - 1
    flops, peak = free_run_flops(fmu_path), machine_peak_flops()
    report = {"steps": n_steps, "flops": flops, "peak": peak}
    for path, (_, label, exact, parallel) in FREE_RUN_PATHS.items():
        times = [simulate_in_c_host(fmu_path, step_size=step, n_steps=n_steps, inputs={"theta_1s": theta_1s},
                                    outputs=["q", "q_upper"],
                                    start_values={"free_run": True, "exact_moments": exact, "parallel": parallel},
                                    repeats=1)["us_per_step"] for _ in range(runs)]
        median_s = float(np.median(times)) * 1e-6
        count, threads = flops["exact" if exact else "fast"], 2 if parallel else 1
        at_peak_s = (count["double"] / peak["double"] + count["single"] / peak["single"]) / threads
        report[path] = {"label": label, "threads": threads, "us_per_step": times, "median_us": median_s * 1e6,
                        "real_time_factor": step / median_s,
                        "gflops": (count["double"] + count["single"]) / median_s * 1e-9,
                        "share_of_peak": at_peak_s / median_s}
    return report


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
    free_run = report.get("paper_free_run")
    if free_run:
        flops, peak = free_run["flops"], free_run["peak"]
        native += [
            "",
            f"Paper model's native FMU, free run along the 3-2-1-1 ({free_run['steps']} steps) in the C host, "
            f"{len(free_run['fast']['us_per_step'])} runs; {flops['terms']} pair terms per step; "
            f"machine peak ({peak['isa']}) {peak['double'] * 1e-9:.1f} GFLOP/s double, "
            f"{peak['single'] * 1e-9:.1f} single",
            f"{'path':<32} {'us/step median':>15} {'runs':>24} {'x real time':>12} {'GFLOP/s':>8} {'of peak':>8}",
            *(f"{free_run[key]['label']:<32} {free_run[key]['median_us']:>15.0f} "
              f"{' '.join(f'{t:.0f}' for t in free_run[key]['us_per_step']):>24} "
              f"{free_run[key]['real_time_factor']:>12.0f} {free_run[key]['gflops']:>8.1f} "
              f"{100 * free_run[key]['share_of_peak']:>7.0f}%"
              for key in FREE_RUN_PATHS),
        ]
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
            free_run = report.get("paper_free_run")
            if free_run:
                for path, (summary_id, *_) in FREE_RUN_PATHS.items():
                    rows.append(SummaryRow(
                        summary_id,
                        f"native FMU free-run step in the C host, {free_run[path]['label']}, {row['model']}",
                        free_run[path]["median_us"], "us", budget_us, at_least=False,
                        note=f"median of {len(free_run[path]['us_per_step'])}; "
                             f"{100 * free_run[path]['share_of_peak']:.0f}% of the peak FLOP rate of "
                             f"{free_run[path]['threads']} core{'s' if free_run[path]['threads'] > 1 else ''}"))
            rows.append(SummaryRow("fmu.paper.native.one_step_us", f"native FMU one-step prediction in the C host, "
                                   f"{row['model']}", row["native_c_host_us_per_step"], "us", None, note=cheaper))
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
