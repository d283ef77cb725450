"""What a campaign's workers run: one function per task kind, each returning the task's figures
and files (docs/campaigns.md, "The spec file"), and the checks the driver makes before anything
runs.

A worker gets the files a task needs as :class:`FileBundle` s (the bytes, sent once per worker by
the runner) and writes each once into its own folder (:func:`local_file`), so workers need no
shared file system. FMUs are opened once per worker thread and kept: one fmpy instance, reset
between tasks (:class:`validation.vehicles.fmu_reference.FMUReference`, with an instance name
unique in the process), keyed by the file's path, which holds its content's hash.
"""
from __future__ import annotations

import atexit
import hashlib
import math
import os
import shutil
import socket
import tempfile
import threading
import time as clock
import traceback
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from validation.campaign.results import flatten
from validation.campaign.spec import file_label, is_file_reference
from validation.core.errors import BadInputError
from validation.core.files import json_text, write_files_atomically
from validation.core.manoeuvres import manoeuvre, time_grid
from validation.core.metrics import rmse
from validation.core.recordings import Recording, recording_files, sidecar_path


@dataclass(frozen=True)
class FileBundle:
    """A file a task needs, with the files that go with it (a recording's JSON sidecar).

    Attributes
    ----------
    label : str
        The spec's name for it (:class:`validation.campaign.spec.FileRef`).
    key : str
        Hash of the names and contents: the folder the worker writes it to.
    files : tuple of (str, bytes)
        File names (paths relative to the bundle's folder, with ``/``) and contents; the first is
        the file ``label`` names.
    """

    label: str
    key: str
    files: tuple

    @classmethod
    def read(cls, label: str, path, *, companions=()) -> FileBundle:
        """The bundle of ``path`` and its ``companions`` (paths relative to ``path``'s folder: a
        QTG spec's recordings), each ``.csv`` recording with its sidecar, if it has one. The files
        keep their places relative to each other, so ``path`` finds its companions by the same
        relative paths in the worker's copy (:func:`local_file`)."""
        path = Path(os.path.abspath(path))
        paths = []
        for main in dict.fromkeys([path, *(Path(os.path.abspath(path.parent / name)) for name in companions)]):
            sidecar = sidecar_path(main)
            paths += [main, sidecar] if main.suffix == ".csv" and sidecar.is_file() else [main]
        root = Path(os.path.commonpath([p.parent for p in paths]))
        files = tuple((p.relative_to(root).as_posix(), p.read_bytes()) for p in paths)
        digest = hashlib.sha256()
        for name, data in files:
            digest.update(name.encode() + b"\0" + hashlib.sha256(data).digest())
        return cls(label, digest.hexdigest()[:20], files)


@dataclass
class TaskOutput:
    """What a task kind's function returns.

    Attributes
    ----------
    figures : dict of str to float
        The task's numbers: a column each in results.csv, with statistics in summary.json.
    files : dict of str to str or bytes
        Files for the task's folder, by name.
    """

    figures: dict
    files: dict = field(default_factory=dict)


@dataclass
class TaskOutcome:
    """A finished task, as the worker returns it: its :class:`TaskOutput`, the worker's name
    and the seconds it took there."""

    output: TaskOutput
    worker: str
    seconds: float


class TaskError(Exception):
    """A task raised: what it said (one line), the worker, seconds until it raised, and the
    traceback (picklable: Dask carries it back to the driver)."""

    def __init__(self, message: str, worker: str, seconds: float, details: str = ""):
        super().__init__(message, worker, seconds, details)
        self.message, self.worker, self.seconds, self.details = message, worker, seconds, details

    def __str__(self) -> str:
        return self.message


