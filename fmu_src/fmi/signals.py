"""FMU variables of recorded signals (build time): each signal's unit and largest plausible
magnitude come from the recording conventions (docs/conventions.md, "Units and axes"), its
description from :data:`SIGNAL_PHRASES`."""
from __future__ import annotations

from fmu_src.fmi.slave import UNITS
from validation.core.errors import BadInputError
from validation.core.recordings import column_limit, column_unit

#: What the known signals are, for variable descriptions (Padfield's Bo105 names and the JSBSim
#: commands of validation.vehicles.jsbsim).
SIGNAL_PHRASES = {
    "theta_0": "main rotor collective pitch", "theta_1s": "longitudinal cyclic pitch",
    "theta_1c": "lateral cyclic pitch", "theta_0T": "tail rotor collective pitch",
    "p": "roll rate", "q": "pitch rate", "r": "yaw rate",
    "phi": "roll angle", "theta": "pitch angle", "psi": "heading",
    "u": "forward velocity", "v": "lateral velocity", "w": "vertical velocity (positive down)",
    "elevator": "elevator (pitch stick) command", "aileron": "aileron (roll stick) command",
    "rudder": "rudder pedal command", "collective": "collective lever command",
    "longitudinal_cyclic": "longitudinal cyclic stick command",
    "lateral_cyclic": "lateral cyclic stick command", "pedal": "tail rotor pedal command",
}


def signal(name: str, kind: str) -> tuple:
    """``(name, unit, limit, phrase)`` of a recorded signal as an FMU variable.

    Parameters
    ----------
    name : str
        Recording column name.
    kind : str
        What the signal is to the model (``"input"``, ``"output"``, ``"state"``), for messages
        and for the phrase of a signal not in :data:`SIGNAL_PHRASES`.

    Returns
    -------
    tuple
        The name; its unit, a key of :data:`fmu_src.fmi.slave.UNITS`; its largest plausible
        magnitude (None: unbounded); a phrase saying what it is.

    Raises
    ------
    validation.core.errors.BadInputError
        The signal has no unit an FMU variable can carry.
    """
    unit = column_unit(name)
    if unit not in UNITS:
        raise BadInputError(f"the model's {kind} {name!r} has no known SI unit (got {unit!r}); an "
                            f"FMU variable needs one of {', '.join(UNITS)}")
    return (name, unit, column_limit(name), SIGNAL_PHRASES.get(name, f"{kind} {name}"))
