"""FMU variables of recorded signals (build time): each signal's unit, largest plausible
magnitude and phrase come from the recording conventions (docs/conventions.md, "Units and axes";
:func:`validation.core.recordings.column_unit`, ``column_limit`` and ``column_phrase``)."""
from __future__ import annotations

from dataclasses import dataclass

from fmu_src.fmi.slave import UNITS
from validation.core.errors import BadInputError
from validation.core.recordings import column_limit, column_phrase, column_unit


@dataclass(frozen=True)
class Signal:
    """A recorded signal as an FMU variable.

    Attributes
    ----------
    name : str
        Recording column name.
    unit : str
        A key of :data:`fmu_src.fmi.slave.UNITS`.
    limit : float or None
        Largest plausible magnitude in ``unit`` (None: unbounded).
    phrase : str
        What the signal is, for variable descriptions (e.g. ``"pitch rate"``).
    """

    name: str
    unit: str
    limit: float | None
    phrase: str

    def row(self) -> tuple:
        """``(name, unit, limit, phrase)``: the row the variable-table functions take (plain
        data, which the build writes into the generated slave script by ``repr``)."""
        return (self.name, self.unit, self.limit, self.phrase)


def signal(name: str, kind: str) -> Signal:
    """A recorded signal as an FMU variable.

    Parameters
    ----------
    name : str
        Recording column name.
    kind : str
        What the signal is to the model (``"input"``, ``"output"``, ``"state"``), for messages.

    Returns
    -------
    Signal

    Raises
    ------
    validation.core.errors.BadInputError
        The signal has no unit an FMU variable can carry.
    """
    unit = column_unit(name)
    if unit not in UNITS:
        raise BadInputError(f"the model's {kind} {name!r} has no known SI unit (got {unit!r}); an "
                            f"FMU variable needs one of {', '.join(UNITS)}")
    return Signal(name=name, unit=unit, limit=column_limit(name), phrase=column_phrase(name))