def run_task(task, bundles: dict) -> TaskOutcome:
    """Run ``task`` (:class:`validation.campaign.spec.Task`) on this worker.

    Parameters
    ----------
    task : Task
    bundles : dict of str to FileBundle
        The files it needs, by label.

    Returns
    -------
    TaskOutcome

    Raises
    ------
    TaskError
        Whatever the task raised, in one line (an FMU that refuses a call says so here).
    """
    from threadpoolctl import threadpool_limits

    started, worker = clock.perf_counter(), worker_name()
    try:
        paths = {label: local_file(bundle) for label, bundle in bundles.items()}
        with threadpool_limits(1):  # one worker, one core: BLAS threads would fight the other workers
            output = TASK_KINDS[task.kind](task.settings, seed=task.seed, paths=paths)
    except Exception as error:  # noqa: BLE001 - any failure of a task is recorded, and the campaign goes on
        text = str(error).strip().splitlines()[0] if str(error).strip() else ""
        message = text if isinstance(error, BadInputError) else f"{type(error).__name__}: {text}".rstrip(": ")
        raise TaskError(message, worker, clock.perf_counter() - started, traceback.format_exc()) from None
    return TaskOutcome(output, worker, clock.perf_counter() - started)


def dask_setup(worker) -> None:
    """Dask's preload hook, given to the workers of a local cluster
    (:func:`validation.campaign.runner.dask_client`): they are in the terminal's process group, so
    a Ctrl-C reaches them too. They ignore it; the driver gets it and stops them, and the user sees
    one line (``flightgp campaign: interrupted``) rather than a traceback per worker."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def carry(bundle: FileBundle) -> FileBundle:
    """The identity: the runner submits each bundle through it once, so the bundle is a Dask
    result that workers fetch from each other (and that is recomputed if every holder dies)."""
    return bundle


def worker_name() -> str:
    """The Dask worker's address, or ``host:pid`` outside a worker."""
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


_LOCAL = threading.local()
_FOLDER = {}


def local_file(bundle: FileBundle) -> Path:
    """The worker's copy of ``bundle``'s first file, written once (atomically) into a folder
    named by its key under the worker's local directory (a temporary folder outside a worker)."""
    folder = _files_folder() / bundle.key
    target = folder / bundle.files[0][0]
    if not target.is_file():
        write_files_atomically({folder / name: data for name, data in bundle.files})
    return target


def _files_folder() -> Path:
    try:
        from distributed import get_worker

        return Path(get_worker().local_directory) / "flightgp-files"
    except (ImportError, ValueError):
        if "path" not in _FOLDER:
            _FOLDER["path"] = Path(tempfile.mkdtemp(prefix="flightgp-campaign-"))
            atexit.register(shutil.rmtree, _FOLDER["path"], True)
        return _FOLDER["path"]


def _resolved(name, paths: dict):
    """A ``reference``/``through`` value as the task kinds pass it on: the local copy's path (as a
    string) when it names one of the task's files, else the name itself (None stays None)."""
    return str(paths[name]) if name in paths else name


def open_fmu(path):
    """This thread's kept instance of the FMU at ``path``
    (:class:`~validation.vehicles.fmu_reference.FMUReference`, reset before each replay)."""
    from validation.vehicles.fmu_reference import FMUReference

    kept = _LOCAL.__dict__.setdefault("fmus", {})
    if path not in kept:
        kept[path] = FMUReference(path, workers=1, instance_name=f"flightgp_campaign_{os.getpid()}_"
                                                                 f"{threading.get_ident()}_{len(kept)}")
    return kept[path]


# -- cosim ------------------------------------------------------------------------------------

def input_signal(signal, time: np.ndarray) -> np.ndarray:
    """An input's values on ``time`` (n,): a constant, or a manoeuvre (``amplitude`` in the
    input's unit or ``amplitude_deg`` in deg, ``step_time`` and ``start`` in s)."""
    if not isinstance(signal, dict):
        return np.full(len(time), float(signal))
    amplitude = signal["amplitude"] if "amplitude" in signal else math.radians(signal["amplitude_deg"])
    return manoeuvre(signal["manoeuvre"], time, amplitude=amplitude, step_time=signal["step_time"],
                     start=signal["start"])


