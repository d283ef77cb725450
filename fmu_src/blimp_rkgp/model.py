"""The blimp RKGP model inside the blimp RKGP FMU (Ko et al., ICRA 2007, sec. IV-B): the blimp
ODE integrated by RK4 plus a GP on its one-step residual (:class:`gp_model.GreyBoxGP` with the
physics ``blimp_rk4``). numpy and the standard library only.

Every blimp RKGP FMU (pythonfmu) carries a copy of this file and of what it imports, the shared
FMU runtime (:mod:`fmu_src.fmi.runtime`) and the blimp's equations of motion
(:mod:`validation.vehicles.blimp_equations`, the very functions
:func:`validation.models.blimp_identification.physics_step` steps with), under names unique to
the FMU (:mod:`fmu_src.fmi.pythonfmu`). So the FMU reproduces ``GreyBoxGP.rollout`` with that
physics to rounding (tested to 1e-9). The native FMU evaluates the same formulas in C
(``blimp_model.c``).

Model file (``model.npz``, written by :func:`pack_model`, read without pickle)
------------------------------------------------------------------------------
``format``, ``version``; ``parameter_names``, ``parameters`` (the
``BlimpParameters.to_vector`` the model was trained with), ``max_step`` (longest RK4 substep, s);
``state_columns`` (state columns the GP sees); ``envelope_low``, ``envelope_high`` (range of the
training GP inputs ``[states[state_columns], u_gondola, mu, u_tail, dt]``). Per GP part ``p``
(one for a shared GP, twelve for one GP per state), prefix ``"<p>/"``, in standardised units:
``basis`` (m, d) training inputs, ``weights`` (m, q) ``alpha``, ``variance_factor`` (m, m)
``L^-1``, ``kernel_weights`` (d,) ``w`` of ``k = sigma_f^2 exp(-sum_i w_i (x_i - x'_i)^2)``,
``log_signal_variance`` (), ``input_mean``, ``input_scale`` (d,), ``output_mean``,
``output_scale`` (q,); q = 12 for a shared part, 1 otherwise.

Standard deviations
-------------------
The one-step variance of a state is the GP's latent predictive variance of its residual at
``(s(t_k), u(t_k), h)``, i.e. the spread of ``s(t_{k+1})`` *given that* ``s(t_k)`` is exactly
the FMU's state at ``t_k`` (measurement noise not included; ``GreyBoxGP.predict_one_step`` with
``include_noise=False``). It is not the spread of a free run over many steps: that needs
propagating the state distribution through the dynamics (``GreyBoxGP.sample_rollouts``);
summing one-step variances would ignore that a velocity error integrates into position and that
residuals are correlated along a run, so it would be neither an upper nor a lower bound. The
one-step sd says how far the GP is from its data at this step: it grows toward the prior's
outside the training envelope.
"""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np

from fmu_src.fmi.runtime import (
    Envelope,
    ModelFormatError,
    check_header,
    freeze,
    kernel_rows,
    model_header,
    read_model_file,
    read_part,
)
from fmu_src.fmi.slave import TIME_TOLERANCE
from validation.vehicles.blimp_equations import INPUT_NAMES, STATE_NAMES, parameters_from_vector, rk4_advance

FORMAT = "flightgp-fmu-blimp-rkgp"
VERSION = 1
#: Arrays per GP part and their number of dimensions.
PER_PART = {"basis": 2, "weights": 2, "variance_factor": 2, "kernel_weights": 1,
            "log_signal_variance": 0, "input_mean": 1, "input_scale": 1, "output_mean": 1,
            "output_scale": 1}


