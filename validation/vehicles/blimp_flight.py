"""The blimp flight-test stand-in ``blimp-flight``: Ko et al.'s blimp with what the reference
:class:`~validation.vehicles.blimp.BlimpReference` leaves out (motor lag, dead band, tail
asymmetry, CG offset, buoyancy drift, motion-capture timing, noise and differentiated
velocities), effect by effect with numbers in :class:`BlimpFlightTest`.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.core.sampling import sampling_metadata
from validation.core.smoothing import local_polynomial
from validation.vehicles.blimp import (
    INPUT_NAMES,
    MAX_STEP,
    SAMPLE_TIME,
    STATE_NAMES,
    BlimpParameters,
    check_command_history,
    checked_max_step,
    hanging_state,
)
from validation.vehicles.blimp_equations import (
    blimp_dynamics,
    rk4,
    states_from_poses,
    substep_count,
)

_REFERENCE_PARAMETERS = BlimpParameters()

#: True parameters of the ``blimp-flight`` stand-in: the reference's, except
#: - tail fan 40 % weaker pushing the tail right (u_tail < 0) than left, as a fixed-pitch
#:   propeller run backwards is (Ko et al. 2007: the tail motor is "stronger in one direction");
#: - CG 5 mm right of the centre line (an off-centre battery, assumed): the blimp hangs rolled by
#:   atan(5 / 155) = 1.8 deg, and the offset couples sway, heave, roll and yaw through ``M``;
#: - 15 % more surge drag (gondola, fan guards and fins add frontal area; assumed).
FLIGHT_TEST_PARAMETERS = dataclasses.replace(
    _REFERENCE_PARAMETERS,
    tail_thrust_negative=0.6 * _REFERENCE_PARAMETERS.tail_thrust_positive,
    cg_position=(0.0, 0.005, _REFERENCE_PARAMETERS.cg_position[2]),
    quadratic_drag=(1.15 * _REFERENCE_PARAMETERS.quadratic_drag[0], *_REFERENCE_PARAMETERS.quadratic_drag[1:]),
)

MOCAP_JITTER_STD = 0.004  # s, frame timing jitter (assumed; Ko et al. report "jitter" only)
MOCAP_JITTER_LIMIT = 0.25  # jitter clipped to this fraction of the smallest command interval
POSITION_NOISE_STD = 0.001  # m per axis, marker noise of an indoor mocap (assumed, ~mm)
ATTITUDE_NOISE_STD = math.radians(0.5)  # rad per Euler angle (assumed)
DIFFERENCE_WINDOW = 5  # samples in the local quadratic fit that differentiates poses (core.smoothing)
DRIFT_TIME_CONSTANT = 60.0  # s, correlation time of the buoyancy drift (assumed)


class BlimpFlightTest:
    """The ``blimp-flight`` stand-in: Ko's blimp with what
    :class:`~validation.vehicles.blimp.BlimpReference` leaves out.

    Effects (each switchable by a keyword-only option; numbers assumed where not cited):

    1. true parameters :data:`FLIGHT_TEST_PARAMETERS` (tail asymmetry, lateral CG offset, more
       surge drag); pass ``params=BlimpParameters()`` to use the reference's.
    2. motor spin-up lag: the thrust of each fan follows its command through a first-order lag,
       ``motor_time_constants = (0.3, 0.2)`` s for the gondola fans and the smaller tail fan.
    3. dead band: a fan stalls (no thrust) for ``|u| < dead_band = 0.1``.
    4. buoyancy drift: net lift is an Ornstein-Uhlenbeck process, std ``buoyancy_drift = 1 mN``
       (0.1 g, helium warming by about 0.5 K: ``V rho_He g / T = 1.9 mN/K`` for 0.337 m^3),
       correlation time 60 s, starting from its stationary distribution (hand ballasting).
    5. motion capture (``mocap=True``): the controller acts on each mocap frame, and frames
       arrive 20 Hz nominal with Gaussian timing jitter of 4 ms (clipped to a quarter of the
       command interval; the first frame is t0), so the recording is unevenly sampled; marker
       noise 1 mm per position axis and 0.5 deg per Euler angle; ``U..R`` are not the true
       velocities but slopes of a 5-sample local quadratic fit of the noisy poses (Savitzky &
       Golay 1964; Sittel, Mueller & Burgard 2013, Univ. Freiburg TR 272, for velocities from
       mocap pose sequences), rotated into body axes with the measured attitude and converted
       from Euler rates by ``omega = T(Theta)^-1 Theta_dot``. Velocity noise is then about
       6 mm/s and rate noise 0.055 rad/s.

    It starts at rest at the origin hanging in its static attitude (1.8 deg roll for the default
    CG), fans stopped. Random draws (jitter, drift, noise) come from independent streams spawned
    from ``seed``, so switching one effect off does not change the others' realisations.
    """

    name = "blimp-flight"
    input_names = INPUT_NAMES
    state_names = STATE_NAMES
    sample_time = SAMPLE_TIME

    def __init__(self, *, params: BlimpParameters | None = None,
                 motor_time_constants: tuple[float, float] | None = (0.3, 0.2),
                 dead_band: float = 0.1, buoyancy_drift: float = 1e-3, mocap: bool = True,
                 max_step: float = MAX_STEP) -> None:
        if motor_time_constants is not None and not all(
                np.isfinite(tau) and tau > 0 for tau in motor_time_constants):
            raise BadInputError(f"motor_time_constants must be two positive times in s or None, "
                                f"got {motor_time_constants}")
        if not (0 <= dead_band < 1 and 0 <= buoyancy_drift < 1):
            raise BadInputError(f"dead_band must be in [0, 1) and buoyancy_drift a force below 1 N; "
                                f"got {dead_band} and {buoyancy_drift}")
        self.params = params if params is not None else FLIGHT_TEST_PARAMETERS
        self.motor_time_constants = (None if motor_time_constants is None
                                     else tuple(map(float, motor_time_constants)))
        self.dead_band = float(dead_band)
        self.buoyancy_drift = float(buoyancy_drift)
        self.mocap = bool(mocap)
        self.max_step = checked_max_step(max_step)

    def start_flight(self, time, *, seed: int = 0) -> StandInFlight:
        """A flight stepped frame by frame (for a controller in the loop; :meth:`simulate` flies
        a whole command history through the same steps).

        Parameters
        ----------
        time : array_like, shape (n,)
            Nominal frame times, s (``t0 + k*h``), jittered when ``mocap``.
        seed : int
            As :meth:`simulate`'s: the same seed gives the same jitter, drift and noise streams.
        """
        return StandInFlight(self, np.asarray(time, dtype=float), seed=seed)

    def derivative(self, state: np.ndarray, command: np.ndarray, params: BlimpParameters) -> np.ndarray:
        """Time derivative of the rigid-body state (12) plus the two fans' effective commands (2)
        under ``command`` (3), with the fans' dead band and spin-up lag; shape (14,)."""
        target = np.where(np.abs(command[[0, 2]]) < self.dead_band, 0.0, command[[0, 2]])
        if self.motor_time_constants is None:
            effective, fans_dot = target, np.zeros(2)
        else:
            effective = state[12:]
            fans_dot = (target - effective) / np.asarray(self.motor_time_constants)
        body_inputs = np.array([effective[0], command[1], effective[1]])
        return np.concatenate([blimp_dynamics(state[:12], body_inputs, params), fans_dot])

    def simulate(self, time, inputs, *, seed: int = 0) -> Recording:
        """Fly ``inputs`` (held from each frame to the next) and return the mocap recording
        (:meth:`fly`, then :meth:`record`).

        Parameters
        ----------
        time : array_like, shape (n,)
            Nominal frame times, s (``t0 + k*h``, n >= 5 for the velocity fit).
        inputs : array_like, shape (n, 3)
        seed : int
            Seeds jitter, buoyancy drift and marker noise; same seed, same recording.

        Returns
        -------
        Recording
            ``time`` are the jittered frame times when ``mocap`` (metadata ``uneven_sampling``
            and ``sample_time_nominal``); outputs are all 12 states as measured.
        """
        time, inputs = check_command_history(time, inputs, min_samples=DIFFERENCE_WINDOW)
        return self.record(self.fly(time, inputs, seed=seed), inputs)

    def fly(self, time, inputs, *, seed: int = 0) -> StandInFlight:
        """The whole flight of :meth:`simulate` before it is measured: its
        :attr:`StandInFlight.states` are the true states at the frames.

        ``time`` (n,) nominal frame times, s; ``inputs`` (n, 3), checked by :meth:`simulate`.
        """
        flight = self.start_flight(time, seed=seed)
        for command in np.asarray(inputs, dtype=float)[:-1]:
            flight.advance(command)
        return flight

    def record(self, flight: StandInFlight, inputs) -> Recording:
        """What motion capture records of a flown ``flight`` under ``inputs`` (n, 3): the poses
        with marker noise and the velocities differentiated from them (when ``mocap``), with the
        sidecar metadata."""
        nominal_step = float(np.median(np.diff(flight.nominal_time)))
        time, states = flight.time, flight.states
        metadata = {"vehicle": self.name, "seed": int(flight.seed),
                    "parameters": dict(zip(BlimpParameters.vector_names(), self.params.to_vector().tolist())),
                    "effects": {"motor_time_constants": self.motor_time_constants,
                                "dead_band": self.dead_band, "buoyancy_drift": self.buoyancy_drift,
                                "buoyancy_drift_time_constant": DRIFT_TIME_CONSTANT,
                                "mocap": self.mocap}}
        if self.mocap:
            states = self._measure(time, states, flight.noise_rng)
            # Velocity noise: interior samples on the nominal grid (validation.core.smoothing).
            slope_gain = 1.0 / (math.sqrt(10.0) * nominal_step)
            noise_std = dict.fromkeys(("x", "y", "z"), POSITION_NOISE_STD)
            noise_std.update(dict.fromkeys(("phi", "theta", "psi"), ATTITUDE_NOISE_STD))
            noise_std.update(dict.fromkeys(("U", "V", "W"), POSITION_NOISE_STD * slope_gain))
            noise_std.update(dict.fromkeys(("P", "Q", "R"), ATTITUDE_NOISE_STD * slope_gain))
            metadata.update(uneven_sampling=True, sample_time_nominal=nominal_step,
                            timing_jitter_std=MOCAP_JITTER_STD, sensor_noise_std=noise_std,
                            velocities="slopes of a 5-sample local quadratic fit of the noisy poses")
        else:
            metadata.update(sampling_metadata(time))
        return Recording(time, inputs, INPUT_NAMES, states, STATE_NAMES, metadata)

    @staticmethod
    def _measure(time: np.ndarray, states: np.ndarray, noise_rng) -> np.ndarray:
        """Noisy poses and the velocities a mocap pipeline differentiates from them, (n, 12)."""
        position = states[:, 0:3] + noise_rng.normal(0.0, POSITION_NOISE_STD, (len(time), 3))
        angles = states[:, 3:6] + noise_rng.normal(0.0, ATTITUDE_NOISE_STD, (len(time), 3))
        _, position_rates = local_polynomial(time, position, window=DIFFERENCE_WINDOW, order=2)
        _, angle_rates = local_polynomial(time, angles, window=DIFFERENCE_WINDOW, order=2)
        return states_from_poses(position, angles, position_rates, angle_rates)


