"""``flightgp bench diagnose``: seconds of ``flightgp diagnose`` per concealed-effect case
against the recording's length (docs/benchmarks.md)."""
from __future__ import annotations

from validation.core.progress import progress_bar

#: ``bench diagnose``: the diagnose-bench cases timed (one per kind of search outcome).
DIAGNOSE_CASES = ("none", "delay-theta_1s-60ms", "M_q-40%", "pair-delay+bias", "outside-quadratic-damping")


#: Goal of ``bench diagnose`` (docs/benchmarks.md): seconds per case for a 20 s recording at 100 Hz.
DIAGNOSE_GOAL_S = 60.0


def run(*, seed: int = 0, progress: bool = True) -> dict:
    """Wall-clock time of ``flightgp diagnose`` on concealed-effect cases
    (:mod:`validation.diagnose.bench`; 20 s at 100 Hz plus a 20 s held-out recording) against
    the recording's duration (real time) and the goal of :data:`DIAGNOSE_GOAL_S` per case.

    Returns
    -------
    dict
        ``{"cases": [{"case", "seconds", "over_recording", "passed"}], "goal_s", "max_seconds",
        "goal_met", "recording_s"}``.
    """
    from validation.diagnose.bench import DURATION, concealed_cases, run_bench

    cases = [case for case in concealed_cases() if case.name in DIAGNOSE_CASES]
    with progress_bar("bench diagnose", enabled=progress, total=len(cases), unit="case") as update:
        report = run_bench(cases, seed=seed, progress=update)
    rows = [{"case": row["case"], "seconds": row["seconds"], "over_recording": row["seconds"] / DURATION,
             "passed": row["passed"]} for row in report["cases"]]
    worst = max(row["seconds"] for row in rows)
    return {"cases": rows, "goal_s": DIAGNOSE_GOAL_S, "max_seconds": worst,
            "goal_met": worst <= DIAGNOSE_GOAL_S, "recording_s": DURATION}


def format_table(report: dict) -> str:
    """The ``bench diagnose`` report as a table."""
    return "\n".join([
        f"flightgp diagnose per case ({report['recording_s']:g} s at 100 Hz + a held-out recording); "
        f"goal <= {report['goal_s']:g} s per case",
        f"{'case':<28} {'s':>6} {'x recording':>12} {'scored':>7}",
        *(f"{r['case']:<28} {r['seconds']:6.1f} {r['over_recording']:12.2f} "
          f"{'pass' if r['passed'] else 'fail':>7}" for r in report["cases"]),
    ])


def summary_rows(report: dict) -> list:
    return [("diagnose per 20 s case (worst of the timed cases)", f"{report['max_seconds']:.1f} s",
             f"<= {report['goal_s']:g} s", report["goal_met"])]
