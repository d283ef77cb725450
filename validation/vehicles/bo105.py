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
import math
from functools import cache
from importlib.resources import files

import numpy as np

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.core.sampling import check_history
from validation.vehicles.linear_discretisation import zero_order_hold

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
_STATE = {name: i for i, name in enumerate(STATE_NAMES)}
_INPUT = {name: i for i, name in enumerate(INPUT_NAMES)}


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


def cached_zero_order_hold(cache: dict, A: np.ndarray, B: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~validation.vehicles.linear_discretisation.zero_order_hold` at ``step`` rounded to
    1e-12 s, kept in ``cache`` (one dict per system, so a vehicle discretises once per sample
    interval)."""
    key = round(step, 12)
    if key not in cache:
        cache[key] = zero_order_hold(A, B, key)
    return cache[key]


def propagate(transition: np.ndarray, forcing: np.ndarray, state: np.ndarray, *,
               every: int = 1) -> np.ndarray:
    """``x[j+1] = transition @ x[j] + forcing[j]`` from ``x[0] = state``; every ``every``-th ``x``.

    Returns shape (len(forcing) // every + 1, len(state)): ``x[0], x[every], ..., x[len(forcing)]``.
    """
    states = np.empty((len(forcing) // every + 1, len(state)))
    for j, push in enumerate(forcing):
        if j % every == 0:
            states[j // every] = state
        state = transition @ state + push
    states[-1] = state
    return states


class Bo105Reference:
    """Padfield's linear 6-DOF Bo105 model at one trim speed (the ``bo105-<V>kt`` reference).

    ``x_dot = A x + B u`` with ``x = (u, w, q, theta, v, p, phi, r)`` and
    ``u = (theta_0, theta_1s, theta_1c, theta_0T)``, perturbations from trim in SI units
    (Padfield 2007; data file ``validation/data/bo105_padfield_linear.json``). The model is
    discretised exactly with a zero-order hold, cached per sample interval.

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

    input_names = INPUT_NAMES
    state_names = STATE_NAMES
    sample_time = SAMPLE_TIME

    def __init__(self, speed_kt: int):
        condition = padfield_condition(speed_kt)
        self.speed_kt = int(condition["speed_kt"])
        self.name = f"bo105-{self.speed_kt}kt"
        self._A = np.array(condition["A"], dtype=float)
        self._B = np.array(condition["B"], dtype=float)
        self._changed: dict[str, float] = {}
        self._discretisations: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    @classmethod
    def _from_matrices(cls, speed_kt: int, A: np.ndarray, B: np.ndarray,
                       changed: dict[str, float]) -> Bo105Reference:
        """The reference at ``speed_kt`` with state matrix ``A`` (8, 8), 1/s, and control matrix
        ``B`` (8, 4), state units per rad per s, in place of Padfield's; ``changed`` (derivative
        name -> value) names what differs from the table, for the recordings' metadata."""
        reference = cls(speed_kt)
        reference._A, reference._B, reference._changed = A, B, changed
        return reference

    @property
    def A(self) -> np.ndarray:
        """State matrix, shape (8, 8), 1/s (a copy)."""
        return self._A.copy()

    @property
    def B(self) -> np.ndarray:
        """Control matrix, shape (8, 4), state units per rad per s (a copy)."""
        return self._B.copy()

    def eigenvalues(self) -> np.ndarray:
        """Eigenvalues of ``A``, shape (8,), 1/s, sorted by real part then imaginary part."""
        return np.sort_complex(np.linalg.eigvals(self._A))

    @staticmethod
    def derivative_names() -> list[str]:
        """All derivative names: 6 rows x (8 states + 4 inputs), e.g. ``"X_u"``, ``"N_theta_0T"``."""
        return [f"{letter}_{column}" for letter in ROW_LETTERS for column in STATE_NAMES + INPUT_NAMES]

    def _locate(self, name: str) -> tuple[str, int, int]:
        """(``"A"`` or ``"B"``, row, column) of derivative ``name``."""
        letter, _, column = name.partition("_")
        if letter in ROW_LETTERS and (column in _STATE or column in _INPUT):
            row = _STATE[ROW_LETTERS[letter]]
            return ("A", row, _STATE[column]) if column in _STATE else ("B", row, _INPUT[column])
        raise BadInputError(
            f"unknown derivative {name!r}: a name is a row letter ({', '.join(ROW_LETTERS)}) + '_' + a "
            f"state ({', '.join(STATE_NAMES)}) or input ({', '.join(INPUT_NAMES)}), e.g. M_q, L_theta_1c")

    def derivative(self, name: str) -> float:
        """The value of derivative ``name`` (e.g. ``"M_q"``, 1/s), as divided by mass or inertia."""
        matrix, row, column = self._locate(name)
        return float((self._A if matrix == "A" else self._B)[row, column])

    def with_derivatives(self, values: dict[str, float]) -> Bo105Reference:
        """A new reference with the derivatives in ``values`` (name -> value) replaced.

        Raises
        ------
        BadInputError
            For an unknown name (the message lists the valid ones) or a non-finite value.
        """
        A, B, changed = self._A.copy(), self._B.copy(), dict(self._changed)
        for name, value in values.items():
            matrix, row, column = self._locate(name)
            try:
                number = float(value)
            except (TypeError, ValueError):
                number = math.nan
            if not math.isfinite(number):
                raise BadInputError(f"derivative {name} must be a finite number, got {value!r}")
            (A if matrix == "A" else B)[row, column] = number
            changed[name] = number
        return self._from_matrices(self.speed_kt, A, B, changed)

    def discretisation(self, step: float) -> tuple[np.ndarray, np.ndarray]:
        """Exact ZOH ``(Phi, Gamma)`` at ``step`` s, shapes (8, 8) and (8, 4); cached."""
        return cached_zero_order_hold(self._discretisations, self._A, self._B, step)

    def simulate_states(self, time, inputs, *, initial_state=None) -> np.ndarray:
        """State history from ``initial_state`` under ``inputs`` held over each interval.

        Parameters
        ----------
        time : array_like, shape (n,)
            Evenly spaced sample times, s (``t0 + k*h``), n >= 2.
        inputs : array_like, shape (n, 4)
            ``theta_0, theta_1s, theta_1c, theta_0T``, rad; row k is held from ``time[k]`` to
            ``time[k+1]`` (the last row does not act).
        initial_state : array_like, shape (8,), optional
            State at ``time[0]``; trim (zeros) by default.

        Returns
        -------
        ndarray, shape (n, 8)
            ``u, w, q, theta, v, p, phi, r`` at each sample time.
        """
        time, inputs, step = check_history(time, inputs, INPUT_NAMES)
        state = np.zeros(len(STATE_NAMES))
        if initial_state is not None:
            state = np.asarray(initial_state, dtype=float)
            if state.shape != (len(STATE_NAMES),) or not np.all(np.isfinite(state)):
                raise BadInputError(f"initial_state must be 8 finite numbers ({', '.join(STATE_NAMES)}), "
                                    f"got shape {state.shape}")
        Ad, Bd = self.discretisation(step)
        return propagate(Ad, inputs[:-1] @ Bd.T, state)

    def simulate(self, time, inputs, *, seed: int = 0) -> Recording:
        """Fly ``inputs`` from trim and record all 8 states (see :meth:`simulate_states`).

        ``seed`` is accepted for the Vehicle interface; the reference is deterministic.
        """
        time, inputs, step = check_history(time, inputs, INPUT_NAMES)
        metadata = {"vehicle": self.name, "speed_kt": self.speed_kt, "sample_time": step,
                    "source": padfield_table()["source"]}
        if self._changed:
            metadata["changed_derivatives"] = dict(self._changed)
        return Recording(time, inputs, INPUT_NAMES, self.simulate_states(time, inputs),
                         STATE_NAMES, metadata)
