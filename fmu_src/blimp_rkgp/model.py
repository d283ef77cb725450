"""The blimp RKGP model inside the blimp RKGP FMU (Ko et al., ICRA 2007, sec. IV-B): the blimp
ODE integrated by RK4 plus a GP on its one-step residual (:class:`gp_model.GreyBoxGP` with the
physics ``blimp_rk4``), the lagged fan commands its GP may see, and the state covariance
propagated along the run. numpy and the standard library only.

Every blimp RKGP FMU (pythonfmu) carries a copy of this file and of what it imports, the shared
FMU runtime (:mod:`fmu_src.fmi.runtime`), the grey-box FMUs' residual GPs and covariance
propagation (:mod:`fmu_src.fmi.greybox`) and the blimp's equations of motion
(:mod:`validation.vehicles.blimp_equations`, the very functions
:func:`validation.models.blimp_identification.physics_step` steps with), under names unique to
the FMU (:mod:`fmu_src.fmi.pythonfmu`). So the FMU reproduces ``GreyBoxGP.rollout`` (means) and
``GreyBoxGP.propagate`` (standard deviations) with that physics to rounding (tested to 1e-9).
The native FMU evaluates the same formulas in C (``blimp_model.c``).

Model file (``model.npz``, written by :func:`pack_model`, read without pickle)
------------------------------------------------------------------------------
``format``, ``version``; ``parameter_names``, ``parameters`` (the
``BlimpParameters.to_vector`` the model was trained with), ``max_step`` (longest RK4 substep, s);
``state_columns`` (state columns the GP sees); ``command_lags`` (L,) time constants of the
lagged commands, s (empty: none), ``lag_command_columns`` (F,) the commands (columns of
``u_gondola, mu, u_tail``) each lag filters; ``propagation_step`` (the central-difference step of
``GreyBoxGP.propagate``, state units); ``gp_input_names`` (d,) and ``envelope_low``,
``envelope_high`` (d,) (names and training range of the GP inputs
``[states[state_columns], u_gondola, mu, u_tail, dt, lags]``); the GP parts, ``"<p>/<name>"``
(:mod:`fmu_src.fmi.greybox`, "Residual GPs").

Lagged commands
---------------
With ``L`` time constants ``T_j`` the GP's last ``F L`` inputs are the fan commands passed
through first-order lags, for each ``T_j`` each fan (``validation.models.blimp_greybox``,
``lagged_commands``): ``T z' = -z + u`` with ``u`` held over the step is exact as
``z(k+1) = a z(k) + (1 - a) u(k)``, ``a = exp(-h / T)`` (Franklin, Powell & Workman, *Digital
Control of Dynamic Systems*, 3rd ed., 1998, sec. 4.3). The lags start at 0 (fans at rest) at
the start time; step k's GP input holds ``z(k)``, then the lags advance with ``u(k)``.

Standard deviations
-------------------
The state covariance is propagated to first order along the mean run, as ``GreyBoxGP.propagate``
(:mod:`fmu_src.fmi.greybox`, "Standard deviations").
"""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np

from fmu_src.fmi.greybox import FirstOrderPropagation, ResidualGPs, checked_state_columns, pack_gp_parts
from fmu_src.fmi.runtime import Envelope, ModelFormatError, check_header, freeze, model_header, read_model_file
from fmu_src.fmi.slave import TIME_TOLERANCE
from validation.vehicles.blimp_equations import INPUT_NAMES, STATE_NAMES, parameters_from_vector, rk4_advance

FORMAT = "flightgp-fmu-blimp-rkgp"
#: Version 2 added the lagged commands, the noise variances and the propagation step.
VERSION = 2


