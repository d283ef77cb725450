"""The Bo105 physics reference ``bo105-<V>kt``: Padfield's linear 6-DOF model at 0-140 kt.

States ``u, w, q, theta, v, p, phi, r`` (m/s, rad/s, rad; body axes, perturbations from trim)
and inputs ``theta_0, theta_1s, theta_1c, theta_0T`` (main collective, longitudinal cyclic,
lateral cyclic, tail-rotor collective; rad, perturbations from trim), as docs/vehicles.md names
them. Recordings start at trim (all zeros); the state recorded at ``time[k]`` is the state
before ``inputs[k]`` acts, and ``inputs[k]`` is held until ``time[k+1]`` (zero-order hold).

:class:`Bo105Reference` is ``x_dot = A x + B u`` with Padfield's tabulated derivatives
(G. D. Padfield, *Helicopter Flight Dynamics*, 2nd ed., 2007; the numbers and their provenance
are in ``validation/vehicles/data/bo105_padfield_linear.json``), discretised exactly. The
flight-test stand-in built on it is :mod:`validation.vehicles.bo105_flight`.
"""
from __future__ import annotations

import json
from functools import cache
from importlib.resources import files

from validation.core.errors import BadInputError
from validation.vehicles.state_space import LinearReference

STATE_NAMES = ("u", "w", "q", "theta", "v", "p", "phi", "r")
INPUT_NAMES = ("theta_0", "theta_1s", "theta_1c", "theta_0T")
#: Derivative row letters and the state-derivative row each names (Padfield 2007, ch. 4).
ROW_LETTERS = {"X": "u", "Z": "w", "M": "q", "Y": "v", "L": "p", "N": "r"}
#: Default recording interval, s (100 Hz).
SAMPLE_TIME = 0.01

#: Trim speeds, kt, at which Padfield tabulates the Bo105 linear models.
BO105_SPEEDS_KT = (0, 20, 40, 60, 80, 100, 120, 140)

# Bo105 facts (Padfield 2007, ch. 2 and appendix 4B; docs/vehicles.md).
MASS = 2200.0  # kg
I_XX, I_YY = 1433.0, 4973.0  # kg m^2
ROTOR_RADIUS = 4.91  # m
N_BLADES = 4
BLADE_CHORD = 0.27  # m
ROTOR_SPEED = 44.4  # rad/s
LIFT_SLOPE = 6.113  # 1/rad
LOCK_NUMBER = 5.09
AIR_DENSITY = 1.225  # kg/m^3, ISA sea level (assumed)
GRAVITY = 9.80665  # m/s^2
KNOT = 1852.0 / 3600.0  # m/s


@cache
def padfield_table() -> dict:
    """Padfield's tabulated models, parsed once."""
    return json.loads((files("validation.vehicles") / "data" / "bo105_padfield_linear.json").read_text())


def padfield_condition(speed_kt) -> dict:
    """The tabulated trim condition at ``speed_kt``; BadInputError naming the valid speeds."""
    for condition in padfield_table()["conditions"]:
        if condition["speed_kt"] == speed_kt:
            return condition
    raise BadInputError(f"no Bo105 model at {speed_kt} kt: Padfield tabulates "
                        f"{', '.join(map(str, BO105_SPEEDS_KT))} kt")


class Bo105Reference(LinearReference):
    """Padfield's linear 6-DOF Bo105 model at one trim speed (the ``bo105-<V>kt`` reference).

    ``x_dot = A x + B u`` with ``x = (u, w, q, theta, v, p, phi, r)`` and
    ``u = (theta_0, theta_1s, theta_1c, theta_0T)``, perturbations from trim in SI units
    (Padfield 2007; data file ``validation/vehicles/data/bo105_padfield_linear.json``): a
    :class:`~validation.vehicles.state_space.LinearReference`, discretised exactly with a
    zero-order hold, cached per sample interval.

    Derivatives are named by row letter (X, Z, M, Y, L, N for the u, w, q, v, p, r rows) and
    the state or input they multiply: ``M_q``, ``L_q``, ``M_theta_1s``, ``N_r``. Changing them
    gives a new reference (:meth:`with_derivatives`); an instance never changes.

    Parameters
    ----------
    speed_kt : int
        Trim speed, kt; one of 0, 20, 40, 60, 80, 100, 120, 140.

    Attributes
    ----------
    name : str
        ``"bo105-<V>kt"``.
    speed_kt : int
    input_names, state_names : tuple of str
    sample_time : float
        Default recording interval, 0.01 s.
    """

    def __init__(self, speed_kt: int):
        condition = padfield_condition(speed_kt)
        self.speed_kt = int(condition["speed_kt"])
        super().__init__(name=f"bo105-{self.speed_kt}kt", state_names=STATE_NAMES, input_names=INPUT_NAMES,
                         A=condition["A"], B=condition["B"], row_letters=ROW_LETTERS, sample_time=SAMPLE_TIME)

    def recording_metadata(self, step: float) -> dict:
        """The vehicle, trim speed, sample interval, Padfield's source and any changed derivatives."""
        metadata = {"vehicle": self.name, "speed_kt": self.speed_kt, "sample_time": step,
                    "source": padfield_table()["source"]}
        if self.changed_derivatives:
            metadata["changed_derivatives"] = self.changed_derivatives
        return metadata
