"""The files of a QTG run (docs/qtg.md, "Output files"): per test the classic QTG plot (flight test
and simulation overlaid, the tolerance band shaded about the flight test, the inputs beneath, the
verdict in the title), ``summary.md``, one self-contained ``qtg.html`` (the plots embedded as data
URIs), ``junit.xml`` for CI systems and ``qtg.json`` for machines.
"""
from __future__ import annotations

import base64
import html
import re
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from validation.core.files import json_text, write_files_atomically
from validation.core.plots import png_bytes
from validation.core.recordings import column_phrase, column_unit
from validation.diagnose.fidelity import TOLERANCE_SOURCE
from validation.qtg.run import ERROR, FAILED, NOT_RUN, PASSED, READING_UNITS, QtgResult, TestResult, display

#: Colours of the verdicts (plots and qtg.html).
VERDICT_COLOURS = {PASSED: "#1a7f37", FAILED: "#cf222e", ERROR: "#cf222e", NOT_RUN: "#6e7781"}
#: The JUnit element of each verdict that is not a pass.
_JUNIT_ELEMENTS = {FAILED: "failure", ERROR: "error", NOT_RUN: "skipped"}


def plot_names(result: QtgResult) -> dict:
    """Test id -> its plot's path relative to the output folder (``plots/NN_<id>.png``), for the
    tests that ran."""
    names = {}
    for number, test in enumerate(result.tests, start=1):
        if test.outputs:
            slug = re.sub(r"[^A-Za-z0-9.-]+", "_", test.test.id).strip("_")
            names[test.test.id] = f"plots/{number:02d}_{slug}.png"
    return names


def test_figure(test: TestResult, *, model_name: str) -> Figure:
    """The QTG plot of a test that ran (module docstring): one panel per output, the inputs the
    recording moves beneath."""
    outputs = list(test.outputs.values())
    figure = Figure(figsize=(8.5, 2.3 * len(outputs) + 2.4), layout="constrained")
    FigureCanvasAgg(figure)
    panels = figure.subplots(len(outputs) + 1, 1, sharex=True, squeeze=False)[:, 0]
    for panel, output in zip(panels, outputs):
        check = output.check
        unit, scale = display(check.name, check.tolerance)
        time, recorded = output.time, output.recorded * scale
        window = np.where(output.in_window, 1.0, np.nan)  # the band only where it holds
        panel.fill_between(time, (recorded - output.half_width * scale) * window,
                           (recorded + output.half_width * scale) * window, color="tab:green", alpha=0.2, lw=0,
                           label=f"tolerance {check.tolerance.words(output.unit)}")
        panel.plot(time, recorded, color="black", lw=1.2, label="flight test")
        panel.plot(time, output.simulated * scale, color="tab:blue", lw=1.2, ls="--",
                   label=f"simulation ({model_name})")
        if not output.passed:
            k = int(np.argmin(np.abs(time - output.max_error_time)))
            panel.plot(time[k], output.simulated[k] * scale, "x", color=VERDICT_COLOURS[FAILED], ms=9, mew=2,
                       label=f"largest excursion, t = {output.max_error_time:.2f} s")
        if check.window is not None:
            for edge in check.window:
                panel.axvline(edge, color="gray", lw=0.8, ls=":")
        verdict = "pass" if output.passed else "FAIL"
        rule = "" if check.share == 1 else f", {100 * check.share:g} % required"
        panel.set_title(f"{check.name}, {column_phrase(check.name)}: {verdict} "
                        f"({100 * output.inside_share:.0f} % of samples inside{rule})",
                        fontsize="medium", loc="left", color=VERDICT_COLOURS[PASSED if output.passed else FAILED])
        panel.set_ylabel(f"{check.name} [{unit}]")
        panel.legend(fontsize="small", loc="best")
    moved = [name for name, values in test.inputs.items() if np.ptp(values) > 0] or list(test.inputs)
    units = set()
    for name in moved:
        unit, scale = READING_UNITS.get(column_unit(name), (column_unit(name), 1.0))
        units.add(unit)
        panels[-1].step(test.input_time, test.inputs[name] * scale, where="post",
                        label=f"{name}, {column_phrase(name)} [{unit}]")
    panels[-1].set_ylabel(f"input [{units.pop()}]" if len(units) == 1 else "input")
    panels[-1].set_title("inputs (from trim)", fontsize="medium", loc="left")
    panels[-1].legend(fontsize="small", loc="best")
    panels[-1].set_xlabel("time [s]")
    for panel in panels:
        panel.grid(True, alpha=0.3)
    verdict = test.status.upper()
    figure.suptitle(f"{test.test.id}: {verdict}\n"
                    f"{model_name} against flight test {Path(test.test.recording_path).name}",
                    color=VERDICT_COLOURS[test.status])
    return figure


