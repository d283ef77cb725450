"""The Bo105 physics reference FMU: Padfield's linear 6-DOF model at one trim speed.

``x_dot = A x + B u`` with ``x = (u, w, q, theta, v, p, phi, r)`` and
``u = (theta_0, theta_1s, theta_1c, theta_0T)``, perturbations from trim in SI units
(G. D. Padfield, *Helicopter Flight Dynamics*, 2nd ed., 2007; docs/vehicles.md, "Bo105"),
exactly as :class:`validation.vehicles.bo105.Bo105Reference`. ``A`` and ``B`` travel in the FMU's
model file (written by :func:`pack_model`); the run time needs numpy only. docs/fmus.md, "Bo105
reference", lists the variables.

Every Bo105 reference FMU carries a copy of this file (:mod:`fmu_src.fmi.pythonfmu`), so it
imports only the FMI layer (:mod:`fmu_src.fmi.slave`), the shared FMU runtime, the
discretisation (:mod:`validation.vehicles.linear_discretisation`), numpy and the standard library.

Timing (docs/conventions.md, "FMU sampling convention")
-------------------------------------------------------
The host chooses the communication step ``h`` (any positive step; 0.01 s in the default
experiment); the first ``fmi2DoStep`` fixes it until reset, and a different step later is
refused (logged Error, ``fmi2Discard``). The model is discretised exactly for ``h`` with a
zero-order hold on the inputs (Van Loan, IEEE TAC 23(3), 1978, as ``Bo105Reference``):

    x(t_{k+1}) = Phi x(t_k) + Gamma u(t_k),   [[Phi, Gamma], [0, I]] = expm([[A, B], [0, 0]] h)

so the inputs set at ``t_k`` are held over ``[t_k, t_{k+1})`` and ``fmi2DoStep(t_k, h)`` sets the
outputs to ``x(t_{k+1})``: ``Bo105Reference.simulate_states`` on the same inputs. The outputs at
``t0`` (valid after initialisation) are the start state: trim (zeros), or the ``<state>_start``
parameters.

Derivatives as parameters
-------------------------
Every stability and control derivative is a fixed parameter named as flightgp names it
(``<row>_<column>`` with the rows ``X, Z, M, Y, L, N`` of the ``u, w, q, v, p, r`` equations:
``M_q``, ``L_theta_1c``; docs/vehicles.md, "Bo105"), its start value the model file's entry of
``A`` or ``B``. Setting one before initialisation runs the model with that entry replaced, as
``Bo105Reference.with_derivatives`` does, so a diagnosis through the FMU can correct what one
against the built-in reference corrects.
"""
from __future__ import annotations

import numpy as np

from fmu_src.fmi.runtime import ModelFormatError, check_header, model_header, read_model_file
from fmu_src.fmi.slave import FlightgpSlave, Variable
from validation.vehicles.linear_discretisation import zero_order_hold

FORMAT = "flightgp-fmu-linear"
VERSION = 1

#: Padfield's state and input order (validation.vehicles.bo105).
STATE_NAMES = ("u", "w", "q", "theta", "v", "p", "phi", "r")
INPUT_NAMES = ("theta_0", "theta_1s", "theta_1c", "theta_0T")
#: Derivative row letters and the state whose equation each names (validation.vehicles.bo105).
ROW_LETTERS = {"X": "u", "Z": "w", "M": "q", "Y": "v", "L": "p", "N": "r"}


def derivative_entries() -> list[tuple[str, str, int, int]]:
    """Every derivative: (name, ``"A"`` or ``"B"``, row, column), rows in :data:`ROW_LETTERS`
    order, columns the states then the inputs."""
    entries = []
    for letter, state in ROW_LETTERS.items():
        row = STATE_NAMES.index(state)
        entries += [(f"{letter}_{column}", "A", row, j) for j, column in enumerate(STATE_NAMES)]
        entries += [(f"{letter}_{column}", "B", row, j) for j, column in enumerate(INPUT_NAMES)]
    return entries


def pack_model(*, A, B, speed_kt: int, source: str) -> dict:
    """Arrays of the FMU's model file: ``A`` (8, 8) in 1/s, ``B`` (8, 4) in state units per rad
    per s, the trim speed (kt), state and input names, and where the numbers come from."""
    return {**model_header(FORMAT, VERSION), "A": np.asarray(A, dtype=float), "B": np.asarray(B, dtype=float),
            "speed_kt": np.array(int(speed_kt)), "source": np.array(source),
            "state_names": np.array(STATE_NAMES), "input_names": np.array(INPUT_NAMES)}


def bo105_reference_variables(*, inputs, states, derivatives=()) -> tuple:
    """The variable table of the Bo105 reference FMU.

    Parameters
    ----------
    inputs, states : sequence of (name, unit, limit, phrase)
        Controls and states in Padfield's order: name, unit (a key of :data:`fmu_src.fmi.slave.UNITS`),
        largest plausible magnitude (None: unbounded) and a phrase saying what it is.
    derivatives : sequence of (name, unit, value, phrase)
        The derivatives as parameters (module docstring): name, unit, the model's value and what
        it is.

    Returns
    -------
    tuple of Variable
        The controls (inputs), the states (outputs), each state's start value (fixed
        parameters ``<state>_start``) and the derivatives (fixed parameters).
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
    table += [Variable(name, "parameter", "fixed", "exact", unit, phrase, float(value))
              for name, unit, value, phrase in derivatives]
    return tuple(table)


class Bo105ReferenceSlave(FlightgpSlave):
    """Padfield's linear Bo105 model (the class the build generates sets its description,
    PACKAGE and VARIABLES)."""

    DEFAULT_STEP_SIZE = 0.01
    STATE_ATTRIBUTES = ("_state", "_transition", "_input_matrix", "_state_matrix", "_control_matrix")
    CONSTANT_ATTRIBUTES = ("_A", "_B")

    def load_constants(self) -> None:
        path = self.model_file()
        arrays = read_model_file(path)
        check_header(arrays, format_name=FORMAT, version=VERSION)
        if (tuple(arrays["state_names"]) != STATE_NAMES or tuple(arrays["input_names"]) != INPUT_NAMES
                or arrays["A"].shape != (8, 8) or arrays["B"].shape != (8, 4)
                or not (np.isfinite(arrays["A"]).all() and np.isfinite(arrays["B"]).all())):
            raise ModelFormatError(f"{path.name}: A must be 8 x 8 and B 8 x 4, finite, for states "
                                   f"{STATE_NAMES} and inputs {INPUT_NAMES}")
        self._A, self._B = arrays["A"], arrays["B"]
        self.log_info(f"loaded {path.name}: Bo105, {str(arrays['source'])}")

    def start_model(self) -> None:
        self._state_matrix, self._control_matrix = self._A.copy(), self._B.copy()  # with the derivatives set
        for name, matrix, row, column in derivative_entries():
            (self._state_matrix if matrix == "A" else self._control_matrix)[row, column] = self.values[name]
        self._state = np.array([self.values[f"{name}_start"] for name in STATE_NAMES])
        self._transition = self._input_matrix = None  # discretised at the first step
        self._set_outputs(self._state)

    def advance_model(self, t: float, h: float) -> None:
        if self._transition is None:
            transition, input_matrix = zero_order_hold(self._state_matrix, self._control_matrix, h)
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
