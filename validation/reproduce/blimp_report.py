"""The blimp RKGP campaign's summaries over seeds, its goals, notes and report.

The goals are the reproduction's targets for Ko, Klein, Fox & Haehnel (ICRA 2007), Tables I-III,
on the ``blimp-flight`` stand-in (docs/reproductions.md, "Blimp RKGP"): RKGP better than RK and
than GP-only on every state group for every seed, and by at least Ko et al.'s margin (3x) on
position and velocity; the RKGP-with-noise end-point spread, at the spread scale calibrated on
validation repeats, within 30 % of the stand-in's, and the latent-only one narrower; the
RKGP-learned controller's yaw error at least 2x smaller than the RK-learned one's. A goal is met
or missed by the measured number; nothing is rounded.
"""
from __future__ import annotations

from dataclasses import asdict

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from validation.models.blimp_greybox import COMMAND_LAGS, GP_STATE_COLUMNS, ard_relevance, lag_names
from validation.reproduce.blimp_prediction import (
    COMMAND_HOLD,
    COMMAND_RANGES,
    FILTER_WARMUP_FRAMES,
    GROUPS,
    HORIZON_FRAMES,
    METHOD_STYLES,
    METHODS,
    START_KINDS,
)
from validation.vehicles.blimp import INPUT_NAMES, STATE_NAMES
from validation.vehicles.blimp_flight import FLIGHT_TEST_PARAMETERS

#: Ko et al.'s Table I margin of RKGP over RK on position and velocity (7.6 / 1.0 mm and
#: 25.1 / 4.2 mm/s: 7.6x and 6.0x); the goal asks for at least this factor.
TABLE1_MARGIN = 3.0
TABLE1_MARGIN_GROUPS = ("position", "velocity")
#: Table II: the calibrated sampled-with-noise spread within this fraction of the stand-in's.
TABLE2_TOLERANCE = 0.30
#: Table III: the RK-learned controller's yaw error over the RKGP-learned one's, at least.
TABLE3_FACTOR = 2.0
GROUP_UNITS = {"position": "m", "orientation": "rad", "velocity": "m/s", "angular_velocity": "rad/s"}


def assemble_results(runs, *, quick: bool) -> dict:
    """The content of ``results.json`` (without the FMU and the total time) from the seeds'
    :class:`validation.reproduce.blimp.SeedRun` (the setup recorded is the one the first seed
    ran)."""
    setup = runs[0].setup
    first = runs[0].fitted
    results = {
        "case": "Ko et al. (ICRA 2007) Tables I-III on the blimp-flight stand-in",
        "units": "Table I: RMSE over start states of the Euclidean error norm of each state group at "
                 "the 1 s horizon against the recording: position m, orientation rad (yaw wrapped), "
                 "velocity m/s, angular velocity rad/s; time_s: wall time of one one-second prediction",
        "seeds": [run.seed for run in runs],
        "setup": {**asdict(setup), "quick": quick,
                  "commands": {"distribution": f"uniform, independent, held {COMMAND_HOLD} s (4 Hz)",
                               "ranges": {k: list(v) for k, v in COMMAND_RANGES.items()}},
                  "horizon_frames": HORIZON_FRAMES, "filter_warmup_frames": FILTER_WARMUP_FRAMES,
                  "rk_step": "one RK4 step per mocap frame", "ode": "scipy RK45 per frame, rtol 1e-8, atol 1e-10",
                  "gp_inputs": [STATE_NAMES[c] for c in GP_STATE_COLUMNS] + [*INPUT_NAMES, "dt",
                                                                              *lag_names(COMMAND_LAGS)],
                  "gp_training_points": first.n_gp_points,
                  "gp": "one squared-exponential ARD GP per residual output, trained on smoothed states, "
                        "type-II maximum likelihood with a noise floor (validation.models.blimp_greybox)",
                  "start_kinds": {"filtered": "the RKGP extended Kalman filter's estimate from the recorded "
                                              "poses up to the start frame (every method starts there)",
                                  "recorded": "the recorded state (Ko et al.)",
                                  "true": "the stand-in's true state"}},
        "table1": {"by_seed": {str(run.seed): run.table1.table for run in runs}},
        "table2": {"by_seed": {str(run.seed): run.table2 for run in runs}},
        "table3": {"by_seed": {str(run.seed): run.table3 for run in runs}},
        "identification": {str(run.seed): _identification(run.fitted.identified) for run in runs},
        "ard_relevance": ard_relevance(first.models["RKGP"]),
        "seconds": {str(run.seed): run.fitted.seconds for run in runs},
    }
    results["table1"]["summary"] = table1_summary(results["table1"]["by_seed"])
    results["table2"]["summary"] = table2_summary(results["table2"]["by_seed"])
    results["table3"]["summary"] = table3_summary(results["table3"]["by_seed"])
    results["goals"] = goals(results)
    results["notes"] = notes(results)
    return results