def pack_model(*, parameter_names, parameters, max_step: float, state_columns, envelope_low,
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
    envelope_low, envelope_high : array_like, shape (d,)
        Training range of each GP input, physical units.
    parts : list of dict
        One dict of :data:`PER_PART` arrays per GP part.
    """
    arrays = {**model_header(FORMAT, VERSION),
              "parameter_names": np.array(list(parameter_names), dtype=str),
              "parameters": np.asarray(parameters, dtype=float), "max_step": np.array(float(max_step)),
              "state_columns": np.asarray(state_columns, dtype=np.int64),
              "envelope_low": np.asarray(envelope_low, dtype=float),
              "envelope_high": np.asarray(envelope_high, dtype=float)}
    for p, part in enumerate(parts):
        for name in PER_PART:
            arrays[f"{p}/{name}"] = np.asarray(part[name], dtype=float)
    return arrays


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
    parts : list of dict
        Each GP part's arrays (:data:`PER_PART`, plus ``signal_variance``).
    input_names : tuple of str
        The GP inputs: the seen states, the commands and ``dt``.
    envelope : fmu_src.fmi.runtime.Envelope
        Training range of each GP input.
    """

    def __init__(self, arrays: dict) -> None:
        check_header(arrays, format_name=FORMAT, version=VERSION)
        try:
            self.params = SimpleNamespace(**parameters_from_vector(arrays["parameter_names"], arrays["parameters"]))
            self.max_step = float(arrays["max_step"])
            self.state_columns = np.asarray(arrays["state_columns"], dtype=int)
            envelope_low, envelope_high = arrays["envelope_low"], arrays["envelope_high"]
        except KeyError as error:
            raise ModelFormatError(f"the model file lacks the array {error}") from None
        self.parts, p = [], 0
        while f"{p}/basis" in arrays:
            part = read_part(arrays, f"{p}/", PER_PART)
            part["signal_variance"] = np.array(np.exp(part["log_signal_variance"]))
            freeze(part.values())
            self.parts.append(part)
            p += 1
        d = len(self.state_columns) + len(INPUT_NAMES) + 1
        outputs = sum(part["weights"].shape[1] for part in self.parts)
        if (outputs != len(STATE_NAMES) or np.shape(envelope_low) != (d,) or np.shape(envelope_high) != (d,)
                or any(part["basis"].shape[1] != d for part in self.parts)):
            raise ModelFormatError(f"the GP parts must map {d} inputs to {len(STATE_NAMES)} residuals")
        if not self.max_step > 0:
            raise ModelFormatError(f"max_step must be positive, got {self.max_step}")
        self.input_names = tuple(STATE_NAMES[c] for c in self.state_columns) + INPUT_NAMES + ("dt",)
        self.envelope = Envelope(envelope_low, envelope_high, self.input_names)

    @classmethod
    def load(cls, path) -> RKGPModel:
        """Read ``path`` (an ``.npz`` written from :func:`pack_model`; never unpickles)."""
        return cls(read_model_file(path))

    def step_range(self) -> tuple[float, float]:
        """Communication steps (s) the model accepts: the training range of ``dt`` plus the
        envelope margin and the FMI layer's time tolerance (evenly sampled training data has one
        ``dt``, up to rounding)."""
        slack = TIME_TOLERANCE * float(self.envelope.high[-1])
        return float(self.envelope.lower[-1]) - slack, float(self.envelope.upper[-1]) + slack

    def gp_input(self, state: np.ndarray, commands: np.ndarray, dt: float) -> np.ndarray:
        """The GP input (d,): the seen states of ``state`` (12,), ``commands`` (3,) and ``dt``, s."""
        return np.concatenate([state[self.state_columns], commands, [dt]])

    def residual(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Latent mean and variance of the 12 residuals at GP input ``x`` (d,), as
        ``GaussianProcess.predict(return_var=True)`` (Rasmussen & Williams 2006, Alg. 2.1,
        lines 4-6)."""
        means, variances = [], []
        for part in self.parts:
            xs = (x - part["input_mean"]) / part["input_scale"]
            k = kernel_rows(xs, part["basis"], part["kernel_weights"][None], part["log_signal_variance"][None])[0]
            mean = k @ part["weights"]  # (q,)
            v = part["variance_factor"] @ k
            latent = max(float(part["signal_variance"] - v @ v), 0.0)
            # The one-component mixture of GaussianProcess.predict, rounding included.
            var = np.maximum((latent + mean**2) - mean**2, 0.0)
            means.append(mean * part["output_scale"] + part["output_mean"])
            variances.append(var * part["output_scale"] ** 2)
        return np.concatenate(means), np.concatenate(variances)

    def step(self, state: np.ndarray, commands: np.ndarray, dt: float):
        """The next state (12,), mean: RK4 physics over ``dt`` s in substeps no longer than
        ``max_step`` plus the GP residual mean; the residual variance (12,); the GP input (d,)."""
        x = self.gp_input(state, commands, dt)
        mean, var = self.residual(x)
        return rk4_advance(state, commands, dt, self.params, max_step=self.max_step) + mean, var, x

    def describe(self) -> str:
        """One line for the log."""
        return json.dumps({"gp_inputs": list(self.input_names), "gp_parts": len(self.parts),
                           "basis_points": int(self.parts[0]["basis"].shape[0]),
                           "max_step_s": self.max_step, "step_range_s": list(self.step_range())})
