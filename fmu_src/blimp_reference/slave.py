"""The blimp physics reference FMU: the blimp ODE integrated by RK4, every physical parameter a
parameter.

The equations are those of :class:`validation.vehicles.blimp.BlimpReference` (Ko, Klein, Fox &
Haehnel, ICRA 2007, sec. III, in Fossen's 2011 matrix form; docs/vehicles.md, "Blimp"):
:func:`validation.vehicles.blimp_equations.blimp_dynamics` stepped by
:func:`validation.vehicles.blimp_equations.rk4_advance`, the very functions ``BlimpReference``
steps with. docs/fmus.md, "Blimp reference", lists the variables.

Every blimp reference FMU carries a copy of this file (:mod:`fmu_src.fmi.pythonfmu`), so it
imports only the FMI layer (:mod:`fmu_src.fmi.slave`), the shared FMU runtime, the blimp's
equations (:mod:`validation.vehicles.blimp_equations`), numpy and the standard library.

Timing (docs/conventions.md, "FMU sampling convention")
-------------------------------------------------------
The host chooses the communication step ``h`` (any positive step; 0.05 s, the reference's
motion-capture interval, in the default experiment); the first ``fmi2DoStep`` fixes it until
reset, and a different step later is refused (logged Error, ``fmi2Discard``). The inputs set at
``t_k`` are held over ``[t_k, t_{k+1})`` and ``fmi2DoStep(t_k, h)`` sets the outputs to

    s(t_{k+1}) = RK4_blimp(s(t_k), u(t_k), h)

in ``ceil(h / max_step)`` equal classical RK4 substeps (``max_step`` from the model file:
``BlimpReference.max_step``, 0.01 s, so 5 substeps at 0.05 s), which is
``BlimpReference.simulate_states`` on the same inputs. The outputs at ``t0`` are the start state,
the ``<state>_start`` parameters (default: at rest at the origin, hanging in the static attitude
of the default parameters, as ``BlimpReference`` starts).

Parameters
----------
Every entry of ``BlimpParameters.to_vector()`` is a fixed parameter, named as flightgp names it:
as the blimp's effect terms (``validation.vehicles.blimp_effects``) where one is the entry itself
(``X_UU``, ``N_R``, ``Z_0``, ``gondola_thrust_forward``, ...; value ``sign * entry``, the sign
-1 for drag, damping and net lift), as ``BlimpParameters.vector_names()`` elsewhere
(``mass``, ``inertia_y``, ``cg_position_z``, ...). Setting one before initialisation runs the
model with that entry replaced, as ``BlimpReference(params=dataclasses.replace(...))`` does, so
a diagnosis through the FMU can correct what one against the built-in reference corrects.

Model file (``model.npz``, written by :func:`pack_model`, read without pickle)
------------------------------------------------------------------------------
``format``, ``version``; ``entry_names`` (n,), the ``BlimpParameters.vector_names()``;
``parameter_names`` (n,), the FMU parameter of each entry; ``signs`` (n,), +1 or -1, each entry
being ``sign * parameter``; ``max_step``, the longest RK4 substep, s; ``source``, where the
default values come from.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from fmu_src.fmi.runtime import ModelFormatError, check_header, model_header, read_model_file
from fmu_src.fmi.slave import FlightgpSlave, Variable
from validation.vehicles.blimp_equations import (
    INPUT_NAMES,
    STATE_NAMES,
    mass_matrix,
    parameters_from_vector,
    rk4_advance,
)

FORMAT = "flightgp-fmu-blimp-reference"
VERSION = 1


def pack_model(*, entry_names, parameter_names, signs, max_step: float, source: str) -> dict:
    """Arrays of the FMU's model file (module docstring).

    Parameters
    ----------
    entry_names : sequence of str, length n
        ``BlimpParameters.vector_names()``.
    parameter_names : sequence of str, length n
        The FMU parameter that sets each entry.
    signs : sequence of float, length n
        +1 or -1: entry = sign * parameter.
    max_step : float
        Longest RK4 substep, s.
    source : str
        Where the default values come from.
    """
    return {**model_header(FORMAT, VERSION), "entry_names": np.array(list(entry_names), dtype=str),
            "parameter_names": np.array(list(parameter_names), dtype=str),
            "signs": np.asarray(signs, dtype=float), "max_step": np.array(float(max_step)),
            "source": np.array(source)}


def blimp_reference_variables(*, inputs, states, parameters) -> tuple:
    """The variable table of the blimp reference FMU.

    Parameters
    ----------
    inputs : sequence of (name, unit, limit, phrase)
        ``u_gondola, mu, u_tail``: name, unit (a key of :data:`fmu_src.fmi.slave.UNITS`),
        largest plausible magnitude (None: unbounded) and a phrase saying what it is.
    states : sequence of (name, unit, limit, phrase, start)
        ``x, y, z, phi, theta, psi, U, V, W, P, Q, R``, as ``inputs`` plus the default start value.
    parameters : sequence of (name, unit, value, phrase)
        The physical parameters (module docstring): name, unit, the reference's value, what it is.

    Returns
    -------
    tuple of Variable
        The commands (inputs), the states (outputs), each state's start value (fixed parameters
        ``<state>_start``) and the physical parameters (fixed parameters).
    """
    limits = lambda limit: (None, None) if limit is None else (-limit, limit)  # noqa: E731
    table = [Variable(name, "input", "continuous", None, unit,
                      f"{phrase}, held from this communication point to the next", 0.0, *limits(limit))
             for name, unit, limit, phrase in inputs]
    table += [Variable(name, "output", "continuous", "exact", unit, f"{phrase}: the blimp ODE integrated by RK4",
                       start)
              for name, unit, _, phrase, start in states]
    table += [Variable(f"{name}_start", "parameter", "fixed", "exact", unit,
                       f"{phrase} at the start time (default: at rest at the origin, hanging in the static "
                       "attitude of the default parameters)", start, *limits(limit))
              for name, unit, limit, phrase, start in states]
    table += [Variable(name, "parameter", "fixed", "exact", unit, phrase, float(value))
              for name, unit, value, phrase in parameters]
    return tuple(table)


class BlimpReferenceSlave(FlightgpSlave):
    """The blimp ODE (the class the build generates sets its description, PACKAGE, VARIABLES and
    DEFAULT_STEP_SIZE). The state and the parameter vector the run started with are its state."""

    STATE_ATTRIBUTES = ("_state", "_vector")
    CONSTANT_ATTRIBUTES = ("_entry_names", "_parameter_names", "_signs", "_max_step")

    def load_constants(self) -> None:
        path = self.model_file()
        arrays = read_model_file(path)
        check_header(arrays, format_name=FORMAT, version=VERSION)
        entries, names, signs = arrays["entry_names"], arrays["parameter_names"], arrays["signs"]
        declared = {v.name for v in self.VARIABLES if v.causality == "parameter"}
        max_step = float(arrays["max_step"])
        if (entries.shape != names.shape or signs.shape != names.shape or entries.ndim != 1
                or not set(names.tolist()) <= declared or not np.isin(signs, (-1.0, 1.0)).all()
                or not (np.isfinite(max_step) and max_step > 0)):
            raise ModelFormatError(f"{path.name}: entry_names, parameter_names (parameters of this FMU) and "
                                   "signs (+1 or -1) must be alike vectors and max_step a positive number of "
                                   "seconds")
        self._entry_names, self._parameter_names = tuple(entries.tolist()), tuple(names.tolist())
        self._signs, self._max_step = signs, max_step
        self.log_info(f"loaded {path.name}: blimp, {str(arrays['source'])}; RK4 substeps of at most "
                      f"{max_step:.6g} s")

    def start_model(self) -> None:
        vector = self._signs * np.array([self.values[name] for name in self._parameter_names])
        params = self._params(vector)
        try:
            _, inverse = mass_matrix(params.mass, params.added_mass, params.inertia, params.added_inertia,
                                     params.cg_position)
        except np.linalg.LinAlgError:  # singular
            inverse = np.full((6, 6), np.nan)
        if not np.isfinite(inverse).all():
            raise ValueError("the system inertia matrix (mass, added mass, inertia, added inertia, cg_position) "
                             "has no finite inverse; the masses and inertias must be positive")
        self._vector = vector
        self._state = np.array([self.values[f"{name}_start"] for name in STATE_NAMES])
        self._set_outputs(self._state)

    def advance_model(self, t: float, h: float) -> None:
        controls = np.array([self.values[name] for name in INPUT_NAMES])
        state = rk4_advance(self._state, controls, h, self._params(self._vector), max_step=self._max_step)
        if not np.isfinite(state).all():
            raise FloatingPointError(f"non-finite state {state.tolist()} at t = {t + h:.16g} s")
        self._state = state
        self._set_outputs(state)

    def _params(self, vector: np.ndarray) -> SimpleNamespace:
        """The parameters of ``vector`` (entries in ``entry_names`` order) with the fields of
        ``BlimpParameters`` (:func:`validation.vehicles.blimp_equations.parameters_from_vector`)."""
        return SimpleNamespace(**parameters_from_vector(self._entry_names, vector))

    def _set_outputs(self, state: np.ndarray) -> None:
        for name, value in zip(STATE_NAMES, state.tolist()):
            self.values[name] = value
