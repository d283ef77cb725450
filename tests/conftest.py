"""Fixtures that tests of several packages share: the Bo105 3-2-1-1 flights, the paper's GP-NARX
trained on them, its model file and rate-predictor FMU, the Bo105 reference FMU, and the short
flights the QTG tests score (the qtg and campaign tests). Session scope: each is made once per
test process, and only by a process that runs a test using it."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from fmu_src import build_bo105_reference_fmu, build_rate_predictor_fmu
from validation.core.manoeuvres import manoeuvre, time_grid
from validation.core.recordings import write_recording
from validation.models.narx import save_trained
from validation.reproduce.bo105 import PAPER_CONFIG, TRAINING_MANOEUVRE, fly_3211
from validation.vehicles import get_vehicle

# JAX's persistent compilation cache (the RGBlimp hybrid's rollouts, validation/models/
# rgblimp_rollout.py, and diagnose's compiled replays, validation/vehicles/rgblimp_jax.py): both
# test workers, and tests that compile the same shapes, load a compiled function from it instead
# of compiling it again (1-10 s each), however short its compile (JAX keeps only those over 1 s
# by default). JAX reads the variables when imported, after this; an entry is keyed on the
# computation, so a changed model compiles anew.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(Path(__file__).resolve().parents[1] / "build" / "jax-cache"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
# The same for the native FMUs' C (fmu_src/fmi/native.py, compile_shared_library): an object file
# of identical code, e.g. the paper model's narx_model.c, which the FMU tests, the FMU and
# co-simulation benchmarks and the build-fmu command each compile (4-10 s at -O3), is compiled
# once and then taken from build/native-cache; a changed source, header, flag or compiler
# compiles anew.
os.environ.setdefault("FLIGHTGP_NATIVE_CACHE_DIR", str(Path(__file__).resolve().parents[1] / "build" / "native-cache"))

if os.environ.get("PYTEST_XDIST_WORKER"):
    # One BLAS thread per test worker: the workers already fill the cores, and OpenBLAS threads
    # of two workers spin against each other (a residual GP's Cholesky factorisation took 5 ms
    # instead of 0.8 ms under that contention). Results do not depend on the thread count.
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    # The same for XLA's compiled runs, whose Eigen pool would otherwise take every core in each
    # worker (set before JAX is imported, which reads it then).
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false "
                               "intra_op_parallelism_threads=1").strip()


@pytest.fixture(scope="session")
def bo105_speed_kt():
    """Trim speed of the Bo105 flights and of the reference FMU, kt."""
    return 80


@pytest.fixture(scope="session")
def bo105_flights(bo105_speed_kt):
    """Bo105 flight-test stand-in at :func:`bo105_speed_kt`, ``theta_1s`` 3-2-1-1s of 8 s from 1 s: ``"training"``
    is the paper's (1 deg, 0.4 s steps, seed 0; the one ``flightgp cosim --vehicle`` flies by
    default), ``"unseen"`` a larger, faster one (1.3 deg, 0.3 s steps, seed 1) that leaves the
    training envelope in places."""
    fly = lambda seed, amplitude_deg, step_time: fly_3211(  # noqa: E731
        f"bo105-{bo105_speed_kt}kt-flight", input_name="theta_1s", amplitude=np.radians(amplitude_deg),
        step_time=step_time, start=TRAINING_MANOEUVRE["start"],
        duration=TRAINING_MANOEUVRE["duration"], seed=seed)
    return {"training": fly(0, TRAINING_MANOEUVRE["amplitude_deg"], TRAINING_MANOEUVRE["step_time"]),
            "unseen": fly(1, 1.3, 0.3)}


@pytest.fixture(scope="session")
def train_narx_once():
    """:func:`validation.models.narx.train_narx`, each model trained once per test process and
    then taken from memory: keyed on the recordings' arrays and names, the configuration, the
    seed and the inference options (``progress`` aside), the arguments its result depends on.
    The benchmarks that train the paper's model on the training flight of :func:`bo105_flights`
    (``bench fmu``, ``bench cosim``) are given it in place of ``train_narx``, so the model of
    :func:`bo105_trained` is not trained again in their process."""
    from validation.models import narx

    train = narx.train_narx
    trained = {}

    def cached(recordings, config, *, seed: int = 0, progress: bool = False, **inference_options):
        recordings = list(recordings)
        arrays = tuple((r.time.tobytes(), r.inputs.tobytes(), r.outputs.tobytes(), tuple(r.input_names),
                        tuple(r.output_names)) for r in recordings)
        key = (arrays, config, seed, tuple(sorted(inference_options.items())))
        if key not in trained:
            trained[key] = train(recordings, config, seed=seed, progress=progress, **inference_options)
        return trained[key]

    return cached


@pytest.fixture(scope="session")
def bo105_trained(bo105_flights, train_narx_once):
    """The paper's configuration on the training flight: 32 training points, annealing with 400
    hyperparameter samples (about 2 s), so FMUs' mixture over samples is exercised as in
    production."""
    return train_narx_once([bo105_flights["training"]], PAPER_CONFIG, seed=0)


@pytest.fixture(scope="session")
def bo105_model_file(tmp_path_factory, bo105_trained):
    return save_trained(tmp_path_factory.mktemp("model") / "bo105_gp_narx.npz", bo105_trained)


@pytest.fixture(scope="session")
def rate_predictor_fmu(bo105_model_file, tmp_path_factory):
    """The pythonfmu rate-predictor FMU of :func:`bo105_trained`."""
    return build_rate_predictor_fmu(bo105_model_file, tmp_path_factory.mktemp("fmu"),
                                    name="bo105_rate_predictor")


@pytest.fixture(scope="session")
def bo105_reference_fmu(bo105_speed_kt, tmp_path_factory):
    return build_bo105_reference_fmu(bo105_speed_kt, tmp_path_factory.mktemp("fmu"))


#: The flights of :func:`qtg_flights`, name -> (vehicle, manoeuvre, input): doublets flown on the
#: unchanged reference, and a 3-2-1-1 flown on the flight-test stand-in, which the reference misses
#: in pitch rate by about four times the 2 deg/s band (docs/qtg.md, "The Bo105 example").
QTG_FLIGHTS = {
    "ref_theta_1s_doublet": ("bo105-80kt", "doublet", "theta_1s"),
    "ref_theta_1c_doublet": ("bo105-80kt", "doublet", "theta_1c"),
    "ref_theta_0T_doublet": ("bo105-80kt", "doublet", "theta_0T"),
    "flight_theta_1s_3211": ("bo105-80kt-flight", "3211", "theta_1s"),
}


@pytest.fixture(scope="session")
def qtg_flights(tmp_path_factory):
    """A folder holding the :data:`QTG_FLIGHTS` as ``<name>.csv`` recordings (with sidecars): short
    Bo105 flights, 5 s at 100 Hz from trim, 1 deg manoeuvres from 0.5 s."""
    folder = tmp_path_factory.mktemp("qtg")
    for name, (vehicle_name, kind, input_name) in QTG_FLIGHTS.items():
        vehicle = get_vehicle(vehicle_name)
        time = time_grid(duration=5.0, sample_time=0.01)
        inputs = np.zeros((len(time), len(vehicle.input_names)))
        inputs[:, vehicle.input_names.index(input_name)] = manoeuvre(
            kind, time, amplitude=np.radians(1.0), step_time=0.4 if kind == "3211" else 0.5, start=0.5)
        recording = vehicle.simulate(time, inputs, seed=0)
        recording.metadata["vehicle"] = vehicle_name
        write_recording(folder / f"{name}.csv", recording)
    return folder


def pytest_collection_modifyitems(config, items):
    """Run the modules holding slow end-to-end tests first: on two workers (``make test``:
    pytest-xdist, ``--dist loadfile``, a module's tests on one worker, so its module-scoped
    fixtures, e.g. an end-to-end run whose results its tests check, are made once) the longest
    jobs then start early instead of leaving one worker running a minute-long fixture while the
    other idles at the end (longest processing time first, Graham, SIAM J. Appl. Math. 17(2),
    1969)."""
    slow_modules = {item.module.__name__ for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.module.__name__ not in slow_modules)  # stable: order kept within
