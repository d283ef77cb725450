"""The blimp yaw controller of Ko et al.'s Table III and its PEGASUS policy search.

Ko, Klein, Fox & Haehnel (ICRA 2007), sec. V: a 4-parameter yaw controller, learned by policy
search in a simulator with fixed random seeds (PEGASUS: Ng & Jordan, UAI 2000, "PEGASUS: a
policy search method for large MDPs and POMDPs"), flown on the real blimp for a 90 degree turn.
The paper gives the structure (three gains of a second-order yaw model and a tanh smoothing
slope of a switching curve, controller at 4 Hz) but not its exact law; the law below is ours,
with that structure.

Control law
-----------
Yaw error ``e = wrap(psi_target - psi)`` (rad, positive: target to the right), yaw rate
``r = psi_dot`` (rad/s). Second-order yaw model with a tail fan stronger in one direction
(Ko et al. 2007: the tail motor is stronger in one direction)::

    r_dot = b_plus u - a r   (u > 0),      r_dot = b_minus u - a r   (u < 0)

gains ``b_plus``, ``b_minus`` (rad/s^2 per unit command) and ``a`` (1/s). Braking at full
opposite command from rate ``r`` covers the yaw angle (integrate ``dpsi = r dr / r_dot``)::

    d_stop(r) = |r| / a - (b / a^2) ln(1 + a |r| / b),   b = b_minus if r > 0 else b_plus

(-> r^2 / (2 b) as a -> 0: the double integrator). The time-optimal switching curve of this
plant (Athans & Falb, *Optimal Control*, 1966, ch. 7: time-optimal control of second-order
plants) is ``e = sign(r) d_stop(r)``; the switching function and the command are::

    s = e - sign(r) d_stop(r)
    u_tail = clip(tanh(k s), -1, 1)

with ``k`` (1/rad) the tanh smoothing slope (bang-bang as k -> inf; the clip only guards the
command range). Gondola fans off (``u_gondola = 0``, ``mu = 0``): a turn on the spot. The command
is recomputed every 0.25 s (4 Hz) and held for 5 mocap frames.

PEGASUS
-------
A scenario seed fixes every random draw of one simulated turn: the start yaw and yaw rate
(perturbations of the hanging start state) and, in the RKGP simulator, the standard normals from
which each step's residual is drawn, conditioned on the residuals already drawn along the same
turn (:meth:`gp_model.GreyBoxGP.sample_closed_loop`; the commands depend on the sampled states,
so the draws run step by step with the controller in the loop). With a fixed seed set the cost
is a deterministic function of the four parameters, so a derivative-free optimiser
(Nelder-Mead) can compare policies without noise.

Table III
---------
:func:`table3`: the controller is learned in the RK simulator, in the RKGP simulator and, as a
reference no real experiment has, on the stand-in itself (PEGASUS with the stand-in's seeds:
the best this controller structure does on the stand-in within the same search budget); each
learned controller then flies seeded 90 degree turns of the stand-in in the loop.
"""
from __future__ import annotations

import math
import time as clock
from dataclasses import asdict, dataclass

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from scipy.optimize import minimize

from validation.core.progress import progress_bar
from validation.core.smoothing import local_polynomial
from validation.models.blimp_greybox import COMMAND_LAGS, advance_lags
from validation.vehicles.blimp import SAMPLE_TIME, hanging_state
from validation.vehicles.blimp_equations import euler_rates
from validation.vehicles.blimp_flight import (
    ATTITUDE_NOISE_STD,
    BlimpFlightTest,
)

#: Controller parameters, in the order of every parameter vector.
PARAMETER_NAMES = ("b_plus", "b_minus", "damping", "tanh_slope")
PARAMETER_UNITS = ("rad/s^2", "rad/s^2", "1/s", "1/rad")
#: Start of the search (chosen before any run: about the full-command yaw acceleration seen in a
#: 3 s full-tail turn of the stand-in, a weaker negative direction, the identified ODE's yaw
#: damping order, and a slope that saturates the command beyond 20 deg of switching function).
INITIAL_PARAMETERS = np.array([0.5, 0.3, 0.5, 3.0])
TURN = math.radians(90.0)
FRAMES_PER_DECISION = 5  # 4 Hz controller on 20 Hz mocap frames (Ko et al. 2007, sec. V)


