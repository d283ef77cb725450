"""What every grey-box (RKGP) FMU runs: the residual GPs, the first-order propagation of the state
covariance, the variable table and the slave (docs/fmus.md, "Blimp RKGP" and "RGBlimp RKGP").
numpy, pythonfmu and the standard library only.

A grey-box FMU steps a :class:`gp_model.GreyBoxGP` (Ko et al., ICRA 2007, sec. IV-B): a physics
step plus GPs on its one-step residual. Its model (the blimp's,
:class:`fmu_src.blimp_rkgp.model.RKGPModel`; the RGBlimp's,
:class:`fmu_src.rgblimp_rkgp.model.RGBlimpRKGPModel`) supplies the physics and the GP inputs and
uses the pieces here for the rest, so that both reproduce ``GreyBoxGP.rollout`` (means) and
``GreyBoxGP.propagate`` (standard deviations) with the same formulas in the same order. Every
grey-box FMU (pythonfmu) carries a copy of this file (:mod:`fmu_src.fmi.pythonfmu`); the native
ones evaluate the same formulas in C (``greybox.c``).

Residual GPs (model-file arrays)
--------------------------------
One GP part ``p`` (one shared by all states, or one per state), arrays prefixed ``"<p>/"``
(:data:`PER_PART`), in standardised units: ``basis`` (m, d) training inputs, ``weights`` (m, q)
``alpha``, ``variance_factor`` (m, m) ``L^-1``, ``kernel_weights`` (d,) ``w`` of
``k = sigma_f^2 exp(-sum_i w_i (x_i - x'_i)^2)``, ``log_signal_variance`` (),
``log_noise_variance`` (), ``input_mean``, ``input_scale`` (d,), ``output_mean``,
``output_scale`` (q,); q = 12 for a shared part, 1 otherwise (:class:`ResidualGPs`).

Standard deviations
-------------------
The state's covariance ``P`` is propagated along the mean run to first order, as
``GreyBoxGP.propagate`` (with a known start, ``P(0) = 0``, and the GPs' noise included): with
``g(s) = physics(s, u) + E[residual | s, u]`` the one-step map and ``J = dg/ds`` by central
differences of step ``propagation_step`` in each of the n states (2 n + 1 evaluations of ``g``),

    P(k+1) = J P(k) J^T + diag(Sigma(k)),

``Sigma(k)`` the residual GPs' predictive variance at the mean, observation noise included
(Girard, Rasmussen, Quinonero-Candela & Murray-Smith, NIPS 2003, sec. 3: the first-order
Taylor approximation; the prediction step of an extended Kalman filter;
:class:`FirstOrderPropagation`). So a velocity's uncertainty integrates into position and the
standard deviations grow along a free run. It is a linearisation: the spread of sampled runs
(``GreyBoxGP.sample_rollouts``) may differ where the dynamics or the GP are far from linear over
the spread. Outside the training envelope ``Sigma`` grows toward the prior.
"""
from __future__ import annotations

import math

import numpy as np

from fmu_src.fmi.runtime import ModelFormatError, freeze, read_part
from fmu_src.fmi.slave import FlightgpSlave, Variable

#: Arrays per GP part and their number of dimensions (module docstring).
PER_PART = {"basis": 2, "weights": 2, "variance_factor": 2, "kernel_weights": 1,
            "log_signal_variance": 0, "log_noise_variance": 0, "input_mean": 1, "input_scale": 1,
            "output_mean": 1, "output_scale": 1}


def checked_state_columns(columns, n_states: int) -> np.ndarray:
    """A model file's ``state_columns`` (the states the GPs see) as distinct integer columns of
    an ``n_states`` state; ModelFormatError otherwise (a native FMU would read outside its state)."""
    columns = np.asarray(columns)
    if columns.ndim != 1 or not np.issubdtype(columns.dtype, np.integer) or len(set(columns.tolist())) != len(columns) \
            or (len(columns) and not (0 <= columns.min() and columns.max() < n_states)):
        raise ModelFormatError(f"state_columns {columns.tolist()} must be distinct columns 0..{n_states - 1}")
    return columns.astype(int)


def pack_gp_parts(parts) -> dict:
    """Arrays for ``numpy.savez`` of the GP parts ``parts`` (a list of dicts of :data:`PER_PART`
    arrays), part ``p``'s under ``"<p>/"``."""
    return {f"{p}/{name}": np.asarray(part[name], dtype=float) for p, part in enumerate(parts) for name in PER_PART}


