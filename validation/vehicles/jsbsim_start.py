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
import math
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


def start_fdm(recipe: StartingRecipe, *, dt: float, output_dir: str | None = None,
              wind: tuple = (0.0, 0.0), shifts: tuple = ()):
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
    wind : (float, float)
        A steady horizontal wind, ft/s: the air's velocity toward the north and toward the east
        (JSBSim's ``atmosphere/wind-north-fps``, ``wind-east-fps``). It blows from before the
        starting condition is reached: it goes into JSBSim's initial conditions (``ic/vw-mag-fps``
        and ``ic/vw-dir-deg``, the direction the air moves toward), from which ``run_ic`` and every
        trim iteration start the atmosphere. ``"trim"``: the airspeed, heading and climb angle
        that the initial conditions set stay, the airspeed and climb angle relative to the air,
        and the ground velocity takes the wind (``ic/vn-fps``, ``ic/ve-fps``); JSBSim's full trim
        leaves the sideslip alone, so the aircraft trims as in still air (to the trim's
        tolerance), crabbing, and drifts with the air. ``"script"``: the script's initial ground
        velocity (at rest on the ground) stays, and the script flies in the wind.
    shifts : sequence of (str, float)
        JSBSim properties and amounts added to their values as the model or script loaded them,
        before the initial conditions, ``run_ic`` and the trim or script (e.g.
        ``("metrics/aero-rp-x-in", -3.9)``: the aerodynamic reference point 3.9 in forward).

    Returns
    -------
    jsbsim.FGFDMExec
        Debug level 0, output disabled, time step ``dt``, at the starting condition.

    Raises
    ------
    TrimFailure
        ``method == "trim"`` and JSBSim cannot trim the aircraft there.
    RuntimeError
        JSBSim's atmosphere does not hold ``wind`` once the initial conditions are run (a JSBSim
        whose initial conditions treat the wind otherwise than 1.3.3's).

    Notes
    -----
    With no wind and no shift nothing is set beyond the recipe, so the start is the recipe's
    bit for bit.
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
        _shift(fdm, shifts)
        _blow(fdm, wind, keep_airspeed=False)
        fdm.run_ic()
        _check_wind(fdm, wind)
        for _ in range(int(round(recipe.script_time / dt))):
            fdm.run()
    else:
        fdm.load_model(recipe.aircraft)
        fdm.disable_output()
        fdm.set_dt(dt)
        _shift(fdm, shifts)
        for name, value in recipe.initial_conditions:
            fdm[name] = value
        _blow(fdm, wind, keep_airspeed=True)
        fdm.run_ic()
        _check_wind(fdm, wind)
        fdm["propulsion/set-running"] = -1  # -1: all engines
        try:
            fdm.do_trim(1)  # 1 = tFull: all six accelerations to zero
        except jsbsim.TrimFailureError:
            conditions = ", ".join(f"{name} = {value:g}" for name, value in recipe.initial_conditions)
            changes = "".join(f", {name} {amount:+g}" for name, amount in shifts if amount)
            changes += f", wind {wind[0]:g} ft/s north, {wind[1]:g} ft/s east" if any(wind) else ""
            raise TrimFailure(f"JSBSim cannot trim {recipe.aircraft} at {conditions}{changes}") from None
    for name, value in recipe.after_start:
        fdm[name] = value
    return fdm


def _shift(fdm, shifts) -> None:
    """Add each amount of ``shifts`` to its property (zeros are not written)."""
    for name, amount in shifts:
        if amount:
            fdm[name] = fdm[name] + amount


def _blow(fdm, wind, *, keep_airspeed: bool) -> None:
    """Put the horizontal ``wind`` (ft/s north, east) into the initial conditions
    (:func:`start_fdm`); nothing when it is calm. JSBSim's wind setters keep the ground
    velocity, so to keep the airspeed the ground velocity is then moved by the wind."""
    north, east = (float(w) for w in wind)
    if not (north or east):
        return
    ground = (fdm["ic/vn-fps"] + north, fdm["ic/ve-fps"] + east)
    fdm["ic/vw-mag-fps"] = math.hypot(north, east)
    fdm["ic/vw-dir-deg"] = math.degrees(math.atan2(east, north))
    if keep_airspeed:
        fdm["ic/vn-fps"], fdm["ic/ve-fps"] = ground


def _check_wind(fdm, wind) -> None:
    """Raise RuntimeError unless JSBSim's atmosphere holds ``wind`` (ft/s north, east) after
    ``run_ic``; nothing is read when it is calm."""
    import jsbsim

    if not any(wind):
        return
    held = (fdm["atmosphere/wind-north-fps"], fdm["atmosphere/wind-east-fps"])
    if any(abs(h - w) > _WIND_ROUNDING * abs(complex(*wind)) for h, w in zip(held, wind)):
        raise RuntimeError(f"JSBSim {jsbsim.__version__} started the atmosphere with the wind {held[0]:g}, "
                           f"{held[1]:g} ft/s (north, east), not the {wind[0]:g}, {wind[1]:g} ft/s asked for")


#: Tolerance of :func:`_check_wind`, relative to the wind speed: the initial conditions store the
#: wind as a magnitude and a direction in degrees, a round trip that costs a few units in the last
#: place (about 1e-15); a wind taken the other way or not at all is off by the whole wind.
_WIND_ROUNDING = 1e-9


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
