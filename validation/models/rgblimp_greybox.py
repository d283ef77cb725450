"""The RGBlimp's grey-box model (RKGP): the identified first-principle model plus residual GPs.

As Ko et al. (ICRA 2007, sec. IV-B) did for their blimp and :mod:`validation.models.blimp_greybox`
does for flightgp's, a :class:`gp_model.GreyBoxGP` learns the one-step residual
``s(k+1) - s(k) - f(s(k), u(k))`` of the physics step ``f``, here
:meth:`validation.models.rgblimp_identification.RGBlimpModel.step` with the identified
coefficients (one RK4 step of 1/60 s, the source's integrator), from:

- **GP inputs** (:data:`GP_STATE_COLUMNS`): the state without position and yaw (the residual
  cannot depend on where the blimp is or which way it faces, Ko et al.) and the five inputs
  (thrusts and gondola position; constant within a flight, so they tell configurations apart);
- **training transitions**: :data:`TRAINING_POINTS` of the fitting flights' one-step transitions,
  evenly spread (exact GPs cost n^3), between states re-estimated from the recorded poses
  (:func:`smoothed_states`: positions and Euler angles and their slopes by a quadratic through
  :data:`SMOOTHING_WINDOW` samples, turned into body velocities and rates). The recorded
  velocities are smooth but disagree with the slope of the recorded positions (rotated to the
  earth frame) by about 7 mm/s RMS on spiral flights and 1.5-2 mm/s on straight ones (flights
  1, 2, 29, 30, 121, 122), and that disagreement, not the dynamics, would be most of the one-step
  position residual;
- **one GP per residual output** with a floor :data:`MIN_NOISE_VARIANCE` under each noise
  variance (standardised), as for flightgp's blimp: the residuals of smooth states are nearly
  functions of the inputs, and without the floor the GPs become ill-conditioned.

Yaw: the source's step keeps ``psi`` in [-pi, pi], so at the wrap its one-step difference jumps
by a turn. :func:`physics_step` and :func:`continuous_states` carry yaw continuously instead (the
GPs never see it, and errors are measured wrapped), so no residual jumps.

A model file of such a model stores the GPs and :class:`RGBlimpStepDescription` as its
``physics`` (``gp_model.save_model(..., physics=description.as_dict())``): every number of the
identified model, from which :func:`physics_step` is rebuilt (``flightgp build-fmu`` builds the
RGBlimp RKGP FMU from it, docs/fmus.md, "RGBlimp RKGP").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gp_model import GreyBoxGP
from validation.core.errors import BadInputError
from validation.core.smoothing import local_polynomial
from validation.models.rgblimp_identification import RGBlimpModel
from validation.models.rgblimp_step import carry_yaw, parameters_as_dict, parameters_from_dict
from validation.vehicles.blimp_equations import states_from_poses
from validation.vehicles.rgblimp_equations import INPUT_NAMES, SAMPLE_TIME, STATE_NAMES

#: The states the GPs see: every state but position and yaw (Ko et al. 2007, sec. IV-B).
GP_STATE_COLUMNS = tuple(STATE_NAMES.index(n) for n in ("phi", "theta", "U", "V", "W", "P", "Q", "R"))
#: Names of the GP inputs, in their order: those states, then the inputs.
GP_INPUT_NAMES = tuple(STATE_NAMES[c] for c in GP_STATE_COLUMNS) + INPUT_NAMES
#: Training transitions per GP (150 against 300 on the validation flights, where 150 gave the
#: better free runs, docs/rgblimp.md, "Identification and RKGP"): an exact GP's fit costs n^3
#: and each free-run step n^2 per output.
TRAINING_POINTS = 150
#: Samples and degree of the pose fit that re-estimates the training states (0.15 s at 60 Hz;
#: against the recorded states and 21 samples on the validation flights, docs/rgblimp.md,
#: "Identification and RKGP").
SMOOTHING_WINDOW, SMOOTHING_ORDER = 9, 2
#: Floor under each residual GP's noise variance, standardised (1 % of the residual's spread, as
#: for flightgp's blimp, :data:`validation.models.blimp_greybox.MIN_NOISE_VARIANCE`).
MIN_NOISE_VARIANCE = 1e-4
#: The ``kind`` of :class:`RGBlimpStepDescription`: :func:`physics_step` of an RGBlimpModel.
RGBLIMP_PHYSICS = "rgblimp_rk4"
_YAW = STATE_NAMES.index("psi")


def physics_step(model):
    """``model.step`` with yaw carried continuously: ``step(states (n, 12), inputs (n, 5))``.

    The next yaw is the current one plus the wrapped yaw change of ``model.step``, which wraps
    ``psi`` into [-pi, pi] as the source does (:func:`validation.models.rgblimp_step.carry_yaw`).
    """
    def step(states, inputs):
        return carry_yaw(states, model.step(states, inputs))

    return step


def continuous_states(states) -> np.ndarray:
    """Recorded states (n, 12) with yaw unwrapped (:func:`numpy.unwrap`) along the flight."""
    states = np.array(states, dtype=float)
    states[:, _YAW] = np.unwrap(states[:, _YAW])
    return states


def smoothed_states(recording, *, window: int = SMOOTHING_WINDOW, order: int = SMOOTHING_ORDER) -> np.ndarray:
    """The 12 states at every sample re-estimated from the recorded poses alone (module
    docstring): :func:`validation.core.smoothing.local_polynomial` of the positions and the Euler
    angles (yaw continuous), their slopes turned into body velocities and rates by
    :func:`validation.vehicles.blimp_equations.states_from_poses`; shape (n, 12)."""
    poses = continuous_states(recording.outputs)[:, :6]
    if len(poses) < window:
        raise BadInputError(f"a flight of {len(poses)} samples is shorter than the smoothing window of {window}")
    positions, position_rates = local_polynomial(recording.time, poses[:, :3], window=window, order=order)
    angles, angle_rates = local_polynomial(recording.time, poses[:, 3:], window=window, order=order)
    return states_from_poses(positions, angles, position_rates, angle_rates)


def training_transitions(flights, *, n_points: int = TRAINING_POINTS, smoothing=(SMOOTHING_WINDOW, SMOOTHING_ORDER)):
    """About ``n_points`` one-step transitions, evenly spread over the flights' samples.

    Parameters
    ----------
    flights : sequence of RGBlimpFlight
    n_points : int
    smoothing : (int, int) or None
        Window and degree of :func:`smoothed_states`; None: the recorded states.

    Returns
    -------
    states, inputs, next_states : ndarray, shapes (m, 12), (m, 5), (m, 12)
        ``m <= n_points``; yaw continuous (:func:`continuous_states`).
    """
    def states(flight):
        if smoothing is None:
            return continuous_states(flight.recording.outputs)
        return smoothed_states(flight.recording, window=smoothing[0], order=smoothing[1])

    pairs = [(states(f), f.recording.inputs) for f in flights]
    total = sum(len(states) - 1 for states, _ in pairs)
    if total < 1 or n_points < 1:
        raise BadInputError("no transitions to train the residual GPs on")
    stride = max(1, int(np.ceil(total / n_points)))
    parts = []
    offset = 0
    for states, inputs in pairs:
        rows = np.arange((-offset) % stride, len(states) - 1, stride)  # one grid across the flights
        offset += len(states) - 1
        parts.append((states[rows], inputs[rows], states[rows + 1]))
    return tuple(np.vstack(part) for part in zip(*parts))


def fit_rkgp(flights, model, *, n_points: int = TRAINING_POINTS, min_noise_variance: float = MIN_NOISE_VARIANCE,
             smoothing=(SMOOTHING_WINDOW, SMOOTHING_ORDER), seed: int = 0) -> GreyBoxGP:
    """A :class:`gp_model.GreyBoxGP` on the residual of ``model`` (module docstring).

    Parameters
    ----------
    flights : sequence of RGBlimpFlight
        The fitting flights.
    model : RGBlimpModel
        The identified model (:func:`validation.models.rgblimp_identification.identify_parameters`).
    n_points : int
        :data:`TRAINING_POINTS`.
    min_noise_variance : float
        :data:`MIN_NOISE_VARIANCE`.
    smoothing : (int, int) or None
        :func:`training_transitions`.
    seed : int
        Seed of the hyperparameter search.

    Returns
    -------
    GreyBoxGP
        Its physics step is :func:`physics_step` of ``model``.
    """
    states, inputs, next_states = training_transitions(flights, n_points=n_points, smoothing=smoothing)
    greybox = GreyBoxGP(state_columns=GP_STATE_COLUMNS, shared=False, n_restarts=0,
                        min_noise_variance=min_noise_variance)
    return greybox.fit(states, inputs, next_states, physics_step(model), seed=seed)


@dataclass(frozen=True)
class RGBlimpStepDescription:
    """What an RGBlimp grey-box model file stores as its ``physics``: every number of the
    identified model whose :func:`physics_step` (one RK4 sample of 1/60 s, yaw carried
    continuously) the GPs were trained with.

    Attributes
    ----------
    model : RGBlimpModel
        Its parameters (the published ones with the identified coefficients), thrust factor and
        wind.
    """

    model: RGBlimpModel

    def physics_step(self):
        """:func:`physics_step` of :attr:`model`."""
        return physics_step(self.model)

    def as_dict(self) -> dict:
        """The JSON description (``kind`` :data:`RGBLIMP_PHYSICS`): every field of the parameters
        (:func:`validation.models.rgblimp_step.parameters_as_dict`), the thrust factor, the wind
        (m/s, earth x and y), the sample time (s) and the state and input names; floats written by
        JSON come back as the same doubles."""
        return {"kind": RGBLIMP_PHYSICS, "parameters": parameters_as_dict(self.model.params),
                "thrust_gain": float(self.model.thrust_gain), "wind": [float(w) for w in self.model.wind],
                "sample_time": SAMPLE_TIME, "state_names": list(STATE_NAMES), "input_names": list(INPUT_NAMES)}

    @classmethod
    def from_dict(cls, description) -> RGBlimpStepDescription:
        """The description :meth:`as_dict` wrote; ``.model`` is the model it describes, equal to
        the one described.

        Raises
        ------
        validation.core.errors.BadInputError
            Not an ``rgblimp_rk4`` description, or its parameters, thrust factor, wind, sample
            time or names are missing or unusable.
        """
        if not isinstance(description, dict) or description.get("kind") != RGBLIMP_PHYSICS:
            kind = description.get("kind") if isinstance(description, dict) else None
            raise BadInputError(f"the model's physics is {kind!r}; an RGBlimp grey-box model needs "
                                f"{RGBLIMP_PHYSICS!r} (validation.models.rgblimp_greybox)")
        try:
            wind = description["wind"]
            if not (isinstance(wind, list) and len(wind) == 2):
                raise ValueError(f"wind must be two numbers (m/s along earth x and y), got {wind!r}")
            model = RGBlimpModel(parameters_from_dict(description["parameters"]), float(description["thrust_gain"]),
                                 (float(wind[0]), float(wind[1])))
            if description["sample_time"] != SAMPLE_TIME:
                raise ValueError(f"its sample time is {description['sample_time']!r} s; the RGBlimp's step is "
                                 f"{SAMPLE_TIME!r} s")
            if (list(description["state_names"]) != list(STATE_NAMES)
                    or list(description["input_names"]) != list(INPUT_NAMES)):
                raise ValueError("its state or input names differ from this flightgp's RGBlimp")
        except KeyError as error:
            raise BadInputError(f"the model's {RGBLIMP_PHYSICS} physics description lacks {error}") from None
        except (TypeError, ValueError) as error:
            raise BadInputError(f"the model's {RGBLIMP_PHYSICS} physics description is unusable: {error}") from None
        return cls(model)
