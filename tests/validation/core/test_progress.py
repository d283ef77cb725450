"""Progress output (validation/core/progress.py; docs/conventions.md, "Progress output"): away
from a terminal, plain lines without carriage returns, each with the count and its total, at a
modest rate; nothing after an error; nothing when disabled."""
import io
import re

import pytest

import validation.core.progress as progress
from validation.core.progress import progress_bar


def test_a_small_total_gets_a_line_per_count_with_its_total():
    stream = io.StringIO()
    with progress_bar("diagnose", total=3, unit="stage", stream=stream) as update:
        update(1)
        update(0, fit="locate")  # a status within a step: no line of its own
        update(1)
        update(1)
    assert "\r" not in stream.getvalue()
    assert _lines(stream) == ["diagnose: 1/3 stages, _ s", "diagnose: 2/3 stages, _ s (fit: locate)",
                              "diagnose: 3/3 stages, _ s (fit: locate)"]


def test_a_large_total_gets_a_line_per_tenth_and_one_at_the_end():
    stream = io.StringIO()
    with progress_bar("free run", total=95, unit="step", stream=stream) as update:
        for _ in range(95):
            update(1)
    lines = _lines(stream)
    assert len(lines) == 10 and lines[0] == "free run: 10/95 steps, _ s" and lines[-1] == "free run: 95/95 steps, _ s"


def test_without_a_total_the_lines_say_what_is_counted_every_interval(monkeypatch):
    stream = io.StringIO()
    with progress_bar("search", total=None, unit="candidate", stream=stream) as update:
        update(1)  # within the interval: no line yet
        monkeypatch.setattr(progress, "PLAIN_INTERVAL", 0.0)
        update(1)
        monkeypatch.setattr(progress, "PLAIN_INTERVAL", 10.0)
        update(1)
    assert _lines(stream) == ["search: 2 candidates, _ s", "search: 3 candidates, _ s"]


def test_no_line_after_an_error_and_none_when_disabled():
    stream = io.StringIO()
    with pytest.raises(ValueError), progress_bar("fit", total=1000, unit="fit", stream=stream) as update:
        update(1)
        raise ValueError("bad input")
    assert stream.getvalue() == ""
    with progress_bar("fit", total=1, unit="fit", enabled=False, stream=stream) as update:
        assert update is None
    assert stream.getvalue() == ""


def _lines(stream) -> list:
    """The lines written, elapsed seconds as ``_``."""
    return [re.sub(r", \d+ s", ", _ s", line) for line in stream.getvalue().splitlines()]
