"""A SINDYc peer for the RGBlimp: the published model plus a sparse polynomial of the residual
accelerations, fitted with PySINDy.

Zhu, Cheng & Zhang (IEEE RA-L 2024, sec. V) compare their neural ODEs with SINDYc (Brunton,
Proctor & Kutz, IFAC-PapersOnLine 49(18), 2016: sparse identification of nonlinear dynamics with
control). Here it is the peer of the RKGP in :mod:`validation.reproduce.rgblimp`, built the same
way on the same fitting flights:

- **target**: the residual body accelerations, the recorded ones (the files' ``vb_dot_*``,
  ``wb_dot_*``) minus the published model's at the recorded state and input
  (:func:`validation.vehicles.rgblimp_equations.body_accelerations`), shape (n, 6);
- **features**: the states the RKGP's GPs see (:data:`validation.models.rgblimp_greybox.GP_STATE_COLUMNS`:
  no position, no yaw) and the five inputs, a polynomial library of degree :data:`DEGREE`;
- **regression**: PySINDy's ``PolynomialLibrary`` and sequentially thresholded least squares
  (``STLSQ``) with threshold :data:`THRESHOLD` (chosen on validation flights) and PySINDy's
  default ridge weight, on the raw features (SINDYc's derivative is the physics' plus this regression, so
  PySINDy's ``SINDy`` model, which regresses a state's own derivative, is not used whole);
- **free run**: one RK4 step per 1/60 s sample, as the source integrates, of the published
  model's derivative with the polynomial added to its accelerations (:meth:`SINDYcResidual.simulate`).

PySINDy is a test extra (``pip install -e '.[test]'``); :func:`fit_sindyc` names it when it is
missing.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from validation.core.errors import BadInputError
from validation.models.rgblimp_greybox import GP_STATE_COLUMNS
from validation.vehicles.blimp_equations import rk4
from validation.vehicles.rgblimp_equations import (
    SAMPLE_TIME,
    RGBlimpParameters,
    body_accelerations,
    rgblimp_dynamics,
    wrap_heading,
)

#: Degree of the polynomial library (PySINDy's ``PolynomialLibrary`` default).
DEGREE = 2
#: STLSQ threshold on the coefficients: chosen on validation flights (fit on ``4j+1``, free run
#: of ``4j+2`` for configurations 0, 7, 12 and 31) among 0.01, 0.1 (PySINDy's default) and 1,
#: with raw and with normalised columns; every other choice diverged on every flight
#: (docs/rgblimp.md, "Identification and RKGP").
THRESHOLD = 1.0
#: At most this many fitting samples, evenly spread (the regression is linear, so many more than
#: the library's 105 features add little).
MAX_SAMPLES = 20000


@dataclass
class SINDYcResidual:
    """The published model plus a fitted sparse residual.

    Attributes
    ----------
    library : pysindy.PolynomialLibrary
        Fitted on the 13 features (8 states, 5 inputs).
    powers : ndarray of int, shape (n_library, 13)
        The exponents of each of its monomials (``library.powers_``).
    coefficients : ndarray, shape (6, n_library)
        STLSQ's coefficients of the residual accelerations.
    params : RGBlimpParameters
        The physics the residual is added to.
    n_terms : int
        Non-zero coefficients over the six outputs.
    fit_seconds : float
    """

    library: object
    coefficients: np.ndarray
    powers: np.ndarray
    params: RGBlimpParameters
    n_terms: int
    fit_seconds: float

    def residual(self, states, inputs) -> np.ndarray:
        """Residual accelerations (n, 6) at ``states`` (n, 12), ``inputs`` (n, 5)."""
        states, inputs = np.atleast_2d(states), np.atleast_2d(inputs)
        variables = np.hstack([states[:, GP_STATE_COLUMNS], inputs])
        # The library's monomials from its exponents (``powers_``, in its column order): the
        # library's own transform costs a millisecond a call, four calls per free-run step.
        features = np.prod(variables[:, None, :] ** self.powers[None], axis=2)
        return features @ self.coefficients.T

    def derivative(self, states, inputs) -> np.ndarray:
        """The published model's state derivative plus the residual on its accelerations (n, 12)."""
        derivative = rgblimp_dynamics(states, inputs, self.params)
        return np.concatenate([derivative[..., :6], derivative[..., 6:] + self.residual(states, inputs)], axis=-1)

    def simulate(self, initial_state, inputs) -> np.ndarray:
        """Free run from ``initial_state`` (12,) through ``inputs`` (n, 5), one RK4 step per sample
        and the yaw wrapped, as the source: states (n, 12), row 0 the start; NaN from the first
        sample where the run left the finite numbers (a polynomial residual can diverge)."""
        state = np.asarray(initial_state, dtype=float)[None]
        path = [state[0]]
        with np.errstate(over="ignore", invalid="ignore"):  # divergence is detected below
            for command in np.asarray(inputs, dtype=float)[:-1]:
                state = wrap_heading(rk4(lambda s, u=command[None]: self.derivative(s, u), state, SAMPLE_TIME))
                if not np.all(np.isfinite(state)):  # a polynomial can diverge: the run ends there
                    path.extend([np.full(12, np.nan)] * (len(inputs) - len(path)))
                    break
                path.append(state[0])
        return np.array(path)


def residual_targets(flights, params: RGBlimpParameters) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Features' states (m, 8), inputs (m, 5) and residual accelerations (m, 6) of the flights,
    at most :data:`MAX_SAMPLES` samples evenly spread."""
    states = np.vstack([f.recording.outputs for f in flights])
    inputs = np.vstack([f.recording.inputs for f in flights])
    measured = np.vstack([f.measured_accelerations for f in flights])
    rows = np.linspace(0, len(states) - 1, min(len(states), MAX_SAMPLES)).round().astype(int)
    residual = measured[rows] - body_accelerations(states[rows], inputs[rows], params)
    return states[rows][:, GP_STATE_COLUMNS], inputs[rows], residual


def require_pysindy():
    """The ``pysindy`` module.

    Raises
    ------
    BadInputError
        It is not installed.
    """
    try:
        import pysindy
    except ImportError:
        raise BadInputError("the SINDYc peer needs PySINDy: pip install pysindy (a test extra of flightgp)") from None
    return pysindy


def fit_sindyc(flights, *, params: RGBlimpParameters | None = None, degree: int = DEGREE,
               threshold: float = THRESHOLD) -> SINDYcResidual:
    """Fit the sparse residual on ``flights`` (module docstring).

    Parameters
    ----------
    flights : sequence of RGBlimpFlight
    params : RGBlimpParameters, optional
        Default the published values.
    degree : int
    threshold : float

    Raises
    ------
    BadInputError
        PySINDy is not installed.
    """
    pysindy = require_pysindy()
    params = RGBlimpParameters() if params is None else params
    started = time.perf_counter()
    states, inputs, residual = residual_targets(flights, params)
    library = pysindy.PolynomialLibrary(degree=degree)
    features = np.asarray(library.fit_transform(np.hstack([states, inputs])))
    with warnings.catch_warnings():  # an output with no term left is a result, not a fault
        warnings.filterwarnings("ignore", message="Sparsity parameter is too big")
        coefficients = np.atleast_2d(pysindy.STLSQ(threshold=threshold).fit(features, residual).coef_)
    return SINDYcResidual(library, coefficients, np.asarray(library.powers_), params,
                          int(np.count_nonzero(coefficients)), time.perf_counter() - started)