def run_cosim(settings: dict, *, seed: int, paths: dict) -> TaskOutput:
    """Co-simulate the FMU (fmpy) on the study's inputs, parameters and start values, add the
    measurement noise, and compare with ``compare_with`` flown on the same inputs.

    Figures, per output ``y`` (its unit): ``peak_y`` (largest magnitude) and ``rms_y`` of the
    measured output (FMU output plus noise of standard deviation ``noise[y]``, seeded by
    ``seed``); with ``compare_with``, ``rmse_y`` of the measured output against that vehicle's
    recording (flown with ``seed``). Files: ``recording.csv`` and its sidecar (time, inputs,
    measured outputs; docs/conventions.md, "Recording files").
    """
    fmu = open_fmu(paths[file_label(settings["fmu"])])
    step = settings["step"] or fmu.sample_time
    time = time_grid(duration=settings["duration"], sample_time=step)
    inputs = np.zeros((len(time), len(fmu.input_names)))
    for name, signal in settings["inputs"].items():
        inputs[:, fmu.input_names.index(name)] = input_signal(signal, time)
    outputs = tuple(settings["outputs"] or fmu.state_names)
    states = fmu.replay(time, inputs, parameters=settings["parameters"], start=settings["start_values"])
    simulated = states[:, [fmu.state_names.index(name) for name in outputs]]
    if not np.isfinite(simulated).all():
        raise FloatingPointError("the FMU's outputs are not finite (did the simulation diverge?)")
    noise_sd = np.array([settings["noise"].get(name, 0.0) for name in outputs])
    measured = simulated + np.random.default_rng(seed).standard_normal(simulated.shape) * noise_sd
    figures = {}
    for j, name in enumerate(outputs):
        figures[f"peak_{name}"] = float(np.max(np.abs(measured[:, j])))
        figures[f"rms_{name}"] = float(np.sqrt(np.mean(measured[:, j] ** 2)))
    if settings["compare_with"]:
        flight = _fly(settings["compare_with"], time, inputs, fmu.input_names, seed=seed)
        for j, name in enumerate(outputs):
            figures[f"rmse_{name}"] = rmse(measured[:, j], flight.output(name))
    metadata = {"source": "flightgp campaign (cosim)", "fmu": file_label(settings["fmu"]), "seed": seed,
                "sample_time": step, "sensor_noise_std": dict(zip(outputs, noise_sd.tolist()))}
    recording = Recording(time, inputs, fmu.input_names, measured, outputs, metadata)
    return TaskOutput(figures, {str(path): text for path, text in
                                recording_files(Path("recording.csv"), recording).items()})


def _fly(vehicle_name: str, time, inputs, input_names, *, seed: int) -> Recording:
    """``vehicle_name`` flown on ``inputs`` (its other inputs at zero) with ``seed``."""
    vehicle = _vehicle(vehicle_name)
    flown = np.zeros((len(time), len(vehicle.input_names)))
    for j, name in enumerate(input_names):
        flown[:, vehicle.input_names.index(name)] = inputs[:, j]
    return vehicle.simulate(time, flown, seed=seed)


def _vehicle(name: str):
    from validation.vehicles import get_vehicle

    kept = _LOCAL.__dict__.setdefault("vehicles", {})
    if name not in kept:
        kept[name] = get_vehicle(name)
    return kept[name]


# -- diagnose ---------------------------------------------------------------------------------

def run_diagnose(settings: dict, *, seed: int, paths: dict) -> TaskOutput:
    """``flightgp diagnose`` on the recordings (docs/diagnose.md).

    Figures: ``findings`` (how many), ``missing_physics`` (1 or 0), each finding's value as
    ``<effect>.<input, term or output>`` (its unit), and per output ``y`` the held-out RMSE
    ``rmse_reference_y``, ``rmse_corrected_y`` and ``rmse_corrected_gp_y``. Files: everything
    ``flightgp diagnose`` writes (``diagnosis.json``, ``report.md`` and its PNGs,
    ``corrected_model.json``).
    """
    from validation.diagnose import diagnose, diagnosis_files

    diagnosis = diagnose([paths[name] for name in settings["recordings"]],
                         reference=_resolved(settings["reference"], paths),
                         holdout=[paths[name] for name in settings["holdout"]] if settings["holdout"] else None,
                         seed=seed, folds=settings["folds"], workers=1)
    result = diagnosis.as_dict()
    figures = {"findings": float(len(result["findings"])),
               "missing_physics": float(result["verdict"] == "missing_physics")}
    for finding in result["findings"]:
        target = finding.get("input") or finding.get("term") or finding.get("output")
        if isinstance(finding.get("value"), (int, float)):
            figures[f"{finding['effect']}.{target}"] = float(finding["value"])
    fit = result["fit"]
    for name in fit["outputs"]:
        for key in ("rmse_reference", "rmse_corrected", "rmse_corrected_gp"):
            figures[f"{key}_{name}"] = fit[key][name]
    return TaskOutput(figures, {str(path): content for path, content in diagnosis_files(diagnosis, Path()).items()})


