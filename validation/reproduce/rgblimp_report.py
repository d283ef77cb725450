"""The RGBlimp real-flight reproduction's models by name, its figures, text table and report
(:mod:`validation.reproduce.rgblimp` runs the models and imports these names)."""
from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

#: The models, in the order of every table (``sindyc``: the peer of
#: :mod:`validation.models.rgblimp_sindyc`).
MODELS = ("physics", "identified", "rkgp", "rkgp_global", "sindyc", "hybrid", "hybrid_global")
#: The models with a propagated uncertainty band.
BAND_MODELS = ("rkgp", "rkgp_global", "hybrid", "hybrid_global")
#: Normal quantile of a two-sided 95 % band.
BAND_QUANTILE = 1.959963984540054

#: Colour and line style of each model in every figure.
STYLES = {"physics": ("tab:red", "--"), "identified": ("tab:orange", "-."), "rkgp": ("tab:blue", "-"),
          "rkgp_global": ("tab:green", ":"), "sindyc": ("tab:purple", (0, (3, 1, 1, 1))),
          "hybrid": ("tab:cyan", "-"), "hybrid_global": ("tab:olive", "-")}
#: The states drawn against time in a flight figure: column, name, unit.
_TIME_PANELS = ((0, "x", "m"), (1, "y", "m"), (2, "z", "m"), (3, "roll phi", "rad"), (4, "pitch theta", "rad"))


def figures(results: dict, runs, *, count: int) -> dict:
    """``scores.png`` (every configuration) and ``flight_<j>.png`` for up to ``count``
    configurations spread over those run: name -> Figure."""
    out = {"scores.png": scores_figure(results)}
    chosen = sorted({int(round(i)) for i in np.linspace(0, len(runs) - 1, min(count, len(runs)))})
    for index in chosen:
        run = runs[index]
        out[f"flight_{run.split.configuration}.png"] = flight_figure(run)
    return out


def scores_figure(results: dict) -> Figure:
    """The source's score and the position RMSE of each model on each configuration's test
    flight (log scales)."""
    entries = results["configurations"]
    index = [e["index"] for e in entries]
    figure = Figure(figsize=(12, 6), layout="constrained")
    FigureCanvasAgg(figure)
    panels = figure.subplots(2, 1, sharex=True)
    for panel, key, label in ((panels[0], "score", "source's score"),
                              (panels[1], "position_rmse_m", "position RMSE [m]")):
        for name in MODELS:
            colour, style = STYLES[name]
            panel.plot(index, [e[key][name] for e in entries], marker="o", ms=4, color=colour, ls=style,
                       label=f"{name} (mean {results['summary']['mean_' + key][name]:.3g})")
        panel.set_yscale("log")
        panel.set_ylabel(label)
        panel.grid(True, which="both", alpha=0.3)
    panels[0].legend(fontsize="small", ncol=2)
    panels[1].set_xlabel("configuration j (test flight: the highest-numbered flight present)")
    figure.suptitle("RGBlimp: free run of each test flight from its first recorded state")
    return figure


