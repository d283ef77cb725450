"""Running a campaign on Dask (docs/campaigns.md): a local cluster started and stopped here, or
an existing one; results written as tasks finish, so a run can be resumed.

The driver (this process) builds the reference FMUs the spec asks for, checks every task
(:func:`validation.campaign.tasks.check_tasks`), skips the tasks whose result is stored, sends
each file the others need once (a Dask result workers fetch from each other) and submits one
Dask task per campaign task. As each finishes, its files and ``result.json`` are written
atomically into ``DIR/tasks/<id>/``; at the end ``results.csv`` and ``summary.json`` are rebuilt
from every stored result. A task that raises is recorded as failed (after ``retries`` more
tries); a worker that dies takes only its running task with it, which the scheduler starts again
on another worker (up to Dask's ``distributed.scheduler.allowed-failures`` times, then the task
is recorded as failed).
"""
from __future__ import annotations

import json
import logging
import re
import time as clock
import uuid
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from validation.campaign.results import (
    RESULT_FILES,
    TaskResult,
    read_result,
    result_files,
    summarise,
    task_folder,
    write_results,
)
from validation.campaign.tasks import FileBundle, TaskError, carry, check_tasks, run_task
from validation.core.errors import BadInputError
from validation.core.files import check_output_folder, json_text, write_atomically, write_files_atomically
from validation.core.progress import progress_bar

#: Seconds to wait for the first worker of an existing cluster.
WORKER_TIMEOUT_S = 60.0
#: Seconds to wait for an existing scheduler to answer.
CONNECT_TIMEOUT_S = 20.0


@dataclass
class CampaignRun:
    """What :func:`run_campaign` did.

    Attributes
    ----------
    out_dir : Path
    tasks, done, failed : int
        The campaign's tasks, and how many have a result that is done or failed.
    ran : int
        Tasks run by this call.
    resumed : int
        Tasks whose stored result this call kept.
    interrupted : list of (str, int)
        Tasks of this call whose worker died before they finished (running them, holding them
        queued, or holding their result not yet collected), and how many times; each ran again
        on another worker.
    workers : int
        Dask workers when the tasks were submitted (0 when nothing ran).
    seconds : float
        Wall-clock time of the call, s.
    task_seconds : float
        Wall-clock time from submitting the first task to storing the last result, s (0 when
        nothing ran): the call's time without the cluster's start and stop and the checks.
    summary : dict
        The content of ``summary.json``.
    """

    out_dir: Path
    tasks: int
    done: int
    failed: int
    ran: int
    resumed: int
    interrupted: list = field(default_factory=list)
    workers: int = 0
    seconds: float = 0.0
    task_seconds: float = 0.0
    summary: dict = field(default_factory=dict)


def run_campaign(spec, out_dir, *, scheduler: str | None = None, workers: int | None = None,
                 retry_failed: bool = False, progress: bool = True, execute=run_task) -> CampaignRun:
    """Run the tasks of ``spec`` that have no stored result, on Dask.

    Parameters
    ----------
    spec : CampaignSpec
        :func:`validation.campaign.spec.read_spec` or :func:`~validation.campaign.spec.parse_spec`.
    out_dir : path
        The campaign's folder: ``results.csv``, ``summary.json``, ``tasks/<id>/``, ``fmus/``.
    scheduler : str, optional
        An existing Dask scheduler: its address (``tcp://host:8786``) or its scheduler file
        (``dask scheduler --scheduler-file FILE``). Default: a local cluster of ``workers``
        processes, started and stopped here.
    workers : int, optional
        Worker processes of the local cluster (one thread each); default: the cores available.
    retry_failed : bool
        Run the tasks whose stored result failed again too.
    progress : bool
        A progress bar on stderr.
    execute : callable
        What the workers run, ``execute(task, bundles) -> TaskOutcome`` (default
        :func:`validation.campaign.tasks.run_task`; tests wrap it).

    Returns
    -------
    CampaignRun

    Raises
    ------
    BadInputError
        ``out_dir`` a file, a reference FMU that cannot be built, a task the checks refuse, a
        scheduler that cannot be reached or that has no workers, workers without flightgp.
    """
    started = clock.perf_counter()
    out_dir = check_output_folder(out_dir, writes=RESULT_FILES)
    if workers is not None and workers < 1:
        raise BadInputError(f"workers must be at least 1, got {workers}")
    if workers is not None and scheduler is not None:
        raise BadInputError("a number of workers sizes the local cluster; an existing cluster (a scheduler) has "
                            "its own workers")
    paths = prepare_files(spec, out_dir)
    check_tasks(spec.tasks, paths)
    stored = {task.id: read_result(out_dir, task.as_dict()) for task in spec.tasks}
    pending = [task for task in spec.tasks
               if stored[task.id] is None or (retry_failed and stored[task.id].status != "done")]
    interrupted, n_workers, task_seconds = [], 0, 0.0
    if pending:
        labels = {label for task in pending for label in task.files}
        bundles = {label: FileBundle.read(label, paths[label], companions=spec.files[label].companions)
                   for label in sorted(labels)}
        with dask_client(scheduler=scheduler, workers=workers) as client:
            n_workers = len(client.scheduler_info()["workers"])
            submitted = clock.perf_counter()
            interrupted = _run_pending(client, pending, bundles, out_dir, stored, retries=spec.retries,
                                       progress=progress, execute=execute)
            task_seconds = clock.perf_counter() - submitted
    results = [stored[task.id] for task in spec.tasks if stored[task.id] is not None]
    seconds = clock.perf_counter() - started
    summary = summarise(results, name=spec.name, tasks=len(spec.tasks), interrupted=interrupted,
                        run={"tasks_run": len(pending), "resumed": len(spec.tasks) - len(pending),
                             "workers": n_workers, "scheduler": scheduler or "local", "seconds": seconds,
                             "task_seconds": task_seconds})
    write_results(out_dir, results, summary)
    return CampaignRun(out_dir, len(spec.tasks), summary["done"], summary["failed"], len(pending),
                       len(spec.tasks) - len(pending), interrupted, n_workers, seconds, task_seconds, summary)


