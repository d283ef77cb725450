"""``flightgp bench rgblimp``: the RGBlimp rollout-trained hybrid's free run, gradient and fit,
and diagnose's compiled replays, each against its peer in the same process (docs/benchmarks.md).

On the excerpt shipped with the package (configuration 29: fit on ``data_117.csv`` and
``data_118.csv``, 18 and 14 s; free run of ``data_119.csv``, 12 s) except the blimp's replay:

- the free run of the physics through the JAX step (:mod:`validation.models.rgblimp_rollout`,
  compiled once, then timed) against :meth:`validation.models.rgblimp_identification.RGBlimpModel.simulate`
  (numpy), as a ratio, over several runs;
- diagnose's replay of many hypotheses over several flights
  (:meth:`validation.vehicles.rgblimp_effects.RGBlimpEffects.simulate_recordings`: 24 effect
  lists over the three flights of configuration 29, as one batch) on the compiled free run against
  the numpy step, as a ratio, over several runs;
- the same for the blimp reference's replays (:func:`validation.vehicles.blimp_effects.simulate_batch`:
  24 effect lists over its 20 s identification manoeuvre), compiled
  (:mod:`validation.vehicles.blimp_jax`) against the numpy step;
- the fit's loss and exact gradient (one L-BFGS-B evaluation) with each RK4 step checkpointed
  (:func:`validation.models.rgblimp_rollout.gradient_call`) against the same gradient through
  stored steps, as a ratio, over several runs;
- the hybrid's fit with the default setup (:func:`validation.models.rgblimp_rollout.fit_rollout`,
  compilation included, as a user meets it) against the goal of :data:`FIT_GOAL_S` per
  configuration, beside the identification the hybrid starts from (the peer).
"""
from __future__ import annotations

import time as clock

import numpy as np

from validation.bench.rows import SummaryRow
from validation.core.progress import progress_bar

#: Goal: seconds to fit one configuration's hybrid (two flights) on 2 cores.
FIT_GOAL_S = 60.0
#: Timed runs of each free run.
FREE_RUN_REPEATS = 5
#: Timed runs of each replay, and its batch of effect lists (a diagnosis' screening batch).
REPLAY_REPEATS, REPLAY_MEMBERS = 3, 24


def run(*, progress: bool = True, setup=None, identification_iterations: int | None = None) -> dict:
    """Time the free runs, the replays, the gradients and the fit (module docstring).

    ``setup``: the hybrid's :class:`~validation.models.rgblimp_rollout.RolloutSetup` (default
    the reproduction's). ``identification_iterations``: at most this many iterations of the
    identification the hybrid starts from (default the identification's own,
    :data:`~validation.models.rgblimp_identification.MAX_ITERATIONS`).

    Returns
    -------
    dict
        ``free_run``: ``numpy_s`` and ``jax_s`` (lists over runs), ``speedup`` (median ratio),
        ``samples``; ``replay``: the same for diagnose's batched replay, with ``members`` and
        ``flights``; ``blimp_replay``: the same for the blimp's, with ``members``; ``gradient``:
        ``checkpointed_s``, ``stored_s``, ``speedup``, ``speedup_range``, ``flights``; ``fit``:
        ``hybrid_s``, ``identification_s``, ``iterations``, ``goal_s``,
        ``goal_met``.
    """
    from validation.models.rgblimp_identification import MAX_ITERATIONS, identify_parameters
    from validation.models.rgblimp_rollout import RolloutHybrid, RolloutSetup, fit_rollout
    from validation.vehicles.rgblimp_data import EXCERPT_FOLDER, read_rgblimp_flight

    fitting = [read_rgblimp_flight(EXCERPT_FOLDER / f"data_{n}.csv") for n in (117, 118)]
    test = read_rgblimp_flight(EXCERPT_FOLDER / "data_119.csv").recording
    with progress_bar("bench rgblimp", enabled=progress, total=2 * FREE_RUN_REPEATS + 6 * REPLAY_REPEATS + 2,
                      unit="run") as update:
        began = clock.perf_counter()
        identified = identify_parameters(fitting, max_iterations=MAX_ITERATIONS if identification_iterations is None
                                         else identification_iterations).model
        identification_s = clock.perf_counter() - began
        if update:
            update(1, stage="identification")
        physics = RolloutHybrid(identified, None, RolloutSetup())
        physics.simulate(test.outputs[0], test.inputs)  # compile once
        numpy_s, jax_s = [], []
        for _ in range(FREE_RUN_REPEATS):
            for times, model in ((numpy_s, identified), (jax_s, physics)):
                began = clock.perf_counter()
                model.simulate(test.outputs[0], test.inputs)
                times.append(clock.perf_counter() - began)
                if update:
                    update(1, stage="free run")
        replay = _time_replays([f.recording for f in fitting] + [test], update)
        blimp_replay = _time_blimp_replays(update)
        gradient = _time_gradients(fitting, identified, setup or RolloutSetup(), update)
        hybrid = fit_rollout(fitting, identified, setup=setup or RolloutSetup())
        if update:
            update(1, stage="hybrid fit")
    return {"free_run": {**_ratio(numpy_s, jax_s), "samples": len(test.time), "flight": "data_119.csv"},
            "replay": {**replay, "members": REPLAY_MEMBERS,
                       "flights": ["data_117.csv", "data_118.csv", "data_119.csv"]},
            "blimp_replay": {**blimp_replay, "members": REPLAY_MEMBERS},
            "gradient": {**gradient, "flights": ["data_117.csv", "data_118.csv"]},
            "fit": {"hybrid_s": hybrid.fit_seconds, "identification_s": identification_s,
                    "iterations": hybrid.iterations, "flights": ["data_117.csv", "data_118.csv"],
                    "goal_s": FIT_GOAL_S, "goal_met": hybrid.fit_seconds <= FIT_GOAL_S}}