#: The files a QTG run writes in its folder besides the plots (in ``plots/``), which the command
#: checks before it runs (docs/conventions.md, "Writing files").
QTG_FILES = ("summary.md", "qtg.html", "junit.xml", "qtg.json")


def qtg_files(result: QtgResult, out_dir) -> dict:
    """Every file of a QTG run as ``{path: text or bytes}`` (module docstring), written by
    :func:`write_qtg`."""
    out_dir = Path(out_dir)
    plots = {name: png_bytes(test_figure(test, model_name=result.model_name))
             for name, test in zip(plot_names(result).values(), [t for t in result.tests if t.outputs])}
    reports = (summary_markdown(result), qtg_html(result, plots), junit_xml(result), json_text(qtg_json(result)))
    return {**{out_dir / name: data for name, data in plots.items()},
            **{out_dir / name: data for name, data in zip(QTG_FILES, reports, strict=True)}}


def write_qtg(result: QtgResult, out_dir) -> list[Path]:
    """Write :func:`qtg_files` as one atomic step (docs/conventions.md, "Writing files")."""
    return write_files_atomically(qtg_files(result, out_dir))


def _counts(result: QtgResult) -> str:
    return (f"{len(result.tests)} tests: {result.count(PASSED)} passed, {result.count(FAILED)} failed, "
            f"{result.count(ERROR)} errors, {result.count(NOT_RUN)} not run")


def _rows(result: QtgResult) -> list:
    """The summary table: per output of a test that ran (per test otherwise) the cells of
    :data:`_COLUMNS`."""
    rows = []
    for test in result.tests:
        if not test.outputs:
            rows.append((test, [test.test.id, test.status, "", test.reason or "", "", "", "", "", "", ""]))
            continue
        for index, output in enumerate(test.outputs.values()):
            unit, scale = display(output.check.name, output.check.tolerance)
            window = "" if output.check.window is None else " in [{:g}, {:g}] s".format(*output.check.window)
            cost = "" if output.frequency_cost is None else f"{output.frequency_cost:.3g}"
            rows.append((test, [test.test.id if index == 0 else "", test.status if index == 0 else "",
                                output.check.name, output.check.tolerance.words(output.unit) + window,
                                f"{output.max_error * scale:.3g} {unit} at {output.max_error_time:.2f} s",
                                f"{output.excursion * scale:.3g} {unit}",
                                f"{100 * output.inside_share:.0f} % (need {100 * output.check.share:g} %)",
                                f"{output.rmse * scale:.3g} {unit}", f"{output.theil:.3f}", cost]))
    return rows


_COLUMNS = ("test", "verdict", "output", "band", "largest difference", "beyond band", "samples inside",
            "RMSE", "Theil's U", "J")


def _sources(result: QtgResult) -> str:
    return (f"Bands: as the spec gives them; an output without one takes its band of {TOLERANCE_SOURCE}. "
            "RMSE and Theil's U (0 a perfect match) over the compared samples; J is Tischler's "
            "frequency-domain cost (J <= 100 acceptable, J <= 50 nearly indistinguishable; empty where no "
            "input is coherent with the output).")


