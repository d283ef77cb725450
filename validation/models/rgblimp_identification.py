"""Identify the RGBlimp's uncertain coefficients from its recorded flights by output error.

On the real flights the first-principle model of Zhu, Cheng & Zhang (IEEE RA-L 2024, arXiv
2404.18580; :mod:`validation.vehicles.rgblimp_equations`) flies too fast and climbs
(docs/rgblimp.md). Here a few of its coefficients are re-fitted to recorded flights by output
error, as Ko et al. (ICRA 2007, sec. III-B) identified their blimp ("minimizing the point-wise
differences between simulated and recorded states") and as
:mod:`validation.models.blimp_identification` does for flightgp's blimp: the flights are cut into
segments of :data:`SEGMENT_DURATION`; every segment is simulated from its recorded first state by
the source's integrator (one RK4 step per 1/60 s sample,
:func:`validation.vehicles.rgblimp_equations.rk4_step`) with the recorded inputs; the residuals
are the differences to the recorded states at every sample, each state column divided by a scale
(:data:`STATE_SCALE`), the yaw difference wrapped; ``scipy.optimize.least_squares``
(trust-region reflective) minimises their sum of squares. The recorded states are smooth (the
source's motion capture is filtered: second differences of the positions are 8e-5 m), so the
segments start at the recorded states rather than at free start states.

Which coefficients (:data:`IDENTIFIED_PARAMETERS`): each flight holds its inputs constant
(docs/rgblimp.md, "The recordings"), so a flight shows a launch transient and then one steady
spiral; a small set is identifiable from it, about one coefficient for each thing the steady
spiral shows:

- ``thrust_gain``: a factor on both propellers' thrusts; with ``c_d0`` it sets the speed;
- ``buoyancy_mass``: the buoyancy, so the sink or climb rate (which differs between repeats of
  one configuration);
- ``c_d0``, ``c_l0``: drag and lift at zero angle of attack;
- ``c_my0``: the pitching moment, so the pitch trim;
- ``c_mx0``: the rolling moment, so the bank in the turn;
- ``rate_damping_z``: yaw damping, so the turn rate the thrust difference gives;
- ``wind_x``, ``wind_y``: a steady horizontal air motion in the room (the air's velocity along
  the motion capture's x and y axes, m/s) (:func:`validation.vehicles.rgblimp_equations.advance`). The
  recorded spirals drift (their centres move by about 1 m a minute) and the recorded ground
  speed oscillates once per turn, as a circle flown in moving air does (what the two components
  change on the validation flights: docs/rgblimp.md, "Identification and RKGP").

Uncertainty: the covariance of the estimate is the cluster-robust sandwich ``A^-1 B A^-1`` with
``A = J^T J`` and ``B`` the sum over segments of ``(J_s^T r_s)(J_s^T r_s)^T``, times ``S / (S - 1)``
for S segments (Liang & Zeger 1986): residuals within a segment are strongly correlated, segments
nearly independent (:func:`validation.models.blimp_identification.cluster_robust_covariance`
computes it for both identifications). It needs more segments than coefficients (and is
rough with few more: a configuration's two flights give 2 to 25 segments for nine
coefficients); with no more it is reported as unknown.

Speed: the segments are simulated together, vectorised
(:func:`validation.vehicles.rgblimp_equations.free_run`), and the Jacobian's
forward differences perturb every coefficient at once, as one batch of parameter sets
(:func:`batched_parameters`) evaluated with the residuals, which costs about 1.3 times one
residual evaluation; a fit on two flights takes about 5 s.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from scipy.optimize import least_squares

from validation.core.errors import BadInputError, check_count
from validation.core.metrics import robust_sd
from validation.models.blimp_identification import cluster_robust_covariance
from validation.vehicles.rgblimp_equations import (
    SAMPLE_TIME,
    STATE_NAMES,
    RGBlimpParameters,
    advance,
    free_run,
)

#: The coefficients identified by default (module docstring).
IDENTIFIED_PARAMETERS = ("thrust_gain", "buoyancy_mass", "c_d0", "c_l0", "c_my0", "c_mx0", "rate_damping_z",
                         "wind_x", "wind_y")
#: Segment length, s: long enough for the spiral's speed, turn and sink rate to show in the
#: positions, short enough for the free runs to stay near the recording (against 3 and 12 s on
#: the validation flights, docs/rgblimp.md, "Identification and RKGP").
SEGMENT_DURATION = 6.0
#: At most this many segments per fit, evenly spread over the flights (the cost is linear in it).
MAX_SEGMENTS = 60
#: Divisor of each state's residual: 5 cm, 0.02 rad, 2 cm/s, 0.02 rad/s, so that position,
#: attitude, velocity and rate errors of a few-second free run count about alike (not tuned).
STATE_SCALE = (0.05,) * 3 + (0.02,) * 3 + (0.02,) * 3 + (0.02,) * 3
#: Unit of each scaled optimisation variable for coefficients whose published value is zero or
#: tiny: the variable is ``(theta - theta0) / max(|theta0|, this)``.
_MIN_PARAMETER_SCALE = 0.01
#: Most residual evaluations of one fit (scipy's ``max_nfev``; each also gives the Jacobian).
MAX_ITERATIONS = 30
#: Relative tolerance on the cost and the step (scipy's ftol and xtol): far below the
#: coefficients' standard errors.
_TOLERANCE = 1e-6
#: Relative step of the Jacobian's forward differences (in the scaled variable).
_DIFFERENCE_STEP = 1e-6
#: A configuration's coefficients' prior standard deviation about the vehicle's, in units of
#: their spread between configurations (:func:`identify_configurations`), chosen on validation
#: flights (docs/rgblimp.md, "Configurations drawn toward the vehicle").
SHRINKAGE = 0.25
_YAW = STATE_NAMES.index("psi")
_DAMPING_AXES = {"rate_damping_x": 0, "rate_damping_y": 1, "rate_damping_z": 2}
_WIND_AXES = {"wind_x": 0, "wind_y": 1}
_COEFFICIENTS = tuple(f.name for f in dataclasses.fields(RGBlimpParameters) if f.name.startswith("c_"))
_PARAMETER_FIELDS = ("buoyancy_mass", *_COEFFICIENTS)
#: Every name :func:`identify_parameters` accepts.
IDENTIFIABLE = ("thrust_gain", *_WIND_AXES, *_PARAMETER_FIELDS, *_DAMPING_AXES)


@dataclass(frozen=True)
class RGBlimpModel:
    """The first-principle model with a factor on the thrusts and a steady wind.

    Attributes
    ----------
    params : RGBlimpParameters
        Default: the source's published values.
    thrust_gain : float
        Multiplies ``thrust_left`` and ``thrust_right`` (1: the recorded thrusts).
    wind : (2,) tuple of float
        The air's velocity along the earth x and y axes, m/s (:func:`validation.vehicles.rgblimp_equations.advance`).
    """

    def __post_init__(self):
        if not (np.isfinite(self.thrust_gain) and np.all(np.isfinite(self.wind)) and len(self.wind) == 2):
            raise BadInputError(f"RGBlimpModel needs a finite thrust gain and two finite wind components, got "
                                f"{self.thrust_gain!r} and {self.wind!r}")

    params: RGBlimpParameters = dataclasses.field(default_factory=RGBlimpParameters)
    thrust_gain: float = 1.0
    wind: tuple = (0.0, 0.0)

    def value(self, name: str) -> float:
        """One coefficient of :data:`IDENTIFIABLE`."""
        _check_names([name])
        if name == "thrust_gain":
            return float(self.thrust_gain)
        if name in _WIND_AXES:
            return float(self.wind[_WIND_AXES[name]])
        if name in _DAMPING_AXES:
            return float(self.params.rate_damping[_DAMPING_AXES[name]])
        return float(getattr(self.params, name))

    def replaced(self, values: dict) -> RGBlimpModel:
        """This model with some coefficients of :data:`IDENTIFIABLE` replaced."""
        _check_names(list(values))
        fields = {n: float(v) for n, v in values.items() if n in _PARAMETER_FIELDS}
        damping = list(self.params.rate_damping)
        for name, axis in _DAMPING_AXES.items():
            if name in values:
                damping[axis] = float(values[name])
        wind = tuple(float(values.get(name, self.wind[axis])) for name, axis in _WIND_AXES.items())
        params = dataclasses.replace(self.params, rate_damping=tuple(damping), **fields)
        return RGBlimpModel(params, float(values.get("thrust_gain", self.thrust_gain)), wind)

    def step(self, states, inputs) -> np.ndarray:
        """One sample (1/60 s) on (:func:`validation.vehicles.rgblimp_equations.advance`):
        ``states`` (..., 12), ``inputs`` (..., 5) -> (..., 12). This is a :class:`gp_model.GreyBoxGP`
        ``physics_step``."""
        return advance(states, inputs, self.params, thrust_gain=self.thrust_gain, wind=self.wind)

    def simulate(self, initial_state, inputs) -> np.ndarray:
        """Free run from ``initial_state`` (..., 12) through ``inputs`` (..., n, 5), each held
        over one sample (:func:`validation.vehicles.rgblimp_equations.free_run`): states
        (..., n, 12), the first the start
        (``inputs[..., -1, :]`` is not used)."""
        return free_run(initial_state, inputs, self.params, thrust_gain=self.thrust_gain, wind=self.wind)


def wrapped_difference(predicted, recorded) -> np.ndarray:
    """``predicted - recorded`` (..., 12) with the yaw difference wrapped into [-pi, pi)."""
    difference = np.asarray(predicted, dtype=float) - np.asarray(recorded, dtype=float)
    difference[..., _YAW] = (difference[..., _YAW] + np.pi) % (2 * np.pi) - np.pi
    return difference


def _check_names(names) -> None:
    unknown = [n for n in names if n not in IDENTIFIABLE]
    if unknown or len(set(names)) != len(names):
        raise BadInputError(f"unknown or repeated RGBlimp coefficient name(s) {list(names)}; choose from "
                            f"{', '.join(IDENTIFIABLE)}")


def batched_parameters(model: RGBlimpModel, names, vectors) -> tuple[SimpleNamespace, np.ndarray, np.ndarray]:
    """B variants of ``model`` at once, for states of shape (B, S, 12).

    :mod:`validation.vehicles.rgblimp_equations` broadcasts its parameters against the states:
    an aerodynamic coefficient multiplies arrays of shape (B, S) (angle of attack, sideslip), the
    buoyancy a (B, S, 3) direction and the rate damping (B, S, 3) rates. So a namespace with the
    identified coefficients as arrays of shapes (B, 1), (B, 1, 1) and (B, 1, 3) evaluates the B
    parameter sets in one call (tested against one call per set).

    Parameters
    ----------
    model : RGBlimpModel
        The values of every coefficient not in ``names``.
    names : sequence of str
        Coefficients of :data:`IDENTIFIABLE`.
    vectors : ndarray, shape (B, len(names))

    Returns
    -------
    params : SimpleNamespace
        The fields of :class:`RGBlimpParameters`, batched where identified.
    thrust_gain : ndarray, shape (B, 1)
    wind : ndarray, shape (B, 1, 2)
        For :func:`advance` of states (B, S, 12) and inputs (B, S, 5).
    """
    _check_names(names)
    vectors = np.atleast_2d(np.asarray(vectors, dtype=float))
    fields = {f.name: getattr(model.params, f.name) for f in dataclasses.fields(RGBlimpParameters)}
    damping = np.tile(np.asarray(model.params.rate_damping), (len(vectors), 1))
    gain = np.full(len(vectors), float(model.thrust_gain))
    wind = np.tile(np.asarray(model.wind), (len(vectors), 1))
    for column, name in enumerate(names):
        values = vectors[:, column]
        if name == "thrust_gain":
            gain = values
        elif name in _WIND_AXES:
            wind[:, _WIND_AXES[name]] = values
        elif name in _DAMPING_AXES:
            damping[:, _DAMPING_AXES[name]] = values
        elif name == "buoyancy_mass":
            fields[name] = values[:, None, None]
        else:
            fields[name] = values[:, None]
    fields["rate_damping"] = damping[:, None, :]
    return SimpleNamespace(**fields), gain[:, None], wind[:, None, :]


@dataclass(frozen=True)
class Segments:
    """Pieces of recorded flights to simulate from their first recorded state.

    Attributes
    ----------
    starts : ndarray, shape (S, 12)
    inputs : ndarray, shape (S, L, 5)
        ``inputs[:, k]`` held from sample k to k + 1 of each segment.
    targets : ndarray, shape (S, L, 12)
        Recorded states at samples 1 .. L of each segment.
    mask : ndarray of bool, shape (S, L)
        False past the end of a flight shorter than a segment (its last input and state repeat
        there and count for nothing).
    flights : ndarray of int, shape (S,)
        The flight number each segment comes from.
    """

    starts: np.ndarray
    inputs: np.ndarray
    targets: np.ndarray
    mask: np.ndarray
    flights: np.ndarray


def cut_segments(flights, *, duration: float = SEGMENT_DURATION, max_segments: int = MAX_SEGMENTS) -> Segments:
    """Non-overlapping segments of ``duration`` covering each flight, about ``max_segments`` in all.

    A flight's last segment, and the only one of a flight shorter than ``duration`` (the straight
    flights last 6 to 9 s), is masked past the flight's end.

    Parameters
    ----------
    flights : sequence of RGBlimpFlight
        :func:`validation.vehicles.rgblimp_data.read_rgblimp_flight`.
    duration : float
        Segment length, s (rounded to whole samples of 1/60 s).
    max_segments : int
        When the flights hold more, each flight keeps its share of them (in proportion to its
        segments, evenly over its time, at least one: no flight is left out), so the total may
        exceed it by about one per flight.

    Raises
    ------
    BadInputError
        No flights, a duration that is not a positive number, ``max_segments < 1``.
    """
    if not (np.isfinite(duration) and duration > 0):
        raise BadInputError(f"segment duration must be a positive number of seconds, got {duration}")
    if max_segments < 1:
        raise BadInputError(f"max_segments must be at least 1, got {max_segments}")
    if not flights:
        raise BadInputError("no flights to identify from")
    length = max(1, int(round(duration / SAMPLE_TIME)))
    firsts = [np.arange(0, max(len(f.recording.outputs) - 1, 1), length) for f in flights]
    total = sum(len(first) for first in firsts)
    starts, inputs, targets, masks, numbers = [], [], [], [], []
    for flight, first in zip(flights, firsts):
        if total > max_segments:
            share = max(1, int(round(max_segments * len(first) / total)))
            first = first[np.unique(np.round(np.linspace(0, len(first) - 1, share)).astype(int))]
        states, commands = flight.recording.outputs, flight.recording.inputs
        steps = first[:, None] + np.arange(length)
        last = len(states) - 2  # the last step that has a recorded next state
        starts.append(states[first])
        inputs.append(commands[np.minimum(steps, last)])
        targets.append(states[np.minimum(steps, last) + 1])
        masks.append(steps <= last)
        numbers.append(np.full(len(first), flight.number))
    return Segments(*(np.concatenate(part) for part in (starts, inputs, targets, masks, numbers)))


def simulate_segments(model: RGBlimpModel, segments: Segments) -> np.ndarray:
    """Each segment's free run of ``model``: (S, L, 12), the states at samples 1 .. L."""
    inputs = np.concatenate([segments.inputs, segments.inputs[:, -1:]], axis=1)
    return model.simulate(segments.starts, inputs)[:, 1:]


