"""The RGBlimp RKGP model inside the RGBlimp RKGP FMU: the identified RGBlimp model (Zhu, Cheng &
Zhang, IEEE RA-L 2024, with re-fitted coefficients) stepped by RK4 over one 1/60 s sample, plus
GPs on its one-step residual (:class:`gp_model.GreyBoxGP` with the physics ``rgblimp_rk4``,
:mod:`validation.models.rgblimp_greybox`), and the state covariance propagated along the run.
numpy and the standard library only.

Every RGBlimp RKGP FMU (pythonfmu) carries a copy of this file and of what it imports: the shared
FMU runtime (:mod:`fmu_src.fmi.runtime`), the grey-box FMUs' residual GPs and covariance
propagation (:mod:`fmu_src.fmi.greybox`), the RGBlimp's equations
(:mod:`validation.vehicles.rgblimp_equations`: ``advance``, the step of
:meth:`validation.models.rgblimp_identification.RGBlimpModel.step`) and the RKGP's continuous yaw
and parameter form (:mod:`validation.models.rgblimp_step`), under names unique to the FMU
(:mod:`fmu_src.fmi.pythonfmu`). So the FMU reproduces ``GreyBoxGP.propagate`` (means and
standard deviations) with :func:`validation.models.rgblimp_greybox.physics_step` to rounding
(tested to 1e-9). The native FMU evaluates the same formulas in C (``rgblimp_model.c``).

Model file (``model.npz``, written by :func:`pack_model`, read without pickle)
------------------------------------------------------------------------------
``format``, ``version``; ``physics``, the model file's physics description as JSON text
(:meth:`validation.models.rgblimp_greybox.RGBlimpStepDescription.as_dict`: every parameter of the
identified model, its thrust factor and wind); ``state_columns`` (the states the GP sees);
``propagation_step`` (the central-difference step of ``GreyBoxGP.propagate``, state units);
``gp_input_names`` (d,) and ``envelope_low``, ``envelope_high`` (d,) (names and training range
of the GP inputs ``[states[state_columns], thrust_left, thrust_right, gondola_x, gondola_y,
gondola_z]``); the GP parts, ``"<p>/<name>"`` (:mod:`fmu_src.fmi.greybox`, "Residual GPs").

Step
----
With ``u`` the inputs held over the sample and ``g(s) = f(s, u) + E[residual | s, u]``, ``f``
the identified model's RK4 step with yaw carried continuously
(:func:`validation.models.rgblimp_greybox.physics_step`), each step gives ``g`` at the mean and
the covariance ``P(k+1) = J P(k) J^T + diag(Sigma(k))`` (:mod:`fmu_src.fmi.greybox`, "Standard
deviations").
"""
from __future__ import annotations

import json

import numpy as np

from fmu_src.fmi.greybox import FirstOrderPropagation, ResidualGPs, checked_state_columns, pack_gp_parts
from fmu_src.fmi.runtime import Envelope, ModelFormatError, check_header, freeze, model_header, read_model_file
from validation.models.rgblimp_step import carry_yaw, parameters_from_dict
from validation.vehicles.rgblimp_equations import INPUT_NAMES, STATE_NAMES, advance

FORMAT = "flightgp-fmu-rgblimp-rkgp"
VERSION = 1


def pack_model(*, physics: dict, state_columns, propagation_step: float, gp_input_names, envelope_low,
               envelope_high, parts) -> dict:
    """Arrays for ``numpy.savez`` (module docstring).

    Parameters
    ----------
    physics : dict
        :meth:`validation.models.rgblimp_greybox.RGBlimpStepDescription.as_dict`.
    state_columns : sequence of int
        The state columns the GP sees.
    propagation_step : float
        Central-difference step of the covariance propagation, state units.
    gp_input_names : sequence of str, shape (d,)
        Names of the GP inputs, for messages.
    envelope_low, envelope_high : array_like, shape (d,)
        Training range of each GP input, physical units.
    parts : list of dict
        One dict of :data:`fmu_src.fmi.greybox.PER_PART` arrays per GP part.
    """
    arrays = {**model_header(FORMAT, VERSION), "physics": np.array(json.dumps(physics)),
              "state_columns": np.asarray(state_columns, dtype=np.int64),
              "propagation_step": np.array(float(propagation_step)),
              "gp_input_names": np.array(list(gp_input_names), dtype=str),
              "envelope_low": np.asarray(envelope_low, dtype=float),
              "envelope_high": np.asarray(envelope_high, dtype=float)}
    return {**arrays, **pack_gp_parts(parts)}


