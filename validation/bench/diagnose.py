"""``flightgp bench diagnose``: seconds of ``flightgp diagnose`` per concealed-effect case
against the recording's length, built in and through the Bo105 reference FMU
(docs/benchmarks.md)."""
from __future__ import annotations

import tempfile

from validation.bench.rows import SummaryRow
from validation.core.progress import progress_bar

#: The cases also timed through the Bo105 reference FMU (``diagnose --reference FILE.fmu``): an
#: input effect (replays that resume from saved states) and a derivative (an FMU parameter,
#: replays from the start).
FMU_CASES = ("delay-theta_1s-60ms", "M_q-40%")


#: Goal of ``bench diagnose`` (docs/benchmarks.md): seconds for every case of the Bo105 suite, a
#: 20 s recording at 100 Hz.
DIAGNOSE_GOAL_S = 15.0
#: Goal through the Bo105 reference FMU, seconds per case for a 20 s recording at 100 Hz on 2 cores.
FMU_GOAL_S = 120.0


def run(*, seed: int = 0, cases=None, fmu_cases=FMU_CASES, workers: int | None = None,
        progress: bool = True) -> dict:
    """Wall-clock time of ``flightgp diagnose`` on the concealed-effect cases of the Bo105 suite
    (:mod:`validation.diagnose.bench`; 20 s at 100 Hz plus a 20 s held-out recording) against
    the recording's duration (real time) and the goal of :data:`DIAGNOSE_GOAL_S` per case; and
    of :data:`FMU_CASES` diagnosed through the Bo105 reference FMU (pythonfmu, built here),
    against :data:`FMU_GOAL_S` and as a ratio to the same case built in (the peer, same process).
    ``cases``: the names of the Bo105 suite's cases to time (default: every one);
    ``fmu_cases``: those timed through the FMU as well; ``workers``: the processes that replay
    the FMU's candidates (default: the cores this process may use).

    Returns
    -------
    dict
        ``{"cases": [{"case", "seconds", "over_recording", "passed"}], "goal_s", "max_seconds",
        "goal_met", "recording_s", "fmu": {"cases": [{"case", "seconds", "over_built_in",
        "passed"}], "goal_s", "max_seconds", "goal_met", "workers"}}``.
    """
    from fmu_src import build_bo105_reference_fmu
    from validation.diagnose.bench import DURATION, concealed_cases, run_bench
    from validation.vehicles.fmu_reference import available_cores

    suite = concealed_cases()
    unknown = sorted(set(cases or ()).union(fmu_cases) - {case.name for case in suite})
    if unknown:
        raise ValueError(f"bench diagnose: no case {', '.join(unknown)} in the Bo105 suite "
                         f"({', '.join(case.name for case in suite)})")
    cases = [case for case in suite if cases is None or case.name in cases]
    through_fmu = [case for case in suite if case.name in fmu_cases]
    with progress_bar("bench diagnose", enabled=progress, total=len(cases) + len(through_fmu),
                      unit="case") as update:
        report = run_bench(cases, seed=seed, duration=DURATION, progress=update)
        with tempfile.TemporaryDirectory(prefix="flightgp-bench-") as folder:
            fmu = str(build_bo105_reference_fmu(80, folder))
            fmu_report = run_bench(through_fmu, through=fmu, seed=seed, duration=DURATION, workers=workers,
                                   progress=update)
    rows = [{"case": row["case"], "seconds": row["seconds"], "over_recording": row["seconds"] / DURATION,
             "passed": row["passed"]} for row in report["cases"]]
    built_in = {row["case"]: row["seconds"] for row in rows}
    for case in through_fmu:  # the peer of a case timed through the FMU only
        if case.name not in built_in:
            built_in[case.name] = run_bench([case], seed=seed, duration=DURATION)["cases"][0]["seconds"]
    fmu_rows = [{"case": row["case"], "seconds": row["seconds"],
                 "over_built_in": row["seconds"] / built_in[row["case"]], "passed": row["passed"]}
                for row in fmu_report["cases"]]
    worst, worst_fmu = max(row["seconds"] for row in rows), max(row["seconds"] for row in fmu_rows)
    return {"cases": rows, "goal_s": DIAGNOSE_GOAL_S, "max_seconds": worst,
            "goal_met": worst <= DIAGNOSE_GOAL_S, "recording_s": DURATION,
            "fmu": {"cases": fmu_rows, "goal_s": FMU_GOAL_S, "max_seconds": worst_fmu,
                    "goal_met": worst_fmu <= FMU_GOAL_S, "workers": workers or available_cores()}}


def format_table(report: dict) -> str:
    """The ``bench diagnose`` report as a table."""
    fmu = report["fmu"]
    return "\n".join([
        f"flightgp diagnose per case of the Bo105 suite ({report['recording_s']:g} s at 100 Hz + a held-out "
        f"recording); goal <= {report['goal_s']:g} s per case",
        f"{'case':<28} {'s':>6} {'x recording':>12} {'scored':>7}",
        *(f"{r['case']:<28} {r['seconds']:6.1f} {r['over_recording']:12.2f} "
          f"{'pass' if r['passed'] else 'fail':>7}" for r in report["cases"]),
        f"through the Bo105 reference FMU (pythonfmu, {fmu['workers']} worker processes); goal <= "
        f"{fmu['goal_s']:g} s per case",
        f"{'case':<28} {'s':>6} {'x built in':>12} {'scored':>7}",
        *(f"{r['case']:<28} {r['seconds']:6.1f} {r['over_built_in']:12.1f} "
          f"{'pass' if r['passed'] else 'fail':>7}" for r in fmu["cases"]),
    ])


def summary_rows(report: dict) -> list[SummaryRow]:
    fmu = report["fmu"]
    return [SummaryRow("diagnose.worst_case.seconds", "diagnose per 20 s case (worst of the Bo105 suite)",
                       report["max_seconds"], "s", report["goal_s"], at_least=False),
            SummaryRow("diagnose.fmu.worst_case.seconds", "diagnose through the Bo105 FMU per 20 s case (worst)",
                       fmu["max_seconds"], "s", fmu["goal_s"], at_least=False)]