def prepare_files(spec, out_dir: Path) -> dict:
    """The driver's path of every file the spec names, by label: the files as they are, and the
    reference FMUs built into ``out_dir/fmus/`` (once: an FMU already there is kept)."""
    from fmu_src import build_reference_fmu

    paths = {}
    for label, ref in spec.files.items():
        if ref.path is not None:
            paths[label] = ref.path
            continue
        name = re.sub(r"\W", "_", ref.reference) + "_reference"
        target = out_dir / "fmus" / f"{name}.fmu"
        try:
            paths[label] = target if target.is_file() else build_reference_fmu(ref.reference, target.parent,
                                                                               name=name)
        except BadInputError as error:
            raise BadInputError(f"{spec.source}: fmu {{\"reference\": \"{ref.reference}\"}}: {error}") from None
    return paths


@contextmanager
def dask_client(*, scheduler: str | None = None, workers: int | None = None):
    """A Dask client: of a local cluster of ``workers`` processes (one thread each, default the
    cores available), closed on exit; or of the existing scheduler at ``scheduler`` (an address
    or a scheduler file), with at least one worker running the same flightgp (``workers`` must
    then be None)."""
    from distributed import Client, LocalCluster

    # Dask logs its start and stop at INFO, and its workers race the scheduler when a cluster
    # stops (an ERROR about a heartbeat); show those only with `flightgp -v` (the root level).
    # Failed tasks are recorded whatever is logged, and dying workers are still reported.
    dask_logger = logging.getLogger("distributed")
    level, verbose = dask_logger.level, logging.getLogger().getEffectiveLevel() <= logging.INFO
    dask_logger.setLevel(logging.INFO if verbose else logging.WARNING)
    try:
        if scheduler is None:
            from validation.vehicles.fmu_reference import available_cores

            # No dashboard, and its HTTP server on a free port (two campaigns may run at once); the
            # workers ignore Ctrl-C (validation.campaign.tasks.dask_setup): the driver stops them.
            with LocalCluster(n_workers=workers or available_cores(), threads_per_worker=1, processes=True,
                              dashboard_address=None, scheduler_kwargs={"dashboard_address": ":0"},
                              preload=["validation.campaign.tasks"],
                              silence_logs=logging.INFO if verbose else logging.CRITICAL) as cluster, \
                    Client(cluster) as client:
                yield client
        else:
            with _existing_client(scheduler) as client:
                yield client
    finally:
        dask_logger.setLevel(level)


@contextmanager
def _existing_client(scheduler: str):
    from distributed import Client

    address = _scheduler_address(scheduler)
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as error:
        raise BadInputError(f"cannot reach the Dask scheduler at {scheduler}: {error}") from None
    with client:
        try:
            client.wait_for_workers(1, timeout=WORKER_TIMEOUT_S)
        except TimeoutError:
            raise BadInputError(f"the Dask scheduler at {scheduler} has no workers after {WORKER_TIMEOUT_S:g} s; "
                                f"start some with `dask worker {address}`") from None
        try:
            versions = client.run(flightgp_version)
        except Exception as error:  # noqa: BLE001 - whatever a worker without flightgp raises
            raise BadInputError(f"the Dask workers of {scheduler} cannot run flightgp tasks ({type(error).__name__}: "
                                f"{error}); install flightgp where the workers run") from None
        other = {worker: version for worker, version in versions.items() if version != flightgp_version()}
        if other:
            worker, version = next(iter(other.items()))
            raise BadInputError(f"the Dask worker {worker} runs flightgp {version}, this command {flightgp_version()}; "
                                "install the same version everywhere")
        yield client


