"""JSBSim aircraft as flightgp vehicles (``jsbsim:<aircraft>``, docs/vehicles.md).

:class:`JSBSimVehicle` flies one of the aircraft that ship with the ``jsbsim`` package
(``jsbsim.get_default_root_dir()/aircraft``) from a steady starting condition:

- fixed-wing aircraft (e.g. ``c172x``): trimmed straight and level at
  :data:`CRUISE_AIRSPEED_KT` and :data:`CRUISE_ALTITUDE_FT`, heading east (so that ``psi``,
  which JSBSim keeps in [0, 2 pi), does not wrap around during a recording), engines running,
  with JSBSim's full trim (``do_trim(1)``). Inputs ``elevator``, ``aileron``, ``rudder``:
  ``fcs/{elevator,aileron,rudder}-cmd-norm``, normalised stick and pedal commands (full
  travel -1..1), recorded as perturbations from their trim values. Note for ``c172x``: its
  elevator actuator has a hysteresis of 0.05 rad (``c172x.xml``), so elevator commands below
  about 0.06 do not move the elevator at all, and after a manoeuvre the elevator may rest up to
  0.025 rad from trim, which starts a slow pitch excursion; use amplitudes of 0.1 to 0.2.
- the ``ah1s`` helicopter: JSBSim cannot trim it (``do_trim`` reports "wdot doesn't appear
  to be trimmable"), so its own flight-test script ``scripts/ah1s_flight_test.xml`` (JSBSim
  1.3.3) flies it from the ground (initialisation ``reset00``: KEDW, heading 180 deg) to an
  out-of-ground-effect hover at about 90 ft AGL with the RPM governor and the pitch, roll and
  yaw AFCS channels engaged. The script's hover phase runs from about 60 s to the fly-off
  event at 120 s; the recording starts at script time :data:`AH1S_HOVER_TIME_S`, where flightgp
  sets ``simulation/test-variant`` to 0 so that no later test event fires, and takes over the
  controls. Inputs ``collective``, ``longitudinal_cyclic``, ``lateral_cyclic``, ``pedal``:
  ``fcs/{collective,elevator,aileron,rudder}-cmd-norm``, normalised commands (collective 0..1,
  the others -1..1), recorded as perturbations from their hover values. The AFCS stays on, so
  the recorded response is that of the augmented helicopter. The hover is not perfectly steady:
  the AFCS holds attitude, not position, and the helicopter drifts backwards at about 0.8 m/s
  and sinks at about 0.4 m/s.

Recorded states (both kinds): body velocities ``u, v, w`` (m/s, from ``velocities/{u,v,w}-fps``
times 0.3048), body rates ``p, q, r`` (rad/s, ``velocities/{p,q,r}-rad_sec``) and Euler angles
``phi, theta, psi`` (rad, ``attitude/{phi,theta,psi}-rad``). States are absolute values, not
perturbations. JSBSim integrates with a fixed step equal to the sample time (default 0.01 s),
one step per sample; the input at ``time[k]`` is applied for the step from ``time[k]`` to
``time[k+1]``, and the states at ``time[k]`` are those before that step. JSBSim is
deterministic (no turbulence), so ``seed`` is accepted and ignored.

The starting condition is reached by :func:`validation.vehicles.jsbsim_start.start_fdm` from
the aircraft's :func:`starting_recipe`, the code and data the JSBSim aircraft FMU starts with
too. JSBSim's messages (banner, script notifications, trim reports), which its default logger
prints to standard output, go to the Python logger ``validation.vehicles.jsbsim`` instead, at
DEBUG level (JSBSim warnings and errors at INFO, so ``flightgp -v`` shows them), through JSBSim
1.3's ``jsbsim.set_logger`` (:func:`validation.vehicles.jsbsim_start.routed_messages`, only while
a simulation runs, then the previous logger is back).
"""
from __future__ import annotations

import difflib
import logging
import tempfile
from pathlib import Path

import jsbsim
import numpy as np

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.core.sampling import check_history
from validation.vehicles.jsbsim_start import (
    StartingRecipe,
    TrimFailure,
    message_buffer,
    routed_messages,
    start_fdm,
)

#: Level-flight trim condition of fixed-wing aircraft: calibrated airspeed, kt ...
CRUISE_AIRSPEED_KT = 100.0
#: ... and altitude above sea level, ft (a typical c172 cruise condition).
CRUISE_ALTITUDE_FT = 4000.0
#: Time into ``ah1s_flight_test.xml`` at which the AH-1S hovers and the recording starts, s.
AH1S_HOVER_TIME_S = 100.0