def _identification(identified) -> dict:
    truth = dict(zip(FLIGHT_TEST_PARAMETERS.vector_names(), FLIGHT_TEST_PARAMETERS.to_vector()))
    return {"parameters": {name: {**entry, "stand_in_value": float(truth[name])}
                           for name, entry in identified.as_dict().items()},
            "n_segments": identified.n_segments, "rms_scaled_residual": identified.rms_residual}


def table1_summary(by_seed: dict) -> dict:
    """Over the seeds, per start kind: each method's mean RMSE per group, the noise floor's, the
    ratios RK / RKGP and GPonly / RKGP per seed and group, and their smallest value."""
    seeds = list(by_seed)
    summary = {"noise_floor": {g: float(np.mean([by_seed[s]["noise_floor"][g] for s in seeds])) for g in GROUPS}}
    for kind in START_KINDS:
        entry = {"mean": {m: {g: float(np.mean([by_seed[s][kind][m][g] for s in seeds])) for g in GROUPS}
                          for m in METHODS}}
        for other in ("RK", "GPonly"):
            ratios = {s: {g: by_seed[s][kind][other][g] / by_seed[s][kind]["RKGP"][g] for g in GROUPS} for s in seeds}
            entry[f"{other}_over_RKGP"] = ratios
            entry[f"{other}_over_RKGP_smallest"] = {g: float(min(r[g] for r in ratios.values())) for g in GROUPS}
        summary[kind] = entry
    return summary


def table2_summary(by_seed: dict) -> dict:
    """Per seed the sampled spreads over the stand-in's (with noise, latent only, and with noise
    at the spread scale calibrated on validation repeats) and that scale."""
    summary = {key: {s: t[key] for s, t in by_seed.items()}
               for key in ("spread_ratio_noise", "spread_ratio_latent", "spread_ratio_calibrated")}
    summary["spread_scale"] = {s: t["calibration"]["spread_scale"] for s, t in by_seed.items()}
    return summary


def table3_summary(by_seed: dict) -> dict:
    """Mean over seeds of each learned controller's mean yaw error on the stand-in, and the
    ratio RK / RKGP per seed and of the means."""
    from validation.reproduce.blimp_control import LEARNED_IN

    mean = {name: float(np.mean([t[name]["yaw_error_deg"] for t in by_seed.values()])) for name in LEARNED_IN}
    return {"yaw_error_deg": mean, "ratio_RK_to_RKGP": {s: t["yaw_error_ratio_RK_to_RKGP"] for s, t in by_seed.items()},
            "ratio_of_means_RK_to_RKGP": mean["RK"] / mean["RKGP"]}


