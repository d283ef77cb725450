"""The GP-NARX rate predictor FMU (Bo105 GP-NARX paper, AHS 74th Forum, 2018): control inputs
and the previous rates in, predicted rates and their confidence bounds out.

Every rate predictor FMU carries a copy of this file (:mod:`fmu_src.fmi.pythonfmu`), so it
imports only the FMI layer (:mod:`fmu_src.fmi.slave`), the GP-NARX prediction
(:mod:`fmu_src.rate_predictor.predictor`), numpy and the standard library. The per-FMU slave
script that :func:`fmu_src.rate_predictor.build.build_rate_predictor_fmu` generates subclasses
:class:`RatePredictor` with the FMU's variable table (:func:`rate_predictor_variables`), its
package name and its NARX step. docs/fmus.md, "GP-NARX rate predictor", lists the variables.

Timing (docs/conventions.md, "FMU sampling convention", with ``h`` = the NARX step)
-----------------------------------------------------------------------------------
The host must step with ``h`` equal to the model's NARX step (e.g. 0.1 s; declared as the default
experiment's step size; ``canHandleVariableCommunicationStepSize=false``); any other step or
communication point is refused with a logged Error and ``fmi2Discard``. At ``t_k`` the host sets
the controls ``u(t_k)`` and the measured rates ``y_prev(t_k)``; ``fmi2DoStep(t_k, h)`` pushes them
into the internal lag histories and sets the outputs to the one-step-ahead prediction

    y(t_{k+1}) = f(u(t_{k+1-i}) for i in input_lags, y(t_{k+1-j}) for j in output_lags),

which is exactly ``GPNarx.one_step`` on the recording sampled at ``h`` (from sample ``max_lag``
on). Before ``t0`` the vehicle is taken to be steady: every lag before ``t0`` holds the values set
at initialisation (recordings of perturbation models start at trim). At ``t0`` the outputs equal
the ``*_prev`` inputs (the given initial rates) with zero-width bounds.

Free-run mode (``free_run = true``): the FMU predicts from its own earlier predictions instead of
the ``*_prev`` inputs, which are then read only once, at initialisation, as the initial rates. It
propagates a Gaussian over the lagged rates by exact moment matching (Girard et al. 2003;
Deisenroth & Rasmussen 2011; :mod:`gp_model.uncertain_input`), so its bounds grow with the
horizon as the free run's uncertainty does: outputs equal
``GPNarx.free_run(method="moment_matching")`` from a vehicle steady at the initial rates. It
matches the moments of the mixture over the hyperparameter samples, so a free-run step costs
about S times a point-hyperparameter one (S samples).

Bounds: ``mean -/+ z sd`` with ``z`` the two-sided normal quantile of ``confidence_level``; ``sd``
is, one step ahead, the square root of the mixture variance over the hyperparameter samples and,
in free-run mode, the propagated standard deviation; measurement noise included (as
``flightgp predict``).

Envelope: when a regressor leaves the training range (by more than 10 % of the range), the FMU
logs a Warning once per excursion; the GP variance then grows toward the prior's, so the bounds
widen.
"""
from __future__ import annotations

import math
from functools import lru_cache
from statistics import NormalDist

import numpy as np

from fmu_src.fmi.slave import FlightgpSlave, Variable
from fmu_src.rate_predictor.predictor import NarxPredictor


def rate_predictor_variables(*, inputs, outputs, exact_moments: bool = False) -> tuple:
    """The variable table of a GP-NARX rate predictor.

    Parameters
    ----------
    inputs, outputs : sequence of (name, unit, limit, phrase)
        The model's control inputs and predicted outputs: name, unit (a key of
        :data:`fmu_src.fmi.slave.UNITS`), largest plausible magnitude (None: unbounded) and a phrase saying
        what it is (e.g. ``"longitudinal cyclic"``).
    exact_moments : bool, default False
        The start value of ``exact_moments`` (the build's choice from its check of the fast path,
        :func:`fmu_src.rate_predictor.build.fast_path_error`).

    Returns
    -------
    tuple of Variable
        Controls, previous outputs (inputs); predicted outputs and their bounds (outputs);
        ``confidence_level``, ``free_run``, ``exact_moments`` and ``parallel`` (parameters).
    """
    table = []
    for name, unit, limit, phrase in inputs:
        table.append(Variable(name, "input", "continuous", None, unit,
                              f"{phrase} at the current communication point, held until the next "
                              "(perturbation from trim)", 0.0, None if limit is None else -limit, limit))
    for name, unit, limit, phrase in outputs:
        table.append(Variable(f"{name}_prev", "input", "continuous", None, unit,
                              f"{phrase} at the communication point t_k the next step starts from: with free_run "
                              f"false (the default) the host must set it before every step to the {phrase} "
                              f"measured at t_k, and the step predicts {name} at t_k + h from it (prev: the value "
                              f"before the one predicted); with free_run true it is read only at initialisation, as "
                              f"the starting {phrase}", 0.0, None if limit is None else -limit, limit))
    for name, unit, _, phrase in outputs:
        table += [
            Variable(name, "output", "continuous", "exact", unit,
                     f"predicted {phrase} at the current communication point (the middle of the band): after a "
                     "step from t_k, the prediction for t_k + h", 0.0),
            Variable(f"{name}_lower", "output", "continuous", "exact", unit,
                     f"lower end of the band that holds the {phrase} with probability confidence_level", 0.0),
            Variable(f"{name}_upper", "output", "continuous", "exact", unit,
                     f"upper end of the band that holds the {phrase} with probability confidence_level", 0.0),
        ]
    table += [
        Variable("confidence_level", "parameter", "tunable", "exact", "1",
                 "probability that the true value lies between the lower and upper bounds (0.95: a 95 % band)",
                 0.95, 0.5, 0.9999),
        Variable("free_run", "parameter", "fixed", "exact", None,
                 "false (default): predict one step ahead from measured rates, which the host must then feed "
                 "back into the *_prev inputs at every step; true: predict from the FMU's own earlier predictions "
                 "(no measured rates needed: *_prev are read only at initialisation, as the starting rates), "
                 "with bounds that widen with time as the uncertainty accumulates", False),
        Variable("exact_moments", "parameter", "fixed", "exact", None,
                 "free run only: true computes how the uncertainty carries from step to step in double precision "
                 "throughout; false does part of it in single precision, faster, within 2 % of the predicted "
                 "standard deviation; the build checked the faster way on a test input and chose this default "
                 "(the FMU's description says what it measured)", exact_moments),
        Variable("parallel", "parameter", "fixed", "exact", None,
                 "free run only: true makes the native FMU compute each step on two threads, its own and one it "
                 "starts (about 1.5x faster where two cores are free); the pythonfmu FMU runs on one thread "
                 "either way", False),
    ]
    return tuple(table)


