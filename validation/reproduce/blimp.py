"""Reproduce the blimp RKGP paper's Tables I, II and III (Ko, Klein, Fox & Haehnel, ICRA 2007)
over a campaign of seeds.

For each seed: fly the stand-in's training and held-out flights, identify the ODE and fit the
residual GPs, then Table I (:mod:`validation.reproduce.blimp_prediction`), Table II
(:mod:`validation.reproduce.blimp_spread`) and Table III (:mod:`validation.reproduce.blimp_control`);
:mod:`validation.reproduce.blimp_report` summarises the seeds, checks the goals and writes the
report.
"""
from __future__ import annotations

import functools
import time as clock
from dataclasses import dataclass
from pathlib import Path

from fmu_src import build_blimp_rkgp_fmu
from gp_model import model_bytes
from validation.core.files import write_atomically, write_json
from validation.core.plots import png_bytes
from validation.core.progress import progress_bar
from validation.models.blimp_greybox import COMMAND_LAGS, BlimpStepDescription
from validation.reproduce import blimp_control, blimp_prediction, blimp_report, blimp_spread
from validation.reproduce.blimp_prediction import RK_MAX_STEP, FittedModels

#: The campaign's seeds.
DEFAULT_SEEDS = (0, 1, 2, 3, 4)


@dataclass
class SeedRun:
    """Everything one seed measured: the three tables (``results.json`` entries), the fitted
    models, and the arrays the figures draw."""

    seed: int
    fitted: FittedModels
    table1: blimp_prediction.Table1
    table2: dict
    table2_paths: blimp_spread.SpreadPaths
    table3: dict
    table3_paths: dict
    #: The Table I setup the seed ran (``results.json`` records it).
    setup: blimp_prediction.Table1Setup


def run_seed(seed: int, *, quick: bool = False, progress: bool = False) -> SeedRun:
    """Tables I, II and III for one seed (seeds: :func:`reproduce_blimp`)."""
    setup = blimp_prediction.QUICK_SETUP if quick else blimp_prediction.DEFAULT_SETUP
    training, held_out = blimp_prediction.fly_flights(setup, seed=seed, progress=progress)
    fitted = blimp_prediction.fit_models(training, seed=seed, identification_iterations=setup.identification_iterations,
                                         progress=progress)
    first = blimp_prediction.table1(fitted, held_out, setup, seed=seed, progress=progress)
    rkgp, rk = fitted.models["RKGP"], fitted.physics["RK"]
    spread_setup = blimp_spread.QUICK_SETUP if quick else blimp_spread.DEFAULT_SETUP
    calibration = blimp_spread.calibrate_spread(rkgp, rk, spread_setup, seed=seed, progress=progress)
    second, second_paths = blimp_spread.table2(held_out[0].recording.inputs, rkgp, rk, spread_setup, seed=seed,
                                               calibration=calibration, progress=progress)
    third, third_paths = blimp_control.table3(
        rkgp, rk, fitted.identified.params, blimp_control.QUICK_SETUP if quick else blimp_control.DEFAULT_SETUP,
        seed=seed, progress=progress)
    return SeedRun(seed, fitted, first, second, second_paths, third, third_paths, setup)


def reproduce_blimp(out_dir, *, seeds=DEFAULT_SEEDS, progress: bool = True, quick: bool = False,
                    map_seeds=None) -> dict:
    """Run Tables I, II and III for each seed; write ``results.json``, ``report.md``, the figures,
    and the first seed's RKGP model file ``blimp_rkgp.npz`` and its FMU to ``out_dir``.

    Parameters
    ----------
    out_dir : path
    seeds : sequence of int, default :data:`DEFAULT_SEEDS`
        For seed s: training flight i ``SeedSequence([s, 0, i])``, held-out flight i
        ``SeedSequence([s, 1, i])`` (commands and stand-in), start states ``default_rng([s, 2])``,
        GP restarts ``s``; Table II stand-in run i ``[s, 3, i]`` and its samples ``[s, 3]``, its
        calibration's commands and samples ``[s, 7]`` and stand-in run i ``[s, 7, i]``;
        Table III scenario i ``[s, 4, i]``, stand-in turn i ``[s, 5, i]``.
    progress : bool
        Progress bars on stderr.
    quick : bool
        The ``QUICK_SETUP`` of each table (shorter flights, 20 start states, 20 samples, a short
        policy search; for tests) instead of the ``DEFAULT_SETUP``.
    map_seeds : callable, optional
        ``map_seeds(run, seeds) -> list`` of ``run(seed)`` in seed order, where the seeds run
        elsewhere (``flightgp reproduce blimp --cluster-workers N`` maps them over a Dask
        cluster: docs/campaigns.md); by default one after the other here. Each seed's numbers
        depend on its seed alone, so where it runs changes nothing.

    Returns
    -------
    dict
        The content of ``results.json``.
    """
    out_dir = Path(out_dir)
    seeds = [int(s) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be distinct and at least one, got {seeds}")
    started = clock.perf_counter()
    if map_seeds is not None:
        runs = list(map_seeds(functools.partial(run_seed, quick=quick), seeds))
    else:
        runs = []
        with progress_bar("blimp campaign", enabled=progress, total=len(seeds), unit="seed") as update:
            for seed in seeds:
                runs.append(run_seed(seed, quick=quick, progress=progress))
                if update:
                    update(1)
    results = blimp_report.assemble_results(runs, quick=quick)
    results["fmu"] = _save_rkgp_model(out_dir, runs[0].fitted)
    figures = {"table1.png": blimp_report.table1_figure(results),
               "predictions.png": blimp_prediction.prediction_figure(runs[0].table1),
               "table2.png": blimp_spread.table2_figure(runs[0].table2_paths),
               "table3.png": blimp_control.table3_figure(runs[0].table3_paths)}
    for name, figure in figures.items():
        write_atomically(out_dir / name, png_bytes(figure))
    results["total_seconds"] = clock.perf_counter() - started
    write_json(out_dir / "results.json", results)
    write_atomically(out_dir / "report.md", blimp_report.report_markdown(results, figures=list(figures)))
    return results


def _save_rkgp_model(out_dir: Path, fitted: FittedModels) -> dict:
    """The RKGP model as a portable file and as the blimp RKGP FMU built from it."""
    description = BlimpStepDescription(fitted.identified.params, max_step=RK_MAX_STEP, command_lags=COMMAND_LAGS)
    model_path = write_atomically(out_dir / "blimp_rkgp.npz",
                                  model_bytes(fitted.models["RKGP"], physics=description.as_dict()))
    return {"model": model_path.name, "fmu": build_blimp_rkgp_fmu(model_path, out_dir, name="blimp_rkgp").name}