class RGBlimpRKGPModel:
    """An RGBlimp RKGP model loaded from an FMU model file (module docstring).

    Attributes
    ----------
    params : validation.vehicles.rgblimp_equations.RGBlimpParameters
        The identified model's parameters.
    thrust_gain : float
        Its factor on both thrusts.
    wind : ndarray, shape (2,)
        Its steady wind along earth x and y, m/s.
    state_columns : ndarray of int
        The state columns the GP sees.
    propagation : fmu_src.fmi.greybox.FirstOrderPropagation
        The covariance propagation and its central-difference step.
    gps : fmu_src.fmi.greybox.ResidualGPs
        The residual GPs (one shared part, or one per state).
    input_names : tuple of str
        The GP inputs: the seen states and the five inputs.
    envelope : fmu_src.fmi.runtime.Envelope
        Training range of each GP input.
    """

    def __init__(self, arrays: dict) -> None:
        check_header(arrays, format_name=FORMAT, version=VERSION)
        try:
            physics = json.loads(str(arrays["physics"]))
            self.params = parameters_from_dict(physics["parameters"])
            self.thrust_gain = float(physics["thrust_gain"])
            self.wind = np.array(physics["wind"], dtype=float)
            self.state_columns = checked_state_columns(arrays["state_columns"], len(STATE_NAMES))
            propagation_step = float(arrays["propagation_step"])
            self.input_names = tuple(str(name) for name in np.ravel(arrays["gp_input_names"]))
            envelope_low, envelope_high = arrays["envelope_low"], arrays["envelope_high"]
        except KeyError as error:
            raise ModelFormatError(f"the model file lacks {error}") from None
        except (TypeError, ValueError) as error:  # json.JSONDecodeError is a ValueError
            raise ModelFormatError(f"the model file's physics is unusable: {error}") from None
        if not (self.wind.shape == (2,) and np.isfinite(self.wind).all() and np.isfinite(self.thrust_gain)):
            raise ModelFormatError(f"thrust_gain {self.thrust_gain} and wind {self.wind.tolist()} must be finite, "
                                   "the wind two components")
        d = len(self.state_columns) + len(INPUT_NAMES)
        self.gps = ResidualGPs(arrays, n_outputs=len(STATE_NAMES), n_inputs=d)
        if np.shape(envelope_low) != (d,) or np.shape(envelope_high) != (d,) or len(self.input_names) != d:
            raise ModelFormatError(f"the GP parts must map {d} named inputs to {len(STATE_NAMES)} residuals")
        self.propagation = FirstOrderPropagation(len(STATE_NAMES), propagation_step)
        self.envelope = Envelope(envelope_low, envelope_high, self.input_names)
        freeze((self.wind, self.state_columns))

    @classmethod
    def load(cls, path) -> RGBlimpRKGPModel:
        """Read ``path`` (an ``.npz`` written from :func:`pack_model`; never unpickles)."""
        return cls(read_model_file(path))

    def start_hidden(self) -> np.ndarray:
        """No hidden state beyond the mean and its covariance: shape (0,)."""
        return np.zeros(0)

    def start_covariance(self) -> np.ndarray:
        """The start is known: covariance zero."""
        return self.propagation.known_start()

    def physics(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """The identified model's step of ``states`` (r, 12) under ``inputs`` (5,) held, yaw carried
        continuously (:func:`validation.models.rgblimp_greybox.physics_step`), shape (r, 12)."""
        held = np.broadcast_to(inputs, (len(states), len(inputs)))
        return carry_yaw(states, advance(states, held, self.params, thrust_gain=self.thrust_gain, wind=self.wind))

    def gp_inputs(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """The GP inputs (r, d) of ``states`` (r, 12) under ``inputs`` (5,): ``[states[:, state_columns],
        inputs]`` (``GreyBoxGP.gp_inputs``)."""
        return np.hstack([states[:, self.state_columns], np.broadcast_to(inputs, (len(states), len(inputs)))])

    def step(self, state: np.ndarray, covariance: np.ndarray, hidden: np.ndarray, inputs: np.ndarray, h: float):
        """One sample on under ``inputs`` (5,) held (module docstring, "Step").

        Parameters
        ----------
        state : ndarray, shape (12,)
            Mean state at ``t_k``.
        covariance : ndarray, shape (12, 12)
            Its covariance ``P(k)``.
        hidden : ndarray, shape (0,)
            :meth:`start_hidden`, passed through.
        inputs : ndarray, shape (5,)
        h : float
            The communication step, s: the sample time the FMU requires (its ``STEP_SIZE``), which
            the physics integrates over.

        Returns
        -------
        state : ndarray, shape (12,)
            ``f(s, u) + E[residual]`` (``GreyBoxGP.propagate``'s mean).
        covariance : ndarray, shape (12, 12)
            ``P(k+1) = J P(k) J^T + diag(Sigma)``.
        hidden : ndarray, shape (0,)
        x : ndarray, shape (d,)
            The GP input at the state, for the envelope check.
        """
        points = self.propagation.points(state)  # (2n + 1, n)
        X = self.gp_inputs(points, inputs)
        mean, var = self.gps.predict(X)
        moved = self.physics(points, inputs) + mean
        state, covariance = self.propagation.advance(moved, covariance, var)
        return state, covariance, hidden, X[0]

    def describe(self) -> str:
        """One line for the log."""
        return json.dumps({"gp_inputs": list(self.input_names), **self.gps.describe(),
                           "thrust_gain": self.thrust_gain, "wind_m_s": self.wind.tolist(),
                           "propagation_step": self.propagation.step})