def pack_model(*, parameter_names, parameters, max_step: float, state_columns, command_lags,
               lag_command_columns, propagation_step: float, gp_input_names, envelope_low,
               envelope_high, parts) -> dict:
    """Arrays for ``numpy.savez`` (module docstring).

    Parameters
    ----------
    parameter_names : sequence of str
        ``BlimpParameters.vector_names()``.
    parameters : array_like, shape (n_parameters,)
        ``BlimpParameters.to_vector()`` of the physics, SI units.
    max_step : float
        Longest RK4 substep, s.
    state_columns : sequence of int
        The state columns the GP sees.
    command_lags : sequence of float, shape (L,)
        Time constants of the lagged commands, s; empty for none.
    lag_command_columns : sequence of int, shape (F,)
        The commands (columns of ``u_gondola, mu, u_tail``) each lag filters.
    propagation_step : float
        Central-difference step of the covariance propagation, state units.
    gp_input_names : sequence of str, shape (d,)
        Names of the GP inputs, for messages.
    envelope_low, envelope_high : array_like, shape (d,)
        Training range of each GP input, physical units.
    parts : list of dict
        One dict of :data:`fmu_src.fmi.greybox.PER_PART` arrays per GP part.
    """
    arrays = {**model_header(FORMAT, VERSION),
              "parameter_names": np.array(list(parameter_names), dtype=str),
              "parameters": np.asarray(parameters, dtype=float), "max_step": np.array(float(max_step)),
              "state_columns": np.asarray(state_columns, dtype=np.int64),
              "command_lags": np.asarray(command_lags, dtype=float).reshape(-1),
              "lag_command_columns": np.asarray(lag_command_columns, dtype=np.int64).reshape(-1),
              "propagation_step": np.array(float(propagation_step)),
              "gp_input_names": np.array(list(gp_input_names), dtype=str),
              "envelope_low": np.asarray(envelope_low, dtype=float),
              "envelope_high": np.asarray(envelope_high, dtype=float)}
    return {**arrays, **pack_gp_parts(parts)}