@dataclass
class IdentificationResult:
    """Identified coefficients with their uncertainty.

    Attributes
    ----------
    model : RGBlimpModel
        ``initial`` with the identified coefficients replaced.
    names : tuple of str
    values, standard_errors, standard_errors_iid, initial_values : ndarray, shape (p,)
        Estimates, cluster-robust and textbook (``s^2 (J^T J)^-1``) standard errors, starting
        values (which are also the prior's means). The cluster-robust ones are NaN with no more
        segments than coefficients (the textbook ones then understate the uncertainty: the
        residuals within a segment are correlated).
    covariance : ndarray, shape (p, p)
        Cluster-robust covariance of ``values`` (NaN as the standard errors).
    rms_residual, initial_rms_residual : float
        Root mean square of the scaled state residuals at the optimum and at the start.
    n_segments, n_evaluations : int
    converged : bool
        Whether ``least_squares`` met its tolerances (False: it stopped at ``max_iterations``
        function evaluations).
    flights : tuple of int
        The flight numbers identified on.
    seconds : float
        Wall time of the fit.
    """

    model: RGBlimpModel
    names: tuple
    values: np.ndarray
    standard_errors: np.ndarray
    standard_errors_iid: np.ndarray
    initial_values: np.ndarray
    covariance: np.ndarray
    rms_residual: float
    initial_rms_residual: float
    n_segments: int
    n_evaluations: int
    converged: bool
    flights: tuple
    seconds: float

    def as_dict(self) -> dict:
        """JSON-ready: per coefficient its value, standard errors (null where not available) and
        starting value, and the fit."""
        def number(value):
            return float(value) if np.isfinite(value) else None

        return {"parameters": {name: {"value": float(v), "standard_error": number(se),
                                      "standard_error_iid": number(se_iid), "initial": float(v0)}
                               for name, v, se, se_iid, v0 in zip(self.names, self.values, self.standard_errors,
                                                                  self.standard_errors_iid, self.initial_values)},
                "rms_scaled_residual": self.rms_residual, "initial_rms_scaled_residual": self.initial_rms_residual,
                "n_segments": self.n_segments, "n_evaluations": self.n_evaluations, "converged": self.converged,
                "flights": list(self.flights), "seconds": self.seconds}


