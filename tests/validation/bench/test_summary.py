"""validation.bench.summary: the benchmark registry and the combined table of headline rows."""
import inspect

import pytest

from validation.bench.summary import BENCHMARKS, format_summary


@pytest.mark.parametrize("name", sorted(BENCHMARKS))
def test_every_option_a_benchmark_takes_is_a_keyword_of_its_run(name):
    parameters = inspect.signature(BENCHMARKS[name].run).parameters
    assert "progress" in parameters
    assert set(BENCHMARKS[name].options.values()) <= set(parameters)


def test_the_combined_table_has_one_line_per_headline_row_and_says_whether_each_goal_is_met():
    # Reports cut down to what the headline rows read.
    reports = {"gp": {"rows": [{"n": 30, "fit_speedup": 4.0}, {"n": 60, "fit_speedup": 2.0}]},
               "narx": {"speedup": 12.0, "vectorised_s": 0.5, "goal_speedup": 10.0, "goal_seconds": 5.0,
                        "goal_met": None}}
    lines = format_summary(reports).splitlines()
    assert lines[0].split() == ["measure", "measured", "goal", "met"]
    assert [line.split()[-1] for line in lines[1:]] == ["yes", "no", "-"]
    assert lines[1].startswith("GP fit vs scikit-learn, n = 30")
    assert lines[3].startswith("Monte Carlo free run vs run-by-run loop")
