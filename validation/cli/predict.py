"""``flightgp predict``: a GP-NARX model's predictions (free run or one step) of a recording."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from fmu_src.fmi.runtime import ENVELOPE_MARGIN
from validation.cli.arguments import add_format_argument, seed
from validation.core.errors import BadInputError
from validation.core.files import check_output_folder, write_files_atomically
from validation.models.narx import free_run, load_trained, one_step, unseen_inputs
from validation.vehicles import read_recording

METHODS = ("monte_carlo", "moment_matching", "mean", "one_step")


def register(subparsers) -> None:
    predict = subparsers.add_parser(
        "predict", help="predict a recording with a GP-NARX model",
        description="Predict the model's outputs under a recording's inputs and write "
                    "time, measured, mean and 95 %% bounds per output as CSV.")
    predict.add_argument("model", type=Path, metavar="MODEL.npz")
    predict.add_argument("recording", type=Path, metavar="RECORDING")
    predict.add_argument("--out", type=Path, required=True, metavar="PREDICTION.csv")
    add_format_argument(predict)
    predict.add_argument("--method", choices=METHODS, default="monte_carlo",
                         help="free run by Monte Carlo (default), moment matching or mean; or one_step")
    predict.add_argument("--runs", type=int, default=1000, help="Monte Carlo runs (default 1000)")
    predict.add_argument("--seed", type=seed, default=0)
    predict.add_argument("--plot", action="store_true", help="also write PREDICTION.png")
    predict.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.out.suffix != ".csv":
        raise BadInputError(f"{args.out}: the prediction file name must end in .csv")
    if args.runs < 1:
        raise BadInputError(f"--runs must be at least 1, got {args.runs}")
    plot_path = args.out.with_suffix(".png")
    outputs = [args.out] + ([plot_path] if args.plot else [])
    check_output_folder(args.out.parent, writes=[path.name for path in outputs])
    trained = load_trained(args.model)
    recording = read_recording(args.recording, file_format=args.file_format)
    name = str(args.recording)
    for phrase in unseen_inputs(trained, recording, margin=ENVELOPE_MARGIN):
        print(f"flightgp predict: warning: {phrase}", file=sys.stderr)
    if args.method == "one_step":
        prediction = one_step(trained, recording, name=name)
    else:
        prediction = free_run(trained, recording, method=args.method, n_runs=args.runs,
                              seed=args.seed, progress=True, name=name)
    band = 1.96 * np.sqrt(prediction.var)
    outputs = trained.config.outputs
    header = ["time"] + [f"{o}_{part}" for o in outputs for part in ("measured", "mean", "lower", "upper")]
    columns = [prediction.time]
    for j in range(len(outputs)):
        columns += [prediction.measured[:, j], prediction.mean[:, j],
                    prediction.mean[:, j] - band[:, j], prediction.mean[:, j] + band[:, j]]
    table = np.column_stack(columns)
    png = None
    if args.plot:
        from validation.core.plots import png_bytes
        from validation.reproduce.bo105 import paper_figure

        png = png_bytes(paper_figure(prediction, None, title=f"{args.method}: {args.recording.name}",
                                     axes=outputs))
    lines = [",".join(header)] + [",".join(map(repr, row)) for row in table.tolist()]
    files = {args.out: "\n".join(lines) + "\n"}
    if png is not None:
        files[plot_path] = png
    write_files_atomically(files)
    print(f"{args.method} prediction of {args.recording} ({len(prediction.time)} samples, "
          f"step {trained.step:g} s); wrote {args.out}")
    print(f"{'output':>8} {'RMSE':>10} {'95 % coverage':>14}")
    for output, rmse, coverage in zip(outputs, prediction.rmse(), prediction.coverage()):
        print(f"{output:>8} {rmse:10.4g} {coverage:14.2f}")
    return 0
