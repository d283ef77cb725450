"""validation.bench.summary: the benchmark registry and the combined table of headline rows."""
import inspect

import pytest

from validation.bench.rows import SummaryRow
from validation.bench.summary import BENCHMARKS, format_summary


@pytest.mark.parametrize("name", sorted(BENCHMARKS))
def test_every_option_a_benchmark_takes_is_a_keyword_of_its_run(name):
    parameters = inspect.signature(BENCHMARKS[name].run).parameters
    assert "progress" in parameters
    assert set(BENCHMARKS[name].options.values()) <= set(parameters)


def test_the_combined_table_has_one_line_per_headline_row_and_says_whether_each_goal_is_met():
    # Reports cut down to what the headline rows read.
    reports = {"gp": {"rows": [{"n": 500, "fit_speedup": 7.0}, {"n": 2000, "fit_speedup": 2.0}]},
               "narx": {"runs": 10, "steps": 20, "speedup": 12.0, "vectorised_s": 0.5, "goal_speedup": 50.0,
                        "goal_seconds": 1.0, "goal_met": None}}
    lines = format_summary(reports).splitlines()
    assert lines[0].split() == ["id", "measure", "measured", "goal", "met"]
    assert [line.split()[-1] for line in lines[1:]] == ["yes", "no", "-", "-"]
    assert [line.split()[0] for line in lines[1:]] == ["gp.fit.speedup.n500", "gp.fit.speedup.n2000",
                                                       "narx.montecarlo.seconds", "narx.montecarlo.speedup"]
    assert "GP fit vs scikit-learn, n = 500" in lines[1] and "7 x" in lines[1] and ">= 6 x" in lines[1]


def test_a_summary_row_says_whether_its_goal_is_met_either_way():
    assert SummaryRow("a", "a time", 0.9, "s", 1.0, at_least=False).met is True
    assert SummaryRow("a", "a time", 1.1, "s", 1.0, at_least=False).met is False
    assert SummaryRow("b", "a speed-up", 6.0, "x", 6.0).met is True
    assert SummaryRow("b", "a speed-up", float("nan"), "x", 6.0).met is None
    assert SummaryRow("c", "no goal", 3.0, "x", None).as_dict() == {
        "id": "c", "measure": "no goal", "value": 3.0, "unit": "x", "goal": None, "goal_is": "at least", "met": None}