def _ratio(peer_s, fast_s, *, keys=("numpy_s", "jax_s")) -> dict:
    """The peer's and the fast call's times under ``keys``, ``speedup`` (the median of their
    ratios) and ``speedup_range``."""
    ratios = np.asarray(peer_s) / np.asarray(fast_s)
    return {keys[0]: peer_s, keys[1]: fast_s, "speedup": float(np.median(ratios)),
            "speedup_range": [float(ratios.min()), float(ratios.max())]}


def _time_replays(recordings, update) -> dict:
    """Diagnose's batched replay of :data:`REPLAY_MEMBERS` effect lists (each a thrust factor and a
    drag coefficient) over ``recordings``, compiled (once compiled) and numpy, alternating."""
    from validation.vehicles.rgblimp import RGBlimpReference
    from validation.vehicles.rgblimp_effects import RGBlimpEffects

    reference = RGBlimpReference()
    effect_lists = [[{"term": "thrust_gain", "value": 0.8 + 0.01 * b}, {"term": "c_d0", "value": 0.2 + 0.005 * b}]
                    for b in range(REPLAY_MEMBERS)]
    compiled, numpy_step = RGBlimpEffects(reference), RGBlimpEffects(reference, compiled=False)
    args = (effect_lists, [r.time for r in recordings], [r.inputs for r in recordings],
            [compiled.start_state(r) for r in recordings])
    return _alternate(lambda: compiled.simulate_recordings(*args), lambda: numpy_step.simulate_recordings(*args),
                      update)


def _time_blimp_replays(update) -> dict:
    """The blimp's (:mod:`validation.vehicles.blimp_effects`) replay of :data:`REPLAY_MEMBERS`
    effect lists (a gondola-fan lag and a yaw damping each) over its identification manoeuvre
    (20 s at 20 Hz), compiled (:mod:`validation.vehicles.blimp_jax`, once compiled) and numpy."""
    from validation.vehicles.blimp import BlimpReference
    from validation.vehicles.blimp_effects import identification_manoeuvre, simulate_batch

    reference, (time, inputs) = BlimpReference(), identification_manoeuvre()
    effect_lists = [[{"effect": "input_lag", "input": "u_gondola", "value": 0.1 + 0.01 * b},
                     {"effect": "stability_derivative", "term": "N_R", "value": -0.01 - 0.001 * b}]
                    for b in range(REPLAY_MEMBERS)]
    return _alternate(lambda: simulate_batch(reference, effect_lists, time, inputs),
                      lambda: simulate_batch(reference, effect_lists, time, inputs, compiled=False), update)


def _time_gradients(fitting, identified, setup, update) -> dict:
    """The fit's loss and gradient at its start, steps checkpointed and stored (the peer):
    ``checkpointed_s``, ``stored_s`` (:data:`REPLAY_REPEATS` timed calls each, alternating, after
    one call of each that compiles it), ``speedup`` (median ratio) and ``speedup_range``."""
    from validation.models.rgblimp_rollout import gradient_call

    checkpointed = gradient_call(fitting, identified, setup=setup)
    stored = gradient_call(fitting, identified, setup=setup, checkpoint_steps=False)
    stored()
    return _alternate(checkpointed, stored, update, stage="gradient", keys=("stored_s", "checkpointed_s"))


