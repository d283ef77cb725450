"""``flightgp campaign SPEC.json --out DIR [--scheduler ADDRESS] [--workers N]``: run a campaign
of co-simulations, diagnoses, bench cases, reproductions and QTGs on Dask (docs/campaigns.md)."""
from __future__ import annotations

import argparse
from pathlib import Path

from validation.cli.arguments import add_cluster_arguments
from validation.core.errors import BadInputError


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "campaign", help="run many co-simulations, diagnoses, bench cases, reproductions or QTGs on Dask",
        description="Expand SPEC.json (docs/campaigns.md) into tasks (Monte Carlo samples and grid sweeps "
                    "of FMU co-simulations, diagnose runs, diagnose-bench cases, reproductions, QTGs against many "
                    "models) and run them on a local Dask cluster or an existing one. Each finished task is written to "
                    "DIR/tasks/<id>/ (result.json and its files) at once; DIR/results.csv (one row per task) "
                    "and DIR/summary.json (counts, failures, statistics per figure) are rebuilt at the end. "
                    "Running the same command again resumes: only tasks without a result run.")
    parser.add_argument("spec", type=Path, metavar="SPEC.json", help="the campaign spec (paths in it are relative "
                                                                     "to its folder)")
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="the campaign's folder")
    add_cluster_arguments(parser)
    parser.add_argument("--retry-failed", action="store_true",
                        help="also run again the tasks whose stored result failed")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from validation.campaign import read_spec, run_campaign
    from validation.campaign.results import format_summary

    if args.cluster_workers is not None and args.cluster_workers < 1:
        raise BadInputError(f"--workers must be at least 1, got {args.cluster_workers}")
    spec = read_spec(args.spec)
    run = run_campaign(spec, args.out, scheduler=args.scheduler, workers=args.cluster_workers,
                       retry_failed=args.retry_failed, progress=not args.no_progress)
    print(format_summary(run.summary))
    ran = (f"ran {run.ran} task(s) on {run.workers} worker(s)" if run.ran else "nothing to run")
    print(f"{ran} in {run.seconds:.1f} s, kept {run.resumed} stored result(s); written {args.out}/results.csv, "
          f"{args.out}/summary.json and {args.out}/tasks/")
    return 0
