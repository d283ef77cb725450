"""``flightgp demo``: the built-in Bo105 case, end to end.

1. Record and train: the paper part of :func:`validation.reproduce.bo105.reproduce_bo105`
   (the flight-test stand-in's 80 kt 3-2-1-1 and an unseen one, a GP-NARX with Higdon's kernel
   and simulated annealing, Monte Carlo free runs against the physics reference).
2. Export: the trained model as a rate-predictor FMU (and the physics reference as an FMU).
3. Co-simulate: both FMUs in fmpy under each recording's inputs, compared with the recording.
4. Report: ``report.md`` with the tables and figures; the FMUs stay in the folder.
"""
from __future__ import annotations

from pathlib import Path

from fmu_src import build_bo105_reference_fmu, build_rate_predictor_fmu
from validation.core.files import write_atomically
from validation.cosim.cosimulation import cosimulate
from validation.reproduce.bo105 import format_results, reproduce_bo105
from validation.vehicles import read_recording


def run_demo(out_dir, *, seed: int = 0, n_runs: int = 1000, progress: bool = True) -> dict:
    """Run the demo into ``out_dir``; returns ``{"results": ..., "cosim": {...}}``."""
    out_dir = Path(out_dir)
    results = reproduce_bo105(out_dir, seed=seed, n_runs=n_runs, beyond=False, progress=progress)
    gp_fmu = build_rate_predictor_fmu(out_dir / "bo105_gp_narx.npz", out_dir, name="bo105_gp_rate_predictor")
    reference_fmu = build_bo105_reference_fmu(80, out_dir, name="bo105_80kt_reference")
    cosim = {}
    for name in ("training", "unseen"):
        recording = read_recording(out_dir / f"flight_test_{name}.csv")
        result = cosimulate(gp_fmu, recording, reference_fmu=reference_fmu, out_dir=out_dir / f"cosim_{name}")
        cosim[name] = {"rmse": result.rmse(), "coverage": result.coverage()}
    write_atomically(out_dir / "report.md", _report(results, cosim))
    return {"results": results, "cosim": cosim}


def format_cosim(cosim: dict) -> str:
    """The co-simulation RMSE table of the demo."""
    lines = [f"{'fmpy co-simulation, RMSE [rad/s]':40}{'p':>9}{'q':>9}{'r':>9}"]
    for name, entry in cosim.items():
        for model, label in (("gp", "GP FMU (free run)"), ("reference", "reference FMU")):
            if model in entry["rmse"]:
                values = entry["rmse"][model]
                lines.append(f"{name + ' manoeuvre, ' + label:40}" + "".join(f"{values[a]:9.4f}" for a in "pqr"))
    return "\n".join(lines)


def _report(results: dict, cosim: dict) -> str:
    return "\n".join([
        "# flightgp demo: Bo105 80 kt GP-NARX rate predictor",
        "",
        "Python model (Monte Carlo free run, 1000 runs) against the flight-test stand-in:",
        "",
        "```", format_results(results), "```",
        "",
        "The same model exported as an FMU (`bo105_gp_rate_predictor.fmu`, free-run mode: it feeds "
        "back its predicted means) and co-simulated in fmpy:",
        "",
        "```", format_cosim(cosim), "```",
        "",
        "![free run](fmp.png)", "![unseen manoeuvre](fmp_unseen.png)",
        "![fmpy co-simulation](cosim_training/cosim.png)", "",
    ])
