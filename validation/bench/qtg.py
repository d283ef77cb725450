"""``flightgp bench qtg``: the example QTG (``examples/qtg/bo105_80kt.toml``, docs/qtg.md)
against the Bo105 reference FMU, as ``flightgp qtg`` runs it (one FMU instance reset between the
tests) and as a script that calls fmpy once per test would (a fresh extraction and instance per
test), repeated; the whole command's time (tests, plots and reports) against its goal.

Each repeat times, in this process, one after the other so both see the same load: the tests
with one instance (:func:`validation.qtg.run_qtg` on :func:`validation.qtg.open_model`), the
same tests with an instance per test, and the files ``flightgp qtg`` writes (the plots drawn,
:func:`validation.qtg.report.qtg_files`; not written to disk). The FMU is built once.
"""
from __future__ import annotations

import dataclasses
import tempfile
import time as clock
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from validation.bench.rows import SummaryRow
from validation.core.progress import progress_bar

#: The example QTG the benchmark runs.
EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "qtg" / "bo105_80kt.toml"
REPEATS = 3
#: Goal of the whole example (about 20 tests: runs, plots and reports) on 2 cores, s.
EXAMPLE_GOAL_S = 60.0


def run(*, repeats: int = REPEATS, progress: bool = True) -> dict:
    """Time the example QTG with one FMU instance and with one per test, and its reports.

    Returns
    -------
    dict
        ``{"tests", "repeats", "runs": [{"one_instance_s", "instance_per_test_s", "reports_s"}],
        "median_one_instance_s", "median_instance_per_test_s", "median_reports_s",
        "median_total_s", "reuse_speedup", "instantiations", "goal_s"}``: the total is the tests
        with one instance plus the reports; the speed-up is the instance-per-test time over the
        one-instance time, on the medians.
    """
    from fmu_src import build_bo105_reference_fmu
    from validation.qtg import open_model, read_spec, run_qtg
    from validation.qtg.report import qtg_files

    spec = read_spec(EXAMPLE)
    runs = []
    with tempfile.TemporaryDirectory(prefix="flightgp-bench-qtg-") as folder, \
            progress_bar("bench qtg", total=repeats, unit="repeat", enabled=progress) as update:
        fmu = build_bo105_reference_fmu(80, folder)
        for _ in range(repeats):
            started = clock.perf_counter()
            with ExitStack() as stack:
                result = run_qtg(spec, open_model(stack, fmu=fmu), progress=False)
            one_instance = clock.perf_counter() - started
            started = clock.perf_counter()
            for test in spec.tests:
                with ExitStack() as stack:
                    run_qtg(dataclasses.replace(spec, tests=(test,)), open_model(stack, fmu=fmu), progress=False)
            per_test = clock.perf_counter() - started
            started = clock.perf_counter()
            qtg_files(result, Path(folder) / "out")
            runs.append({"one_instance_s": one_instance, "instance_per_test_s": per_test,
                         "reports_s": clock.perf_counter() - started})
            if update:
                update(1)
    medians = {key: float(np.median([r[key] for r in runs])) for key in runs[0]}
    return {"tests": len(spec.tests), "repeats": repeats, "runs": runs,
            **{f"median_{key}": value for key, value in medians.items()},
            "median_total_s": medians["one_instance_s"] + medians["reports_s"],
            "reuse_speedup": medians["instance_per_test_s"] / medians["one_instance_s"],
            "instantiations": result.instantiations, "goal_s": EXAMPLE_GOAL_S}


def format_table(report: dict) -> str:
    lines = [f"QTG example ({report['tests']} tests, Bo105 reference FMU), {report['repeats']} repeats, s",
             f"{'':38} {'median':>8} {'runs':>26}"]
    for key, label in (("one_instance_s", "tests, one FMU instance (flightgp)"),
                       ("instance_per_test_s", "tests, an instance per test (peer)"),
                       ("reports_s", "plots and reports")):
        runs = ", ".join(f"{r[key]:.2f}" for r in report["runs"])
        lines.append(f"{label:38} {report[f'median_{key}']:8.2f} {runs:>26}")
    lines.append(f"instance reuse: {report['reuse_speedup']:.2f}x ({report['instantiations']} instantiation); "
                 f"whole QTG {report['median_total_s']:.1f} s (goal <= {report['goal_s']:g} s)")
    return "\n".join(lines)


def summary_rows(report: dict) -> list[SummaryRow]:
    return [SummaryRow("qtg.example.seconds", f"example QTG, {report['tests']} tests with reports",
                       report["median_total_s"], "s", report["goal_s"], at_least=False,
                       note=f"tests {report['median_one_instance_s']:.2f} s"),
            SummaryRow("qtg.instance_reuse.speedup", "one FMU instance over one per test", report["reuse_speedup"],
                       "x", None)]
