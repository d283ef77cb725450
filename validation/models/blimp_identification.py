"""Identify the blimp ODE's unknown parameters from recordings (Ko et al., ICRA 2007, sec. III-B).

Ko et al. learned their blimp's parameters "by minimizing the point-wise differences between
simulated and recorded states" over one-second pieces of motion-capture data. We do the same
with scipy's ``least_squares`` (trust-region reflective, finite-difference Jacobian): the
recordings are cut into non-overlapping one-second segments; each segment is simulated with
:func:`physics_step` (RK4, the reference's step) from its *recorded* start state with the
recorded commands and the recorded (possibly jittered) frame times; the residuals are the
differences to the recorded states at every frame, each state column divided by a scale.

Which parameters (:data:`IDENTIFIED_PARAMETERS`): those Ko et al. name as unknown (drag, motor
maps, centre of mass) and those the ``blimp-flight`` stand-in changes, but not the ones fixed by
weighing and measuring the vehicle (mass, geometry: arms, fin size) nor the ones with small
effect on one-second pieces at these speeds (linear drag, added inertia):

- ``quadratic_drag_x/y/z``: translational drag (the stand-in has 15 % more surge drag);
- ``added_mass_x``: surge added mass, which with the thrust gain sets the surge time scale
  (sway and heave added mass trade off with the fin and drag terms; fixed at EPFL values);
- ``rotational_damping_z``: yaw damping;
- ``gondola_thrust_forward``, ``gondola_thrust_backward``, ``tail_thrust_positive``,
  ``tail_thrust_negative``: motor maps, one gain per direction (the stand-in's tail is 40 %
  weaker one way);
- ``cg_position_y``, ``cg_position_z``: the centre-of-gravity offset (the stand-in's is 5 mm to
  the right; ``z`` sets the pendulum frequency).

Uncertainty: the covariance of the estimate is ``A^-1 B A^-1`` with ``A = J^T J`` and ``B`` the
sum over segments of ``(J_s^T r_s)(J_s^T r_s)^T`` (a cluster-robust sandwich, Liang & Zeger
1986), times ``S / (S - 1)`` for S segments. Residuals within a segment are strongly correlated
(the noisy start state and the unmodelled effects propagate along it), so the textbook
``s^2 (J^T J)^-1`` (also reported, ``standard_errors_iid``) is too narrow; segments are
nearly independent, which is what the sandwich needs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from validation.core.errors import BadInputError, check_count
from validation.vehicles.blimp import INPUT_NAMES, MAX_STEP, STATE_NAMES, BlimpParameters
from validation.vehicles.blimp_equations import rk4_advance

IDENTIFIED_PARAMETERS = (
    "quadratic_drag_x", "quadratic_drag_y", "quadratic_drag_z", "added_mass_x", "rotational_damping_z",
    "gondola_thrust_forward", "gondola_thrust_backward", "tail_thrust_positive", "tail_thrust_negative",
    "cg_position_y", "cg_position_z",
)
#: Smallest step of the scaled optimisation variable per parameter unit, for parameters whose
#: starting value is zero (cg_position_y): 1 cm.
_MIN_PARAMETER_SCALE = 0.01
_SEGMENT_DURATION = 1.0  # s, Ko et al.'s one-second pieces


def physics_step(params: BlimpParameters, *, max_step: float = MAX_STEP):
    """The blimp ODE over one recorded frame interval, as a vectorised step callable.

    Returns ``step(states, inputs) -> next_states`` with ``states`` (n, 12) and ``inputs``
    (n, 4) = ``u_gondola, mu, u_tail, dt`` (commands held over the interval of ``dt`` seconds):
    :func:`validation.vehicles.blimp_equations.rk4_advance`, each row in equal RK4 steps no
    longer than ``max_step`` (as :class:`~validation.vehicles.blimp.BlimpReference` steps, so it
    matches the reference's RK4 simulation to rounding). This is the ``physics_step`` of
    :class:`gp_model.GreyBoxGP`, and the blimp RKGP FMU steps with the same function.
    """
    def step(states, inputs):
        inputs = np.asarray(inputs, dtype=float)
        return rk4_advance(np.asarray(states, dtype=float), inputs[..., :3], inputs[..., 3], params,
                           max_step=max_step)

    return step


def recording_arrays(recording) -> tuple[np.ndarray, np.ndarray]:
    """States (n, 12) and step inputs (n, 4) = commands and ``dt`` to the next frame.

    The last row's ``dt`` repeats the one before (it is never used to step).
    """
    missing = [n for n in STATE_NAMES if n not in recording.output_names]
    if missing:
        raise BadInputError(f"identification needs all 12 blimp states; the recording lacks {', '.join(missing)}")
    states = np.column_stack([recording.output(n) for n in STATE_NAMES])
    commands = np.column_stack([recording.input(n) for n in INPUT_NAMES])
    dt = np.diff(recording.time)
    return states, np.column_stack([commands, np.append(dt, dt[-1])])


def segments(states, inputs, *, length: int, stride: int | None = None):
    """Cut one recording into segments of ``length`` steps (``length + 1`` frames).

    Returns
    -------
    starts : ndarray, shape (S, 12)
        Recorded state at each segment's first frame.
    step_inputs : ndarray, shape (S, length, 4)
    targets : ndarray, shape (S, length, 12)
        Recorded states at the following ``length`` frames.
    """
    stride = length if stride is None else stride
    first = np.arange(0, len(states) - length, stride)
    if first.size == 0:
        raise BadInputError(f"a recording of {len(states)} frames is too short for a segment of {length} steps")
    steps = first[:, None] + np.arange(length)
    return states[first], inputs[steps], states[steps + 1]


def simulate_segments(step, starts, step_inputs) -> np.ndarray:
    """Roll ``step`` from each start through its inputs; (S, 12), (S, L, 4) -> (S, L, 12)."""
    state, path = starts, []
    for k in range(step_inputs.shape[1]):
        state = step(state, step_inputs[:, k])
        path.append(state)
    return np.stack(path, axis=1)


@dataclass
class IdentificationResult:
    """Identified parameters with their uncertainty.

    Attributes
    ----------
    params : BlimpParameters
        ``initial`` with the identified entries replaced.
    names : tuple of str
        Identified entries (:meth:`BlimpParameters.vector_names`).
    values, standard_errors, standard_errors_iid, initial_values : ndarray, shape (p,)
        Estimates, cluster-robust and textbook standard errors, starting values.
    covariance : ndarray, shape (p, p)
        Cluster-robust covariance of ``values``.
    rms_residual : float
        Root mean square of the scaled residuals at the optimum.
    n_segments, n_residuals : int
    """

    params: BlimpParameters
    names: tuple
    values: np.ndarray
    standard_errors: np.ndarray
    standard_errors_iid: np.ndarray
    initial_values: np.ndarray
    covariance: np.ndarray
    rms_residual: float
    n_segments: int
    n_residuals: int

    def as_dict(self) -> dict:
        """JSON-ready: per parameter its value, standard error and starting value."""
        return {name: {"value": float(v), "standard_error": float(se), "initial": float(v0)}
                for name, v, se, v0 in zip(self.names, self.values, self.standard_errors,
                                           self.initial_values)}


def identify_parameters(recordings, *, names=IDENTIFIED_PARAMETERS, initial: BlimpParameters | None = None,
                        segment_duration: float = _SEGMENT_DURATION, state_scale=None,
                        max_step: float = MAX_STEP, max_iterations: int | None = None) -> IdentificationResult:
    """Least-squares fit of blimp parameters to one-second segments of recordings.

    Parameters
    ----------
    recordings : sequence of Recording
        Blimp recordings with all 12 states (``blimp`` or ``blimp-flight``).
    names : sequence of str
        Entries of :meth:`BlimpParameters.vector_names` to identify; the rest stay at ``initial``.
    initial : BlimpParameters, optional
        Starting point and fixed values; default ``BlimpParameters()`` (the reference).
    segment_duration : float
        Segment length, s (rounded to whole frames at the median frame interval).
    state_scale : array_like, shape (12,), optional
        Divides each state's residual; default the standard deviation of each state column
        over all recordings (so every state counts in its own units).
    max_step : float
        Largest RK4 step, s.
    max_iterations : int, optional
        Most residual evaluations of the least-squares fit (scipy's ``max_nfev``; each also
        gives the Jacobian), for a fit that need not converge (tests); default: until its
        tolerances are met.

    Returns
    -------
    IdentificationResult
    """
    if max_iterations is not None:
        check_count(max_iterations, "max_iterations")
    initial = BlimpParameters() if initial is None else initial
    all_names = BlimpParameters.vector_names()
    unknown = [n for n in names if n not in all_names]
    if unknown or not names:
        raise BadInputError(f"unknown parameter name(s) {unknown or names}; choose from {', '.join(all_names)}")
    index = np.array([all_names.index(n) for n in names])
    base = initial.to_vector()
    pieces, all_states = [], []
    for recording in recordings:
        states, inputs = recording_arrays(recording)
        length = max(1, int(round(segment_duration / np.median(inputs[:-1, 3]))))
        pieces.append(segments(states, inputs, length=length))
        all_states.append(states)
    if not pieces:
        raise BadInputError("no recordings to identify from")
    lengths = {p[1].shape[1] for p in pieces}
    if len(lengths) != 1:
        raise BadInputError(f"recordings have different frame rates (segment lengths {sorted(lengths)} frames)")
    starts, step_inputs, targets = (np.concatenate(parts) for parts in zip(*pieces))
    if state_scale is None:
        scale = np.vstack(all_states).std(axis=0)
        scale = np.where(scale > 0, scale, 1.0)
    else:
        scale = np.asarray(state_scale, dtype=float)
        if scale.shape != (12,) or not np.all(scale > 0):
            raise BadInputError(f"state_scale must be 12 positive numbers, got {state_scale}")
    units = np.maximum(np.abs(base[index]), _MIN_PARAMETER_SCALE)  # x = (theta - theta0) / units
    n_segments, length, n_parameters = len(starts), step_inputs.shape[1], len(index)

    def parameters(x) -> BlimpParameters:
        vector = base.copy()
        vector[index] = base[index] + units * x[:n_parameters]
        return BlimpParameters.from_vector(vector)

    def residuals(x) -> np.ndarray:
        # Start states are unknowns too, measured by the segment's first frame (multiple
        # shooting without continuity constraints): x[p:] = (start - recorded start) / scale.
        offsets = x[n_parameters:].reshape(n_segments, 12)
        predicted = simulate_segments(physics_step(parameters(x), max_step=max_step),
                                      starts + offsets * scale, step_inputs)
        return np.concatenate([offsets[:, None], (predicted - targets) / scale], axis=1).ravel()

    # Each segment's residuals depend on the parameters and on its own start state only.
    rows_per_segment = (length + 1) * 12
    sparsity = np.zeros((n_segments * rows_per_segment, n_parameters + 12 * n_segments), dtype=bool)
    sparsity[:, :n_parameters] = True
    for segment in range(n_segments):
        sparsity[segment * rows_per_segment:(segment + 1) * rows_per_segment,
                 n_parameters + 12 * segment:n_parameters + 12 * (segment + 1)] = True
    # Drag, damping, added mass and thrust gains stay positive; the CG offset is free.
    lower = np.concatenate([
        np.where([n.startswith("cg_position") for n in names], -np.inf, -base[index] / units * 0.99),
        np.full(12 * n_segments, -np.inf)])
    solution = least_squares(residuals, np.zeros(len(lower)), bounds=(lower, np.inf), method="trf",
                             jac_sparsity=sparsity, diff_step=1e-6, x_scale=1.0, max_nfev=max_iterations)
    jacobian = solution.jac.toarray() if hasattr(solution.jac, "toarray") else np.asarray(solution.jac)
    residual = solution.fun
    n_residuals = residual.size
    information, sandwich = _parameter_information(jacobian, residual, n_parameters=n_parameters,
                                                   n_segments=n_segments)
    sigma2 = residual @ residual / max(n_residuals - n_parameters - 12 * n_segments, 1)
    covariance = sandwich * np.outer(units, units)
    x = solution.x
    return IdentificationResult(
        params=parameters(x), names=tuple(names), values=base[index] + units * x[:n_parameters],
        standard_errors=np.sqrt(np.diag(covariance)),
        standard_errors_iid=np.sqrt(np.diag(sigma2 * information)) * units,
        initial_values=base[index], covariance=covariance,
        rms_residual=float(np.sqrt(np.mean(residual**2))), n_segments=n_segments, n_residuals=n_residuals)


def _parameter_information(jacobian: np.ndarray, residual: np.ndarray, *, n_parameters: int,
                           n_segments: int) -> tuple[np.ndarray, np.ndarray]:
    """The parameter block of ``(J^T J)^-1`` and the cluster-robust sandwich covariance (module
    docstring), both (p, p) in the scaled optimisation variable.

    ``jacobian`` (S * rows, p + 12 S) and ``residual`` (S * rows,) hold the S segments' rows in
    turn; columns: the p parameters, then each segment's 12 start-state offsets. The parameter
    block of ``(J^T J)^-1`` comes from the Schur complement over the per-segment start states;
    the per-segment scores are ``J_g,s^T r_s`` (their start-state part is zero at the optimum).
    """
    rows_per_segment = len(residual) // n_segments
    schur = np.zeros((n_parameters, n_parameters))
    scores = np.empty((n_segments, n_parameters))
    for segment in range(n_segments):
        rows = slice(segment * rows_per_segment, (segment + 1) * rows_per_segment)
        j_global = jacobian[rows, :n_parameters]
        j_start = jacobian[rows, n_parameters + 12 * segment:n_parameters + 12 * (segment + 1)]
        coupling = j_global.T @ j_start
        schur += j_global.T @ j_global - coupling @ np.linalg.solve(j_start.T @ j_start, coupling.T)
        scores[segment] = j_global.T @ residual[rows]
    information = np.linalg.inv(schur)
    return information, cluster_robust_covariance(information, scores)


def cluster_robust_covariance(information: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """The cluster-robust sandwich ``A^-1 B A^-1 S / (S - 1)`` (Liang & Zeger, Biometrika 1986).

    Parameters
    ----------
    information : ndarray, shape (p, p)
        ``A^-1``, the inverse of ``J^T J`` (Gauss-Newton information), in the optimisation's
        variables.
    scores : ndarray, shape (S, p)
        Each cluster's (segment's) score ``J_s^T r_s``; ``B`` is the sum of their outer products.

    Returns
    -------
    ndarray, shape (p, p)
        NaN with no more clusters than parameters: ``B`` then has rank at most S (one less at
        the optimum, where the scores sum to about zero), so the estimate is singular.
    """
    n_clusters, n_parameters = scores.shape
    if n_clusters <= n_parameters:
        return np.full((n_parameters, n_parameters), np.nan)
    return information @ (scores.T @ scores) @ information * n_clusters / max(n_clusters - 1, 1)


#: The ``kind`` of the physics description of a blimp grey-box model (its model file's header).
