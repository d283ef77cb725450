"""``flightgp bench [NAME ...]``: run benchmarks, print their tables and one summary table of
every headline ratio and goal; write ``build/bench/<name>.json`` and ``build/bench.json``."""
from __future__ import annotations

import argparse
from pathlib import Path

from validation.bench.summary import BENCHMARKS, format_summary, summary_rows
from validation.core.errors import BadInputError
from validation.core.files import check_output_folder, write_json

#: Checks of the benchmark-specific options: dest -> (smallest value, what it is).
_MINIMA = {"sizes": (10, "training-set sizes"), "restarts": (0, "restarts"),
           "runs": (1, "Monte Carlo runs"), "steps": (1, "time steps"),
           "fmu_steps": (10, "FMU steps")}


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "bench", help="speed benchmarks, each as a ratio against a peer run in the same process",
        description="Run benchmarks and write build/bench/<name>.json. Available: "
                    + ", ".join(BENCHMARKS) + ". Without a name, all run. Options that belong to "
                    "one benchmark apply to it only.",
    )
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help=f"benchmarks to run ({', '.join(BENCHMARKS)}); default all")
    parser.add_argument("--sizes", type=int, nargs="+",
                        help="`bench gp`: training-set sizes (default: 100 500 2000)")
    parser.add_argument("--restarts", type=int,
                        help="`bench gp`: random restarts of the hyperparameter optimiser (default 1)")
    parser.add_argument("--runs", type=int,
                        help="`bench narx`: Monte Carlo runs of the free run (default 1000)")
    parser.add_argument("--steps", type=int,
                        help="`bench narx`: time steps of the free run (default 800)")
    parser.add_argument("--fmu-steps", type=int,
                        help="`bench fmu`: communication steps timed per repeat (default 2000)")
    parser.add_argument("--threads", type=int, default=1,
                        help="BLAS threads for flightgp and its peer alike (default 1: on a 2-core "
                             "machine a second BLAS thread spins between calls and slows both)")
    parser.add_argument("--out-dir", type=Path, default=Path("build/bench"),
                        help="where each benchmark's JSON report goes (default build/bench)")
    parser.add_argument("--summary", type=Path, default=Path("build/bench.json"),
                        help="the combined report of the benchmarks run (default build/bench.json)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    names = args.names or list(BENCHMARKS)
    unknown = sorted(set(names) - set(BENCHMARKS))
    if unknown:
        raise BadInputError(f"unknown benchmark {', '.join(unknown)}; available: {', '.join(BENCHMARKS)}")
    for dest, (minimum, what) in _MINIMA.items():
        value, option = getattr(args, dest), "--" + dest.replace("_", "-")
        if value is None:
            continue
        owners = [name for name, bench in BENCHMARKS.items() if dest in bench.options]
        if not set(owners) & set(names):
            raise BadInputError(f"{option} applies to `bench {' '.join(owners)}` only, which is not "
                                f"being run; name it or drop {option}")
        if min(value if isinstance(value, list) else [value]) < minimum:
            raise BadInputError(f"{option} ({what}) must be at least {minimum}, got {value}")
    if args.threads < 1:
        raise BadInputError(f"--threads must be 1 or more, got {args.threads}")
    if args.summary.is_dir():
        raise BadInputError(f"--summary {args.summary} is a folder; give a file name such as build/bench.json")
    check_output_folder(args.out_dir, writes=[f"{name}.json" for name in names])
    check_output_folder(args.summary.parent, writes=[args.summary.name])
    from threadpoolctl import threadpool_limits

    reports = {}
    for name in names:
        bench = BENCHMARKS[name]
        options = {keyword: getattr(args, dest) for dest, keyword in bench.options.items()
                   if getattr(args, dest) is not None}
        with threadpool_limits(args.threads):
            report = bench.run(**options)
        report["blas_threads"] = args.threads
        print(bench.format_table(report))
        path = write_json(args.out_dir / f"{name}.json", report)
        print(f"written {path}\n")
        reports[name] = report
    summary = format_summary(reports)
    print(summary)
    rows = [{"benchmark": name, **row.as_dict()} for name in reports for row in summary_rows({name: reports[name]})]
    path = write_json(args.summary, {"summary": rows, "reports": reports})
    print(f"written {path}")
    return 0