_FEET = 0.3048  # m per ft, exact
#: Control input name -> JSBSim command property, for fixed-wing aircraft and helicopters.
FIXED_WING_CONTROLS = {
    "elevator": "fcs/elevator-cmd-norm",
    "aileron": "fcs/aileron-cmd-norm",
    "rudder": "fcs/rudder-cmd-norm",
}
HELICOPTER_CONTROLS = {
    "collective": "fcs/collective-cmd-norm",
    "longitudinal_cyclic": "fcs/elevator-cmd-norm",
    "lateral_cyclic": "fcs/aileron-cmd-norm",
    "pedal": "fcs/rudder-cmd-norm",
}
#: Aircraft flown to hover by their own flight-test script instead of being trimmed:
#: script (relative to the JSBSim root) and the script time at which the recording starts, s.
HOVER_SCRIPTS = {"ah1s": ("scripts/ah1s_flight_test.xml", AH1S_HOVER_TIME_S)}
#: State name -> (JSBSim property, factor to SI).
STATE_PROPERTIES = {
    "u": ("velocities/u-fps", _FEET),
    "v": ("velocities/v-fps", _FEET),
    "w": ("velocities/w-fps", _FEET),
    "p": ("velocities/p-rad_sec", 1.0),
    "q": ("velocities/q-rad_sec", 1.0),
    "r": ("velocities/r-rad_sec", 1.0),
    "phi": ("attitude/phi-rad", 1.0),
    "theta": ("attitude/theta-rad", 1.0),
    "psi": ("attitude/psi-rad", 1.0),
}


def available_aircraft() -> list[str]:
    """Names of the aircraft that ship with the installed ``jsbsim`` package, sorted."""
    aircraft = Path(_root_dir()) / "aircraft"
    return sorted(entry.name for entry in aircraft.iterdir() if (entry / f"{entry.name}.xml").is_file())


