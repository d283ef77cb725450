"""A campaign's results on disk (docs/campaigns.md, "Results"): each task's ``result.json`` in
its folder, written as the task finishes, and ``results.csv`` and ``summary.json``, rebuilt from
them at the end of every run.
"""
from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from validation.core.files import json_text, write_files_atomically

#: ``result.json``'s format name and version.
RESULT_FORMAT = "flightgp-campaign-result"
RESULT_VERSION = 1
#: The percentiles summary.json gives of every figure, %.
PERCENTILES = (5, 50, 95)
#: The campaign folder's own files, rebuilt at the end of every run (:func:`write_results`).
RESULT_FILES = ("results.csv", "summary.json")
#: The first columns of results.csv; the task's settings and figures follow.
COLUMNS = ("id", "study", "kind", "seed", "status", "workers_lost", "wall_time_s", "worker", "message")


@dataclass
class TaskResult:
    """One task's result, as ``DIR/tasks/<id>/result.json`` holds it.

    Attributes
    ----------
    task : dict
        :meth:`validation.campaign.spec.Task.as_dict` of the task.
    status : {"done", "failed"}
    figures : dict of str to float or None
        The task's numbers (None where not finite).
    message : str
        Why it failed (empty when done).
    worker : str
        The Dask worker that ran it (its address), or ``""`` when no worker reported.
    wall_time_s : float
        Seconds the task took on its worker (NaN when no worker reported).
    files : list of str
        The files written next to ``result.json``.
    workers_lost : int
        Times a worker died while the task was assigned to it (running, queued, or finished
        but not yet collected); Dask then ran it on another worker.
    traceback : str
        The worker's traceback of a failed task (empty otherwise).
    """

    task: dict
    status: str
    figures: dict = field(default_factory=dict)
    message: str = ""
    worker: str = ""
    wall_time_s: float = math.nan
    files: list = field(default_factory=list)
    workers_lost: int = 0
    traceback: str = ""

    def as_dict(self) -> dict:
        data = asdict(self)
        data["figures"] = {name: _finite(value) for name, value in self.figures.items()}
        data["wall_time_s"] = _finite(self.wall_time_s)
        return {"format": RESULT_FORMAT, "version": RESULT_VERSION, **data}


def task_folder(out_dir, task_id: str) -> Path:
    """``DIR/tasks/<id>``."""
    return Path(out_dir) / "tasks" / task_id


def result_files(out_dir, result: TaskResult, files: dict) -> dict:
    """``{path: content}`` of a finished task: its own files, then ``result.json`` (renamed last by
    :func:`~validation.core.files.write_files_atomically`, so a result never names a file that is
    not there)."""
    folder = task_folder(out_dir, result.task["id"])
    written = {folder / name: content for name, content in files.items()}
    written[folder / "result.json"] = json_text(result.as_dict())
    return written


def read_result(out_dir, task: dict) -> TaskResult | None:
    """The stored result of ``task`` (:meth:`~validation.campaign.spec.Task.as_dict`), or None
    when there is none, it cannot be read, or it belongs to a task with other settings (the
    spec changed: the task runs again)."""
    path = task_folder(out_dir, task["id"]) / "result.json"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("format") != RESULT_FORMAT or data.get("version") != RESULT_VERSION:
        return None
    if data.get("task") != json.loads(json.dumps(task)):  # compared as JSON holds it (tuples become lists)
        return None
    known = {key: data[key] for key in TaskResult.__dataclass_fields__ if key in data}
    result = TaskResult(**known)
    result.wall_time_s = math.nan if result.wall_time_s is None else result.wall_time_s
    return result if _well_formed(result) else None


def _well_formed(result: TaskResult) -> bool:
    """Whether a result read from disk has the types :class:`TaskResult` gives (an edited or
    foreign file does not, and its task runs again)."""
    number = (int, float)
    return (result.status in ("done", "failed") and isinstance(result.figures, dict)
            and all(isinstance(v, number) or v is None for v in result.figures.values())
            and all(isinstance(v, str) for v in (result.message, result.worker, result.traceback))
            and isinstance(result.wall_time_s, number) and isinstance(result.files, list)
            and isinstance(result.workers_lost, int))


def flatten(tree, *, prefix: str = "") -> dict:
    """Nested dicts as one level, keys joined by dots: ``{"a": {"b": 1}}`` -> ``{"a.b": 1}``.
    Lists and other leaves are kept as they are."""
    if not isinstance(tree, dict):
        return {prefix: tree}
    flat = {}
    for key, value in tree.items():
        flat.update(flatten(value, prefix=f"{prefix}.{key}" if prefix else str(key)))
    return flat


