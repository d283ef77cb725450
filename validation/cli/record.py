"""``flightgp record``: fly a manoeuvre on a vehicle and write the recording
(format: docs/conventions.md, "Recording files")."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from validation.cli.arguments import FLIGHT_SUFFIX, add_flight_arguments, fly
from validation.core.files import check_output_folder, write_files_atomically
from validation.core.recordings import Recording, recording_files, sidecar_path
from validation.vehicles import get_vehicle


def register(subparsers) -> None:
    record = subparsers.add_parser(
        "record",
        help="fly a test manoeuvre on a vehicle and write the recording",
        description=(
            "Fly a manoeuvre on one input of a vehicle, all other inputs held at trim, and write "
            "OUT (CSV: time, inputs, outputs) with its JSON sidecar (same name, .json). The "
            "recording starts at trim at t = 0 s."
        ),
    )
    add_flight_arguments(record)
    record.add_argument("--out", required=True, type=Path, metavar="FILE.csv",
                        help="recording to write; folders are created")
    record.add_argument("--plot", action="store_true",
                        help="also write FILE.png; a -flight stand-in is overlaid with its reference")
    record.set_defaults(func=_record)


def _record(args: argparse.Namespace) -> int:
    recording, _ = fly(args)  # quick, and it checks the flight's options first
    plot_path = args.out.with_suffix(".png")
    outputs = [args.out, sidecar_path(args.out)] + ([plot_path] if args.plot else [])
    check_output_folder(args.out.parent, writes=[path.name for path in outputs])
    vehicle_name = recording.metadata["vehicle"]
    # Everything is computed before the first file is written, so an error leaves no files.
    png = _plot(recording, vehicle_name=vehicle_name) if args.plot else None
    files = recording_files(args.out, recording)
    if png is not None:
        files[plot_path] = png
    written = write_files_atomically(files)
    print(f"recorded {vehicle_name}: {args.manoeuvre} on {args.input}, {len(recording.time)} samples; "
          f"wrote {', '.join(map(str, written))}")
    return 0


def _plot(recording: Recording, *, vehicle_name: str) -> bytes:
    """PNG of ``recording``; a flight-test stand-in gets its reference flown on the same inputs."""
    from validation.core.plots import png_bytes, recording_figure  # matplotlib only when asked for

    reference = None
    if vehicle_name.endswith(FLIGHT_SUFFIX):
        reference_vehicle = get_vehicle(vehicle_name[: -len(FLIGHT_SUFFIX)])
        reference_inputs = np.column_stack([recording.input(name) for name in reference_vehicle.input_names])
        reference = reference_vehicle.simulate(recording.time, reference_inputs)
        reference.metadata.setdefault("vehicle", reference_vehicle.name)
    manoeuvre_ = recording.metadata["manoeuvre"]
    title = f"{vehicle_name}: {manoeuvre_['kind']} on {manoeuvre_['input']}"
    if reference is not None:
        title += f" (dashed: reference {reference.metadata['vehicle']})"
    return png_bytes(recording_figure(recording, reference=reference, title=title))
