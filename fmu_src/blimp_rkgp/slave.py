"""The blimp RKGP FMU (Ko et al., ICRA 2007, sec. IV-B): motor commands in; the full state and its
standard deviations, propagated along the run, out; the blimp ODE integrated by RK4 plus a GP on
its one-step residual inside (:mod:`fmu_src.blimp_rkgp.model`). docs/fmus.md, "Blimp RKGP",
lists the variables.

Every blimp RKGP FMU carries a copy of this file (:mod:`fmu_src.fmi.pythonfmu`), so it imports
only the FMI layer (:mod:`fmu_src.fmi.slave`), the model, numpy and the standard library. The
per-FMU slave script that :func:`fmu_src.blimp_rkgp.build.build_blimp_rkgp_fmu` generates
subclasses :class:`BlimpRKGP` with the FMU's variable table (:func:`blimp_rkgp_variables`), its
package name and its default step.

Timing (docs/conventions.md, "FMU sampling convention")
-------------------------------------------------------
The model was trained on frame pairs with the frame interval as its input column ``dt``
(:func:`validation.models.blimp_identification.recording_arrays`): the physics integrates over ``dt``
and the GP sees it. The FMU does exactly that with ``dt = h``, the communication step: the host
chooses ``h`` (the default experiment's step is the median training frame interval), the first
``fmi2DoStep`` fixes it until reset, and a step outside the training range of ``dt`` (widened by
the envelope margin) is refused (logged Error, ``fmi2Discard``): the residual of another step
length is not what the GP learned. The commands set at ``t_k`` are held over ``[t_k, t_{k+1})``;
``fmi2DoStep(t_k, h)`` sets the state outputs to

    s(t_{k+1}) = RK4_blimp(s(t_k), u(t_k), h) + E[residual | s(t_k), u(t_k), h, z(k)]

(each step cut into equal RK4 substeps no longer than ``max_step``), which is
``GreyBoxGP.rollout`` (the mean rollout: the mean is fed back). ``z(k)`` are the lagged fan
commands when the model's GP sees them (``validation.models.blimp_greybox``): hidden states that
start at 0 (fans at rest) at the start time and advance with ``u(t_k)`` over each step. The
outputs at ``t0`` are the start state, the ``<state>_start`` parameters (default: at rest at the
origin hanging in the static attitude of the model's parameters, as
:class:`validation.vehicles.blimp.BlimpReference` starts).

Standard deviations
-------------------
``<state>_sd`` at ``t_{k+1}`` is the standard deviation of the state propagated along the run
from the known start (0 at ``t0``): ``GreyBoxGP.propagate`` with the GPs' noise included, the
first-order propagation of the state covariance through the linearised one-step map (the
model's docstring says how and what it is not). The covariance (12 x 12) is a hidden state.

Envelope: when a GP input leaves the training range (by more than 10 % of the range), the FMU
logs a Warning once per excursion; the GP then extrapolates, and the sd outputs grow faster.
"""
from __future__ import annotations

import math

import numpy as np

from fmu_src.blimp_rkgp.model import RKGPModel
from fmu_src.fmi.slave import FlightgpSlave, Variable
from validation.vehicles.blimp_equations import INPUT_NAMES, STATE_NAMES


def blimp_rkgp_variables(*, inputs, states) -> tuple:
    """The variable table of the blimp RKGP FMU.

    Parameters
    ----------
    inputs : sequence of (name, unit, limit, phrase)
        The commands: name, unit (a key of :data:`fmu_src.fmi.slave.UNITS`), largest magnitude, phrase.
    states : sequence of (name, unit, limit, phrase, start)
        The states, with the default start value (the hanging equilibrium).

    Returns
    -------
    tuple of Variable
        Commands (inputs); states and their propagated standard deviations (outputs); each
        state's start value (fixed parameters ``<state>_start``).
    """
    limits = lambda limit: (None, None) if limit is None else (-limit, limit)  # noqa: E731
    table = [Variable(name, "input", "continuous", None, unit,
                      f"{phrase}, held from this communication point to the next", 0.0, *limits(limit))
             for name, unit, limit, phrase in inputs]
    table += [Variable(name, "output", "continuous", "exact", unit,
                       f"{phrase}: RK4 physics plus GP residual mean (mean rollout)", start)
              for name, unit, _, phrase, start in states]
    table += [Variable(f"{name}_sd", "output", "continuous", "exact", unit,
                       f"standard deviation of the {phrase}, propagated along the run from the known "
                       "start (first order, GP noise included: GreyBoxGP.propagate; 0 at the start)", 0.0)
              for name, unit, _, phrase, _ in states]
    table += [Variable(f"{name}_start", "parameter", "fixed", "exact", unit,
                       f"{phrase} at the start time (default: at rest at the origin, hanging)", start,
                       *limits(limit))
              for name, unit, limit, phrase, start in states]
    return tuple(table)


class BlimpRKGP(FlightgpSlave):
    """Blimp RKGP (the class the build generates sets its description, PACKAGE, VARIABLES and
    DEFAULT_STEP_SIZE)."""

    STATE_ATTRIBUTES = ("_state", "_covariance", "_lags", "_outside_envelope")
    CONSTANT_ATTRIBUTES = ("_model",)

    def load_constants(self) -> None:
        self._model = self.shared_model(RKGPModel.load, self.model_file(), "blimp RKGP model")

    def step_problem(self, h: float) -> str | None:
        low, high = self._model.step_range()
        if not low <= h <= high:
            return (f"communicationStepSize {h:.16g} s is outside {low:.6g} .. {high:.6g} s, the "
                    "frame intervals the GP residual was trained on (plus 10 %); step with the "
                    "default experiment's step size")
        return None

    def start_model(self) -> None:
        n = len(STATE_NAMES)
        self._state = np.array([self.values[f"{name}_start"] for name in STATE_NAMES])
        self._covariance = np.zeros((n, n))  # the start is known
        self._lags = np.zeros(self._model.n_lags)  # fans at rest
        self._outside_envelope = False
        self._set_outputs(self._state, self._covariance)

    def advance_model(self, t: float, h: float) -> None:
        commands = np.array([self.values[name] for name in INPUT_NAMES])
        state, covariance, lags, x = self._model.step(self._state, self._covariance, self._lags, commands, h)
        if not (np.isfinite(state).all() and np.isfinite(covariance).all()):
            raise FloatingPointError(f"non-finite state {state.tolist()} or covariance at t = {t + h:.16g} s")
        outside = self.report_envelope(self._model.envelope.outside(x), self._outside_envelope, t + h,
                                       "its standard deviations grow")
        # Commit only after everything that can fail (a refused step leaves the state as it was).
        self._state, self._covariance, self._lags, self._outside_envelope = state, covariance, lags, outside
        self._set_outputs(state, covariance)

    def _set_outputs(self, state: np.ndarray, covariance: np.ndarray) -> None:
        # PropagatedRollout.sd: the square root of the diagonal, negative rounding clipped.
        for name, value, variance in zip(STATE_NAMES, state.tolist(), np.diagonal(covariance).tolist()):
            self.values[name] = value
            self.values[f"{name}_sd"] = math.sqrt(max(variance, 0.0))
