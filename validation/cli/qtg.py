"""``flightgp qtg SPEC --out DIR (--fmu FILE.fmu | --reference NAME)``: run a qualification test
guide against a model (docs/qtg.md)."""
from __future__ import annotations

import argparse
from contextlib import ExitStack
from pathlib import Path

from validation.core.files import check_output_folder


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "qtg", help="run a qualification test guide (QTG) against an FMU or a reference",
        description="Run every test of the QTG spec SPEC (TOML: flight-test recordings and the outputs a "
                    "simulation must match each in, within a tolerance; docs/qtg.md) against a model: any FMI "
                    "2.0 co-simulation FMU (--fmu; a flightgp GP rate predictor runs in free-run mode) or a "
                    "built-in reference or state-space FILE.json (--reference). Writes to DIR a QTG plot per "
                    "test, summary.md, qtg.html, junit.xml and qtg.json. Exit code 0 when every test that ran "
                    "passed (and one ran), 1 when a test failed or its model did not run, 2 for bad input.")
    parser.add_argument("spec", type=Path, metavar="SPEC.toml")
    model = parser.add_mutually_exclusive_group(required=True)
    model.add_argument("--fmu", type=Path, metavar="FILE.fmu", help="an FMI 2.0 co-simulation FMU")
    model.add_argument("--reference", metavar="NAME",
                       help="a built-in reference (bo105-<V>kt, ...), a state-space FILE.json, or the "
                            "corrected_model.json of a diagnosis")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR")
    parser.add_argument("--no-progress", action="store_true", help="show no progress on stderr")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from validation.qtg import open_model, read_spec, run_qtg, write_qtg
    from validation.qtg.report import QTG_FILES
    from validation.qtg.run import PASSED

    check_output_folder(args.out, writes=QTG_FILES)
    spec = read_spec(args.spec)
    with ExitStack() as stack:
        model = open_model(stack, fmu=args.fmu, reference=args.reference)
        result = run_qtg(spec, model, progress=not args.no_progress)
    write_qtg(result, args.out)
    print(f"QTG {spec.title}: {result.model_name}, {len(result.tests)} tests, {result.seconds:.1f} s")
    for test in result.tests:
        detail = test.reason or test.failure() or ""
        print(f"  {test.status.upper():8} {test.test.id}" + (f": {detail}" if detail and test.status != PASSED else ""))
    print(f"{result.count('passed')} passed, {result.count('failed')} failed, {result.count('error')} errors, "
          f"{result.count('not run')} not run; written {args.out}/qtg.html, summary.md, junit.xml, qtg.json and "
          "the plots")
    return 0 if result.passed else 1
