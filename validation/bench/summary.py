"""The benchmarks of ``flightgp bench`` by name, and the one table of their headline
measures against their goals.

Each benchmark measures flightgp against a peer run in the same process, as a ratio; speed
goals live here, never in timed unit tests (docs/benchmarks.md)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from validation.bench import campaign, cosim, diagnose, fmu, gp, narx, qtg, rgblimp
from validation.bench.rows import SummaryRow


@dataclass(frozen=True)
class Benchmark:
    """One entry of :data:`BENCHMARKS`.

    Attributes
    ----------
    run : callable
        ``run(progress=..., **options) -> dict``, the JSON report.
    format_table : callable
        ``format_table(report) -> str``.
    options : dict
        Command-line option of ``flightgp bench`` (argparse dest) -> keyword of ``run``.
    summary : callable
        ``summary(report) -> [SummaryRow]``: the headline rows of the combined ``flightgp bench``
        table and of ``build/bench.json``.
    """

    run: Callable[..., dict]
    format_table: Callable[[dict], str]
    options: dict
    summary: Callable[[dict], list]


#: Benchmarks by name, with the ``flightgp bench`` options each takes (argparse dest -> keyword
#: of its ``run``). ``flightgp bench`` without a name runs them all.
BENCHMARKS = {
    "gp": Benchmark(gp.run, gp.format_table, {"sizes": "sizes", "restarts": "n_restarts"}, gp.summary_rows),
    "narx": Benchmark(narx.run, narx.format_table, {"runs": "n_runs", "steps": "n_steps"}, narx.summary_rows),
    "fmu": Benchmark(fmu.run, fmu.format_table, {"fmu_steps": "n_steps"}, fmu.summary_rows),
    "cosim": Benchmark(cosim.run, cosim.format_table, {}, cosim.summary_rows),
    "diagnose": Benchmark(diagnose.run, diagnose.format_table, {}, diagnose.summary_rows),
    "campaign": Benchmark(campaign.run, campaign.format_table, {}, campaign.summary_rows),
    "rgblimp": Benchmark(rgblimp.run, rgblimp.format_table, {}, rgblimp.summary_rows),
    "qtg": Benchmark(qtg.run, qtg.format_table, {}, qtg.summary_rows),
}


def summary_rows(reports: dict) -> list[SummaryRow]:
    """Every benchmark's headline rows, in the order of ``reports`` (name -> report)."""
    return [row for name, report in reports.items() for row in BENCHMARKS[name].summary(report)]


def format_summary(reports: dict) -> str:
    """One table of every benchmark's headline rows (``flightgp bench``)."""
    rows = summary_rows(reports)
    width = max(len(row.measure) for row in rows)
    id_width = max(len(row.id) for row in rows)
    lines = [f"{'id':<{id_width}}  {'measure':<{width}}  {'measured':<34} {'goal':<18} met"]
    for row in rows:
        value, goal = row.text()
        met = "-" if row.met is None else "yes" if row.met else "no"
        lines.append(f"{row.id:<{id_width}}  {row.measure:<{width}}  {value:<34} {goal:<18} {met}")
    return "\n".join(lines)