def flight_figure(run) -> Figure:
    """One test flight: the 3-D track of the recording and of every model's free run, and the
    positions, roll and pitch against time with the band models' 95 % bands."""
    figure = Figure(figsize=(15, 11), layout="constrained")
    FigureCanvasAgg(figure)
    grid = figure.add_gridspec(len(_TIME_PANELS), 2, width_ratios=(1.1, 1.0))
    track = figure.add_subplot(grid[:, 0], projection="3d")
    recorded = run.recorded
    # z is down (docs/conventions.md, "Units and axes"): draw height -z upwards.
    track.plot(recorded[:, 0], recorded[:, 1], -recorded[:, 2], color="k", lw=1.5, label="recorded")
    for name in MODELS:
        colour, style = STYLES[name]
        path = run.predicted[name]
        track.plot(path[:, 0], path[:, 1], -path[:, 2], color=colour, ls=style, lw=1, label=name)
    track.scatter(*recorded[0, :2], -recorded[0, 2], color="k", s=20)
    track.set_xlabel("x [m]")
    track.set_ylabel("y [m]")
    track.set_zlabel("height -z [m]")
    track.legend(fontsize="small", loc="upper left")
    for row, (column, name, unit) in enumerate(_TIME_PANELS):
        axis = figure.add_subplot(grid[row, 1])
        axis.plot(run.time, recorded[:, column], color="k", lw=1.5, label="recorded")
        for model in MODELS:
            colour, style = STYLES[model]
            axis.plot(run.time, run.predicted[model][:, column], color=colour, ls=style, lw=1, label=model)
            if model in BAND_MODELS:
                half = BAND_QUANTILE * run.sd[model][:, column]
                axis.fill_between(run.time, run.predicted[model][:, column] - half,
                                  run.predicted[model][:, column] + half, color=colour, alpha=0.15, lw=0)
        # The recording's range with a margin as wide again: a band that grows past it (the
        # RKGPs' do) is cut rather than flattening the recording.
        low, high = recorded[:, column].min(), recorded[:, column].max()
        margin = max(high - low, 0.05 if unit == "rad" else 0.5)
        axis.set_ylim(low - margin, high + margin)
        axis.set_ylabel(f"{name} [{unit}]")
        axis.grid(True, alpha=0.3)
    axis.set_xlabel("time [s]")
    figure.axes[1].legend(fontsize="small", ncol=3)
    fit = ", ".join(f"data_{n}" for n in run.split.fit)
    figure.suptitle(f"RGBlimp configuration {run.split.configuration} ({run.split.kind}): test flight "
                    f"data_{run.split.test}, fitted on {fit}; bands: 95 % of the RKGPs' propagated covariance "
                    "and of the hybrids' disturbed runs")
    return figure


def format_results(results: dict) -> str:
    """Every configuration's score and position RMSE per model, the means and the goals, as text."""
    lines = [results["case"], "",
             f"{'j':>3} {'test':>13}" + "".join(f"{name:>13}" for name in MODELS)
             + "".join(f"{'cov ' + name:>17}" for name in BAND_MODELS),
             f"{'':17}" + "".join(f"{'score / m':>13}" for _ in MODELS)]
    for entry in results["configurations"]:
        lines.append(f"{entry['index']:>3} {entry['test']:>13}"
                     + "".join(_score_text(entry, n) for n in MODELS)
                     + "".join(f"{entry['coverage95_position'][n]:17.2f}" for n in BAND_MODELS))
    summary = results["summary"]
    lines.append(f"{'mean':>17}" + "".join(f"{summary['mean_score'][n]:7.4f}/{summary['mean_position_rmse_m'][n]:5.2f}"
                                           for n in MODELS)
                 + "".join(f"{summary['mean_coverage95_position'][n]:17.2f}" for n in BAND_MODELS))
    alone = summary["identified_global"]
    lines.append(f"(the global RKGP's identified model alone: mean score {alone['mean_score']:.4f}, "
                 f"position RMSE {alone['mean_position_rmse_m']:.2f} m)")
    if any(summary["diverged"].values()):
        lines.append("diverged free runs (left out of the means): " + ", ".join(
            f"{n} {count}" for n, count in summary["diverged"].items() if count))
    lines += ["", "beats physics in score on: " + ", ".join(
        f"{n} {summary['beats_physics_in_score'][n]} of {summary['n_configurations']}" for n in MODELS[1:]), "",
        "goals:"]
    for name, goal in results["goals"].items():
        lines.append(f"  {'met   ' if goal['met'] else 'MISSED'} {name}: {goal['target']} (measured "
                     f"{_brief(goal['measured'])})")
    return "\n".join(lines)


