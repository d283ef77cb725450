"""``flightgp bench diagnose``: seconds of ``flightgp diagnose`` per concealed-effect case
against the recording's length, built in and through the Bo105 reference FMU
(docs/benchmarks.md)."""
from __future__ import annotations

import tempfile

from validation.core.progress import progress_bar

#: ``bench diagnose``: the diagnose-bench cases timed (one per kind of search outcome).
DIAGNOSE_CASES = ("none", "delay-theta_1s-60ms", "M_q-40%", "pair-delay+bias", "outside-quadratic-damping")
#: The cases also timed through the Bo105 reference FMU (``diagnose --reference FILE.fmu``): an
#: input effect (replays that resume from saved states) and a derivative (an FMU parameter,
#: replays from the start).
FMU_CASES = ("delay-theta_1s-60ms", "M_q-40%")


#: Goal of ``bench diagnose`` (docs/benchmarks.md): seconds per case for a 20 s recording at 100 Hz.
DIAGNOSE_GOAL_S = 60.0
#: Goal through the Bo105 reference FMU, seconds per case for a 20 s recording at 100 Hz on 2 cores.
FMU_GOAL_S = 120.0


def run(*, seed: int = 0, fmu_cases=FMU_CASES, progress: bool = True) -> dict:
    """Wall-clock time of ``flightgp diagnose`` on concealed-effect cases
    (:mod:`validation.diagnose.bench`; 20 s at 100 Hz plus a 20 s held-out recording) against
    the recording's duration (real time) and the goal of :data:`DIAGNOSE_GOAL_S` per case; and
    of :data:`FMU_CASES` diagnosed through the Bo105 reference FMU (pythonfmu, built here),
    against :data:`FMU_GOAL_S` and as a ratio to the same case built in (the peer, same process).
    ``fmu_cases``: those timed through the FMU (a subset of :data:`DIAGNOSE_CASES`).

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

    cases = [case for case in concealed_cases() if case.name in DIAGNOSE_CASES]
    through_fmu = [case for case in cases if case.name in fmu_cases]
    with progress_bar("bench diagnose", enabled=progress, total=len(cases) + len(through_fmu),
                      unit="case") as update:
        report = run_bench(cases, seed=seed, duration=DURATION, progress=update)
        with tempfile.TemporaryDirectory(prefix="flightgp-bench-") as folder:
            fmu = str(build_bo105_reference_fmu(80, folder))
            fmu_report = run_bench(through_fmu, through=fmu, seed=seed, duration=DURATION, progress=update)
    rows = [{"case": row["case"], "seconds": row["seconds"], "over_recording": row["seconds"] / DURATION,
             "passed": row["passed"]} for row in report["cases"]]
    built_in = {row["case"]: row["seconds"] for row in rows}
    fmu_rows = [{"case": row["case"], "seconds": row["seconds"],
                 "over_built_in": row["seconds"] / built_in[row["case"]], "passed": row["passed"]}
                for row in fmu_report["cases"]]
    worst, worst_fmu = max(row["seconds"] for row in rows), max(row["seconds"] for row in fmu_rows)
    return {"cases": rows, "goal_s": DIAGNOSE_GOAL_S, "max_seconds": worst,
            "goal_met": worst <= DIAGNOSE_GOAL_S, "recording_s": DURATION,
            "fmu": {"cases": fmu_rows, "goal_s": FMU_GOAL_S, "max_seconds": worst_fmu,
                    "goal_met": worst_fmu <= FMU_GOAL_S, "workers": available_cores()}}


def format_table(report: dict) -> str:
    """The ``bench diagnose`` report as a table."""
    fmu = report["fmu"]
    return "\n".join([
        f"flightgp diagnose per case ({report['recording_s']:g} s at 100 Hz + a held-out recording); "
        f"goal <= {report['goal_s']:g} s per case",
        f"{'case':<28} {'s':>6} {'x recording':>12} {'scored':>7}",
        *(f"{r['case']:<28} {r['seconds']:6.1f} {r['over_recording']:12.2f} "
          f"{'pass' if r['passed'] else 'fail':>7}" for r in report["cases"]),
        f"through the Bo105 reference FMU (pythonfmu, {fmu['workers']} worker processes); goal <= "
        f"{fmu['goal_s']:g} s per case",
        f"{'case':<28} {'s':>6} {'x built in':>12} {'scored':>7}",
        *(f"{r['case']:<28} {r['seconds']:6.1f} {r['over_built_in']:12.1f} "
          f"{'pass' if r['passed'] else 'fail':>7}" for r in fmu["cases"]),
    ])


def summary_rows(report: dict) -> list:
    fmu = report["fmu"]
    return [("diagnose per 20 s case (worst of the timed cases)", f"{report['max_seconds']:.1f} s",
             f"<= {report['goal_s']:g} s", report["goal_met"]),
            ("diagnose through the Bo105 FMU per 20 s case (worst)", f"{fmu['max_seconds']:.1f} s",
             f"<= {fmu['goal_s']:g} s", fmu["goal_met"])]