class RKGPModel:
    """A blimp RKGP model loaded from an FMU model file (module docstring).

    Attributes
    ----------
    params : types.SimpleNamespace
        The physics parameters, fields as :class:`validation.vehicles.blimp.BlimpParameters`'s
        (:func:`validation.vehicles.blimp_equations.parameters_from_vector` of the model file's
        named vector).
    max_step : float
        Longest RK4 substep, s.
    state_columns : ndarray of int
        The state columns the GP sees.
    command_lags : ndarray, shape (L,)
        Time constants of the lagged commands, s.
    lag_command_columns : ndarray of int, shape (F,)
        The commands each lag filters.
    n_lags : int
        ``F L``, the lagged-command GP inputs (and hidden states).
    propagation : fmu_src.fmi.greybox.FirstOrderPropagation
        The covariance propagation and its central-difference step.
    gps : fmu_src.fmi.greybox.ResidualGPs
        The residual GPs (one shared part, or one per state).
    input_names : tuple of str
        The GP inputs: the seen states, the commands, ``dt`` and the lagged commands.
    dt_column : int
        Index of ``dt`` among the GP inputs.
    envelope : fmu_src.fmi.runtime.Envelope
        Training range of each GP input.
    """

    def __init__(self, arrays: dict) -> None:
        check_header(arrays, format_name=FORMAT, version=VERSION)
        try:
            self.params = SimpleNamespace(**parameters_from_vector(arrays["parameter_names"], arrays["parameters"]))
            self.max_step = float(arrays["max_step"])
            self.state_columns = checked_state_columns(arrays["state_columns"], len(STATE_NAMES))
            self.command_lags = np.array(arrays["command_lags"], dtype=float).reshape(-1)
            self.lag_command_columns = np.array(arrays["lag_command_columns"], dtype=int).reshape(-1)
            propagation_step = float(arrays["propagation_step"])
            self.input_names = tuple(str(name) for name in np.ravel(arrays["gp_input_names"]))
            envelope_low, envelope_high = arrays["envelope_low"], arrays["envelope_high"]
        except KeyError as error:
            raise ModelFormatError(f"the model file lacks the array {error}") from None
        if not (np.isfinite(self.command_lags).all() and (self.command_lags > 0).all()):
            raise ModelFormatError(f"command lags must be positive times in s, got {self.command_lags.tolist()}")
        if self.command_lags.size and (not self.lag_command_columns.size or self.lag_command_columns.min() < 0
                                       or self.lag_command_columns.max() >= len(INPUT_NAMES)):
            raise ModelFormatError(f"lag_command_columns {self.lag_command_columns.tolist()} must name commands "
                                   f"0 .. {len(INPUT_NAMES) - 1}")
        self.n_lags = len(self.command_lags) * len(self.lag_command_columns)
        self.dt_column = len(self.state_columns) + len(INPUT_NAMES)
        d = self.dt_column + 1 + self.n_lags
        self.gps = ResidualGPs(arrays, n_outputs=len(STATE_NAMES), n_inputs=d)
        if np.shape(envelope_low) != (d,) or np.shape(envelope_high) != (d,) or len(self.input_names) != d:
            raise ModelFormatError(f"the GP parts must map {d} named inputs to {len(STATE_NAMES)} residuals")
        if not self.max_step > 0:
            raise ModelFormatError(f"max_step must be positive, got {self.max_step}")
        self.propagation = FirstOrderPropagation(len(STATE_NAMES), propagation_step)
        self.envelope = Envelope(envelope_low, envelope_high, self.input_names)
        self._lag_time_constants = np.repeat(self.command_lags, len(self.lag_command_columns))
        freeze((self.state_columns, self.command_lags, self.lag_command_columns, self._lag_time_constants))

    @classmethod
    def load(cls, path) -> RKGPModel:
        """Read ``path`` (an ``.npz`` written from :func:`pack_model`; never unpickles)."""
        return cls(read_model_file(path))

    def step_range(self) -> tuple[float, float]:
        """Communication steps (s) the model accepts: the training range of ``dt`` plus the
        envelope margin and the FMI layer's time tolerance (evenly sampled training data has one
        ``dt``, up to rounding)."""
        dt = self.dt_column
        slack = TIME_TOLERANCE * float(self.envelope.high[dt])
        return float(self.envelope.lower[dt]) - slack, float(self.envelope.upper[dt]) + slack

    def gp_inputs(self, states: np.ndarray, commands: np.ndarray, dt: float, lags: np.ndarray) -> np.ndarray:
        """The GP inputs (r, d) of ``states`` (r, 12) under ``commands`` (3,) held for ``dt`` s with
        the lagged commands ``lags`` (n_lags,): ``[states[:, state_columns], commands, dt, lags]``."""
        held = np.concatenate([commands, [dt], lags])
        return np.hstack([states[:, self.state_columns], np.broadcast_to(held, (len(states), len(held)))])

    def start_hidden(self) -> np.ndarray:
        """The lagged commands at the start: 0 (fans at rest), shape (n_lags,)."""
        return np.zeros(self.n_lags)

    def start_covariance(self) -> np.ndarray:
        """The start is known: covariance zero."""
        return self.propagation.known_start()

    def advance_lags(self, lags: np.ndarray, commands: np.ndarray, dt: float) -> np.ndarray:
        """The lagged commands (n_lags,) ``dt`` s on under ``commands`` (3,) held: ``a z + (1 - a) u``,
        ``a = exp(-dt / T)`` (module docstring)."""
        decay = np.exp(-dt / self._lag_time_constants)
        return decay * lags + (1.0 - decay) * np.tile(commands[self.lag_command_columns], len(self.command_lags))

    def step(self, state: np.ndarray, covariance: np.ndarray, lags: np.ndarray, commands: np.ndarray,
             dt: float):
        """One step of ``dt`` s under ``commands`` (3,) held (module docstring).

        Parameters
        ----------
        state : ndarray, shape (12,)
            Mean state at ``t_k``.
        covariance : ndarray, shape (12, 12)
            Its covariance ``P(k)``.
        lags : ndarray, shape (n_lags,)
            The lagged commands ``z(k)``.
        commands : ndarray, shape (3,)
        dt : float
            s.

        Returns
        -------
        state : ndarray, shape (12,)
            ``RK4(s, u, dt) + E[residual]`` (``GreyBoxGP.rollout``).
        covariance : ndarray, shape (12, 12)
            ``P(k+1) = J P(k) J^T + diag(Sigma)`` (``GreyBoxGP.propagate``).
        lags : ndarray, shape (n_lags,)
            ``z(k+1)``.
        x : ndarray, shape (d,)
            The GP input at the state, for the envelope check.
        """
        points = self.propagation.points(state)  # (2n + 1, n)
        X = self.gp_inputs(points, commands, dt, lags)
        mean, var = self.gps.predict(X)
        moved = rk4_advance(points, commands, dt, self.params, max_step=self.max_step) + mean
        state, covariance = self.propagation.advance(moved, covariance, var)
        return state, covariance, self.advance_lags(lags, commands, dt), X[0]

    def describe(self) -> str:
        """One line for the log."""
        return json.dumps({"gp_inputs": list(self.input_names), **self.gps.describe(),
                           "command_lags_s": self.command_lags.tolist(), "max_step_s": self.max_step,
                           "propagation_step": self.propagation.step, "step_range_s": list(self.step_range())})
