"""``flightgp state-space NAME --out FILE.json``: a built-in linear reference written as a
state-space model file (docs/vehicles.md, "State-space models"), which ``diagnose --reference
FILE.json`` reads back."""
from __future__ import annotations

import argparse
from pathlib import Path

from validation.core.errors import BadInputError


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "state-space", help="write a built-in linear reference as a state-space JSON file",
        description="Write the linear model NAME (bo105-<V>kt: Padfield's Bo105 at V kt) as a "
                    "state-space JSON file: states, inputs, A, B, derivative rows and units "
                    "(docs/vehicles.md). diagnose --reference FILE.json diagnoses against it, and "
                    "any linear model written in this format.")
    parser.add_argument("name", metavar="NAME", help="a linear reference: bo105-<V>kt")
    parser.add_argument("--out", type=Path, required=True, metavar="FILE.json")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from validation.core.files import check_output_folder, write_json
    from validation.vehicles.registry import get_vehicle
    from validation.vehicles.state_space import LinearReference

    if args.out.suffix != ".json":
        raise BadInputError(f"{args.out}: the state-space file name must end in .json")
    check_output_folder(args.out.parent, writes=[args.out.name])
    reference = get_vehicle(args.name)
    if not isinstance(reference, LinearReference):
        raise BadInputError(f"{args.name} is not a linear model; state-space files hold the bo105-<V>kt references")
    path = write_json(args.out, reference.as_dict())
    print(f"wrote {path} ({len(reference.state_names)} states, {len(reference.input_names)} inputs)")
    return 0
