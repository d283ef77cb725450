"""The Bo105 physics reference FMU: Padfield's linear 6-DOF model at one trim speed.

``x_dot = A x + B u`` with ``x = (u, w, q, theta, v, p, phi, r)`` and
``u = (theta_0, theta_1s, theta_1c, theta_0T)``, perturbations from trim in SI units
(G. D. Padfield, *Helicopter Flight Dynamics*, 2nd ed., 2007; DESIGN.md, "Vehicles and reference
names"), exactly as :class:`validation.vehicles.bo105.Bo105Reference`. ``A`` and ``B`` travel in the FMU
(``resources/<package>/model.npz``, written by :func:`pack_model`); the run time needs numpy
only.

This file is copied into every Bo105 reference FMU (``resources/<package>/bo105_reference.py``),
so it imports only :mod:`._base`, numpy and the standard library.

Timing (the sampling convention of :mod:`._base`)
--------------------------------------------------
The host chooses the communication step ``h`` (any positive step; 0.01 s in the default
experiment); the first ``fmi2DoStep`` fixes it until reset, and a different step later is
refused (logged Error, ``fmi2Discard``). The model is discretised exactly for ``h`` with a
zero-order hold on the inputs (Van Loan, IEEE TAC 23(3), 1978, as ``Bo105Reference``):

    x(t_{k+1}) = Phi x(t_k) + Gamma u(t_k),   [[Phi, Gamma], [0, I]] = expm([[A, B], [0, 0]] h)

so the inputs set at ``t_k`` are held over ``[t_k, t_{k+1})`` and ``fmi2DoStep(t_k, h)`` sets the
outputs to ``x(t_{k+1})``: ``Bo105Reference.simulate_states`` on the same inputs. The outputs at
``t0`` (valid after initialisation) are the start state: trim (zeros), or the ``<state>_start``
parameters.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ._base import FlightgpSlave, Variable

FORMAT = "flightgp-fmu-linear"
VERSION = 1
#: The model file inside the FMU's package folder.
MODEL_FILE = "model.npz"

#: Padfield's state and input order (DESIGN.md).
STATE_NAMES = ("u", "w", "q", "theta", "v", "p", "phi", "r")
INPUT_NAMES = ("theta_0", "theta_1s", "theta_1c", "theta_0T")


def pack_model(*, A, B, speed_kt: int, source: str) -> dict:
    """Arrays of the FMU's model file: ``A`` (8, 8) in 1/s, ``B`` (8, 4) in state units per rad
    per s, the trim speed (kt), state and input names, and where the numbers come from."""
    return {"format": np.array(FORMAT), "version": np.array(VERSION),
            "A": np.asarray(A, dtype=float), "B": np.asarray(B, dtype=float),
            "speed_kt": np.array(int(speed_kt)), "source": np.array(source),
            "state_names": np.array(STATE_NAMES), "input_names": np.array(INPUT_NAMES)}


def bo105_reference_variables(*, inputs, states) -> tuple:
    """The variable table of the Bo105 reference FMU.

    Parameters
    ----------
    inputs, states : sequence of (name, unit, limit, phrase)
        Controls and states in Padfield's order: name, unit (a key of :data:`._base.UNITS`),
        largest plausible magnitude (None: unbounded) and a phrase saying what it is.

    Returns
    -------
    tuple of Variable
        The controls (inputs), the states (outputs) and each state's start value (fixed
        parameters ``<state>_start``).
    """
    limits = lambda limit: (None, None) if limit is None else (-limit, limit)  # noqa: E731
    table = [Variable(name, "input", "continuous", None, unit,
                      f"{phrase}, perturbation from trim, held from this communication point to the next",
                      0.0, *limits(limit))
             for name, unit, limit, phrase in inputs]
    table += [Variable(name, "output", "continuous", "exact", unit,
                       f"{phrase}, perturbation from trim (body axes)", 0.0)
              for name, unit, _, phrase in states]
    table += [Variable(f"{name}_start", "parameter", "fixed", "exact", unit,
                       f"{phrase} at the start time, perturbation from trim (default 0: trim)", 0.0,
                       *limits(limit))
              for name, unit, limit, phrase in states]
    return tuple(table)


class Bo105ReferenceSlave(FlightgpSlave):
    """Padfield's linear Bo105 model (the generated subclass sets the class attributes)."""

    #: The FMU's package folder under ``resources/`` (holds this code and the model file).
    PACKAGE = ""
    DEFAULT_STEP_SIZE = 0.01
    STATE_ATTRIBUTES = ("_state", "_transition", "_input_matrix")
    CONSTANT_ATTRIBUTES = ("_A", "_B")

    def load_constants(self) -> None:
        path = Path(self.resources) / self.PACKAGE / MODEL_FILE
        with np.load(path, allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
        if str(arrays.get("format")) != FORMAT or int(arrays.get("version", -1)) != VERSION:
            raise ValueError(f"{path.name} is not a {FORMAT} model file of version {VERSION}")
        if (tuple(arrays["state_names"]) != STATE_NAMES or tuple(arrays["input_names"]) != INPUT_NAMES
                or arrays["A"].shape != (8, 8) or arrays["B"].shape != (8, 4)
                or not (np.isfinite(arrays["A"]).all() and np.isfinite(arrays["B"]).all())):
            raise ValueError(f"{path.name}: A must be 8 x 8 and B 8 x 4, finite, for states "
                             f"{STATE_NAMES} and inputs {INPUT_NAMES}")
        self._A, self._B = arrays["A"], arrays["B"]
        self.log_info(f"loaded {path.name}: Bo105, {str(arrays['source'])}")

    def start_model(self, t0: float) -> None:
        self._state = np.array([self.values[f"{name}_start"] for name in STATE_NAMES])
        self._transition = self._input_matrix = None  # discretised at the first step
        self._set_outputs(self._state)

    def advance_model(self, k: int, t: float, h: float) -> None:
        if self._transition is None:
            transition, input_matrix = zero_order_hold(self._A, self._B, h)
            if not (np.isfinite(transition).all() and np.isfinite(input_matrix).all()):
                raise FloatingPointError(f"the discretisation at h = {h:.16g} s is not finite")
        else:
            transition, input_matrix = self._transition, self._input_matrix
        controls = np.array([self.values[name] for name in INPUT_NAMES])
        state = transition @ self._state + input_matrix @ controls
        if not np.isfinite(state).all():
            raise FloatingPointError(f"non-finite state {state.tolist()} at t = {t + h:.16g} s")
        self._transition, self._input_matrix, self._state = transition, input_matrix, state
        self._set_outputs(state)

    def _set_outputs(self, state: np.ndarray) -> None:
        for name, value in zip(STATE_NAMES, state.tolist()):
            self.values[name] = value


def zero_order_hold(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretisation ``(Phi, Gamma)`` of ``x_dot = A x + B u`` at step ``h``.

    ``expm([[A, B], [0, 0]] h) = [[Phi, Gamma], [0, I]]`` (Van Loan, IEEE TAC 23(3), 1978).
    """
    n, m = B.shape
    augmented = np.zeros((n + m, n + m))
    augmented[:n, :n], augmented[:n, n:] = A, B
    transition = _expm(augmented * h)
    return transition[:n, :n], transition[:n, n:]


# Higham (2005), "The scaling and squaring method for the matrix exponential revisited",
# SIAM J. Matrix Anal. Appl. 26(4), 1179-1193: Table 2.3 (theta_13) and eq. (2.1)-(2.3), the
# [13/13] Pade approximant (the algorithm scipy.linalg.expm implements; numpy only here).
_THETA_13 = 5.371920351148152
_PADE_13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
            129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
            40840800.0, 960960.0, 16380.0, 182.0, 1.0)


def _expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential by scaling and squaring with the [13/13] Pade approximant
    (Higham 2005, Algorithm 2.3 with m = 13 throughout): ``expm(M) = r_13(M / 2^s)^(2^s)``,
    ``s`` the least with ``||M / 2^s||_1 <= theta_13``."""
    norm = np.linalg.norm(M, 1)
    s = max(0, int(np.ceil(np.log2(norm / _THETA_13)))) if norm > 0 else 0
    X = M / 2.0**s
    b = _PADE_13
    I = np.eye(len(M))  # noqa: E741
    X2 = X @ X
    X4 = X2 @ X2
    X6 = X4 @ X2
    U = X @ (X6 @ (b[13] * X6 + b[11] * X4 + b[9] * X2) + b[7] * X6 + b[5] * X4 + b[3] * X2 + b[1] * I)
    V = X6 @ (b[12] * X6 + b[10] * X4 + b[8] * X2) + b[6] * X6 + b[4] * X4 + b[2] * X2 + b[0] * I
    R = np.linalg.solve(V - U, V + U)
    for _ in range(s):
        R = R @ R
    return R
