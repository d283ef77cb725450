"""``flightgp diagnose-bench [--cases NAME...] [--reference NAME] [--through REFERENCE] [--seed N...] [--out DIR]
[--scheduler ADDRESS | --cluster-workers N]``: the concealed-effect benchmark of ``flightgp diagnose``
(:mod:`validation.diagnose.bench`), in this process or, with a Dask option, as a campaign
(docs/campaigns.md, "`diagnose-bench` on Dask")."""
from __future__ import annotations

import argparse
from pathlib import Path

from validation.cli.arguments import add_cluster_arguments, seed
from validation.core.errors import BadInputError
from validation.core.files import check_output_folder, json_text, write_files_atomically
from validation.core.progress import progress_bar

#: The files diagnose-bench writes in ``--out`` (besides the ``campaign/`` folder of a run on Dask).
SCORECARD_FILES = ("scorecard.json", "scorecard.txt")


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "diagnose-bench", help="score flightgp diagnose on recordings with concealed effects",
        description="Fly a Bo105 or the blimp reference with effects diagnose is not told about (named effects "
                    "on several channels and magnitudes, pairs, none, and physics outside the named "
                    "list), with sensor noise; diagnose each and print a scorecard: effect named, "
                    "true value inside the interval, held-out RMSE cut of the affected output, false "
                    "findings, seconds per case (with several --seed values, also the rates over "
                    "seeds). Writes DIR/scorecard.json and DIR/scorecard.txt. With --scheduler or "
                    "--cluster-workers, the cases and seeds run side by side on Dask as a campaign in "
                    "DIR/campaign/ (resumed when run again; docs/campaigns.md).")
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
    parser.add_argument("--input-terms", action="store_true",
                        help="with --through an FMU: let the residual search add terms fed into its inputs "
                             "(flightgp diagnose --input-terms); polynomial terms of the flying reference are "
                             "then through_inputs cases; this machine only")
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
    add_cluster_arguments(parser, workers_flag="--cluster-workers",
                          without="the cases run one after the other in this process, unless --cluster-workers")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from validation.diagnose.bench import (
        concealed_cases,
        format_scorecard,
        format_seed_summary,
        run_bench,
        summarise_seeds,
    )
    from validation.diagnose.pipeline import take_input_terms
    from validation.vehicles.effect_vehicle import effect_model

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
    check_output_folder(args.out, writes=SCORECARD_FILES)
    if args.duration is not None and not args.duration >= 5:
        raise BadInputError(f"--duration must be at least 5 s (a 3-2-1-1 on each input), got {args.duration}")
    if args.workers is not None and args.workers < 1:
        raise BadInputError(f"--workers must be at least 1, got {args.workers}")
    options = {"through": args.through, "workers": args.workers, "input_terms": args.input_terms}
    if args.input_terms:  # refused before any case flies: a --through that is not an FMU, colliding inputs
        if args.through is None:
            raise BadInputError("--input-terms is for a diagnosis --through an FMU")
        take_input_terms(effect_model(args.through, purpose="diagnose-bench"))
    if args.duration is not None:
        options["duration"] = args.duration
    seeds = list(dict.fromkeys(args.seed))
    if args.scheduler is not None or args.cluster_workers is not None:
        if args.cluster_workers is not None and args.cluster_workers < 1:
            raise BadInputError(f"--cluster-workers must be at least 1, got {args.cluster_workers}")
        if args.workers is not None:
            raise BadInputError("--workers (replay processes) does not apply on Dask: each case runs in one "
                                "worker process; drop it or drop --scheduler/--cluster-workers")
        if args.input_terms:
            raise BadInputError("--input-terms runs on this machine only; drop it or drop "
                                "--scheduler/--cluster-workers")
        reports = _run_on_dask(args, cases, seeds)
    else:
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
    json_name, text_name = SCORECARD_FILES
    written = write_files_atomically({args.out / json_name: json_text(result), args.out / text_name: table + "\n"})
    print(f"written {', '.join(str(path) for path in written)}")
    return 0


def _run_on_dask(args: argparse.Namespace, cases, seeds) -> list:
    """Every case and seed as a task of a campaign in ``DIR/campaign`` (docs/campaigns.md,
    "`diagnose-bench` on Dask"): run on the cluster, resumed when run again; returns the report
    of each seed (:func:`validation.diagnose.bench.bench_report`)."""
    import json

    from validation.campaign import parse_spec, read_result, run_campaign, task_folder
    from validation.diagnose.bench import DURATION, bench_report

    study = {"id": "bench", "kind": "diagnose-bench", "cases": [case.name for case in cases],
             "reference": args.reference, "seed": {"grid": seeds}}
    if args.through is not None:
        study["through"] = args.through
    if args.duration is not None:
        study["duration"] = args.duration
    spec = parse_spec({"name": "diagnose-bench", "studies": [study]}, base_dir=Path.cwd(), source="diagnose-bench")
    folder = args.out / "campaign"
    run_campaign(spec, folder, scheduler=args.scheduler, workers=args.cluster_workers,
                 progress=not args.no_progress)
    rows = {}
    for task in spec.tasks:
        result = read_result(folder, task.as_dict())
        if result.status != "done":
            raise RuntimeError(f"case {task.settings['case']} with seed {task.seed} failed: {result.message} "
                               f"(see {task_folder(folder, task.id) / 'result.json'})")
        score = json.loads((task_folder(folder, task.id) / "score.json").read_text(encoding="utf-8"))
        rows[task.settings["case"], task.seed] = score
    duration = DURATION if args.duration is None else args.duration
    return [bench_report([rows[case.name, s] for case in cases], reference=args.reference, through=args.through,
                         seed=s, duration=duration) for s in seeds]