def summary_markdown(result: QtgResult) -> str:
    """``summary.md``: the title, the model, the counts and the table, each test linking to its plot."""
    plots = plot_names(result)
    lines = [f"# QTG: {result.spec.title}", ""]
    if result.spec.description:
        lines += [result.spec.description, ""]
    lines += [f"Model `{result.model_name}` ({result.model_kind}), spec `{result.spec.path.name}`. "
              f"**{'PASSED' if result.passed else 'NOT PASSED'}**: {_counts(result)}; run in {result.seconds:.1f} s.",
              "", _sources(result), "",
              "| " + " | ".join(_COLUMNS) + " |", "|" + "---|" * len(_COLUMNS)]
    for test, cells in _rows(result):
        if cells[0] and test.test.id in plots:
            cells[0] = f"[{cells[0]}]({plots[test.test.id]})"
        lines.append("| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |")
    notes = [f"- {test.test.id}: {test.test.note}" for test in result.tests if test.test.note]
    if notes:
        lines += ["", "Notes:", "", *notes]
    return "\n".join(lines) + "\n"


def qtg_html(result: QtgResult, plots: dict) -> str:
    """``qtg.html``: one self-contained page, the summary table and every plot as a data URI."""
    names = plot_names(result)
    escape = html.escape
    rows = []
    for test, cells in _rows(result):
        colour = VERDICT_COLOURS[test.status]
        if cells[0] and test.test.id in names:
            cells = [f'<a href="#test-{result.tests.index(test) + 1}">{escape(cells[0])}</a>',
                     *map(escape, cells[1:])]
        else:
            cells = list(map(escape, cells))
        if cells[1]:
            cells[1] = f'<b style="color:{colour}">{cells[1]}</b>'
        rows.append("<tr>" + "".join(f"<td>{cell}</td>" for cell in cells) + "</tr>")
    sections = []
    for number, test in enumerate(result.tests, start=1):
        heading = (f'<h2 id="test-{number}">{escape(test.test.id)}: '
                   f'<span style="color:{VERDICT_COLOURS[test.status]}">{escape(test.status)}</span></h2>')
        body = [f"<p>Flight test: <code>{escape(test.test.recording_path)}</code>.</p>"]
        if test.test.note:
            body.append(f"<p>{escape(test.test.note)}</p>")
        if test.reason:
            body.append(f"<p>{escape(test.status)}: {escape(test.reason)}</p>")
        elif test.failure():
            body.append(f"<p>{escape(test.failure())}</p>")
        if test.test.id in names:
            data = base64.b64encode(plots[names[test.test.id]]).decode("ascii")
            body.append(f'<img alt="QTG plot of {escape(test.test.id)}" src="data:image/png;base64,{data}">')
        sections.append(heading + "\n" + "\n".join(body))
    verdict = "PASSED" if result.passed else "NOT PASSED"
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>QTG: {escape(result.spec.title)}</title>
<style>body{{font-family:sans-serif;max-width:70em;margin:2em auto;padding:0 1em}}
table{{border-collapse:collapse;font-size:90%}}td,th{{border:1px solid #ccc;padding:0.2em 0.5em;text-align:left}}
img{{max-width:100%}}</style></head><body>
<h1>QTG: {escape(result.spec.title)}</h1>
{f"<p>{escape(result.spec.description)}</p>" if result.spec.description else ""}
<p>Model <code>{escape(result.model_name)}</code> ({escape(result.model_kind)}), spec
<code>{escape(result.spec.path.name)}</code>. <b>{verdict}</b>: {escape(_counts(result))}; run in
{result.seconds:.1f} s.</p>
<p>{escape(_sources(result))}</p>
<table><tr>{"".join(f"<th>{escape(c)}</th>" for c in _COLUMNS)}</tr>
{chr(10).join(rows)}
</table>
{chr(10).join(sections)}
</body></html>
"""


def junit_xml(result: QtgResult) -> str:
    """``junit.xml``: one ``testsuite`` of one ``testcase`` per QTG test, in the JUnit XML format
    CI systems read; a failing test's ``failure`` message names each failing output, its largest
    excursion beyond the band and its time; a test not run is ``skipped``, one whose model did not
    run an ``error``."""
    counts = {"tests": str(len(result.tests)), "failures": str(result.count(FAILED)),
              "errors": str(result.count(ERROR)), "skipped": str(result.count(NOT_RUN)),
              "time": f"{result.seconds:.3f}"}
    suites = ElementTree.Element("testsuites", {"name": f"flightgp qtg {result.spec.path.name}", **counts})
    suite = ElementTree.SubElement(suites, "testsuite", {"name": result.spec.title, **counts})
    properties = ElementTree.SubElement(suite, "properties")
    for name, value in (("model", result.model_name), ("model_kind", result.model_kind),
                        ("spec", str(result.spec.path))):
        ElementTree.SubElement(properties, "property", {"name": name, "value": value})
    classname = f"qtg.{result.spec.path.stem}"
    for test in result.tests:
        case = ElementTree.SubElement(suite, "testcase", {"name": test.test.id, "classname": classname,
                                                          "time": f"{test.seconds:.3f}"})
        if test.status in _JUNIT_ELEMENTS:
            message = test.failure() if test.status == FAILED else f"{test.status}: {test.reason}"
            element = ElementTree.SubElement(case, _JUNIT_ELEMENTS[test.status], {"message": message})
            if test.status == FAILED:
                element.set("type", "tolerance")
                element.text = "\n".join(
                    f"{o.check.name}: largest difference {o.max_error:.4g} {o.unit} at t = {o.max_error_time:.2f} s, "
                    f"band {o.check.tolerance.words(o.unit)} ({o.half_width:.4g} {o.unit}), "
                    f"{100 * o.inside_share:.1f} % inside" for o in test.outputs.values())
    ElementTree.indent(suites)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ElementTree.tostring(suites, encoding="unicode") + "\n"


def qtg_json(result: QtgResult) -> dict:
    """``qtg.json`` (docs/qtg.md, "qtg.json"): the counts and per test its verdict and per output
    the band, the largest excursion beyond it and its time, the share inside, RMSE, Theil's U and
    the frequency-domain cost, in SI units."""
    tests = []
    for test in result.tests:
        outputs = {}
        for name, o in test.outputs.items():
            outputs[name] = {
                "unit": o.unit, "tolerance": o.half_width, "tolerance_as_stated": o.check.tolerance.as_stated,
                "tolerance_relative": o.check.tolerance.relative, "tolerance_source": o.check.tolerance.source,
                "window": list(o.check.window) if o.check.window else None, "share_required": o.check.share,
                "inside_share": o.inside_share, "passed": o.passed,
                "max_error": o.max_error, "max_error_time": o.max_error_time,
                "excursion": o.excursion, "excursion_time": o.max_error_time if o.excursion > 0 else None,
                "rmse": o.rmse, "theil": o.theil, "frequency_cost": o.frequency_cost,
                "frequency_input": o.frequency_input}
        tests.append({"id": test.test.id, "recording": test.test.recording_path, "status": test.status,
                      "passed": test.status == PASSED, "reason": test.reason, "failure": test.failure(),
                      "seconds": test.seconds, "outputs": outputs})
    return {"title": result.spec.title, "spec": str(result.spec.path),
            "model": {"name": result.model_name, "kind": result.model_kind,
                      "instantiations": result.instantiations},
            "tolerance_source": TOLERANCE_SOURCE, "passed": result.count(PASSED), "failed": result.count(FAILED),
            "errors": result.count(ERROR), "not_run": result.count(NOT_RUN), "all_passed": result.passed,
            "seconds": result.seconds, "tests": tests}
