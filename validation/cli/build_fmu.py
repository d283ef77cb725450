"""``flightgp build-fmu (MODEL_FILE | --reference NAME) --out DIR [--name NAME] [--native]``: an
FMI 2.0 co-simulation FMU of a trained model (a GP-NARX model: the rate predictor of
:mod:`fmu_src.rate_predictor`; a grey-box ``GreyBoxGP``, by the physics its model file
describes: ``blimp_rk4`` the blimp RKGP FMU of :mod:`fmu_src.blimp_rkgp`, ``rgblimp_rk4`` the
RGBlimp RKGP FMU of :mod:`fmu_src.rgblimp_rkgp`) or of a physics reference (``bo105-<V>kt``:
:mod:`fmu_src.bo105_reference`; ``blimp``: :mod:`fmu_src.blimp_reference`; ``jsbsim:<aircraft>``:
:mod:`fmu_src.jsbsim_aircraft`).

With ``--native``, a trained model's FMU is built as C compiled with the system gcc, with the
same interface and numbers and no Python at run time (docs/fmus.md, "Native FMUs (no Python in the host)")."""
from __future__ import annotations

import argparse
from pathlib import Path

from validation.core.errors import BadInputError


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "build-fmu", help="build an FMI 2.0 co-simulation FMU from a trained model or a reference",
        description="Build a pythonfmu FMU and write DIR/NAME.fmu. From MODEL_FILE (written by "
                    "`flightgp train`): the GP-NARX rate predictor, the model's control inputs and the "
                    "previous outputs in, the predicted outputs and their confidence bounds out, one "
                    "NARX step per communication step; or, from a grey-box model (GreyBoxGP), the RKGP "
                    "FMU of the physics its model file describes: blimp_rk4 (the blimp, e.g. DIR/blimp_rkgp.npz "
                    "of `flightgp reproduce blimp`: fan commands in) or rgblimp_rk4 (the RGBlimp, e.g. "
                    "OUT/models/rgblimp_rkgp_J.npz of `flightgp reproduce rgblimp`: propeller thrusts and "
                    "gondola position in, steps of 1/60 s); the 12 states and their standard deviations "
                    "propagated along the run out, RK4 physics plus GP residual inside; or, from an RGBlimp "
                    "hybrid's JSON model file (OUT/models/rgblimp_hybrid_J.json of `flightgp reproduce rgblimp`), "
                    "the hybrid FMU: the identified physics plus the rollout-trained correction, its free run "
                    "and the first-order spread of its band out. With --native, any "
                    "of these model FMUs is native C instead (same interface and outputs, compiled with the "
                    "system gcc, no Python at run time). With --reference: a physics reference, "
                    "bo105-<V>kt (Padfield's linear Bo105, V in 0, 20, ..., 140), blimp (the blimp ODE, every "
                    "physical parameter an FMU parameter) or jsbsim:<aircraft> "
                    "(a JSBSim aircraft, e.g. jsbsim:c172x or jsbsim:ah1s; the host needs the jsbsim "
                    "Python package).")
    parser.add_argument("model", type=Path, nargs="?", metavar="MODEL_FILE",
                        help="trained model (.npz, or an RGBlimp hybrid's .json)")
    parser.add_argument("--reference", metavar="NAME",
                        help="build a reference FMU instead: bo105-<V>kt, blimp or jsbsim:<aircraft>")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder for the FMU")
    parser.add_argument("--native", action="store_true",
                        help="build MODEL_FILE's FMU (the GP-NARX rate predictor, the blimp RKGP, the "
                             "RGBlimp RKGP or the RGBlimp hybrid) as a native FMU: C compiled with the system gcc, "
                             "no Python at run time")
    parser.add_argument("--name", help="FMU name and model identifier (letters, digits, underscores; "
                                       "default: the model file's name, bo105_<V>kt_reference, "
                                       "blimp_reference or jsbsim_<aircraft>)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fmu_src import build_model_fmu, build_reference_fmu

    if (args.model is None) == (args.reference is None):
        raise BadInputError("give either MODEL_FILE (a trained GP-NARX or grey-box model) or "
                            "--reference NAME (bo105-<V>kt, blimp or jsbsim:<aircraft>), not both or neither")
    if args.reference is not None and args.native:
        raise BadInputError("--native builds the FMU of a trained MODEL_FILE (GP-NARX rate predictor, "
                            "blimp RKGP or RGBlimp RKGP); reference FMUs have no native build (drop --native)")
    if args.reference is not None:
        path = build_reference_fmu(args.reference, args.out, name=args.name)
    else:
        path = build_model_fmu(args.model, args.out, name=args.name, native=args.native)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return 0
