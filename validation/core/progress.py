"""Progress of long work on stderr, handed to :mod:`gp_model` as callbacks so the maths stays
free of user-interface imports (docs/conventions.md, "Progress output").

On a terminal, a tqdm bar redrawn in place and erased at the end. Anywhere else (a log file, a
pipe, a CI job), plain lines without carriage returns: one each time the count passes a tenth of
the total (every count of a total of ten or less, e.g. each stage of ``diagnose``), one at least
every :data:`PLAIN_INTERVAL` seconds while updates come, and one when the work ends, each with
the count, its total and the elapsed time, e.g. ``diagnose: 3/7 stages, 4 s (fit: 2 of 3)``.
"""
from __future__ import annotations

import sys
import time
from contextlib import contextmanager

#: The longest a plain progress line waits while updates come, s.
PLAIN_INTERVAL = 10.0
#: Plain progress lines per total (one each time the count passes this fraction of it).
PLAIN_STEPS = 10


@contextmanager
def progress_bar(description: str, *, total: int | None, unit: str, enabled: bool = True, stream=None):
    """Show the progress of a piece of work (module docstring).

    Parameters
    ----------
    description : str
        What the work is (``"diagnose"``).
    total : int or None
        How many ``unit`` s the work counts. None only where it cannot be known beforehand: the
        count then stands alone, with ``unit`` saying what is counted.
    unit : str
        What is counted, singular (``"stage"``, ``"GP"``).
    enabled : bool, default True
        False shows nothing (and yields None).
    stream : text file, optional
        Where to write; default ``sys.stderr`` as it is on entry. A terminal gets a tqdm bar,
        anything else plain lines.

    Yields
    ------
    callable or None
        ``update(n, **status)``: advances the count by ``n`` and shows ``status`` (at once on a
        terminal when ``n`` is 0: a status within a step).
    """
    if not enabled:
        yield None
        return
    stream = sys.stderr if stream is None else stream
    if _is_terminal(stream):
        from tqdm.auto import tqdm

        bar = tqdm(total=total, desc=description, unit=unit, leave=False, file=stream)

        def update(n: int, **status) -> None:
            bar.update(n)
            if status:
                bar.set_postfix(status, refresh=n == 0)

        try:
            yield update
        finally:
            bar.close()
        return
    lines = _PlainLines(description, total=total, unit=unit, stream=stream)
    yield lines.update
    lines.finish()  # not after an error: its one line is what the reader needs


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or closed
        return False


class _PlainLines:
    """The plain progress lines of :func:`progress_bar` (module docstring)."""

    def __init__(self, description: str, *, total: int | None, unit: str, stream) -> None:
        self.description, self.total, self.unit, self.stream = description, total, unit, stream
        self.count = self.written = 0
        self.status: dict = {}
        self.started = self.last_line = time.monotonic()

    def update(self, n: int, **status) -> None:
        self.count += n
        if status:
            self.status = status
        now = time.monotonic()
        if self._passed_a_step() or now - self.last_line >= PLAIN_INTERVAL:
            self._write(now)

    def finish(self) -> None:
        if self.count != self.written:
            self._write(time.monotonic())

    def _passed_a_step(self) -> bool:
        if not self.total:
            return False
        return self.count * PLAIN_STEPS // self.total > self.written * PLAIN_STEPS // self.total

    def _write(self, now: float) -> None:
        counted = f"{self.count}/{self.total}" if self.total is not None else f"{self.count}"
        plural = "" if (self.total if self.total is not None else self.count) == 1 else "s"
        status = ", ".join(f"{key}: {value}" for key, value in self.status.items())
        self.stream.write(f"{self.description}: {counted} {self.unit}{plural}, {now - self.started:.0f} s"
                          + (f" ({status})" if status else "") + "\n")
        self.stream.flush()
        self.written, self.last_line = self.count, now