def identify_parameters(flights, *, names=IDENTIFIED_PARAMETERS, initial: RGBlimpModel | None = None,
                        prior_sd=None, segment_duration: float = SEGMENT_DURATION,
                        max_segments: int = MAX_SEGMENTS, state_scale=STATE_SCALE,
                        max_iterations: int = MAX_ITERATIONS) -> IdentificationResult:
    """Least-squares output-error fit of RGBlimp coefficients to segments of recorded flights.

    Minimises ``sum_s |r_s|^2 / L + sum_i ((theta_i - theta0_i) / sd_i)^2``: each segment's
    scaled state residuals ``r_s`` (its L samples' residuals are strongly correlated, so a
    segment counts about as one observation of the 12 states) and a Gaussian prior about the
    starting values ``theta0``, which makes the estimate the maximum a posteriori one and keeps
    coefficients that a short flight hardly shows near their starting values.

    Parameters
    ----------
    flights : sequence of RGBlimpFlight
    names : sequence of str
        Coefficients of :data:`IDENTIFIABLE` to fit; the rest stay at ``initial``.
    initial : RGBlimpModel, optional
        Starting point, prior mean and fixed values; default the published model.
    prior_sd : dict, optional
        Prior standard deviation of each coefficient in ``names`` about its starting value;
        default none (least squares alone).
    segment_duration : float
        s, :data:`SEGMENT_DURATION`.
    max_segments : int
        :data:`MAX_SEGMENTS`.
    state_scale : sequence of float, shape (12,)
        Divides each state's residual (:data:`STATE_SCALE`).
    max_iterations : int
        Most trust-region iterations (:data:`MAX_ITERATIONS`).

    Returns
    -------
    IdentificationResult
    """
    started = time.perf_counter()
    names = tuple(names)
    _check_names(names)
    if not names:
        raise BadInputError("no coefficient to identify")
    check_count(max_iterations, "max_iterations")
    initial = RGBlimpModel() if initial is None else initial
    scale = np.asarray(state_scale, dtype=float)
    if scale.shape != (12,) or not np.all(scale > 0):
        raise BadInputError(f"state_scale must be 12 positive numbers, got {state_scale}")
    segments = cut_segments(flights, duration=segment_duration, max_segments=max_segments)
    base = np.array([initial.value(n) for n in names])
    units = np.maximum(np.abs(base), _MIN_PARAMETER_SCALE)
    if prior_sd is None:
        prior_weight = np.zeros(len(names))
    else:
        missing = [n for n in names if n not in prior_sd]
        if missing:
            raise BadInputError(f"prior_sd has no standard deviation for {', '.join(missing)}")
        sds = np.array([float(prior_sd[n]) for n in names])
        if not np.all(np.isfinite(sds) & (sds > 0)):
            raise BadInputError(f"prior standard deviations must be positive numbers, got {dict(zip(names, sds))}")
        prior_weight = units / sds
    n_segments, length = segments.inputs.shape[:2]
    inputs = np.concatenate([segments.inputs, segments.inputs[:, -1:]], axis=1)
    weight = segments.mask[..., None] / (scale * np.sqrt(length))  # (S, L, 12)

    def batch_residuals(xs: np.ndarray) -> np.ndarray:
        """Weighted residuals of B parameter points ``xs`` (B, p) at once: (B, S * L * 12 + p)."""
        params, gain, wind = batched_parameters(initial, names, base + units * xs)
        batch = len(xs)
        starts = np.broadcast_to(segments.starts, (batch, *segments.starts.shape))
        batch_inputs = np.broadcast_to(inputs, (batch, *inputs.shape))
        path = free_run(starts, batch_inputs, params, thrust_gain=gain, wind=wind)
        data = wrapped_difference(path[:, :, 1:], segments.targets[None]) * weight
        return np.concatenate([data.reshape(batch, -1), prior_weight * xs], axis=1)

    cache = {}

    def evaluate(x):
        """Residuals and their forward-difference Jacobian at ``x``, in one batch: the batch
        costs about 1.3 times one run, so computing the Jacobian with every trial point is
        cheaper than a separate call for it after each accepted step."""
        key = x.tobytes()
        if key not in cache:
            points = x + np.vstack([np.zeros(len(x)), _DIFFERENCE_STEP * np.eye(len(x))])
            values = batch_residuals(points)
            cache.clear()
            cache[key] = values[0], (values[1:] - values[0]).T / _DIFFERENCE_STEP
        return cache[key]

    def residuals(x):
        return evaluate(x)[0]

    def jacobian(x):
        return evaluate(x)[1]

    n_data = n_segments * length * 12
    n_used = int(segments.mask.sum()) * 12

    def rms_state_residual(residual: np.ndarray) -> float:  # back to the scaled states, unweighted by L
        return float(np.sqrt(np.sum(residual[:n_data] ** 2) * length / n_used))

    start = np.zeros(len(names))
    initial_rms = rms_state_residual(residuals(start))
    solution = least_squares(residuals, start, jac=jacobian, method="trf", x_scale=1.0, ftol=_TOLERANCE,
                             xtol=_TOLERANCE, max_nfev=max_iterations)
    residual, jac = solution.fun, solution.jac
    data_jacobian = jac[:n_data]
    information = np.linalg.pinv(jac.T @ jac)  # the prior's rows included
    scores = np.einsum("sri,sr->si", data_jacobian.reshape(n_segments, length * 12, -1),
                       residual[:n_data].reshape(n_segments, -1))
    sandwich = cluster_robust_covariance(information, scores)
    sigma2 = residual[:n_data] @ residual[:n_data] / max(n_used - len(names), 1)  # per weighted sample
    values = base + units * solution.x
    return IdentificationResult(
        model=initial.replaced(dict(zip(names, values))), names=names, values=values,
        standard_errors=np.sqrt(np.diag(sandwich)) * units,
        standard_errors_iid=np.sqrt(np.diag(sigma2 * information)) * units,
        initial_values=base, covariance=sandwich * np.outer(units, units),
        rms_residual=rms_state_residual(residual), initial_rms_residual=initial_rms,
        n_segments=n_segments, n_evaluations=int(solution.nfev), converged=bool(solution.status > 0),
        flights=tuple(sorted({int(n) for n in segments.flights})), seconds=time.perf_counter() - started)