def switching_function(yaw_error, yaw_rate, params) -> np.ndarray:
    """``s = e - sign(r) d_stop(r)`` (module docstring), rad; broadcasts ``yaw_error`` and ``yaw_rate``."""
    b_plus, b_minus, damping = (float(p) for p in params[:3])
    if min(b_plus, b_minus, damping) <= 0:
        raise ValueError(f"b_plus, b_minus and damping must be positive, got {params[:3]}")
    r = np.asarray(yaw_rate, dtype=float)
    authority = np.where(r > 0, b_minus, b_plus)  # braking a right turn needs u < 0
    speed = np.abs(r)
    stop = speed / damping - authority / damping**2 * np.log1p(damping * speed / authority)
    return np.asarray(yaw_error, dtype=float) - np.sign(r) * stop


def yaw_command(yaw_error, yaw_rate, params) -> np.ndarray:
    """``u_tail = clip(tanh(k s), -1, 1)``; ``params`` = :data:`PARAMETER_NAMES`."""
    return np.clip(np.tanh(float(params[3]) * switching_function(yaw_error, yaw_rate, params)), -1.0, 1.0)


def _wrap(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def euler_yaw_rate(states) -> np.ndarray:
    """``psi_dot`` from the states' roll, pitch and body rates (Fossen 2011, sec. 2.2.1); (..., 12) -> (...)."""
    return euler_rates(states[..., 3:6], states[..., 9:12])[..., 2]


@dataclass(frozen=True)
class TurnTask:
    """The 90 degree turn and its PEGASUS scenarios.

    Attributes
    ----------
    horizon_s : float
        Length of each turn, s (a full-command turn of 90 deg takes about 3 s on the stand-in).
    yaw_start_std_deg, yaw_rate_start_std_deg_s : float
        Start perturbations of the simulated turns (the target stays at 90 deg).
    rate_weight_s2 : float
        Weight of the squared yaw rate in the cost, s^2 (chosen before any run).
    """

    horizon_s: float = 8.0
    yaw_start_std_deg: float = 5.0
    yaw_rate_start_std_deg_s: float = 3.0
    rate_weight_s2: float = 0.1

    @property
    def frames(self) -> int:
        return int(round(self.horizon_s / SAMPLE_TIME))


def scenarios(task: TurnTask, start_state, seeds, *, n_states: int = 12):
    """Start states (n, 12) and standard normals (n, frames, 2, n_states) of each seed.

    Seed i draws ``default_rng(seeds[i])``: start yaw, start yaw rate (added to ``R``), then
    the normals (:meth:`gp_model.GreyBoxGP.sample_closed_loop`'s layout: latent draw and
    observation noise of each step); a simulator without randomness ignores the normals.
    """
    starts, normals = [], []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        start = np.array(start_state, dtype=float)
        start[5] += math.radians(task.yaw_start_std_deg) * rng.standard_normal()
        start[11] += math.radians(task.yaw_rate_start_std_deg_s) * rng.standard_normal()
        starts.append(start)
        normals.append(rng.standard_normal((task.frames, 2, n_states)))
    return np.stack(starts), np.stack(normals)


class TurnPolicy:
    """The controller as a policy for closed-loop simulation of n turns at once.

    Called once per step, in order, with the step index and the n current states, it returns
    their step inputs ``u_gondola, mu, u_tail, dt`` and the lagged fan commands of
    ``command_lags`` (:func:`validation.models.blimp_greybox.advance_lags`; fans at rest at
    step 0): the yaw command is recomputed every :data:`FRAMES_PER_DECISION` steps from the
    true yaw and yaw rate (a simulator's state) and held in between; gondola off.
    """

    def __init__(self, params, n: int, *, command_lags=()) -> None:
        self.params = np.asarray(params, dtype=float)
        self.command_lags = tuple(command_lags)
        self.commands = np.zeros((n, 3))
        self.lags = np.zeros((n, 2 * len(self.command_lags)))

    def __call__(self, k: int, states: np.ndarray) -> np.ndarray:
        if k % FRAMES_PER_DECISION == 0:
            self.commands[:, 2] = yaw_command(_wrap(TURN - states[:, 5]), euler_yaw_rate(states), self.params)
        inputs = np.column_stack([self.commands, np.full(len(states), SAMPLE_TIME), self.lags])
        self.lags = advance_lags(self.lags, self.commands, SAMPLE_TIME, time_constants=self.command_lags)
        return inputs


def rk_simulator(rk):
    """``simulate(params, starts (n, 12), normals, frames) -> paths (n, frames + 1, 12)`` of the
    controller in the loop of a physics step (no randomness beyond the start)."""
    def simulate(params, starts, normals, frames):
        policy = TurnPolicy(params, len(starts))
        state, path = np.asarray(starts, dtype=float), [np.asarray(starts, dtype=float)]
        for k in range(frames):
            state = rk(state, policy(k, state))
            path.append(state)
        return np.stack(path, axis=1)
    return simulate


def rkgp_simulator(model, rk, *, command_lags=COMMAND_LAGS, include_noise: bool = True):
    """``simulate`` of :func:`rk_simulator` for RKGP: the residual drawn step by step with the
    controller in the loop, each draw conditioned on the draws already made along the same turn
    (:meth:`gp_model.GreyBoxGP.sample_closed_loop`), plus the GPs' observation noise (the process
    noise they learned) with ``include_noise``, from the scenario's normals."""
    def simulate(params, starts, normals, frames):
        policy = TurnPolicy(params, len(starts), command_lags=command_lags)
        return model.sample_closed_loop(starts, policy, frames, rk, normals=normals, include_noise=include_noise)
    return simulate


def turn_cost(paths, task: TurnTask) -> float:
    """Mean over scenarios and frames of ``e^2 + w r^2`` (rad, rad/s)."""
    error = _wrap(TURN - paths[..., 5])
    return float(np.mean(error**2 + task.rate_weight_s2 * euler_yaw_rate(paths) ** 2))


def pegasus_cost(params, simulator, task: TurnTask, start_state, seeds) -> float:
    """Cost of one parameter vector over the fixed scenario seeds (deterministic for fixed seeds)."""
    starts, normals = scenarios(task, start_state, seeds)
    return turn_cost(simulator(params, starts, normals, task.frames), task)


def learn_controller(cost, *, max_evaluations: int, initial=INITIAL_PARAMETERS) -> dict:
    """PEGASUS: Nelder-Mead on the log of the four parameters (keeps them positive).

    ``cost(params) -> float`` is deterministic (fixed scenario seeds). Returns ``params`` (4,),
    ``cost``, ``initial_cost`` and ``evaluations``.
    """
    start = np.log(np.asarray(initial, dtype=float))
    result = minimize(lambda log_params: cost(np.exp(log_params)), start, method="Nelder-Mead",
                      options={"maxfev": max_evaluations, "xatol": 1e-3, "fatol": 1e-6})
    # The initial cost at the search's own first vertex, exp(log(initial)): the initial
    # parameters to rounding, and the closed-loop cost moves by 1e-8 with a last-bit change.
    return {"params": np.exp(result.x), "cost": float(result.fun),
            "initial_cost": cost(np.exp(start)), "evaluations": int(result.nfev)}


def fly_stand_in(params, *, seed, frames: int, vehicle: BlimpFlightTest | None = None):
    """The controller in the loop of the ``blimp-flight`` stand-in, frame by frame.

    The stand-in's :meth:`~validation.vehicles.blimp_flight.BlimpFlightTest.simulate` takes the
    whole command history up front; here the same vehicle (fan lag, dead band, buoyancy drift,
    jittered frame times, true parameters) is stepped one frame at a time
    (:meth:`~validation.vehicles.blimp_flight.BlimpFlightTest.start_flight`) so the 4 Hz
    controller can act on what it measures: the yaw with 0.5 deg marker noise and the yaw rate as the slope of a
    quadratic fit through the last 5 noisy yaws (the one-sided end of the stand-in's 5-sample
    differentiator; zero, the known rest, before 5 frames exist). Jitter and drift come from
    the streams ``simulate`` uses with the same seed, so for a command sequence that does not
    depend on the measurements the true states equal ``simulate``'s.

    Returns
    -------
    time : ndarray, shape (frames + 1,)
        Jittered frame times, s.
    states : ndarray, shape (frames + 1, 12)
        True states at the frames.
    commands : ndarray, shape (frames + 1, 3)
        Held commands (the last row repeats the one before).
    """
    vehicle = BlimpFlightTest() if vehicle is None else vehicle
    flight = vehicle.start_flight(np.arange(frames + 1) * SAMPLE_TIME, seed=seed)
    measured_yaw = np.empty(frames + 1)
    commands = np.zeros((frames + 1, 3))
    for k in range(frames + 1):
        noise = flight.noise_rng.normal(0.0, ATTITUDE_NOISE_STD) if vehicle.mocap else 0.0
        measured_yaw[k] = flight.state[5] + noise
        if k == frames:
            commands[k] = commands[k - 1]
            break
        if k % FRAMES_PER_DECISION == 0:
            rate = 0.0 if k < 4 else local_polynomial(flight.time[k - 4:k + 1], measured_yaw[k - 4:k + 1, None],
                                                      window=5, order=2)[1][-1, 0]
            commands[k] = [0.0, 0.0, float(yaw_command(_wrap(TURN - measured_yaw[k]), rate, params))]
        else:
            commands[k] = commands[k - 1]
        flight.advance(commands[k])
    return flight.time, flight.states, commands


def turn_errors(states) -> dict:
    """RMS over the frames of one turn of the yaw error (deg) and yaw-rate error (deg/s; target
    rate 0), and the yaw error at the end (deg)."""
    error = np.degrees(_wrap(TURN - states[:, 5]))
    rate = np.degrees(euler_yaw_rate(states))
    return {"yaw_error_deg": float(np.sqrt(np.mean(error**2))),
            "yaw_rate_error_deg_s": float(np.sqrt(np.mean(rate**2))),
            "final_yaw_error_deg": float(error[-1])}


@dataclass(frozen=True)
class Table3Setup:
    """Sizes of the Table III experiment.

    Attributes
    ----------
    horizon_s : float
        Length of each turn, s.
    n_scenarios : int
        PEGASUS scenario seeds (the same set in every simulator).
    max_evaluations : int
        Nelder-Mead cost evaluations per simulator.
    stand_in_runs : int
        Seeded stand-in turns per learned controller.
    """

    horizon_s: float = 8.0
    n_scenarios: int = 6
    max_evaluations: int = 80
    stand_in_runs: int = 10


DEFAULT_SETUP = Table3Setup()
QUICK_SETUP = Table3Setup(horizon_s=6.0, n_scenarios=2, max_evaluations=12, stand_in_runs=2)
#: Where the controller is learned: the two simulators of the paper and the stand-in itself.
LEARNED_IN = ("RK", "RKGP", "stand_in")


def stand_in_cost(params, task: TurnTask, seeds) -> float:
    """:func:`turn_cost` of the controller flying the stand-in once per seed (true states)."""
    return turn_cost(np.stack([fly_stand_in(params, seed=seed, frames=task.frames)[1] for seed in seeds]), task)


def table3(model, rk, params, setup: Table3Setup = DEFAULT_SETUP, *, seed: int, command_lags=COMMAND_LAGS,
           progress: bool = False) -> tuple[dict, dict]:
    """Table III for one seed: PEGASUS in RK, in RKGP and on the stand-in, then every learned
    controller on seeded stand-in turns.

    Parameters
    ----------
    model : GreyBoxGP
        RKGP (inputs: commands, ``dt`` and the lagged commands of ``command_lags``).
    rk : callable
        The identified ODE's RK step.
    params : BlimpParameters
        The identified parameters (the simulators start from their hanging state).
    setup : Table3Setup
    seed : int
        Scenario i: ``SeedSequence([seed, 4, i])`` (every simulator); stand-in turn i:
        ``SeedSequence([seed, 5, i])`` (every controller).

    Returns
    -------
    table : dict
        The ``table3`` entry of one seed in ``results.json``.
    paths : dict
        Per learned-in, the stand-in turns' true states, (R, frames + 1, 12).
    """
    task = TurnTask(horizon_s=setup.horizon_s)
    start = hanging_state(params)
    seeds = [int(np.random.SeedSequence([seed, 4, i]).generate_state(1)[0]) for i in range(setup.n_scenarios)]
    simulators = {"RK": rk_simulator(rk), "RKGP": rkgp_simulator(model, rk, command_lags=command_lags)}
    costs = {name: (lambda p, sim=sim: pegasus_cost(p, sim, task, start, seeds)) for name, sim in simulators.items()}
    costs["stand_in"] = lambda p: stand_in_cost(p, task, seeds)
    learned = {}
    with progress_bar(f"seed {seed}: Table III policy search", enabled=progress,
                      total=len(LEARNED_IN) * (setup.max_evaluations + 1), unit="evaluation") as update:
        for name in LEARNED_IN:
            def counted(p, cost=costs[name]):
                if update:
                    update(1)
                return cost(p)
            began = clock.perf_counter()
            learned[name] = learn_controller(counted, max_evaluations=setup.max_evaluations)
            learned[name]["seconds"] = clock.perf_counter() - began
    run_seeds = [int(np.random.SeedSequence([seed, 5, i]).generate_state(1)[0]) for i in range(setup.stand_in_runs)]
    table, paths = {}, {}
    for name in LEARNED_IN:
        runs = np.stack([fly_stand_in(learned[name]["params"], seed=s, frames=task.frames)[1] for s in run_seeds])
        paths[name] = runs
        errors = [turn_errors(run) for run in runs]
        row = {}
        for key in errors[0]:
            values = np.array([e[key] for e in errors])
            row[key] = float(values.mean())
            row[key.replace("_deg", "_std_deg", 1)] = float(values.std())
        table[name] = {**row, "parameters": dict(zip(PARAMETER_NAMES, map(float, learned[name]["params"]))),
                       "pegasus_cost": learned[name]["cost"], "initial_cost": learned[name]["initial_cost"],
                       **{f"cost_in_{other}": costs[other](learned[name]["params"]) for other in simulators},
                       "evaluations": learned[name]["evaluations"], "seconds": learned[name]["seconds"]}
    table["yaw_error_ratio_RK_to_RKGP"] = table["RK"]["yaw_error_deg"] / table["RKGP"]["yaw_error_deg"]
    table["setup"] = {
        **asdict(setup), "seed": seed, "task": asdict(task), "turn_deg": math.degrees(TURN),
        "controller": "u_tail = clip(tanh(k s), -1, 1), s = e - sign(r) d_stop(r) "
                      "(validation.reproduce.blimp_control); 4 Hz; gondola off",
        "parameter_units": dict(zip(PARAMETER_NAMES, PARAMETER_UNITS)),
        "initial_parameters": dict(zip(PARAMETER_NAMES, map(float, INITIAL_PARAMETERS))),
        "cost": "mean over scenarios and 20 Hz frames of e^2 + rate_weight_s2 * psi_dot^2 (rad, rad/s)",
        "optimiser": "scipy Nelder-Mead on log parameters from initial_parameters, maxfev max_evaluations",
        "scenario_seeds": "scenario i: SeedSequence([seed, 4, i]): start yaw and yaw-rate perturbations "
                          "(simulators), GP normals (RKGP), jitter, drift and marker noise (stand-in)",
        "rkgp_sampling": "residuals drawn step by step with the controller in the loop, each conditioned "
                         "on the draws along the same turn, plus observation noise",
        "start": "the identified ODE's hanging state (simulators); rest (stand-in)",
        "stand_in_seeds": "turn i: SeedSequence([seed, 5, i]), the same for every controller",
        "errors": "per turn: RMS over frames of the true yaw error (deg) and true yaw rate (deg/s, target 0), "
                  "final yaw error (deg); mean and std (ddof 0) over turns"}
    return table, paths


def table3_figure(paths: dict) -> Figure:
    """Ko et al.'s Fig. 7 style: yaw against yaw rate, and yaw over time, of the stand-in turns
    under each learned controller; ``paths`` per learned-in (R, frames + 1, 12) true states."""
    figure = Figure(figsize=(12, 5), layout="constrained")
    FigureCanvasAgg(figure)
    phase, yaw = figure.subplots(1, 2)
    colors = {"RK": "tab:orange", "RKGP": "tab:blue", "stand_in": "tab:gray"}
    for name, runs in paths.items():
        t = np.arange(runs.shape[1]) * SAMPLE_TIME
        for i, run in enumerate(runs):
            label = f"learned in {name} ({len(runs)} stand-in turns)" if i == 0 else None
            rate = np.degrees(euler_yaw_rate(run))
            phase.plot(np.degrees(run[:, 5]), rate, color=colors[name], lw=0.8, alpha=0.6, label=label)
            yaw.plot(t, np.degrees(run[:, 5]), color=colors[name], lw=0.8, alpha=0.6, label=label)
    phase.plot(math.degrees(TURN), 0.0, "k*", ms=14, label="target")
    yaw.axhline(math.degrees(TURN), color="k", lw=1, ls="--", label="target")
    phase.set_xlabel("yaw psi [deg]")
    phase.set_ylabel("yaw rate psi_dot [deg/s]")
    yaw.set_xlabel("time from start [s]")
    yaw.set_ylabel("yaw psi [deg]")
    for panel in (phase, yaw):
        panel.grid(True, alpha=0.3)
        panel.legend(fontsize="small")
    figure.suptitle("Blimp Table III: 90 deg turns of the stand-in under the PEGASUS-learned yaw "
                    "controllers (Ko et al. 2007, sec. V)")
    return figure