class StandInFlight:
    """One flight of the ``blimp-flight`` stand-in, stepped one frame at a time.

    The frame times are jittered (when the vehicle has ``mocap``) and the buoyancy drift is
    drawn for the whole flight at the start, from independent streams spawned from ``seed``
    (jitter, drift, then marker noise in :attr:`noise_rng`, as :meth:`BlimpFlightTest.simulate`
    draws them). Each :meth:`advance` holds one command over the next frame interval, cut into
    equal RK4 substeps no longer than the vehicle's ``max_step``, with the net lift of each
    substep held.

    Attributes
    ----------
    time : ndarray, shape (n,)
        Frame times, s.
    nominal_time : ndarray, shape (n,)
        The nominal frame times it was started with, s.
    seed : int
    states : ndarray, shape (n, 12)
        True states at the frames reached so far (rows beyond :attr:`frame` are unset).
    frame : int
        Index of the current frame.
    noise_rng : numpy.random.Generator
        The stream of the flight's marker noise.
    """

    def __init__(self, vehicle: BlimpFlightTest, nominal_time: np.ndarray, *, seed: int) -> None:
        jitter_rng, drift_rng, self.noise_rng = (
            np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
        self.vehicle, self.seed = vehicle, seed
        self.nominal_time = self.time = nominal_time
        if vehicle.mocap:
            limit = MOCAP_JITTER_LIMIT * float(np.min(np.diff(nominal_time)))
            jitter = np.clip(jitter_rng.normal(0.0, MOCAP_JITTER_STD, len(nominal_time)), -limit, limit)
            jitter[0] = 0.0
            self.time = nominal_time + jitter
        self._substeps = substep_count(np.diff(self.time), vehicle.max_step)
        self._step_lengths = np.repeat(np.diff(self.time) / self._substeps, self._substeps)
        self._lift = _buoyancy_drift(self._step_lengths, vehicle.buoyancy_drift, drift_rng)
        self._state = np.concatenate([hanging_state(vehicle.params), np.zeros(2)])
        self.states = np.empty((len(self.time), len(STATE_NAMES)))
        self.states[0] = self._state[:12]
        self.frame = 0
        self._substep = 0

    @property
    def state(self) -> np.ndarray:
        """The true state at the current frame, shape (12,)."""
        return self._state[:12].copy()

    def advance(self, command) -> None:
        """Hold ``command`` (3,) from the current frame to the next."""
        if self.frame + 1 >= len(self.time):
            raise IndexError(f"the flight has {len(self.time)} frames; it is at the last")
        command = np.asarray(command, dtype=float)
        params = self.vehicle.params
        for _ in range(self._substeps[self.frame]):
            lifted = dataclasses.replace(params, net_lift=params.net_lift + self._lift[self._substep])
            self._state = rk4(lambda s, p=lifted: self.vehicle.derivative(s, command, p), self._state,
                              self._step_lengths[self._substep])
            self._substep += 1
        self.frame += 1
        self.states[self.frame] = self._state[:12]


def _buoyancy_drift(step_lengths: np.ndarray, drift_sd: float, rng) -> np.ndarray:
    """Net-lift change over each RK4 step, N, shape like ``step_lengths``: an Ornstein-Uhlenbeck
    process of standard deviation ``drift_sd`` and correlation time :data:`DRIFT_TIME_CONSTANT`,
    from its stationary distribution, updated exactly from step to step (held within a step)."""
    decay = np.exp(-step_lengths / DRIFT_TIME_CONSTANT)
    shocks = rng.standard_normal(len(step_lengths) + 1)
    lift = np.empty(len(step_lengths))
    value = drift_sd * shocks[0]
    for j, a in enumerate(decay):
        lift[j] = value
        value = a * value + drift_sd * math.sqrt(1.0 - a * a) * shocks[j + 1]
    return lift
