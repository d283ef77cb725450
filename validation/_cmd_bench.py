"""``flightgp bench [NAME ...]``: run benchmarks, print tables, write ``build/bench/<name>.json``."""
from __future__ import annotations

import argparse
from pathlib import Path

from .benchmarks import BENCHMARKS
from .errors import BadInputError
from .files import write_json


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "bench", help="speed benchmarks, each as a ratio against a peer run in the same process",
        description="Run benchmarks and write build/bench/<name>.json. Available: "
                    + ", ".join(BENCHMARKS) + ". Without a name, all run.",
    )
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help=f"benchmarks to run ({', '.join(BENCHMARKS)}); default all")
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 500, 2000],
                        help="training-set sizes for `bench gp` (default: 100 500 2000)")
    parser.add_argument("--restarts", type=int, default=1,
                        help="random restarts of the hyperparameter optimiser (default 1)")
    parser.add_argument("--threads", type=int, default=1,
                        help="BLAS threads for flightgp and its peer alike (default 1: on a 2-core "
                             "machine a second BLAS thread spins between calls and slows both)")
    parser.add_argument("--out-dir", type=Path, default=Path("build/bench"),
                        help="where the JSON reports go (default build/bench)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    unknown = sorted(set(args.names) - set(BENCHMARKS))
    if unknown:
        raise BadInputError(f"unknown benchmark {', '.join(unknown)}; available: {', '.join(BENCHMARKS)}")
    if any(n < 10 for n in args.sizes):
        raise BadInputError(f"--sizes must all be at least 10, got {args.sizes}")
    if args.restarts < 0:
        raise BadInputError(f"--restarts must be 0 or more, got {args.restarts}")
    if args.threads < 1:
        raise BadInputError(f"--threads must be 1 or more, got {args.threads}")
    from threadpoolctl import threadpool_limits

    for name in args.names or list(BENCHMARKS):
        bench, format_table = BENCHMARKS[name]
        with threadpool_limits(args.threads):
            report = bench(sizes=tuple(args.sizes), n_restarts=args.restarts)
        report["blas_threads"] = args.threads
        print(format_table(report))
        path = write_json(args.out_dir / f"{name}.json", report)
        print(f"written {path}")
    return 0
