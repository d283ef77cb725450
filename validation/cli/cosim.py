"""``flightgp cosim``: co-simulate a GP FMU and a reference FMU in fmpy against a recording."""
from __future__ import annotations

import argparse
from pathlib import Path

from validation.cli.arguments import add_flight_arguments, fly
from validation.core.errors import BadInputError
from validation.core.files import check_output_folder
from validation.vehicles import read_recording


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "cosim", help="co-simulate a GP FMU and a reference FMU against a recording",
        description="Drive the GP rate-predictor FMU (free run) and a reference FMU with the "
                    "same inputs in fmpy, and compare both with a recording: either --recording, "
                    "or a manoeuvre flown on --vehicle (the options of `flightgp record`). Writes "
                    "FMI Cross-Check files (<model>/<model>_in.csv, _ref.csv, _ref.opt), "
                    "cosim.json and cosim.png to DIR and prints the RMSE table.")
    parser.add_argument("gp_fmu", type=Path, metavar="GP.fmu")
    parser.add_argument("--reference", type=Path, metavar="REF.fmu",
                        help="physics reference FMU (flightgp build-fmu --reference ...)")
    parser.add_argument("--recording", type=Path, metavar="FILE.csv",
                        help="recording whose inputs drive the FMUs and whose outputs they are compared with")
    add_flight_arguments(parser, required=False)
    parser.add_argument("--exact-moments", action="store_true", default=None,
                        help="the GP FMU's moment matching in double precision throughout (its parameter "
                             "exact_moments; default: the FMU's, its fast path where its build measured that "
                             "within 1 %% of the predicted sd)")
    parser.add_argument("--parallel", action="store_true", default=None,
                        help="the native GP FMU's free run on two threads (its parameter parallel; a "
                             "pythonfmu FMU has it and runs on one thread either way)")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from validation.cosim.cosimulation import COSIM_FILES, cosimulate
    from validation.vehicles.fmu_reference import read_cosimulation_fmu

    for path in (args.gp_fmu, args.reference):  # before anything is flown or written
        if path is not None:
            read_cosimulation_fmu(path, purpose="cosim")
    check_output_folder(args.out, writes=COSIM_FILES)
    if (args.recording is None) == (args.vehicle is None):
        raise BadInputError("give either --recording FILE.csv or a manoeuvre with --vehicle and --input")
    if args.recording is not None:
        recording = read_recording(args.recording)
        source = str(args.recording)
    else:
        if args.input is None:
            raise BadInputError("--vehicle needs --input (the control that flies the manoeuvre)")
        recording, _ = fly(args)
        source = f"{args.vehicle} {args.manoeuvre} on {args.input}, seed {args.seed}"
    result = cosimulate(args.gp_fmu, recording, reference_fmu=args.reference, out_dir=args.out,
                        exact_moments=args.exact_moments, parallel=args.parallel)
    rmse, coverage = result.rmse(), result.coverage()
    print(f"fmpy co-simulation against {source}, step {result.time[1] - result.time[0]:g} s")
    print(f"{'RMSE [rad/s]':24}" + "".join(f"{a:>9}" for a in result.axes))
    for label, key in (("GP FMU (free run)", "gp"), ("reference FMU", "reference")):
        if key in rmse:
            print(f"{label:24}" + "".join(f"{rmse[key][a]:9.4f}" for a in result.axes))
    print(f"{'GP ' + result.band_words + ' coverage':24}" + "".join(f"{coverage[a]:9.2f}" for a in result.axes))
    print(f"written {args.out}/cosim.json, cosim.png and the Cross-Check files")
    return 0