class ResidualGPs:
    """The residual GPs of a grey-box FMU's model file (module docstring).

    Parameters
    ----------
    arrays : dict of str -> ndarray
        The model file's arrays, part ``p``'s under ``"<p>/"``.
    n_outputs : int
        The residuals (states) the parts map to, together.
    n_inputs : int
        The GP inputs, d.

    Attributes
    ----------
    parts : list of dict
        Each part's arrays (:data:`PER_PART`, plus ``signal_variance`` and ``noise_variance``),
        read-only.

    Raises
    ------
    fmu_src.fmi.runtime.ModelFormatError
        A part lacks an array or has one of another shape, or the parts do not map ``n_inputs``
        inputs to ``n_outputs`` residuals.
    """

    def __init__(self, arrays: dict, *, n_outputs: int, n_inputs: int) -> None:
        self.parts, p = [], 0
        while f"{p}/basis" in arrays:
            part = read_part(arrays, f"{p}/", PER_PART)
            part["signal_variance"] = np.array(np.exp(part["log_signal_variance"]))
            part["noise_variance"] = np.array(np.exp(part["log_noise_variance"]))
            freeze(part.values())
            self.parts.append(part)
            p += 1
        outputs = sum(part["weights"].shape[1] for part in self.parts)
        if outputs != n_outputs or any(part["basis"].shape[1] != n_inputs for part in self.parts):
            raise ModelFormatError(f"the GP parts must map {n_inputs} inputs to {n_outputs} residuals")

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Means of the residuals at the GP inputs ``X`` (r, d), shape (r, n_outputs), and their
        predictive variances at ``X[0]`` with the observation noise, shape (n_outputs,), as
        ``GaussianProcess.predict(return_var=True, include_noise=True)`` (Rasmussen & Williams
        2006, Alg. 2.1, lines 4-6; eq. 2.24 plus the noise variance)."""
        means, variances = [], []
        for part in self.parts:
            xs = (X - part["input_mean"]) / part["input_scale"]  # (r, d)
            # Kernel rows, fmu_src.fmi.runtime.kernel_rows for r inputs: (r, m).
            k = np.exp(part["log_signal_variance"] - ((xs[:, None, :] - part["basis"]) ** 2) @ part["kernel_weights"])
            mean = k @ part["weights"]  # (r, q)
            v = part["variance_factor"] @ k[0]
            spread = max(float(part["signal_variance"] - v @ v), 0.0) + float(part["noise_variance"])
            # The one-component mixture of GaussianProcess.predict, rounding included.
            var = np.maximum((spread + mean[0] ** 2) - mean[0] ** 2, 0.0)
            means.append(mean * part["output_scale"] + part["output_mean"])
            variances.append(var * part["output_scale"] ** 2)
        return np.hstack(means), np.concatenate(variances)

    def describe(self) -> dict:
        """The parts' structure, for the log."""
        return {"gp_parts": len(self.parts), "basis_points": int(self.parts[0]["basis"].shape[0])}


class FirstOrderPropagation:
    """One step of the mean and the first-order covariance of a grey-box free run (module
    docstring, "Standard deviations"), as ``GreyBoxGP.propagate``.

    Parameters
    ----------
    n_states : int
    step : float
        Central-difference step, state units (``gp_model.PROPAGATION_STEP``).
    """

    def __init__(self, n_states: int, step: float) -> None:
        if not (np.isfinite(step) and step > 0):
            raise ModelFormatError(f"propagation_step must be positive, got {step}")
        self.step = float(step)
        # The centre and the states moved by +/- the step, in GreyBoxGP.propagate's order (2n + 1, n).
        self.offsets = self.step * np.concatenate([np.zeros((1, n_states)), np.eye(n_states), -np.eye(n_states)])
        freeze((self.offsets,))

    def known_start(self) -> np.ndarray:
        """The covariance of a known start: zero, (n, n)."""
        return np.zeros((self.offsets.shape[1],) * 2)

    def points(self, state: np.ndarray) -> np.ndarray:
        """Where the one-step map is evaluated: ``state`` (n,) and its 2 n moved copies, (2n + 1, n)."""
        return state + self.offsets

    def advance(self, moved: np.ndarray, covariance: np.ndarray, variance: np.ndarray):
        """The next mean and covariance from the one-step map at :meth:`points`.

        Parameters
        ----------
        moved : ndarray, shape (2n + 1, n)
            ``g`` at each point.
        covariance : ndarray, shape (n, n)
            ``P(k)``.
        variance : ndarray, shape (n,)
            The residuals' predictive variances at the mean, noise included.

        Returns
        -------
        state : ndarray, shape (n,)
            ``moved[0]``.
        covariance : ndarray, shape (n, n)
            ``P(k+1) = J P(k) J^T + diag(variance)``.
        """
        n = moved.shape[1]
        jacobian = (moved[1:n + 1] - moved[n + 1:]).T / (2 * self.step)
        return moved[0], jacobian @ covariance @ jacobian.T + np.diag(variance)


#: What a grey-box FMU's state outputs and their standard deviations are, by default (RKGP).
MEAN_PHRASE = "RK4 physics plus GP residual mean (mean rollout)"
SD_PHRASE = ("propagated along the run from the known start (first order, GP noise included: "
             "GreyBoxGP.propagate; 0 at the start)")