# -- diagnose-bench ---------------------------------------------------------------------------

def run_bench_case(settings: dict, *, seed: int, paths: dict) -> TaskOutput:
    """One case of ``flightgp diagnose-bench`` with ``seed`` (docs/diagnose.md, "The
    concealed-effect benchmark: `flightgp diagnose-bench`").

    Figures: ``passed``, ``named``, ``in_interval`` (1 or 0), ``cut`` (fraction),
    ``false_findings`` (how many), ``rmse_reference`` and ``rmse_corrected`` of the affected
    output (its unit) and ``seconds`` (the diagnosis). Files: ``score.json``, the case's
    scorecard row.
    """
    from validation.diagnose.bench import DURATION, concealed_cases, run_case

    reference, through = _resolved(settings["reference"], paths), _resolved(settings["through"], paths)
    case = next(case for case in concealed_cases(reference=reference) if case.name == settings["case"])
    row = run_case(case, reference=reference, through=through, seed=seed,
                   duration=settings["duration"] or DURATION, workers=1).as_dict()
    figures = {key: float(row[key]) for key in ("passed", "named", "in_interval")}
    figures.update(cut=row["cut"], false_findings=float(len(row["false_findings"])),
                   rmse_reference=row["rmse_reference"], rmse_corrected=row["rmse_corrected"],
                   seconds=row["seconds"])
    return TaskOutput(figures, {"score.json": json_text(row)})


# -- reproduce --------------------------------------------------------------------------------

def run_reproduction(settings: dict, *, seed: int, paths: dict) -> TaskOutput:
    """``flightgp reproduce bo105`` or ``blimp`` with one seed (docs/reproductions.md).

    Figures: bo105, the RMSE (rad/s) and 95 % coverage tables of ``results.json`` (``osap.gp.q``,
    ``fmp.reference.p``, ``unseen.fmp.gp.r``, ``coverage95.q``, ...); blimp, the seed's Table I
    with filtered starts (``table1.<method>.<group>``, the group's unit), Table II's spread ratios
    (``table2.spread_ratio_noise``, ``table2.spread_ratio_latent``, ``table2.spread_ratio_calibrated``)
    and Table III's mean yaw
    errors (``table3.<RK, RKGP or stand_in>``, deg) and their ratio. Files: everything the
    reproduction writes.
    """
    with tempfile.TemporaryDirectory(prefix="flightgp-reproduce-") as folder:
        if settings["paper"] == "bo105":
            from validation.reproduce.bo105 import reproduce_bo105

            results = reproduce_bo105(folder, seed=seed, n_runs=settings["runs"], beyond=not settings["paper_only"],
                                      progress=False)
            tables = {key: results[key] for key in ("osap", "fmp", "coverage95")}
            tables["unseen"] = {key: results["unseen"][key] for key in ("fmp", "coverage95")}
        else:
            from validation.reproduce.blimp import reproduce_blimp
            from validation.reproduce.blimp_control import LEARNED_IN
            from validation.reproduce.blimp_prediction import GROUPS, METHODS

            results = reproduce_blimp(folder, seeds=(seed,), quick=settings["quick"], progress=False)
            first, second, third = (results[f"table{n}"]["by_seed"][str(seed)] for n in (1, 2, 3))
            tables = {"table1": {m: {g: first["filtered"][m][g] for g in GROUPS} for m in METHODS},
                      "table2": {key: second[key] for key in ("spread_ratio_noise", "spread_ratio_latent",
                                                                          "spread_ratio_calibrated")},
                      "table3": {**{name: third[name]["yaw_error_deg"] for name in LEARNED_IN},
                                 "yaw_error_ratio_RK_to_RKGP": third["yaw_error_ratio_RK_to_RKGP"]}}
        files = {str(path.relative_to(folder)): path.read_bytes() for path in sorted(Path(folder).rglob("*"))
                 if path.is_file()}
    figures = {name: float(value) for name, value in flatten(tables).items()
               if isinstance(value, (int, float)) and not isinstance(value, bool)}
    return TaskOutput(figures, files)