def goals(results: dict) -> dict:
    """Each goal with its target, the measured value and whether it is met."""
    first = results["table1"]["summary"]["filtered"]
    by_seed3 = results["table3"]["by_seed"]
    ratios2 = results["table2"]["summary"]["spread_ratio_calibrated"]
    latent_narrower = {s: t["rkgp_sampled"]["position_spread_m"] < t["rkgp_sampled_noise"]["position_spread_m"]
                       for s, t in results["table2"]["by_seed"].items()}
    out = {}
    for other in ("RK", "GPonly"):
        smallest = first[f"{other}_over_RKGP_smallest"]
        out[f"table1_RKGP_beats_{other}_every_group_and_seed"] = {
            "target": "ratio > 1 for every group and seed", "measured_smallest_ratio": smallest,
            "met": all(v > 1.0 for v in smallest.values())}
    margin = {g: first["RK_over_RKGP_smallest"][g] for g in TABLE1_MARGIN_GROUPS}
    out["table1_margin_over_RK"] = {"target": f">= {TABLE1_MARGIN:g}x on {' and '.join(TABLE1_MARGIN_GROUPS)} "
                                              "for every seed", "measured_smallest_ratio": margin,
                                    "met": all(v >= TABLE1_MARGIN for v in margin.values())}
    out["table2_calibrated_spread_within_30_percent"] = {
        "target": f"|ratio - 1| <= {TABLE2_TOLERANCE:g} for every seed, the spread scale chosen on validation "
                  "repeats", "measured_ratio": ratios2,
        "met": all(abs(r - 1.0) <= TABLE2_TOLERANCE for r in ratios2.values())}
    out["table2_latent_narrower_than_with_noise"] = {"target": "every seed", "measured": latent_narrower,
                                                     "met": all(latent_narrower.values())}
    ratios3 = {s: t["yaw_error_ratio_RK_to_RKGP"] for s, t in by_seed3.items()}
    out["table3_rkgp_controller_2x_better"] = {
        "target": f"RK-learned / RKGP-learned mean yaw error >= {TABLE3_FACTOR:g} over the seeds' mean",
        "measured_ratio_of_means": results["table3"]["summary"]["ratio_of_means_RK_to_RKGP"],
        "measured_by_seed": ratios3,
        "met": results["table3"]["summary"]["ratio_of_means_RK_to_RKGP"] >= TABLE3_FACTOR}
    return out


def notes(results: dict) -> list[str]:
    """Plain-words remarks on what the numbers show and what does not come out as in the paper."""
    summary = results["table1"]["summary"]
    floor = summary["noise_floor"]
    filtered, recorded, true = (summary[k] for k in START_KINDS)
    out = []
    for name, goal in results["goals"].items():
        if not goal["met"]:
            out.append(f"Goal missed: {name} (target {goal['target']}; measured "
                       f"{_brief({k: v for k, v in goal.items() if k.startswith('measured')})}).")
    out.append(
        "Table I, filtered starts, mean over seeds: RKGP position {:.4f} m against RK {:.4f} m "
        "(noise floor {:.4f} m), velocity {:.4f} against {:.4f} m/s (floor {:.4f}). From the recorded "
        "(noisy) starts, Ko et al.'s literal protocol: RKGP {:.4f} against RK {:.4f} m, {:.4f} against "
        "{:.4f} m/s; the start's differentiation noise (6 mm/s) alone carries about 6 mm over a second. "
        "From the true states (dynamics error alone, against the recording): RKGP {:.4f} against RK "
        "{:.4f} m.".format(
            filtered["mean"]["RKGP"]["position"], filtered["mean"]["RK"]["position"], floor["position"],
            filtered["mean"]["RKGP"]["velocity"], filtered["mean"]["RK"]["velocity"], floor["velocity"],
            recorded["mean"]["RKGP"]["position"], recorded["mean"]["RK"]["position"],
            recorded["mean"]["RKGP"]["velocity"], recorded["mean"]["RK"]["velocity"],
            true["mean"]["RKGP"]["position"], true["mean"]["RK"]["position"]))
    out.append(
        "Angular velocity is at the noise floor for every method ({:.3f} rad/s: the recorded rates are "
        "slopes of 0.5 deg noisy angles); differences there are not meaningful.".format(floor["angular_velocity"]))
    table2 = results["table2"]["summary"]
    out.append(
        "Table II: sampled-with-noise spread over the stand-in's, by seed: {}; latent only: {}; with "
        "noise at the spread scale chosen on validation repeats ({}): {}. The stand-in's spread is "
        "run-to-run variability (buoyancy drift, frame jitter) plus 1 mm marker noise on the end frame; "
        "the RKGP's is the GPs' posterior uncertainty about the model error along this command "
        "sequence, which as fitted is wider.".format(
            _brief(table2["spread_ratio_noise"]), _brief(table2["spread_ratio_latent"]),
            _brief(table2["spread_scale"]), _brief(table2["spread_ratio_calibrated"])))
    table3 = results["table3"]["summary"]
    out.append(
        "Table III: mean yaw error on the stand-in over seeds: learned in RK {:.2f} deg, in RKGP {:.2f} "
        "deg, on the stand-in itself {:.2f} deg (the best this 4-parameter controller does within the "
        "same search budget). Most of the RMS is the 90 deg transient itself (a full-command turn takes "
        "about 3 s), which bounds how much any controller can improve on another.".format(
            table3["yaw_error_deg"]["RK"], table3["yaw_error_deg"]["RKGP"], table3["yaw_error_deg"]["stand_in"]))
    return out


