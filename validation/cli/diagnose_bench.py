"""``flightgp diagnose-bench [--cases NAME...] [--reference NAME] [--through REFERENCE] [--seed N...] [--out DIR]``: the
concealed-effect benchmark of ``flightgp diagnose`` (:mod:`validation.diagnose.bench`)."""
from __future__ import annotations

import argparse
from pathlib import Path

from validation.cli.arguments import seed
from validation.core.errors import BadInputError
from validation.core.files import check_output_folder, json_text, write_files_atomically
from validation.core.progress import progress_bar


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "diagnose-bench", help="score flightgp diagnose on recordings with concealed effects",
        description="Fly a Bo105 or the blimp reference with effects diagnose is not told about (named effects "
                    "on several channels and magnitudes, pairs, none, and physics outside the named "
                    "list), with sensor noise; diagnose each and print a scorecard: effect named, "
                    "true value inside the interval, held-out RMSE cut of the affected output, false "
                    "findings, seconds per case (with several --seed values, also the rates over "
                    "seeds). Writes DIR/scorecard.json and DIR/scorecard.txt.")
    parser.add_argument("--cases", nargs="+", metavar="NAME",
                        help="run only these cases (default: all; --list shows them)")
    parser.add_argument("--list", action="store_true", help="list the cases and exit")
    parser.add_argument("--reference", default="bo105-80kt", metavar="NAME",
                        help="reference to conceal the effects in: bo105-<V>kt, blimp or an FMI 2.0 "
                             "co-simulation FILE.fmu (default bo105-80kt)")
    parser.add_argument("--through", metavar="REFERENCE",
                        help="diagnose through this reference instead of --reference: an FMU or a "
                             "state-space FILE.json of the same vehicle (e.g. flightgp's Bo105 reference "
                             "FMU, or flightgp state-space bo105-80kt); scored against the effects as "
                             "it names them")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="length of each recording, s (default 20)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="replay processes of an FMU reference (default: the cores available)")
    parser.add_argument("--seed", type=seed, nargs="+", default=[0], metavar="N",
                        help="sensor-noise and diagnosis seed(s) (default 0); with several, every case "
                             "runs once per seed and a summary gives the rates over seeds")
    parser.add_argument("--out", type=Path, default=Path("build/diagnose-bench"), metavar="DIR",
                        help="where scorecard.json and scorecard.txt go (default build/diagnose-bench)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from validation.diagnose.bench import (
        concealed_cases,
        format_scorecard,
        format_seed_summary,
        run_bench,
        summarise_seeds,
    )

    cases = concealed_cases(reference=args.reference)
    if args.list:
        for case in cases:
            print(f"{case.name:<28} {case.kind:<8} {case.description}")
        return 0
    if args.cases:
        unknown = [name for name in args.cases if name not in {case.name for case in cases}]
        if unknown:
            raise BadInputError(f"unknown case(s) {', '.join(unknown)}; see flightgp diagnose-bench --list")
        cases = [case for case in cases if case.name in args.cases]
    check_output_folder(args.out)
    if args.duration is not None and not args.duration >= 5:
        raise BadInputError(f"--duration must be at least 5 s (a 3-2-1-1 on each input), got {args.duration}")
    if args.workers is not None and args.workers < 1:
        raise BadInputError(f"--workers must be at least 1, got {args.workers}")
    options = {"through": args.through, "workers": args.workers}
    if args.duration is not None:
        options["duration"] = args.duration
    seeds = list(dict.fromkeys(args.seed))
    with progress_bar("diagnose-bench", enabled=not args.no_progress, total=len(cases) * len(seeds),
                      unit="case") as update:
        reports = [run_bench(cases, reference=args.reference, seed=s, progress=update, **options) for s in seeds]
    tables = [format_scorecard(report) for report in reports]
    if len(reports) == 1:
        result = reports[0]
    else:
        result = {"summary": summarise_seeds(reports), "runs": reports}
        tables.append(format_seed_summary(result["summary"]))
    table = "\n\n".join(tables)
    print(table)
    written = write_files_atomically({args.out / "scorecard.json": json_text(result),
                                      args.out / "scorecard.txt": table + "\n"})
    print(f"written {', '.join(str(path) for path in written)}")
    return 0
