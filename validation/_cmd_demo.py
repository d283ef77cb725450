"""``flightgp demo [--out DIR]``: the main job end to end on the built-in Bo105 case."""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "demo", help="run the built-in Bo105 case end to end",
        description="Record the Bo105 80 kt 3-2-1-1 from the flight-test stand-in, train a GP, "
                    "compare it with the physics reference, and write recordings, model, plot "
                    "and summary.json to DIR.",
    )
    parser.add_argument("--out", type=Path, default=Path("build/demo"), metavar="DIR",
                        help="output folder (default build/demo)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .demo import run_demo

    print(f"flightgp demo: Bo105 80 kt 3-2-1-1 -> {args.out}/")
    summary = run_demo(args.out, seed=args.seed)
    rmse = summary["one_step_rmse_q_rad_s"]
    print(f"  {summary['case']}")
    print(f"  GP trained on {summary['training_points']} points "
          f"({summary['annealing_stages']} annealing stages)")
    print(f"  one-step pitch-rate RMSE on held-out samples: GP {rmse['gp']:.4f} rad/s, "
          f"physics reference {rmse['reference']:.4f} rad/s; "
          f"GP 95 % band covers {100 * summary['coverage95_q']:.0f} %")
    print(f"  note: {summary['note']}")
    print(f"  written: {', '.join(sorted(p.name for p in Path(args.out).iterdir()))}")
    if args.verbose:
        print(json.dumps(summary, indent=2))
    return 0