def _brief(value) -> str:
    """A compact rendering of nested numbers (3 significant digits)."""
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_brief(v)}" for k, v in value.items()) + "}"
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


def table1_figure(results: dict) -> Figure:
    """Table I as bars: per state group, each method's RMSE from filtered starts (one dot per
    seed, the bar their mean), the noise floor as a line."""
    by_seed = results["table1"]["by_seed"]
    figure = Figure(figsize=(14, 4), layout="constrained")
    FigureCanvasAgg(figure)
    panels = figure.subplots(1, len(GROUPS))
    x = np.arange(len(METHODS))
    for panel, group in zip(panels, GROUPS):
        for i, method in enumerate(METHODS):
            values = [t["filtered"][method][group] for t in by_seed.values()]
            panel.bar(i, np.mean(values), color=METHOD_STYLES[method][0], alpha=0.6)
            panel.plot(np.full(len(values), i), values, "k.", ms=4)
        panel.axhline(results["table1"]["summary"]["noise_floor"][group], color="k", lw=1, ls="--",
                      label="noise floor")
        panel.set_xticks(x, METHODS, rotation=30)
        panel.set_title(f"{group} [{GROUP_UNITS[group]}]")
        panel.set_yscale("log")
        panel.grid(True, axis="y", alpha=0.3)
    panels[0].legend(fontsize="small")
    figure.suptitle(f"Blimp Table I: one-second RMSE from filtered start states, {len(by_seed)} seeds "
                    "(dots: seeds, bars: mean)")
    return figure