def report_markdown(results: dict, *, figures) -> str:
    """``report.md``: the goals, the summary, every configuration and the figures."""
    summary = results["summary"]
    lines = ["# RGBlimp real flights: first-principle model, identified model and RKGP", "",
             results["case"] + ".", "", results["units"] + ".", "", "## Goals", "",
             "| goal | target | measured | met |", "|---|---|---|---|"]
    for name, goal in results["goals"].items():
        lines.append(f"| {name} | {goal['target']} | {_brief(goal['measured'])} | "
                     f"{'yes' if goal['met'] else '**no**'} |")
    lines += ["", f"## Summary over {summary['n_configurations']} configurations", "",
              "| model | mean score | mean position RMSE [m] | mean final error [m] | mean yaw RMSE [rad] | "
              "beats physics (score) | 95 % coverage |", "|---|---|---|---|---|---|---|"]
    n = summary["n_configurations"]
    for name in MODELS:
        beats = summary["beats_physics_in_score"].get(name)
        coverage = summary["mean_coverage95_position"].get(name)
        beats_text = "-" if beats is None else f"{beats} of {n}"
        coverage_text = "-" if coverage is None else f"{coverage:.2f}"
        lines.append(f"| {name} | {summary['mean_score'][name]:.5f} | {summary['mean_position_rmse_m'][name]:.3f} | "
                     f"{summary['mean_final_position_error_m'][name]:.3f} | {summary['mean_yaw_rmse_rad'][name]:.3f} | "
                     f"{beats_text} | {coverage_text} |")
    alone = summary["identified_global"]
    lines += ["", f"The global RKGP's identified model alone (no GPs): mean score {alone['mean_score']:.5f}, "
                  f"mean position RMSE {alone['mean_position_rmse_m']:.3f} m. Free runs that diverged, left "
                  "out of the means: " + (", ".join(f"{n} {c}" for n, c in summary["diverged"].items() if c)
                                          or "none") + ".",
              "", "Mean wall time per configuration, s: fit " + ", ".join(
                  f"{n} {v:.2f}" for n, v in summary["mean_fit_seconds"].items()) + "; free run of the test "
              "flight " + ", ".join(f"{n} {v:.2f}" for n, v in summary["mean_free_run_seconds"].items()) + "."]
    lines += ["", "## Every configuration", "", "Score / position RMSE [m] of each model on the test flight.", "",
              "| j | fit | test | " + " | ".join(MODELS) + " | " + " | ".join(f"coverage {n}" for n in BAND_MODELS)
              + " |", "|---|---|---|" + "---|" * (len(MODELS) + len(BAND_MODELS))]
    for entry in results["configurations"]:
        lines.append(f"| {entry['index']} | {', '.join(entry['fit'])} | {entry['test']} | "
                     + " | ".join(_score_text(entry, n).strip() for n in MODELS)
                     + " | " + " | ".join(f"{entry['coverage95_position'][n]:.2f}" for n in BAND_MODELS) + " |")
    identification = results["global"]["identification"]["parameters"]
    lines += ["", "## Global identification", "", "| coefficient | published | identified | standard error |",
              "|---|---|---|---|"]
    for name, entry in identification.items():
        error = (f"{entry['standard_error']:.2g}" if entry["standard_error"] is not None else
                 f"n/a, too few segments (textbook {entry['standard_error_iid']:.2g})")
        lines.append(f"| {name} | {entry['initial']:.5g} | {entry['value']:.5g} | {error} |")
    lines += ["", "## Figures", "", *[f"![{name}]({name})" for name in figures]]
    return "\n".join(lines) + "\n"


def _score_text(entry: dict, name: str) -> str:
    """``score/position RMSE`` of one model on one test flight, or ``diverged``."""
    if entry["score"][name] is None:
        return f"{'diverged':>13}"
    return f"{entry['score'][name]:7.4f}/{entry['position_rmse_m'][name]:5.2f}"


def _brief(value) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)
