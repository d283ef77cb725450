"""The headline row of a benchmark: one measure, its goal and whether it is met, with a stable
id (docs/benchmarks.md, "Summary table")."""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class SummaryRow:
    """One headline measure of a benchmark against its goal: a row of the combined table and of
    ``build/bench.json``'s ``summary``.

    Attributes
    ----------
    id : str
        Stable identifier, dotted (``"gp.fit.speedup.n500"``): what scripts and CI key on; the
        ``measure`` text may change, the id does not.
    measure : str
        What is measured, in words.
    value : float
        The measured number, in ``unit`` (NaN when not measured).
    unit : str
        ``"x"`` (a ratio), ``"x real time"``, ``"s"``, ``"us"``.
    goal : float or None
        The goal in ``unit``; None: no goal (reported for information).
    at_least : bool
        Whether the goal is a lower bound (speed-ups) or an upper one (times).
    note : str
        Text after the value in the human table (e.g. the time beside a ratio).
    """

    id: str
    measure: str
    value: float
    unit: str
    goal: float | None
    at_least: bool = True
    note: str = ""

    @property
    def met(self) -> bool | None:
        """Whether ``value`` meets ``goal`` (None without a goal or a measured value)."""
        if self.goal is None or not math.isfinite(self.value):
            return None
        return self.value >= self.goal if self.at_least else self.value <= self.goal

    def as_dict(self) -> dict:
        """The row of ``build/bench.json``'s ``summary``."""
        return {"id": self.id, "measure": self.measure, "value": self.value, "unit": self.unit,
                "goal": self.goal, "goal_is": "at least" if self.at_least else "at most", "met": self.met}

    def text(self) -> tuple[str, str]:
        """The measured and the goal columns of the human table."""
        value = f"{self.value:.3g} {self.unit}" + (f", {self.note}" if self.note else "")
        goal = "-" if self.goal is None else f"{'>=' if self.at_least else '<='} {self.goal:g} {self.unit}"
        return value, goal
