"""Argument types and option groups shared by several ``flightgp`` commands."""
from __future__ import annotations

import argparse
import math

import numpy as np

from validation.core.errors import BadInputError
from validation.core.manoeuvres import MANOEUVRES, manoeuvre, time_grid
from validation.core.recordings import Recording, column_limit, column_unit
from validation.vehicles import get_vehicle
from validation.vehicles.registry import RECORDING_FORMATS


def seed(text: str) -> int:
    """argparse type of every ``--seed``: a non-negative integer (numpy's generators need one)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"seed must be a whole number, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"seed must be 0 or more, got {value}")
    return value


def add_format_argument(parser) -> None:
    """``--format`` of the commands that read recording files (``inspect``, ``train``,
    ``predict``, ``diagnose``): the keyword ``file_format`` of :func:`validation.vehicles.read_recording`."""
    parser.add_argument("--format", dest="file_format", choices=RECORDING_FORMATS,
                        help="file format: flightgp (a time column; docs/conventions.md) or rgblimp "
                             "(the RGBlimp source's data_N.csv, 38 columns, 60 Hz); default: "
                             "recognised from the header")


#: Default manoeuvre amplitude for angle inputs, deg (the Bo105 paper's 3-2-1-1) ...
DEFAULT_AMPLITUDE_DEG = 1.0
#: ... and for normalised commands (10 % of full travel).
DEFAULT_AMPLITUDE_NORMALISED = 0.1
#: Suffix of the flight-test stand-ins' names (``bo105-80kt-flight``).
FLIGHT_SUFFIX = "-flight"


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


def add_cluster_arguments(parser, *, workers_flag: str = "--workers",
                          without: str = "a local cluster started and stopped by this command") -> None:
    """``--scheduler`` and, exclusive with it, the local cluster's size (``workers_flag``) of the
    commands that run on Dask (``campaign``, ``diagnose-bench``; docs/campaigns.md), parsed into
    ``scheduler`` and ``cluster_workers``; ``without`` says what the command does without
    ``--scheduler``. The command checks that ``cluster_workers`` is at least 1."""
    cluster = parser.add_mutually_exclusive_group()
    cluster.add_argument("--scheduler", metavar="ADDRESS",
                         help="run on an existing Dask cluster: its scheduler's address (tcp://host:8786) or "
                              f"scheduler file (default: {without})")
    cluster.add_argument(workers_flag, dest="cluster_workers", type=int, metavar="N",
                         help="worker processes of a local Dask cluster started and stopped by this command, "
                              "one thread each (default: the cores available)")