class JSBSimVehicle:
    """A JSBSim aircraft as a flightgp vehicle (see the module docstring for the conditions).

    Parameters
    ----------
    aircraft : str
        Folder name under ``jsbsim.get_default_root_dir()/aircraft``, e.g. ``"c172x"``, ``"ah1s"``.

    Raises
    ------
    BadInputError
        If JSBSim has no such aircraft (the message lists similar or example names).

    Attributes
    ----------
    recipe : validation.vehicles.jsbsim_start.StartingRecipe
        How JSBSim reaches the steady starting condition (:func:`starting_recipe`).
    control_properties : dict of str -> str
        Input name -> JSBSim command property (:data:`FIXED_WING_CONTROLS` or
        :data:`HELICOPTER_CONTROLS`).
    """

    sample_time = 0.01
    state_names = tuple(STATE_PROPERTIES)

    def __init__(self, aircraft: str):
        available = available_aircraft()
        if aircraft not in available:
            close = difflib.get_close_matches(aircraft, available, n=5, cutoff=0.5)
            examples = close or [name for name in ("c172x", "ah1s", "c172p", "pa28", "f16") if name in available]
            raise BadInputError(
                f"JSBSim has no aircraft {aircraft!r}; try {', '.join(f'jsbsim:{name}' for name in examples)} "
                f"({len(available)} aircraft in {Path(_root_dir()) / 'aircraft'})"
            )
        self.aircraft = aircraft
        self.name = f"jsbsim:{aircraft}"
        self.recipe = starting_recipe(aircraft)
        self.control_properties = HELICOPTER_CONTROLS if aircraft in HOVER_SCRIPTS else FIXED_WING_CONTROLS
        self.input_names = tuple(self.control_properties)

    def simulate(self, time: np.ndarray, inputs: np.ndarray, *, seed: int = 0) -> Recording:
        """Fly the input perturbations ``inputs`` from the steady starting condition.

        Parameters
        ----------
        time : ndarray, shape (n,)
            Sample times, s, evenly spaced (``t0 + k*h``); ``h`` becomes JSBSim's time step.
        inputs : ndarray, shape (n, n_inputs)
            Control perturbations from trim (normalised commands, columns as ``input_names``),
            held constant over each sample interval.
        seed : int
            Ignored: JSBSim is deterministic here.

        Returns
        -------
        Recording
            All of ``state_names`` as outputs; metadata holds the vehicle name, sample time,
            seed, the trim value of every control and the starting condition.

        Raises
        ------
        BadInputError
            Bad ``time`` or ``inputs``; a fixed-wing aircraft that JSBSim cannot trim; a
            simulation whose states stop being finite.
        """
        time, inputs, step = check_history(time, inputs, self.input_names)
        # Aircraft files may ask for CSV output files (c172x: JSBout172B.csv, in the current folder
        # by default); they go to a scratch folder that is deleted afterwards.
        with (routed_messages(message_buffer(_to_python_log)),
              tempfile.TemporaryDirectory(prefix="flightgp-jsbsim-") as scratch):
            states, trim, condition = self._fly(step, inputs, output_dir=scratch)
        diverged = np.flatnonzero(~np.all(np.isfinite(states), axis=1))
        if len(diverged):
            raise BadInputError(
                f"{self.name}: the JSBSim states stop being finite at t = {time[diverged[0]]:g} s; "
                "try smaller inputs"
            )
        return Recording(
            time=time, inputs=inputs, input_names=self.input_names,
            outputs=states, output_names=self.state_names,
            metadata={
                "vehicle": self.name,
                "sample_time": step,
                "seed": seed,
                "trim": {name: float(value) for name, value in zip(self.input_names, trim)},
                "initial_condition": condition,
            },
        )

    def _fly(self, step: float, inputs: np.ndarray, *, output_dir: str) -> tuple[np.ndarray, np.ndarray, dict]:
        """States, shape (n, n_states), control trim values, shape (n_inputs,), start condition."""
        fdm = self._start(step, output_dir=output_dir)
        properties = list(self.control_properties.values())
        trim = np.array([fdm[name] for name in properties])
        condition = {
            "airspeed_kt": fdm["velocities/vc-kts"],
            "altitude_ft": fdm["position/h-sl-ft"],
            "altitude_agl_ft": fdm["position/h-agl-ft"],
        }
        states = np.empty((len(inputs), len(STATE_PROPERTIES)))
        for k, perturbation in enumerate(inputs):
            states[k] = [fdm[name] * factor for name, factor in STATE_PROPERTIES.values()]
            for name, value in zip(properties, trim + perturbation):
                fdm[name] = value
            fdm.run()
        return states, trim, condition

    def _start(self, step: float, *, output_dir: str):
        """A JSBSim instance at the steady starting condition, time step ``step`` s, whose
        output files (if the aircraft or script asks for any) go to ``output_dir``."""
        try:
            return start_fdm(self.recipe, dt=step, output_dir=output_dir)
        except TrimFailure:
            raise BadInputError(
                f"JSBSim cannot trim {self.name} in level flight at {CRUISE_AIRSPEED_KT:g} kt, "
                f"{CRUISE_ALTITUDE_FT:g} ft; flightgp supports fixed-wing aircraft that cruise "
                "there (e.g. jsbsim:c172x) and the hovering jsbsim:ah1s"
            ) from None


def starting_recipe(aircraft: str) -> StartingRecipe:
    """The recipe of ``aircraft``'s steady starting condition (module docstring): a helicopter
    of :data:`HOVER_SCRIPTS` flown by its script to the hover, where ``simulation/test-variant``
    is set to 0 (no later test event fires); any other aircraft trimmed in level flight at
    :data:`CRUISE_AIRSPEED_KT` and :data:`CRUISE_ALTITUDE_FT`, heading east."""
    if aircraft in HOVER_SCRIPTS:
        script, hover_time = HOVER_SCRIPTS[aircraft]
        return StartingRecipe(aircraft=aircraft, method="script", script=script, script_time=hover_time,
                              after_start=(("simulation/test-variant", 0.0),))
    return StartingRecipe(aircraft=aircraft, method="trim", initial_conditions=(
        ("ic/h-sl-ft", CRUISE_ALTITUDE_FT), ("ic/vc-kts", CRUISE_AIRSPEED_KT), ("ic/gamma-deg", 0.0),
        ("ic/psi-true-deg", 90.0)))


def _root_dir() -> str:
    return jsbsim.get_default_root_dir()


_LOG = logging.getLogger(__name__)


def _to_python_log(text: str, *, important: bool) -> None:
    """One JSBSim message to :data:`_LOG`: warnings and errors at INFO, the rest at DEBUG."""
    _LOG.log(logging.INFO if important else logging.DEBUG, "JSBSim: %s", text)