class RatePredictor(FlightgpSlave):
    """GP-NARX rate predictor (the class the build generates sets its description, PACKAGE,
    VARIABLES and STEP_SIZE)."""

    STATE_ATTRIBUTES = ("_input_history", "_output_history", "_outside_envelope", "_belief")
    CONSTANT_ATTRIBUTES = ("_predictor", "_input_names", "_output_names")

    def load_constants(self) -> None:
        self._predictor = self._load_predictor()
        self._input_names = self._predictor.input_names
        self._output_names = self._predictor.output_names

    def start_model(self) -> None:
        predictor = self._predictor
        u0 = self._controls()
        y0 = self._previous_outputs()
        self._input_history = np.tile(u0, (predictor.max_lag, 1))  # row i: i steps ago
        self._output_history = np.tile(y0, (predictor.max_lag, 1))
        self._outside_envelope = False
        self._belief = list(predictor.free_run_start(y0)) if self.values["free_run"] else None
        self._set_outputs(y0, np.zeros_like(y0))

    def advance_model(self, t: float, h: float) -> None:
        predictor = self._predictor
        if self.values["free_run"]:
            y = np.array([self.values[name] for name in self._output_names])
        else:
            y = self._previous_outputs()
        input_history = _push(self._input_history, self._controls())
        output_history = _push(self._output_history, y)
        x = predictor.regressor(input_history, output_history)
        belief = self._belief
        if self.values["free_run"]:
            mean, var, belief = predictor.free_run_step(input_history, belief,
                                                        exact_moments=bool(self.values["exact_moments"]))
        else:
            mean, var = predictor.predict(x)
        if not (np.isfinite(mean).all() and np.isfinite(var).all()):
            raise FloatingPointError(f"non-finite prediction {mean.tolist()} (variance {var.tolist()}) "
                                     f"at regressor {x.tolist()}")
        outside = self.report_envelope(predictor.envelope.outside(x), self._outside_envelope, t + h,
                                       "its variance, and so the bounds, widen")
        # Commit only after everything that can fail (a refused step leaves the state as it was).
        self._input_history, self._output_history = input_history, output_history
        self._outside_envelope = outside
        self._belief = None if belief is None else list(belief)
        self._set_outputs(mean, var)

    # -- helpers ------------------------------------------------------------------------------
    def _load_predictor(self) -> NarxPredictor:
        predictor = self.shared_model(NarxPredictor.load, self.model_file(), "GP-NARX model")
        declared = {v.name for v in self.VARIABLES}
        missing = [n for n in predictor.input_names + predictor.output_names if n not in declared]
        if missing:
            raise ValueError(f"the model file's signals {missing} have no FMU variables")
        if self.STEP_SIZE is None or abs(predictor.step - self.STEP_SIZE) > 1e-9 * predictor.step:
            raise ValueError(f"the model's NARX step {predictor.step:.16g} s differs from the FMU's "
                             f"step {self.STEP_SIZE} s")
        return predictor

    def _controls(self) -> np.ndarray:
        return np.array([self.values[name] for name in self._input_names], dtype=float)

    def _previous_outputs(self) -> np.ndarray:
        return np.array([self.values[f"{name}_prev"] for name in self._output_names], dtype=float)

    def _set_outputs(self, mean: np.ndarray, var: np.ndarray) -> None:
        z = _two_sided_quantile(self.values["confidence_level"])
        for name, m, v in zip(self._output_names, mean.tolist(), var.tolist()):
            half_width = z * math.sqrt(v)
            self.values[name] = m
            self.values[f"{name}_lower"] = m - half_width
            self.values[f"{name}_upper"] = m + half_width


def _push(history: np.ndarray, row: np.ndarray) -> np.ndarray:
    """A new lag history (row i: i steps ago) with ``row`` as the current sample."""
    pushed = np.empty_like(history)
    pushed[0] = row
    pushed[1:] = history[:-1]
    return pushed


@lru_cache(maxsize=16)
def _two_sided_quantile(level: float) -> float:
    """``z`` with ``P(|N(0, 1)| <= z) = level``."""
    return NormalDist().inv_cdf(0.5 + 0.5 * level)
