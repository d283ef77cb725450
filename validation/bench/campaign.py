"""``flightgp bench campaign``: one Monte Carlo campaign of the Bo105 reference FMU on a local
Dask cluster of 1 and of 2 workers, repeated, and the speed-up of 2 workers over 1
(docs/campaigns.md, "Scaling").

Each repeat runs both cluster sizes one after the other (so both see the same load on the
machine), each into a fresh folder (nothing resumed); the FMU is built once. Measured per run:
the command's wall time (local cluster started and stopped, checks, tasks, results) and the
task phase alone (first task submitted to last result stored).
"""
from __future__ import annotations

import tempfile
import time as clock
from pathlib import Path

import numpy as np

from validation.bench.rows import SummaryRow
from validation.core.progress import progress_bar

#: Tasks of the campaign, length of each co-simulation (s) and repeats of each cluster size.
N_TASKS = 40
DURATION_S = 30.0
REPEATS = 3
#: Goal of the speed-up of 2 workers over 1 on a 2-core machine (the ideal is 2; the driver
#: writing results and the cluster's start and stop take the rest).
SPEEDUP_GOAL = 1.5


def scaling_study(fmu, *, n_tasks: int = N_TASKS, duration: float = DURATION_S) -> dict:
    """The campaign's one study: ``n_tasks`` co-simulations of ``duration`` s of the FMU at
    ``fmu`` (a path), each a 3-2-1-1 on longitudinal cyclic and a doublet on lateral cyclic of
    sampled sizes, with sampled rate-sensor noise, compared with the Bo105 flight-test stand-in."""
    rates = ("p", "q", "r")
    return {"id": "scaling", "kind": "cosim", "fmu": str(fmu), "duration": duration, "samples": n_tasks,
            "inputs": {"theta_1s": {"manoeuvre": "3211", "amplitude_deg": {"uniform": [0.5, 1.5]},
                                    "step_time": {"uniform": [0.3, 0.5]}, "start": 1.0},
                       "theta_1c": {"manoeuvre": "doublet", "amplitude_deg": {"uniform": [-0.5, 0.5]},
                                    "step_time": 0.5, "start": 6.0}},
            "outputs": list(rates), "noise": {name: {"uniform": [0.001, 0.005]} for name in rates},
            "compare_with": "bo105-80kt-flight"}


def run(*, n_tasks: int = N_TASKS, duration: float = DURATION_S, repeats: int = REPEATS, worker_counts=(1, 2),
        progress: bool = True) -> dict:
    """Time the campaign of :func:`scaling_study` on each local cluster size, ``repeats`` times.

    Returns
    -------
    dict
        ``{"tasks", "duration_s", "repeats", "runs": [{"workers", "repeat", "seconds",
        "task_seconds"}], "by_workers": {n: {"median_s", "min_s", "max_s", "median_task_s",
        "min_task_s", "max_task_s"}}, "speedup", "speedup_tasks", "goal"}``; the speed-ups are of
        the largest worker count over the smallest, on the medians.
    """
    from fmu_src import build_bo105_reference_fmu
    from validation.campaign import parse_spec, run_campaign

    runs = []
    with tempfile.TemporaryDirectory(prefix="flightgp-bench-campaign-") as folder, \
            progress_bar("bench campaign", enabled=progress, total=repeats * len(worker_counts), unit="run") as update:
        fmu = build_bo105_reference_fmu(80, folder)
        spec = parse_spec({"name": "scaling", "studies": [scaling_study(fmu, n_tasks=n_tasks, duration=duration)]},
                          base_dir=folder, source="bench campaign")
        for repeat in range(repeats):
            for workers in worker_counts:
                started = clock.perf_counter()
                campaign = run_campaign(spec, Path(folder) / f"run-{workers}-{repeat}", workers=workers,
                                        progress=False)
                if campaign.done != n_tasks:
                    raise RuntimeError(f"{n_tasks - campaign.done} tasks of the scaling campaign failed: "
                                       f"{campaign.summary['failures'][:1]}")
                runs.append({"workers": workers, "repeat": repeat, "seconds": clock.perf_counter() - started,
                             "task_seconds": campaign.task_seconds})
                if update:
                    update(1, workers=workers)
    by_workers = {}
    for workers in worker_counts:
        total = [r["seconds"] for r in runs if r["workers"] == workers]
        tasks = [r["task_seconds"] for r in runs if r["workers"] == workers]
        by_workers[workers] = {"median_s": float(np.median(total)), "min_s": min(total), "max_s": max(total),
                               "median_task_s": float(np.median(tasks)), "min_task_s": min(tasks),
                               "max_task_s": max(tasks)}
    few, many = by_workers[min(worker_counts)], by_workers[max(worker_counts)]
    return {"tasks": n_tasks, "duration_s": duration, "repeats": repeats, "runs": runs,
            "by_workers": {str(n): entry for n, entry in by_workers.items()},
            "speedup": few["median_s"] / many["median_s"],
            "speedup_tasks": few["median_task_s"] / many["median_task_s"],
            "workers": [min(worker_counts), max(worker_counts)], "goal": SPEEDUP_GOAL}


def format_table(report: dict) -> str:
    """The ``bench campaign`` report as a table."""
    lines = [f"flightgp campaign: {report['tasks']} co-simulations of {report['duration_s']:g} s (Bo105 reference "
             f"FMU, Monte Carlo), {report['repeats']} runs per local cluster size; median (min-max), s",
             f"{'workers':>7} {'command':>22} {'task phase':>22}"]
    for workers, entry in report["by_workers"].items():
        lines.append(f"{workers:>7} {entry['median_s']:8.2f} ({entry['min_s']:5.2f}-{entry['max_s']:5.2f}) "
                     f"{entry['median_task_s']:8.2f} ({entry['min_task_s']:5.2f}-{entry['max_task_s']:5.2f})")
    few, many = report["workers"]
    lines.append(f"speed-up {many} workers over {few}: {report['speedup']:.2f}x the command, "
                 f"{report['speedup_tasks']:.2f}x the task phase (goal >= {report['goal']:g}x the command)")
    return "\n".join(lines)


def summary_rows(report: dict) -> list[SummaryRow]:
    few, many = report["workers"]
    return [SummaryRow(f"campaign.speedup.{many}workers",
                       f"campaign of {report['tasks']} co-simulations, {many} Dask workers over {few}",
                       report["speedup"], "x", report["goal"],
                       note=f"{report['by_workers'][str(many)]['median_s']:.1f} s")]
