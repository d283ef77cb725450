"""``flightgp record`` (fly a manoeuvre on a vehicle, write a recording) and ``flightgp inspect``
(check a recording and summarise it). Recording format: :mod:`validation.recordings`."""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from .cli import seed
from .errors import BadInputError
from .manoeuvres import MANOEUVRES, manoeuvre, time_grid
from .files import write_files_atomically
from .recordings import Recording, column_limit, column_unit, read_recording, recording_files
from .vehicles import get_vehicle

#: Default manoeuvre amplitude for angle inputs, deg (the Bo105 paper's 3-2-1-1) ...
DEFAULT_AMPLITUDE_DEG = 1.0
#: ... and for normalised commands (10 % of full travel).
DEFAULT_AMPLITUDE_NORMALISED = 0.1
_FLIGHT_SUFFIX = "-flight"


def add_flight_arguments(parser, *, required: bool = True) -> None:
    """The options that describe a manoeuvre flown on a vehicle (``record``, ``cosim``)."""
    parser.add_argument("--vehicle", required=required,
                        help="vehicle name, e.g. bo105-80kt, bo105-80kt-flight, blimp, jsbsim:c172x")
    parser.add_argument("--manoeuvre", choices=MANOEUVRES, default="3211",
                        help="input shape (default %(default)s)")
    parser.add_argument("--input", required=required, metavar="NAME",
                        help="the vehicle input that flies the manoeuvre, e.g. theta_1s")
    amplitude = parser.add_mutually_exclusive_group()
    amplitude.add_argument("--amplitude-deg", type=float, metavar="DEG",
                           help=f"amplitude of an angle input, deg (default {DEFAULT_AMPLITUDE_DEG:g})")
    amplitude.add_argument("--amplitude", type=float, metavar="VALUE",
                           help="amplitude in the input's own unit: rad for angles, fraction of full "
                                f"travel for normalised commands (default {DEFAULT_AMPLITUDE_NORMALISED:g})")
    parser.add_argument("--step-time", type=float, default=0.4, metavar="S",
                        help="width of one step of a 3211 or doublet, s (default %(default)s)")
    parser.add_argument("--start", type=float, default=1.0, metavar="S",
                        help="time the manoeuvre starts, s (default %(default)s)")
    parser.add_argument("--duration", type=float, default=10.0, metavar="S",
                        help="length of the recording, s (default %(default)s)")
    parser.add_argument("--seed", type=seed, default=0,
                        help="seed of turbulence and sensor noise of flight-test stand-ins (default %(default)s)")


def fly(args: argparse.Namespace) -> tuple[Recording, np.ndarray]:
    """Fly the manoeuvre that :func:`add_flight_arguments`' options describe.

    Returns the recording (metadata: vehicle, seed, manoeuvre) and the input history, shape
    (n, n_inputs).
    """
    vehicle = get_vehicle(args.vehicle)
    if args.input not in vehicle.input_names:
        raise BadInputError(
            f"--input {args.input!r} is not an input of {vehicle.name}; choose one of "
            f"{', '.join(vehicle.input_names)}"
        )
    amplitude = _amplitude(args)
    time = time_grid(duration=args.duration, sample_time=vehicle.sample_time)
    if not (0.0 <= args.start < args.duration):
        raise BadInputError(f"--start must lie in [0, {args.duration:g}) s (the recording), got {args.start:g}")
    inputs = np.zeros((len(time), len(vehicle.input_names)))
    inputs[:, vehicle.input_names.index(args.input)] = manoeuvre(
        args.manoeuvre, time, amplitude=amplitude, step_time=args.step_time, start=args.start)
    recording = vehicle.simulate(time, inputs, seed=args.seed)
    recording.metadata.update(
        vehicle=vehicle.name,
        seed=args.seed,
        manoeuvre={"kind": args.manoeuvre, "input": args.input, "amplitude": amplitude,
                   "unit": column_unit(args.input), "step_time": args.step_time, "start": args.start},
    )
    return recording, inputs


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
    inspect.set_defaults(func=_inspect)


def _record(args: argparse.Namespace) -> int:
    recording, inputs = fly(args)
    vehicle = get_vehicle(args.vehicle)
    # Everything is computed before the first file is written, so an error leaves no files.
    png = _plot(recording, vehicle_name=vehicle.name, inputs=inputs) if args.plot else None
    files = recording_files(args.out, recording)
    if png is not None:
        files[args.out.with_suffix(".png")] = png
    written = write_files_atomically(files)
    print(f"recorded {vehicle.name}: {args.manoeuvre} on {args.input}, {len(recording.time)} samples; "
          f"wrote {', '.join(map(str, written))}")
    return 0


def _amplitude(args: argparse.Namespace) -> float:
    """The manoeuvre amplitude in the unit of ``args.input`` (rad for angles)."""
    angle = column_unit(args.input) == "rad"
    if args.amplitude_deg is not None:
        if not angle:
            raise BadInputError(
                f"--amplitude-deg is for angle inputs; {args.input!r} is a "
                f"{_unit_phrase(args.input)}: give --amplitude"
            )
        amplitude = math.radians(args.amplitude_deg)
    elif args.amplitude is not None:
        amplitude = args.amplitude
    else:
        amplitude = math.radians(DEFAULT_AMPLITUDE_DEG) if angle else DEFAULT_AMPLITUDE_NORMALISED
    if not math.isfinite(amplitude):
        raise BadInputError(f"the amplitude must be a finite number, got {amplitude}")
    limit = column_limit(args.input)
    if limit is not None and abs(amplitude) > limit:
        if column_unit(args.input) == "rad":
            raise BadInputError(
                f"amplitude {math.degrees(amplitude):g} deg on {args.input!r} exceeds the plausible "
                f"+/-{math.degrees(limit):.3g} deg ({limit:g} rad) for that column")
        raise BadInputError(f"amplitude {amplitude:g} on {args.input!r} exceeds full travel "
                            "(+/-1 for a normalised command)")
    return amplitude


def _unit_phrase(name: str) -> str:
    unit = column_unit(name)
    return "normalised command (-1..1)" if unit == "1" else f"quantity in {unit}"


def _plot(recording: Recording, *, vehicle_name: str, inputs: np.ndarray) -> bytes:
    """PNG of ``recording``; a flight-test stand-in gets its reference flown on the same inputs."""
    from .plots import png_bytes, recording_figure  # matplotlib only when a plot is asked for

    reference = None
    if vehicle_name.endswith(_FLIGHT_SUFFIX):
        reference_vehicle = get_vehicle(vehicle_name[: -len(_FLIGHT_SUFFIX)])
        reference_inputs = np.column_stack([recording.input(name) for name in reference_vehicle.input_names])
        reference = reference_vehicle.simulate(recording.time, reference_inputs)
        reference.metadata.setdefault("vehicle", reference_vehicle.name)
    manoeuvre_ = recording.metadata["manoeuvre"]
    title = f"{vehicle_name}: {manoeuvre_['kind']} on {manoeuvre_['input']}"
    if reference is not None:
        title += f" (dashed: reference {reference.metadata['vehicle']})"
    return png_bytes(recording_figure(recording, reference=reference, title=title))


def _inspect(args: argparse.Namespace) -> int:
    recording = read_recording(args.recording, vehicle=args.vehicle)
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
    return 0