# -- qtg --------------------------------------------------------------------------------------

def run_qtg_task(settings: dict, *, seed: int, paths: dict) -> TaskOutput:
    """``flightgp qtg`` (docs/qtg.md): every test of the QTG spec against the task's model, opened
    once for all of them. A QTG is deterministic: ``seed`` is not used.

    Figures: the counts ``passed``, ``failed``, ``errors`` and ``not_run``, ``all_passed`` (1 or
    0: at least one test ran and none failed or erred), and per output ``y`` of a test that ran,
    numbered ``NN`` as its plot (``01``, ``02``, ...), ``NN.y.excursion``: how far its largest
    difference from the flight test lies beyond its band (the output's SI unit; 0 when every
    sample is inside). Files: everything ``flightgp qtg`` writes (``summary.md``, ``qtg.html``,
    ``junit.xml``, ``qtg.json``, ``plots/``); they name the spec as the campaign spec does.
    """
    from validation.qtg import read_spec, run_qtg
    from validation.qtg.report import qtg_files
    from validation.qtg.run import ERROR, FAILED, NOT_RUN, PASSED

    spec = replace(read_spec(paths[settings["spec"]]), path=Path(settings["spec"]))
    with ExitStack() as stack:
        result = run_qtg(spec, open_qtg_model(stack, settings, paths), progress=False)
    figures = {"passed": result.count(PASSED), "failed": result.count(FAILED), "errors": result.count(ERROR),
               "not_run": result.count(NOT_RUN), "all_passed": result.passed}
    for number, test in enumerate(result.tests, start=1):
        figures.update({f"{number:02d}.{name}.excursion": output.excursion  # numbered as plots/NN_<id>.png
                        for name, output in test.outputs.items()})
    return TaskOutput({name: float(value) for name, value in figures.items()},
                      {str(path): content for path, content in qtg_files(result, Path()).items()})


def open_qtg_model(stack: ExitStack, settings: dict, paths: dict):
    """The model a ``qtg`` task qualifies (:func:`validation.qtg.open_model`), an FMU opened in
    ``stack``."""
    from validation.qtg import open_model

    fmu = None if settings["fmu"] is None else paths[file_label(settings["fmu"])]
    return open_model(stack, fmu=fmu, reference=_resolved(settings["reference"], paths))


#: The function of each task kind: ``function(settings, *, seed, paths) -> TaskOutput``, with
#: ``paths`` the worker's copies of the task's files by label.
TASK_KINDS = {"cosim": run_cosim, "diagnose": run_diagnose, "diagnose-bench": run_bench_case,
              "reproduce": run_reproduction, "qtg": run_qtg_task}


# -- checks before anything runs --------------------------------------------------------------

def check_tasks(tasks, paths: dict) -> None:
    """Check what the spec could not: names of FMU variables, vehicles, references and cases,
    and the recordings themselves, with the files at ``paths`` (label -> the driver's copy).

    Raises
    ------
    BadInputError
        Naming the first task with a problem and the field.
    """
    cache = {}

    def once(key, make):
        if key not in cache:
            cache[key] = make()
        return cache[key]

    for task in tasks:
        try:
            _CHECKS[task.kind](task.settings, paths, once)
        except BadInputError as error:
            raise BadInputError(f"task {task.id} (study {task.study}): {error}") from None