def _alternate(fast, peer, update, *, stage: str = "replay", keys=("numpy_s", "jax_s")) -> dict:
    """:func:`_ratio` of :data:`REPLAY_REPEATS` timed calls of ``peer`` and ``fast`` each,
    alternating, after one call of ``fast`` that compiles it (``keys``: the peer's, the fast one's)."""
    fast()
    times = ([], [])
    for _ in range(REPLAY_REPEATS):
        for kept, call in zip(times, (peer, fast)):
            began = clock.perf_counter()
            call()
            kept.append(clock.perf_counter() - began)
            if update:
                update(1, stage=stage)
    return _ratio(*times, keys=keys)


def format_table(report: dict) -> str:
    """The ``bench rgblimp`` report as a table."""
    free, replay, fit = report["free_run"], report["replay"], report["fit"]
    return "\n".join([
        f"RGBlimp free run of {free['flight']} ({free['samples']} samples), {len(free['jax_s'])} runs each",
        f"  numpy step {np.median(free['numpy_s']) * 1e3:8.1f} ms   JAX step {np.median(free['jax_s']) * 1e3:8.1f} ms"
        f"   speed-up {free['speedup']:.1f}x ({free['speedup_range'][0]:.1f}-{free['speedup_range'][1]:.1f})",
        f"diagnose's replay of {replay['members']} effect lists over {', '.join(replay['flights'])}, "
        f"{len(replay['jax_s'])} runs each",
        f"  numpy step {np.median(replay['numpy_s']) * 1e3:8.1f} ms   "
        f"compiled {np.median(replay['jax_s']) * 1e3:8.1f} ms"
        f"   speed-up {replay['speedup']:.1f}x ({replay['speedup_range'][0]:.1f}-{replay['speedup_range'][1]:.1f})",
        f"blimp replay of {report['blimp_replay']['members']} effect lists over its identification manoeuvre: "
        f"numpy step {np.median(report['blimp_replay']['numpy_s']) * 1e3:.1f} ms, compiled "
        f"{np.median(report['blimp_replay']['jax_s']) * 1e3:.1f} ms, speed-up {report['blimp_replay']['speedup']:.1f}x",
        f"the fit's loss and gradient: through stored steps {np.median(report['gradient']['stored_s']) * 1e3:.0f} ms, "
        f"steps checkpointed {np.median(report['gradient']['checkpointed_s']) * 1e3:.0f} ms, "
        f"speed-up {report['gradient']['speedup']:.1f}x",
        f"rollout-trained hybrid fit on {', '.join(fit['flights'])}: {fit['hybrid_s']:.1f} s "
        f"({fit['iterations']} iterations; goal <= {fit['goal_s']:g} s: {'met' if fit['goal_met'] else 'MISSED'}); "
        f"the identification it starts from {fit['identification_s']:.1f} s"])


def summary_rows(report: dict) -> list[SummaryRow]:
    free, fit = report["free_run"], report["fit"]
    return [SummaryRow("rgblimp.free_run.jax_over_numpy", "RGBlimp free run, JAX step over numpy step",
                       free["speedup"], "x", None,
                       note=f"{free['speedup_range'][0]:.1f}-{free['speedup_range'][1]:.1f} over runs"),
            SummaryRow("rgblimp.diagnose_replay.compiled_over_numpy",
                       f"RGBlimp diagnose replay ({report['replay']['members']} hypotheses, "
                       f"{len(report['replay']['flights'])} flights), compiled over numpy step",
                       report["replay"]["speedup"], "x", None,
                       note=f"{report['replay']['speedup_range'][0]:.1f}-{report['replay']['speedup_range'][1]:.1f} "
                            "over runs"),
            SummaryRow("blimp.diagnose_replay.compiled_over_numpy",
                       f"blimp diagnose replay ({report['blimp_replay']['members']} hypotheses, 20 s), "
                       "compiled over numpy step",
                       report["blimp_replay"]["speedup"], "x", None,
                       note=f"{report['blimp_replay']['speedup_range'][0]:.1f}-"
                            f"{report['blimp_replay']['speedup_range'][1]:.1f} over runs"),
            SummaryRow("rgblimp.hybrid.gradient.checkpointed_over_stored",
                       "RGBlimp hybrid fit's loss and gradient, RK4 steps checkpointed over stored",
                       report["gradient"]["speedup"], "x", None,
                       note=f"{report['gradient']['speedup_range'][0]:.1f}-"
                            f"{report['gradient']['speedup_range'][1]:.1f} over runs"),
            SummaryRow("rgblimp.hybrid.fit_s", "RGBlimp rollout-trained hybrid, fit per configuration",
                       fit["hybrid_s"], "s", FIT_GOAL_S, at_least=False,
                       note=f"identification {fit['identification_s']:.1f} s")]