def _scheduler_address(scheduler: str) -> str:
    """``scheduler`` itself, or the address in the scheduler file ``scheduler`` names."""
    path = Path(scheduler)
    if not path.is_file():
        return scheduler
    try:
        address = json.loads(path.read_text(encoding="utf-8")).get("address")
    except (OSError, ValueError, AttributeError):
        address = None
    if not isinstance(address, str) or not address:
        raise BadInputError(f"{scheduler}: not a Dask scheduler file (JSON with the scheduler's \"address\", as "
                            "`dask scheduler --scheduler-file FILE` writes it)")
    return address


def flightgp_version() -> str:
    """The installed flightgp's version (run on the workers of an existing cluster too: it
    fails there when flightgp is not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("flightgp")
    except PackageNotFoundError:
        return "unknown (not installed as a package)"


def map_on_dask(function, items, *, scheduler: str | None = None, workers: int | None = None,
                label: str = "tasks", progress: bool = True) -> list:
    """``function(item)`` for every item on a Dask cluster (:func:`dask_client`: a local one of
    ``workers`` processes, or the existing one at ``scheduler``), with a progress bar; the
    results in the items' order. What a command whose runs are independent uses to spread them
    (``flightgp reproduce blimp --seeds ... --cluster-workers N``); a run that raises raises here,
    as it would have in this process. ``function`` and the results travel between processes by
    Dask's serialisation (in memory; nothing is written)."""
    from distributed import as_completed

    items = list(items)
    with dask_client(scheduler=scheduler, workers=workers) as client:
        futures = client.map(function, items, pure=False)
        with progress_bar(label, enabled=progress, total=len(items), unit="run") as update:
            for _ in as_completed(futures):
                if update:
                    update(1)
        return client.gather(futures)


def _run_pending(client, pending, bundles: dict, out_dir: Path, stored: dict, *, retries: int, progress: bool,
                 execute) -> list:
    """Submit ``pending``, store each result as it finishes; returns the interrupted tasks
    (:attr:`CampaignRun.interrupted`, from the scheduler's worker-removal events)."""
    from distributed import KilledWorker, as_completed

    token = uuid.uuid4().hex[:8]
    carried = {label: client.submit(carry, bundle, key=f"flightgp-file-{bundle.key}", pure=False)
               for label, bundle in bundles.items()}
    futures = {client.submit(execute, task, {label: carried[label] for label in task.files},
                             key=f"flightgp-campaign-{token}-{task.id}", retries=retries, pure=False): task
               for task in pending}
    keys = {future.key: task.id for future, task in futures.items()}
    counts = Counter()
    with progress_bar("campaign", enabled=progress, total=len(pending), unit="task") as update:
        for future in as_completed(futures):
            task = futures.pop(future)
            files = {}
            if future.status == "finished":
                outcome = future.result()
                files = outcome.output.files
                result = TaskResult(task.as_dict(), "done", dict(outcome.output.figures), worker=outcome.worker,
                                    wall_time_s=outcome.seconds, files=sorted(files))
            elif future.status == "cancelled":
                raise BadInputError(f"the Dask scheduler cancelled task {task.id} (did it stop?); the finished "
                                    "results are kept: run the same command again to resume")
            else:
                error = future.exception()
                if isinstance(error, TaskError):
                    result = TaskResult(task.as_dict(), "failed", message=error.message, worker=error.worker,
                                        wall_time_s=error.seconds, traceback=error.details)
                elif isinstance(error, KilledWorker):
                    result = TaskResult(task.as_dict(), "failed",
                                        message=f"{error.allowed_failures + 1} workers died running it (a crash "
                                                "inside an FMU?); Dask gave up on it")
                else:
                    result = TaskResult(task.as_dict(), "failed", message=f"{type(error).__name__}: {error}")
            write_files_atomically(result_files(out_dir, result, files))
            stored[task.id] = result
            future.release()
            counts[result.status] += 1
            if update:
                update(1, done=counts["done"], failed=counts["failed"])
    interrupted = Counter()
    for _, event in client.get_events("all"):
        if isinstance(event, dict) and event.get("action") == "remove-worker":
            lost = set(event.get("processing-tasks", ())) | set(event.get("lost-computed-tasks", ()))
            for key in lost & keys.keys():
                interrupted[keys[key]] += 1
    for task_id, count in interrupted.items():  # record the lost workers in the stored results
        result = stored[task_id]
        result.workers_lost = count
        write_atomically(task_folder(out_dir, task_id) / "result.json", json_text(result.as_dict()))
    return sorted(interrupted.items())