def _check_cosim(settings: dict, paths: dict, once) -> None:
    from validation.core.recordings import column_unit
    from validation.vehicles.fmu_reference import FMUReference

    label = file_label(settings["fmu"])
    fmu = once(("fmu", label), lambda: FMUReference(paths[label], workers=1))

    def known(field, names, allowed, what):
        unknown = [name for name in names if name not in allowed]
        if unknown:
            raise BadInputError(f"{field}: the FMU {label} has no {what} {unknown[0]!r}; it has "
                                f"{', '.join(allowed) or 'none'}")

    known("inputs", settings["inputs"], fmu.input_names, "input")
    outputs = settings["outputs"] or fmu.state_names
    known("outputs", outputs, fmu.state_names, "output")
    known("parameters", settings["parameters"], tuple(fmu.parameters), "parameter")
    known("start_values", settings["start_values"], tuple(fmu.start_parameters), "output with a start value")
    unrecorded = [name for name in settings["noise"] if name not in outputs]
    if unrecorded:
        raise BadInputError(f"noise: {unrecorded[0]!r} is not a recorded output; the task records "
                            f"{', '.join(outputs)}")
    try:
        time_grid(duration=settings["duration"], sample_time=settings["step"] or fmu.sample_time)
    except BadInputError as error:
        raise BadInputError(f"duration, step: {error}") from None
    for name, signal in settings["inputs"].items():
        if not isinstance(signal, dict):
            continue
        if "amplitude_deg" in signal and column_unit(name) not in ("rad", "?"):
            raise BadInputError(f"inputs.{name}.amplitude_deg: {name!r} is in {column_unit(name)}, not an angle; "
                                "give 'amplitude'")
        if signal["start"] >= settings["duration"]:
            raise BadInputError(f"inputs.{name}.start: the manoeuvre starts at {signal['start']:g} s, not within "
                                f"the run of {settings['duration']:g} s")
    if settings["compare_with"]:
        from validation.vehicles import get_vehicle

        name = settings["compare_with"]
        if is_file_reference(name):
            raise BadInputError(f"compare_with: {name!r}: compare with a vehicle name (e.g. bo105-80kt-flight)")
        vehicle = once(("vehicle", name), lambda: _named("compare_with", get_vehicle, name))
        missing = [n for n in (*fmu.input_names, *outputs) if n not in (*vehicle.input_names, *vehicle.state_names)]
        if missing:
            raise BadInputError(f"compare_with: {name} has no {missing[0]!r}; it flies "
                                f"{', '.join(vehicle.input_names)} -> {', '.join(vehicle.state_names)}")


def _check_diagnose(settings: dict, paths: dict, once) -> None:
    from validation.vehicles import read_recording
    from validation.vehicles.effect_vehicle import effect_model

    reference = _resolved(settings["reference"], paths)
    once(("reference", reference), lambda: _named("reference", effect_model, reference, purpose="diagnose"))
    for name in (*settings["recordings"], *(settings["holdout"] or [])):
        once(("recording", name), lambda name=name: read_recording(paths[name]))


def _check_bench(settings: dict, paths: dict, once) -> None:
    from validation.diagnose.bench import concealed_cases
    from validation.vehicles.effect_vehicle import effect_model

    reference, through = _resolved(settings["reference"], paths), _resolved(settings["through"], paths)
    names = once(("cases", reference),
                 lambda: [case.name for case in _named("reference", concealed_cases, reference=reference)])
    if settings["case"] not in names:
        raise BadInputError(f"cases: no case {settings['case']!r} for {settings['reference']}; its cases: "
                            f"{', '.join(names)}")
    if through is not None:
        once(("through", through), lambda: _named("through", effect_model, through, purpose="diagnose-bench"))


def _check_qtg(settings: dict, paths: dict, once) -> None:
    """The model opens (the QTG spec and its recordings were read with the campaign spec)."""
    field = "reference" if settings["fmu"] is None else "fmu"
    label = settings["reference"] if settings["fmu"] is None else file_label(settings["fmu"])

    def opens():
        with ExitStack() as stack:
            open_qtg_model(stack, settings, paths)

    once(("qtg model", label), lambda: _named(field, opens))


def _named(field: str, function, *args, **kwargs):
    """``function(*args, **kwargs)``, its BadInputError prefixed with the spec's ``field``."""
    try:
        return function(*args, **kwargs)
    except BadInputError as error:
        raise BadInputError(f"{field}: {error}") from None


_CHECKS = {"cosim": _check_cosim, "diagnose": _check_diagnose, "diagnose-bench": _check_bench,
           "reproduce": lambda settings, paths, once: None, "qtg": _check_qtg}