def results_csv(results) -> str:
    """``results.csv``: one row per task, :data:`COLUMNS`, then the settings (flattened, dotted
    names), then the figures; columns in the order they first appear."""
    rows, settings_columns, figure_columns = [], {}, {}
    for result in results:
        task = result.task
        settings = flatten(task["settings"])
        settings_columns.update(dict.fromkeys(settings))
        figure_columns.update(dict.fromkeys(result.figures))
        rows.append({"id": task["id"], "study": task["study"], "kind": task["kind"], "seed": task["seed"],
                     "status": result.status, "workers_lost": result.workers_lost, "wall_time_s": result.wall_time_s,
                     "worker": result.worker, "message": result.message, **settings, **result.figures})
    header = [*COLUMNS, *settings_columns, *(name for name in figure_columns if name not in settings_columns)]
    stream = io.StringIO()
    writer = csv.writer(stream, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow([_cell(row.get(name)) for name in header])
    return stream.getvalue()


def summarise(results, *, name: str, tasks: int, interrupted=(), run: dict | None = None) -> dict:
    """``summary.json`` (docs/campaigns.md, "Results").

    Parameters
    ----------
    results : sequence of TaskResult
        Every stored result of the campaign's tasks.
    name : str
        The campaign's name.
    tasks : int
        How many tasks the campaign has (those without a result are ``missing``).
    interrupted : sequence of (str, int)
        Tasks of this run whose worker died before they finished, and how many times
        (:attr:`TaskResult.workers_lost`).
    run : dict, optional
        About this run (workers, seconds, tasks run and resumed).
    """
    results = list(results)
    failed = [r for r in results if r.status != "done"]
    statistics = {}
    for result in results:
        if result.status != "done":
            continue
        study = statistics.setdefault(result.task["study"], {})
        for figure, value in result.figures.items():
            study.setdefault(figure, []).append(value)
    return {
        "campaign": name, "tasks": tasks, "done": len(results) - len(failed), "failed": len(failed),
        "missing": tasks - len(results),
        "failures": [{"id": r.task["id"], "message": r.message} for r in failed],
        "interrupted": [{"id": task_id, "workers_lost": count} for task_id, count in interrupted],
        "statistics": {study: {figure: figure_statistics(values) for figure, values in figures.items()}
                       for study, figures in statistics.items()},
        **({"run": run} if run else {}),
    }


def figure_statistics(values) -> dict:
    """``{"count", "mean", "p5", "p50", "p95"}`` of the finite values (count 0 and None without)."""
    finite = np.array([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if not len(finite):
        return {"count": 0, "mean": None, **{f"p{p}": None for p in PERCENTILES}}
    return {"count": len(finite), "mean": float(np.mean(finite)),
            **{f"p{p}": float(np.percentile(finite, p)) for p in PERCENTILES}}


def format_summary(summary: dict, *, failures_shown: int = 10) -> str:
    """``summary.json`` as text: the counts, the statistics of every study's figures, the first
    ``failures_shown`` failures and the interrupted tasks."""
    lines = [f"campaign {summary['campaign']}: {summary['tasks']} tasks, {summary['done']} done, "
             f"{summary['failed']} failed" + (f", {summary['missing']} missing" if summary["missing"] else "")]
    for study, figures in summary["statistics"].items():
        width = max([6, *(len(name) for name in figures)])
        lines.append(f"{study:<{width}} {'count':>6} {'mean':>11} " + " ".join(f"{f'p{p}':>11}" for p in PERCENTILES))
        for name, entry in figures.items():
            number = lambda v: f"{'-':>11}" if v is None else f"{v:11.4g}"  # noqa: E731
            lines.append(f"{name:<{width}} {entry['count']:>6} {number(entry['mean'])} "
                         + " ".join(number(entry[f"p{p}"]) for p in PERCENTILES))
    for failure in summary["failures"][:failures_shown]:
        lines.append(f"failed {failure['id']}: {failure['message']}")
    if len(summary["failures"]) > failures_shown:
        lines.append(f"... and {len(summary['failures']) - failures_shown} more failures (summary.json)")
    for entry in summary["interrupted"]:
        lines.append(f"interrupted {entry['id']}: its worker died {entry['workers_lost']} time(s) before it finished; "
                     "it ran again on another")
    return "\n".join(lines)


def write_results(out_dir, results, summary: dict) -> list[Path]:
    """Write ``results.csv`` and ``summary.json`` (:data:`RESULT_FILES`) to ``out_dir`` as one atomic step."""
    out_dir = Path(out_dir)
    csv_name, summary_name = RESULT_FILES
    return write_files_atomically({out_dir / csv_name: results_csv(results),
                                   out_dir / summary_name: json_text(summary)})


def _finite(value):
    return value if value is None or not isinstance(value, float) or math.isfinite(value) else None


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ""
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return str(value)