def greybox_variables(*, inputs, states, start_default: str, mean_phrase: str = MEAN_PHRASE,
                      sd_phrase: str = SD_PHRASE) -> tuple:
    """The variable table of a grey-box FMU.

    Parameters
    ----------
    inputs : sequence of (name, unit, limit, phrase)
        The inputs: name, unit (a key of :data:`fmu_src.fmi.slave.UNITS`), largest magnitude, phrase.
    states : sequence of (name, unit, limit, phrase, start)
        The states, with the default start value.
    start_default : str
        What the default start state is, for the start parameters' descriptions.
    mean_phrase, sd_phrase : str
        What a state output is, and how its standard deviation is propagated.

    Returns
    -------
    tuple of Variable
        Inputs; states and their propagated standard deviations (outputs); each state's start
        value (fixed parameters ``<state>_start``).
    """
    limits = lambda limit: (None, None) if limit is None else (-limit, limit)  # noqa: E731
    table = [Variable(name, "input", "continuous", None, unit,
                      f"{phrase}, held from this communication point to the next", 0.0, *limits(limit))
             for name, unit, limit, phrase in inputs]
    table += [Variable(name, "output", "continuous", "exact", unit,
                       f"{phrase}: {mean_phrase}", start)
              for name, unit, _, phrase, start in states]
    table += [Variable(f"{name}_sd", "output", "continuous", "exact", unit,
                       f"standard deviation of the {phrase}, {sd_phrase}", 0.0)
              for name, unit, _, phrase, _ in states]
    table += [Variable(f"{name}_start", "parameter", "fixed", "exact", unit,
                       f"{phrase} at the start time (default: {start_default})", start, *limits(limit))
              for name, unit, limit, phrase, start in states]
    return tuple(table)


class GreyBoxSlave(FlightgpSlave):
    """The slave of every grey-box FMU: inputs held over each step, the states and their
    propagated standard deviations out, started from the ``<state>_start`` parameters with a
    known start (covariance 0).

    Class attributes a subclass sets
    --------------------------------
    STATE_NAMES, INPUT_NAMES : tuple of str
        The model's states (outputs) and inputs, in the model's order.
    MODEL : type
        The model, with ``load(path)`` (the FMU's model file, read-only), ``start_hidden()`` (the
        hidden state beyond mean and covariance at the start, an ndarray, e.g. lagged commands),
        ``start_covariance()`` (the covariance at the start, n x n or larger when the model
        propagates states beyond the outputs first; zero for a known start),
        ``step(state, covariance, hidden, inputs, h) -> (state, covariance, hidden, x)`` (x: the
        GP input at the state), ``envelope`` (:class:`fmu_src.fmi.runtime.Envelope` of the GP
        inputs) and ``describe()``.
    MODEL_PHRASE : str
        What the model is, for the log.
    ENVELOPE_CONSEQUENCE : str
        What happens outside the training envelope, for the warning.

    The mean state, its covariance (n x n), the hidden state and whether the GP input is outside
    the training envelope make up the FMU state. Envelope: when a GP input leaves the training
    range (by more than 10 % of the range), the FMU logs a Warning once per excursion; the GP then
    extrapolates, and the sd outputs grow faster.
    """

    STATE_NAMES: tuple = ()
    INPUT_NAMES: tuple = ()
    MODEL = None
    MODEL_PHRASE = "grey-box model"
    ENVELOPE_CONSEQUENCE = "its standard deviations grow"
    STATE_ATTRIBUTES = ("_state", "_covariance", "_hidden", "_outside_envelope")
    CONSTANT_ATTRIBUTES = ("_model",)

    def load_constants(self) -> None:
        self._model = self.shared_model(self.MODEL.load, self.model_file(), self.MODEL_PHRASE)

    def start_model(self) -> None:
        self._state = np.array([self.values[f"{name}_start"] for name in self.STATE_NAMES])
        self._covariance = self._model.start_covariance()
        self._hidden = self._model.start_hidden()
        self._outside_envelope = False
        self._set_outputs(self._state, self._covariance)

    def advance_model(self, t: float, h: float) -> None:
        inputs = np.array([self.values[name] for name in self.INPUT_NAMES])
        state, covariance, hidden, x = self._model.step(self._state, self._covariance, self._hidden, inputs, h)
        if not (np.isfinite(state).all() and np.isfinite(covariance).all()):
            raise FloatingPointError(f"non-finite state {state.tolist()} or covariance at t = {t + h:.16g} s")
        outside = self.report_envelope(self._model.envelope.outside(x), self._outside_envelope, t + h,
                                       self.ENVELOPE_CONSEQUENCE)
        # Commit only after everything that can fail (a refused step leaves the state as it was).
        self._state, self._covariance, self._hidden, self._outside_envelope = state, covariance, hidden, outside
        self._set_outputs(state, covariance)

    def _set_outputs(self, state: np.ndarray, covariance: np.ndarray) -> None:
        # PropagatedRollout.sd: the square root of the diagonal, negative rounding clipped.
        for name, value, variance in zip(self.STATE_NAMES, state.tolist(), np.diagonal(covariance).tolist()):
            self.values[name] = value
            self.values[f"{name}_sd"] = math.sqrt(max(variance, 0.0))
