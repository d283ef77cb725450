"""``flightgp demo [--out DIR]``: the main job end to end on the built-in Bo105 case."""
from __future__ import annotations

import argparse
from pathlib import Path

from validation.cli.arguments import seed
from validation.core.files import check_output_folder


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "demo", help="run the built-in Bo105 case end to end",
        description="Record the Bo105 80 kt 3-2-1-1 from the flight-test stand-in, train a "
                    "GP-NARX, free-run it against the physics reference, export it as an FMU, "
                    "co-simulate it in fmpy, and write recordings, model, FMUs, plots, "
                    "results.json and report.md to DIR.",
    )
    parser.add_argument("--out", type=Path, default=Path("build/demo"), metavar="DIR",
                        help="output folder (default build/demo)")
    parser.add_argument("--seed", type=seed, default=0, help="random seed (default 0)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from validation.reproduce.bo105 import format_results
    from validation.reproduce.demo import format_cosim, run_demo

    check_output_folder(args.out, writes=["*"])  # demo writes many files: its folder is its own
    print(f"flightgp demo: Bo105 80 kt 3-2-1-1 -> {args.out}/")
    demo = run_demo(args.out, seed=args.seed)
    print(format_results(demo["results"]))
    print()
    print(format_cosim(demo["cosim"]))
    written = sorted(path.name for path in args.out.iterdir() if not path.name.startswith("."))
    print(f"written: {', '.join(written)}")
    return 0
