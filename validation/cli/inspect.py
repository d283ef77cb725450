"""``flightgp inspect``: check a recording and summarise it."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from validation.cli.arguments import add_format_argument
from validation.core.recordings import column_unit
from validation.vehicles import get_vehicle, read_recording


def register(subparsers) -> None:
    inspect = subparsers.add_parser(
        "inspect",
        help="check a recording and print a summary",
        description="Check a recording (and its JSON sidecar) and print duration, sampling and "
                    "each column's unit and range. A malformed file exits with code 2 and names "
                    "file, row and column.",
    )
    inspect.add_argument("recording", type=Path, metavar="FILE.csv")
    inspect.add_argument("--vehicle", help="check the columns against this vehicle "
                                           "(default: the sidecar's vehicle, if any)")
    add_format_argument(inspect)
    inspect.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    recording = read_recording(args.recording, vehicle=args.vehicle, file_format=args.file_format)
    time = recording.time
    steps = np.diff(time)
    vehicle = args.vehicle or recording.metadata.get("vehicle")
    print(f"{args.recording}: valid recording"
          + (f" of {vehicle}" if vehicle else " (no vehicle named; columns not checked against one)"))
    sampling = (f"sample time {steps[0]:.6g} s ({1 / steps[0]:.6g} Hz)"
                if np.ptp(steps) <= 1e-6 * steps[0] else
                f"uneven sampling, steps {steps.min():.6g} .. {steps.max():.6g} s")
    print(f"{len(time)} samples, {time[0]:g} .. {time[-1]:g} s (duration {time[-1] - time[0]:g} s), {sampling}")
    rows = [("time", "time", time)]
    rows += [(name, "input", recording.input(name)) for name in recording.input_names]
    rows += [(name, "output", recording.output(name)) for name in recording.output_names]
    width = max(len(name) for name, _, _ in rows)
    print(f"{'column':<{width}}  {'role':<6}  {'unit':<5}  {'min':>12}  {'max':>12}")
    for name, role, values in rows:
        print(f"{name:<{width}}  {role:<6}  {column_unit(name):<5}  {values.min():>12.6g}  {values.max():>12.6g}")
    if vehicle and getattr(get_vehicle(vehicle), "perturbations_from_trim", False):
        for phrase in trim_departures(recording):
            print(f"warning: {phrase}; {vehicle}'s columns are perturbations from trim, so its recordings start "
                  "near 0: subtract the trim values (docs/conventions.md, \"Units and axes\")")
    return 0


#: A column starts away from trim when its first value is more than this many times its whole
#: motion over the recording away from zero: a perturbation recording starts within its motion
#: of zero, an absolute one (u = 41 m/s at 80 kt, moving by 1 m/s) far outside it.
TRIM_DEPARTURE_RATIO = 5.0


def trim_departures(recording) -> list[str]:
    """One phrase per column of ``recording`` whose first value lies further from zero than
    :data:`TRIM_DEPARTURE_RATIO` times its peak-to-peak motion: recorded absolute, not as a
    perturbation from trim."""
    columns = [(name, recording.input(name)) for name in recording.input_names]
    columns += [(name, recording.output(name)) for name in recording.output_names]
    return [f"{name} starts at {values[0]:.6g} {column_unit(name)} and moves by {np.ptp(values):.3g} only"
            for name, values in columns if abs(values[0]) > TRIM_DEPARTURE_RATIO * np.ptp(values)]