def check_shrinkage(shrinkage) -> None:
    """Refuse a ``shrinkage`` of :func:`identify_configurations` that is neither None nor a
    positive number (:class:`~validation.core.errors.BadInputError`, one line)."""
    if shrinkage is not None and not (isinstance(shrinkage, (int, float)) and not isinstance(shrinkage, bool)
                                      and np.isfinite(shrinkage) and shrinkage > 0):
        raise BadInputError(f"shrinkage must be a positive number or None, got {shrinkage!r}")


def between_spread(results) -> np.ndarray:
    """How much the identified coefficients differ between configurations: per coefficient, the
    robust standard deviation of ``results``' values (:func:`validation.core.metrics.robust_sd`,
    robust to a few configurations whose fit went astray).

    Parameters
    ----------
    results : sequence of IdentificationResult
        At least three, of the same coefficients.

    Returns
    -------
    ndarray, shape (p,)
        In each coefficient's unit.
    """
    return robust_sd(np.array([r.values for r in results]), axis=0)


def identify_configurations(groups, initial: RGBlimpModel, *, shrinkage: float | None = SHRINKAGE,
                            names=IDENTIFIED_PARAMETERS, alone=None, **options) -> list[IdentificationResult]:
    """Each configuration's coefficients identified on its own flights and drawn toward the
    vehicle's (a hierarchical model, estimated by empirical Bayes: Efron & Morris, JASA 70(350),
    1975). A configuration's two flights show one steady spiral each, and coefficients fitted to
    them alone learn part of what differs between repeats (the buoyancy of the day, the launch);
    the configurations together say how far a configuration's coefficients may sit from the
    vehicle's.

    First every configuration is fitted alone, from ``initial``, with no prior; the spread of
    those estimates between configurations (:func:`between_spread`) times ``shrinkage`` becomes
    the standard deviation of a Gaussian prior about ``initial``'s values, and every
    configuration is fitted again with it (:func:`identify_parameters`'s ``prior_sd``).

    Parameters
    ----------
    groups : sequence of sequence of RGBlimpFlight
        Each configuration's fitting flights.
    initial : RGBlimpModel
        The vehicle's model (identified on every configuration's flights at once): the start and
        the prior's mean.
    shrinkage : float or None
        The prior's standard deviation in units of the spread between configurations
        (:data:`SHRINKAGE`, chosen on validation flights); None fits each configuration alone,
        as does a set of fewer than three configurations (no spread to estimate).
    names : sequence of str
        The coefficients (:data:`IDENTIFIED_PARAMETERS`).
    alone : list of IdentificationResult, optional
        The first fits, if made already (by this function with ``shrinkage=None`` and the same
        groups, start, names and options): they do not depend on ``shrinkage``.
    **options
        ``segment_duration``, ``max_segments``, ``max_iterations`` of :func:`identify_parameters`.

    Returns
    -------
    list of IdentificationResult
        One per group, in order; ``seconds`` counts both fits of the group (the first only if
        made here).
    """
    check_shrinkage(shrinkage)
    if alone is None:
        alone = [identify_parameters(flights, names=names, initial=initial, **options) for flights in groups]
    elif len(alone) != len(groups):
        raise BadInputError(f"{len(alone)} first fits for {len(groups)} configurations")
    if shrinkage is None or len(groups) < 3:
        return alone
    # A coefficient every configuration fits alike keeps a tiny prior width, not zero.
    width = np.maximum(shrinkage * between_spread(alone), 1e-12)
    prior_sd = dict(zip(alone[0].names, width))
    drawn = []
    for flights, first in zip(groups, alone):
        result = identify_parameters(flights, names=names, initial=initial, prior_sd=prior_sd, **options)
        drawn.append(dataclasses.replace(result, seconds=result.seconds + first.seconds))
    return drawn
