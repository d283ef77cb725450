"""``flightgp train``: a GP-NARX model from recordings to a portable model file."""
from __future__ import annotations

import argparse
from pathlib import Path

from validation.cli.arguments import add_format_argument, seed
from validation.core.errors import BadInputError
from validation.core.files import check_output_folder
from validation.models.narx import HYPERPARAMETER_METHODS, KERNELS, NarxConfig, save_trained, train_narx
from validation.vehicles import read_recording


def register(subparsers) -> None:
    defaults = NarxConfig()
    train = subparsers.add_parser(
        "train", help="train a GP-NARX model on recordings",
        description="Train one GP per output on regressors built from the recordings (lags in "
                    "NARX steps of DECIMATION samples) and write a portable model file.")
    train.add_argument("recordings", nargs="+", type=Path, metavar="RECORDING")
    train.add_argument("--out", type=Path, required=True, metavar="MODEL.npz")
    train.add_argument("--vehicle", help="vehicle the recordings come from (default: their sidecar)")
    add_format_argument(train)
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
    train.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.out.suffix != ".npz":
        raise BadInputError(f"{args.out}: the model file name must end in .npz")
    if args.sparse is not None and args.sparse < 1:
        raise BadInputError(f"--sparse must be a positive number of inducing points, got {args.sparse}")
    check_output_folder(args.out.parent, writes=[args.out.name])
    config = NarxConfig(inputs=args.inputs, outputs=args.outputs, input_lags=args.input_lags,
                        output_lags=args.output_lags, decimation=args.decimation, stride=args.stride,
                        kernel=args.kernel, hyperparameters=args.hyperparameters, n_inducing=args.sparse)
    recordings = []
    for path in args.recordings:
        recording = read_recording(path, vehicle=args.vehicle, file_format=args.file_format)
        recording.metadata["source"] = str(path)
        if args.vehicle is not None:  # the vehicle the model is trained on, whatever a sidecar says
            recording.metadata["vehicle"] = args.vehicle
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
