"""``flightgp build-fmu MODEL_FILE --out DIR [--name NAME]``: a trained GP-NARX model as an FMI 2.0
co-simulation FMU (the rate predictor of :mod:`fmu_src.rate_predictor`)."""
from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "build-fmu", help="build an FMI 2.0 co-simulation FMU from a trained GP-NARX model",
        description="Build a GP-NARX rate predictor FMU (pythonfmu) from a model file written by "
                    "`flightgp train`: the model's control inputs and the previous outputs in, the "
                    "predicted outputs and their confidence bounds out, one NARX step per "
                    "communication step. Writes DIR/NAME.fmu.")
    parser.add_argument("model", type=Path, metavar="MODEL_FILE", help="trained model (.npz)")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder for the FMU")
    parser.add_argument("--name", help="FMU name and model identifier (letters, digits, underscores; "
                                       "default: the model file's name)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fmu_src.builder import build_rate_predictor_fmu

    path = build_rate_predictor_fmu(args.model, args.out, name=args.name)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return 0
