"""Reaching a JSBSim aircraft's steady starting condition, and routing JSBSim's messages: the
standard library and jsbsim only.

:class:`validation.vehicles.jsbsim.JSBSimVehicle` starts every recording with :func:`start_fdm`,
and the JSBSim aircraft FMU carries a copy of this file (docs/fmus.md, "JSBSim aircraft") and
starts with the same function from the same :class:`StartingRecipe`, stored in its model file
(:meth:`StartingRecipe.to_json`): so the FMU flies ``JSBSimVehicle.simulate`` bit for bit. The
recipes themselves (which aircraft is trimmed where, which one flies its own script) are
:func:`validation.vehicles.jsbsim.starting_recipe`'s.

``jsbsim`` is imported by the functions that need it, not by this module, so that an FMU host
without it gets a logged Error naming the package instead of a failed instantiation.

JSBSim 1.3 hands its messages (banner, script notifications, trim reports) to a
``jsbsim.FGLogger``, which by default prints them on standard output. :func:`message_buffer`
collects the pieces JSBSim sends for one message and hands the whole message to a callable (the
Python logger of the vehicle, the FMI logger of the FMU), and :func:`routed_messages` installs
such a logger for the duration of a block (JSBSim's logger is per thread).
"""
from __future__ import annotations

import contextlib
import functools
import json
from dataclasses import asdict, dataclass

#: How a recipe reaches the starting condition: trimmed by JSBSim, or flown by a script.
METHODS = ("trim", "script")


class TrimFailure(RuntimeError):
    """JSBSim cannot trim the aircraft at the recipe's initial conditions."""


@dataclass(frozen=True)
class StartingRecipe:
    """How JSBSim reaches an aircraft's steady starting condition (plain data).

    Attributes
    ----------
    aircraft : str
        Folder under ``jsbsim.get_default_root_dir()/aircraft``, e.g. ``"c172x"``.
    method : {"trim", "script"}
        ``"trim"``: ``load_model``, the ``initial_conditions``, ``run_ic``, every engine running,
        then JSBSim's full trim ``do_trim(1)`` (all six accelerations to zero). ``"script"``:
        ``load_script(script)``, ``run_ic``, then the script run to ``script_time``.
    initial_conditions : tuple of (str, float)
        ``"trim"``: JSBSim properties (``ic/...``) and their values, set in this order before
        ``run_ic``.
    script : str
        ``"script"``: the script, relative to the JSBSim root (e.g.
        ``"scripts/ah1s_flight_test.xml"``).
    script_time : float
        ``"script"``: script time at which the starting condition is reached, s.
    after_start : tuple of (str, float)
        Properties set once the starting condition is reached (e.g.
        ``("simulation/test-variant", 0.0)``: no later script event fires).
    """

    aircraft: str
    method: str
    initial_conditions: tuple = ()
    script: str = ""
    script_time: float = 0.0
    after_start: tuple = ()

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        pairs = lambda rows: tuple((str(name), float(value)) for name, value in rows)  # noqa: E731
        object.__setattr__(self, "initial_conditions", pairs(self.initial_conditions))
        object.__setattr__(self, "after_start", pairs(self.after_start))
        object.__setattr__(self, "script_time", float(self.script_time))

    def to_json(self) -> str:
        """The recipe as JSON (floats written exactly: JSON numbers round-trip a double)."""
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> StartingRecipe:
        """Inverse of :meth:`to_json`."""
        return cls(**json.loads(text))


def start_fdm(recipe: StartingRecipe, *, dt: float, output_dir: str | None = None):
    """A JSBSim instance at the steady starting condition of ``recipe``.

    Parameters
    ----------
    recipe : StartingRecipe
    dt : float
        JSBSim's integration step, s (overrides a script's own step).
    output_dir : str, optional
        Where output files that the aircraft or script asks for would go (JSBSim's default: the
        current folder). Output is disabled once the model or script is loaded, so none is
        written; the folder guards against one that is enabled later.

    Returns
    -------
    jsbsim.FGFDMExec
        Debug level 0, output disabled, time step ``dt``, at the starting condition.

    Raises
    ------
    TrimFailure
        ``method == "trim"`` and JSBSim cannot trim the aircraft there.
    """
    import jsbsim

    fdm = jsbsim.FGFDMExec(jsbsim.get_default_root_dir())
    fdm.set_debug_level(0)
    if output_dir is not None:
        fdm.set_output_path(output_dir)
    if recipe.method == "script":
        fdm.load_script(recipe.script)
        fdm.disable_output()
        fdm.set_dt(dt)
        fdm.run_ic()
        for _ in range(int(round(recipe.script_time / dt))):
            fdm.run()
    else:
        fdm.load_model(recipe.aircraft)
        fdm.disable_output()
        fdm.set_dt(dt)
        for name, value in recipe.initial_conditions:
            fdm[name] = value
        fdm.run_ic()
        fdm["propulsion/set-running"] = -1  # -1: all engines
        try:
            fdm.do_trim(1)  # 1 = tFull: all six accelerations to zero
        except jsbsim.TrimFailureError:
            conditions = ", ".join(f"{name} = {value:g}" for name, value in recipe.initial_conditions)
            raise TrimFailure(f"JSBSim cannot trim {recipe.aircraft} at {conditions}") from None
    for name, value in recipe.after_start:
        fdm[name] = value
    return fdm


def message_buffer(deliver):
    """A ``jsbsim.FGLogger`` that hands each whole JSBSim message to ``deliver``.

    Parameters
    ----------
    deliver : callable
        ``deliver(text, important=...)``: ``text`` the message without surrounding whitespace
        (empty messages are dropped), ``important`` True for JSBSim's warnings, errors and fatal
        errors (``jsbsim.LogLevel`` WARN to FATAL), False for the rest (banner, notices, console
        output).
    """
    return _message_buffer_class()(deliver)


@functools.lru_cache(maxsize=1)
def _message_buffer_class() -> type:
    import jsbsim

    class MessageBuffer(jsbsim.FGLogger):
        """JSBSim builds one message from several pieces between ``set_level`` and ``flush``."""

        def __init__(self, deliver) -> None:
            super().__init__()
            self._deliver = deliver
            self._important = False
            self._parts: list[str] = []

        def set_level(self, level) -> None:
            self._important = jsbsim.LogLevel.WARN <= level <= jsbsim.LogLevel.FATAL
            self._parts = []

        def message(self, message: str) -> None:
            self._parts.append(message)

        def flush(self) -> None:
            text = "".join(self._parts).strip()
            self._parts = []
            if text:
                self._deliver(text, important=self._important)

    return MessageBuffer


@contextlib.contextmanager
def routed_messages(logger):
    """Install the ``jsbsim.FGLogger`` ``logger`` (e.g. :func:`message_buffer`'s) for the
    duration, then the previous one again (JSBSim's logger is per thread)."""
    import jsbsim

    previous = jsbsim.get_logger()
    jsbsim.set_logger(logger)
    try:
        yield
    finally:
        jsbsim.set_logger(previous)