def format_results(results: dict) -> str:
    """Tables I-III and the goals as plain text."""
    summary1 = results["table1"]["summary"]
    header = f"{'':8}" + "".join(f"{g[:11]:>12}" for g in GROUPS)
    units = f"{'':8}" + "".join(f"{'[' + GROUP_UNITS[g] + ']':>12}" for g in GROUPS)
    lines = [results["case"], f"seeds {results['seeds']}", ""]
    for kind in START_KINDS:
        lines += [f"Table I, {kind} starts: RMSE at 1 s, mean over seeds", header, units]
        for method in METHODS:
            lines.append(f"{method:8}" + "".join(f"{summary1[kind]['mean'][method][g]:12.4f}" for g in GROUPS))
        lines.append(f"{'floor':8}" + "".join(f"{summary1['noise_floor'][g]:12.4f}" for g in GROUPS))
        lines.append(f"{'RK/RKGP':8}" + "".join(
            f"{summary1[kind]['RK_over_RKGP_smallest'][g]:11.2f}x" for g in GROUPS) + "  (smallest over seeds)")
        lines.append("")
    time_s = np.mean([[t["filtered"][m]["time_s"] for m in METHODS] for t in results["table1"]["by_seed"].values()],
                     axis=0)
    lines.append("time per one-second prediction [s]: " + ", ".join(f"{m} {v:.2e}" for m, v in zip(METHODS, time_s)))
    lines += ["", "Table II: end-point spread (mean distance from the mean end point) [m], per seed",
              f"{'seed':>6}{'stand-in':>11}{'RKGP+noise':>12}{'RKGP latent':>12}{'ratio':>8}{'offset':>9}"
              f"{'scale':>8}{'calibrated':>12}{'ratio':>8}"]
    for seed, t in results["table2"]["by_seed"].items():
        lines.append(f"{seed:>6}{t['stand_in']['position_spread_m']:11.4f}"
                     f"{t['rkgp_sampled_noise']['position_spread_m']:12.4f}"
                     f"{t['rkgp_sampled']['position_spread_m']:12.4f}{t['spread_ratio_noise']:8.2f}"
                     f"{t['rkgp_mean']['offset_from_stand_in_m']:9.4f}{t['calibration']['spread_scale']:8.3f}"
                     f"{t['rkgp_calibrated_noise']['position_spread_m']:12.4f}{t['spread_ratio_calibrated']:8.2f}")
    lines.append("(scale: the posterior's standard deviations times it, chosen on validation repeats of other "
                 "commands; calibrated: the samples with noise at that scale)")
    lines += ["", "Table III: mean RMS yaw error of stand-in turns [deg] by where the controller was learned",
              f"{'seed':>6}{'RK':>9}{'RKGP':>9}{'stand-in':>10}{'RK/RKGP':>9}"]
    for seed, t in results["table3"]["by_seed"].items():
        lines.append(f"{seed:>6}{t['RK']['yaw_error_deg']:9.2f}{t['RKGP']['yaw_error_deg']:9.2f}"
                     f"{t['stand_in']['yaw_error_deg']:10.2f}{t['yaw_error_ratio_RK_to_RKGP']:9.2f}")
    lines += ["", "goals:"]
    for name, goal in results["goals"].items():
        lines.append(f"  {'met   ' if goal['met'] else 'MISSED'} {name}: {goal['target']}")
    lines += [f"note: {note}" for note in results["notes"]]
    return "\n".join(lines)


def report_markdown(results: dict, *, figures) -> str:
    """``report.md``: the goals, Tables I-III, ARD relevance, notes and the figures."""
    summary1 = results["table1"]["summary"]
    lines = ["# Blimp RKGP: Ko et al. (ICRA 2007) Tables I-III on the blimp-flight stand-in", "",
             f"Seeds {results['seeds']}" + (" (quick setup: not the reported configuration)"
                                            if results["setup"]["quick"] else "") + ".", "", "## Goals", "",
             "| goal | target | met |", "|---|---|---|"]
    for name, goal in results["goals"].items():
        lines.append(f"| {name} | {goal['target']} | {'yes' if goal['met'] else '**no**'} |")
    for kind in START_KINDS:
        lines += ["", f"## Table I, {kind} starts (RMSE at 1 s, mean over seeds)", "",
                  "| method | " + " | ".join(f"{g} [{GROUP_UNITS[g]}]" for g in GROUPS) + " |",
                  "|---|" + "---|" * len(GROUPS)]
        for method in METHODS:
            lines.append(f"| {method} | " + " | ".join(f"{summary1[kind]['mean'][method][g]:.4f}" for g in GROUPS)
                         + " |")
        lines.append("| noise floor | " + " | ".join(f"{summary1['noise_floor'][g]:.4f}" for g in GROUPS) + " |")
        lines.append("| RK / RKGP, smallest over seeds | " + " | ".join(
            f"{summary1[kind]['RK_over_RKGP_smallest'][g]:.2f}x" for g in GROUPS) + " |")
    text = format_results(results)
    lines += ["", "## Tables II and III", "", "```", text[text.index("Table II:"):text.index("\ngoals:")], "```"]
    lines += ["", "## ARD relevance of the RKGP inputs (seed " + str(results["seeds"][0]) + ")", "",
              "Share of each residual GP's ARD weights; the three largest per output:", ""]
    for output, shares in results["ard_relevance"].items():
        top = sorted(shares.items(), key=lambda item: -item[1])[:3]
        lines.append(f"- {output}: " + ", ".join(f"{name} {share:.2f}" for name, share in top))
    lines += ["", "## Notes", "", *[f"- {note}" for note in results["notes"]], "", "## Figures", ""]
    lines += [f"![{name}]({name})" for name in figures]
    return "\n".join(lines) + "\n"
