"""``flightgp diagnose RECORDING... --reference NAME [--holdout RECORDING...] --out DIR``."""
from __future__ import annotations

import argparse
from pathlib import Path

from validation.cli.arguments import add_format_argument, seed
from validation.core.errors import BadInputError
from validation.core.files import check_output_folder


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "diagnose", help="locate a simulation/recording mismatch, name the missing physics, model it",
        description="Replay the reference on the recorded inputs, locate where the residual exceeds "
                    "the sensor noise, test named effects (time delay, input lag, control and "
                    "stability derivatives, sensor bias; on the blimp also quadratic drag and force "
                    "offsets; on the RGBlimp aerodynamic coefficients, damping, thrust gain and "
                    "asymmetry, buoyancy, CG, added mass and a steady wind, replayed from each "
                    "flight's first state) by likelihood ratio, build the corrected "
                    "model plus a residual GP, and score all three on held-out data. Writes "
                    "DIR/diagnosis.json, DIR/report.md with PNGs, and DIR/corrected_model.json.")
    parser.add_argument("recordings", nargs="+", type=Path, metavar="RECORDING",
                        help="recording CSV files (docs/conventions.md, Recording files), starting at trim; "
                             "for rgblimp the source's data_N.csv files as they are")
    parser.add_argument("--reference", required=True, metavar="NAME",
                        help="physics reference: bo105-<V>kt, blimp, rgblimp, a linear state-space "
                             "model FILE.json (docs/vehicles.md; flightgp state-space writes the Bo105's) or "
                             "any FMI 2.0 co-simulation FILE.fmu (its parameters become candidate corrections)")
    parser.add_argument("--holdout", nargs="+", type=Path, metavar="RECORDING",
                        help="recordings used only to score the models (default: the last recording, "
                             "or the last 30 %% of a single one)")
    parser.add_argument("--tolerances", type=Path, metavar="FILE.json",
                        help="tolerance bands of the fidelity scorecard, {\"q\": 0.035, ...} in each output's "
                             "SI unit (default: 14 CFR Part 60, Appendix C, Table C2A, for the outputs it names)")
    parser.add_argument("--map", type=Path, metavar="MAP.json", dest="column_map",
                        help="rename recording columns to the reference's names, {\"column\": \"name\", ...} "
                             "(e.g. an FMU's variable names)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="processes that replay candidates side by side for an FMU reference "
                             "(default: the cores available)")
    parser.add_argument("--input-terms", action="store_true",
                        help="through an FMU, let the residual search also add terms fed into its inputs "
                             "(e.g. theta1s_q|q|: the cyclic given c q|q|); about 5x the time")
    add_format_argument(parser)
    parser.add_argument("--out", type=Path, required=True, metavar="DIR")
    parser.add_argument("--seed", type=seed, default=0, help="random seed of the residual GP (default 0)")
    parser.add_argument("--folds", type=int, metavar="K",
                        help="also run the search on K folds of the recordings (K >= 2, at least K "
                             "recordings besides the held-out ones) and state with confidence only "
                             "the findings every fold names (default: no replication)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from validation.core.progress import progress_bar
    from validation.diagnose import diagnose, write_diagnosis
    from validation.diagnose.data import read_column_map
    from validation.diagnose.fidelity import read_tolerances
    from validation.diagnose.pipeline import stage_count
    from validation.diagnose.report import DIAGNOSIS_FILES, ignored_columns_phrase

    check_output_folder(args.out, writes=DIAGNOSIS_FILES)
    tolerances = read_tolerances(args.tolerances) if args.tolerances is not None else None
    column_map = read_column_map(args.column_map) if args.column_map is not None else None
    if args.workers is not None and args.workers < 1:
        raise BadInputError(f"--workers must be at least 1, got {args.workers}")
    with progress_bar("diagnose", enabled=not args.no_progress, total=stage_count(folds=args.folds),
                      unit="stage") as update:
        diagnosis = diagnose(args.recordings, reference=args.reference, holdout=args.holdout,
                             seed=args.seed, folds=args.folds, column_map=column_map, workers=args.workers,
                             input_terms=args.input_terms,
                             file_format=args.file_format, tolerances=tolerances, progress=update)
    written = write_diagnosis(diagnosis, args.out)
    result = diagnosis.as_dict()
    print(f"{result['reference']}: {result['verdict']}")
    banded = {n: e for n, e in result["fidelity"]["outputs"].items() if e["tolerance"] is not None}
    for key, words in (("reference", "before correction"), ("corrected", "after correction")):
        inside = ", ".join(n for n, e in banded.items() if e[key]["passes"]) or "none"
        print(f"inside the tolerance bands {words}: {inside} (of {', '.join(banded) or '-'})")
    if result["ignored_columns"]:
        print(f"left out: {ignored_columns_phrase(result['ignored_columns'], result['reference'])}")
    for finding in result["findings"]:
        print(f"- {finding['statement']}")
    if (result.get("disturbance") or {}).get("looks_like_turbulence"):
        print(f"- {result['disturbance']['statement']}")
    fit = result["fit"]
    print(f"held-out RMSE ({fit['holdout']}): output reference -> corrected -> corrected + GP")
    for name in fit["outputs"]:
        print(f"  {name:6s} {fit['rmse_reference'][name]:.4g} -> {fit['rmse_corrected'][name]:.4g} "
              f"-> {fit['rmse_corrected_gp'][name]:.4g}")
    print(f"written {len(written)} files to {args.out} (report.md, diagnosis.json, corrected_model.json)")
    return 0
