"""``flightgp train`` and ``flightgp predict``: GP-NARX models from recordings to model files and
back to predictions."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from .cli import seed
from .errors import BadInputError
from .files import write_atomically
from .narx import (HYPERPARAMETER_METHODS, KERNELS, NarxConfig, free_run, load_trained, one_step,
                   save_trained, train_narx)
from .plots import png_bytes
from .recordings import read_recording

METHODS = ("monte_carlo", "moment_matching", "mean", "one_step")


def register(subparsers) -> None:
    defaults = NarxConfig()
    train = subparsers.add_parser(
        "train", help="train a GP-NARX model on recordings",
        description="Train one GP per output on regressors built from the recordings (lags in "
                    "NARX steps of DECIMATION samples) and write a portable model file.")
    train.add_argument("recordings", nargs="+", type=Path, metavar="RECORDING")
    train.add_argument("--out", type=Path, required=True, metavar="MODEL.npz")
    train.add_argument("--vehicle", help="vehicle the recordings come from (default: their sidecar)")
    train.add_argument("--inputs", nargs="+", default=list(defaults.inputs), metavar="NAME")
    train.add_argument("--outputs", nargs="+", default=list(defaults.outputs), metavar="NAME")
    train.add_argument("--input-lags", nargs="+", type=int, default=list(defaults.input_lags), metavar="K")
    train.add_argument("--output-lags", nargs="+", type=int, default=list(defaults.output_lags), metavar="K")
    train.add_argument("--decimation", type=int, default=defaults.decimation,
                       help=f"NARX step in recording samples (default {defaults.decimation})")
    train.add_argument("--stride", type=int, default=defaults.stride,
                       help=f"train on every STRIDE-th NARX step (default {defaults.stride})")
    train.add_argument("--kernel", choices=KERNELS, default=defaults.kernel)
    train.add_argument("--hyperparameters", choices=HYPERPARAMETER_METHODS, default=defaults.hyperparameters)
    train.add_argument("--sparse", type=int, metavar="M", help="sparse GP with M inducing points")
    train.add_argument("--seed", type=seed, default=0)
    train.set_defaults(func=run_train)

    predict = subparsers.add_parser(
        "predict", help="predict a recording with a GP-NARX model",
        description="Predict the model's outputs under a recording's inputs and write "
                    "time, measured, mean and 95 %% bounds per output as CSV.")
    predict.add_argument("model", type=Path, metavar="MODEL.npz")
    predict.add_argument("recording", type=Path, metavar="RECORDING")
    predict.add_argument("--out", type=Path, required=True, metavar="PREDICTION.csv")
    predict.add_argument("--method", choices=METHODS, default="monte_carlo",
                         help="free run by Monte Carlo (default), moment matching or mean; or one_step")
    predict.add_argument("--runs", type=int, default=1000, help="Monte Carlo runs (default 1000)")
    predict.add_argument("--seed", type=seed, default=0)
    predict.add_argument("--plot", action="store_true", help="also write PREDICTION.png")
    predict.set_defaults(func=run_predict)


def run_train(args: argparse.Namespace) -> int:
    if args.out.suffix != ".npz":
        raise BadInputError(f"{args.out}: the model file name must end in .npz")
    if args.sparse is not None and args.sparse < 1:
        raise BadInputError(f"--sparse must be a positive number of inducing points, got {args.sparse}")
    config = NarxConfig(inputs=args.inputs, outputs=args.outputs, input_lags=args.input_lags,
                        output_lags=args.output_lags, decimation=args.decimation, stride=args.stride,
                        kernel=args.kernel, hyperparameters=args.hyperparameters, n_inducing=args.sparse)
    recordings = []
    for path in args.recordings:
        recording = read_recording(path, vehicle=args.vehicle)
        recording.metadata["source"] = str(path)
        recordings.append(recording)
    trained = train_narx(recordings, config, seed=args.seed, progress=True)
    save_trained(args.out, trained, meta={"trained_on": [str(p) for p in args.recordings]})
    n_points = len(trained.model.model.gps[0].X_train_)
    print(f"trained GP-NARX on {n_points} points from {len(recordings)} recording(s), "
          f"step {trained.step:g} s; wrote {args.out}")
    print("ARD relevance (share of each regressor per output):")
    for output, shares in trained.model.relevance().items():
        ranked = sorted(shares.items(), key=lambda item: -item[1])
        print(f"  {output}: " + ", ".join(f"{name} {share:.0%}" for name, share in ranked))
    return 0


def run_predict(args: argparse.Namespace) -> int:
    if args.out.suffix != ".csv":
        raise BadInputError(f"{args.out}: the prediction file name must end in .csv")
    if args.runs < 1:
        raise BadInputError(f"--runs must be at least 1, got {args.runs}")
    trained = load_trained(args.model)
    recording = read_recording(args.recording)
    name = str(args.recording)
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
        from .reproduce_bo105 import paper_figure

        png = png_bytes(paper_figure(prediction, None, title=f"{args.method}: {args.recording.name}",
                                     axes=outputs))
    write_atomically(args.out, "\n".join([",".join(header)] + [",".join(map(repr, row)) for row in table.tolist()]) + "\n")
    if png is not None:
        write_atomically(args.out.with_suffix(".png"), png)
    print(f"{args.method} prediction of {args.recording} ({len(prediction.time)} samples, "
          f"step {trained.step:g} s); wrote {args.out}")
    print(f"{'output':>8} {'RMSE':>10} {'95 % coverage':>14}")
    for output, rmse, coverage in zip(outputs, prediction.rmse(), prediction.coverage()):
        print(f"{output:>8} {rmse:10.4g} {coverage:14.2f}")
    return 0
