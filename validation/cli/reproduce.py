"""``flightgp reproduce PAPER --out DIR``: the seed papers' experiments from one command."""
from __future__ import annotations

import argparse
import functools
from pathlib import Path

from validation.cli.arguments import add_cluster_arguments, seed
from validation.core.errors import BadInputError
from validation.core.files import check_output_folder

PAPERS = ("bo105", "blimp", "blimp-settings", "rgblimp", "rgblimp-settings", "rgblimp-hybrid-settings",
          "rgblimp-unseen", "rgblimp-diagnose")


def seed_list(text: str) -> tuple[int, ...]:
    """argparse type of ``--seeds``: distinct seeds separated by commas."""
    seeds = tuple(seed(part.strip()) for part in text.split(","))
    if len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"seeds must be distinct, got {text!r}")
    return seeds


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "reproduce", help="reproduce a seed paper's experiment",
        description="bo105: the Bo105 GP-NARX paper (AHS 74th Forum, 2018) on the flight-test "
                    "stand-in, plus its future work. Writes figures, recordings, models and "
                    "results.json to DIR and prints the RMSE table. blimp: Tables I-III of the "
                    "blimp RKGP paper (Ko et al., ICRA 2007) on the blimp-flight stand-in: "
                    "one-second predictions of RK, ODE, RKGP, ODEGP and GP-only, trajectory "
                    "sampling, and a yaw controller learned by policy search, over a campaign of "
                    "seeds; writes results.json, report.md, table1.png, predictions.png, table2.png, "
                    "table3.png, the first seed's RKGP model blimp_rkgp.npz and its FMU (--runs and "
                    "--paper-only apply to bo105 only, --seeds and --quick to blimp only). "
                    "blimp-settings: the validation-flight study that fixed the blimp RKGP's "
                    "settings (training-state smoothing, command lags, filter process noise); "
                    "writes settings.json (--quick applies). rgblimp: the RGBlimp's real flights "
                    "(Zhu, Cheng & Zhang, IEEE RA-L 2024) from --data DIR: for each configuration with "
                    "two flights or more, fit on all but the highest-numbered flight and test on that one "
                    "by a free run of the whole flight; the published model, the identified model, the "
                    "RKGP, one global RKGP and the SINDYc peer (needs PySINDy, a test extra), scored as the "
                    "source scores; writes results.json, "
                    "report.md, scores.png, flight_J.png and each configuration's RKGP model file "
                    "models/rgblimp_rkgp_J.npz (--configurations selects; --seed applies). "
                    "rgblimp-settings: the validation-flight study behind the rgblimp settings (fit on each "
                    "configuration's lowest-numbered flight, validate on the next; the test flight unread); "
                    "writes settings.json. rgblimp-hybrid-settings: the same study for the rollout-trained "
                    "hybrid's settings; writes hybrid_settings.json. "
                    "rgblimp-unseen: configurations never flown: the configurations dealt into --folds folds, "
                    "vehicle models (identified physics, rollout-trained hybrid) fitted without each fold and "
                    "free-run on its test flights; writes results.json and report.md. "
                    "rgblimp-diagnose: flightgp diagnose --reference rgblimp on the first flight of each of "
                    "several configurations (default 0 6 12 18 24 27 30 33), each configuration on its own "
                    "(--pooled: all at once), validated on the second (what carries over enters the corrected "
                    "model), and the corrected model free-run on the third and scored as the source scores; "
                    "writes results.json, report.md and diagnosis/.")
    parser.add_argument("paper", choices=PAPERS)
    parser.add_argument("--out", type=Path, required=True, metavar="DIR")
    parser.add_argument("--seed", type=seed, default=None,
                        help="random seed (default 0); for blimp, a campaign of this one seed")
    parser.add_argument("--seeds", type=seed_list, default=None, metavar="S,S,...",
                        help="blimp: the campaign's seeds (default 0,1,2,3,4; about 6 minutes a seed)")
    add_cluster_arguments(parser, workers_flag="--cluster-workers",
                          without="the seeds one after the other in this process; blimp only")
    parser.add_argument("--quick", action="store_true",
                        help="blimp: the short setup of every table (about a minute a seed; for checks)")
    parser.add_argument("--runs", type=int, default=1000, help="Monte Carlo runs (default 1000)")
    parser.add_argument("--paper-only", action="store_true", help="skip the beyond-the-paper studies")
    parser.add_argument("--data", type=Path, default=None, metavar="DIR",
                        help="rgblimp: a folder of the source's data_N.csv (any subset) with its data_info/")
    parser.add_argument("--configurations", type=int, nargs="+", default=None, metavar="J",
                        help="rgblimp: only these configurations j (flights 4j+1..4j+4; default every one "
                             "with two flights present)")
    parser.add_argument("--pooled", action="store_true",
                        help="rgblimp-diagnose: one diagnosis of every configuration at once (default: one each)")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="rgblimp-diagnose: configurations diagnosed side by side (default: the cores)")
    parser.add_argument("--folds", type=int, default=None, metavar="K",
                        help="rgblimp-unseen: folds of configurations (default 5; as many as configurations: "
                             "leave-one-configuration-out)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_output_folder(args.out, writes=["*"])  # a reproduction writes many files: its folder is its own
    if args.paper != "blimp" and (args.scheduler is not None or args.cluster_workers is not None):
        raise BadInputError("--scheduler and --cluster-workers apply to reproduce blimp only (its seeds run "
                            "side by side)")
    if args.folds is not None and args.paper != "rgblimp-unseen":
        raise BadInputError("--folds applies to reproduce rgblimp-unseen only")
    if (args.pooled or args.workers is not None) and args.paper != "rgblimp-diagnose":
        raise BadInputError("--pooled and --workers apply to reproduce rgblimp-diagnose only")
    if args.workers is not None and args.workers < 1:
        raise BadInputError(f"--workers must be 1 or more, got {args.workers}")
    if args.paper in ("rgblimp", "rgblimp-settings", "rgblimp-hybrid-settings", "rgblimp-unseen", "rgblimp-diagnose"):
        return _run_rgblimp(args)
    if args.data is not None or args.configurations is not None:
        raise BadInputError("--data and --configurations apply to reproduce rgblimp only")
    if args.paper == "blimp":
        from validation.reproduce.blimp import DEFAULT_SEEDS, reproduce_blimp
        from validation.reproduce.blimp_report import format_results

        if args.seed is not None and args.seeds is not None:
            raise BadInputError("give --seed or --seeds, not both")
        seeds = (args.seed,) if args.seed is not None else args.seeds or DEFAULT_SEEDS
        if args.scheduler is None and args.cluster_workers is None:
            results = reproduce_blimp(args.out, seeds=seeds, quick=args.quick)
        else:
            from validation.campaign.runner import map_on_dask

            if args.cluster_workers is not None and args.cluster_workers < 1:
                raise BadInputError(f"--cluster-workers must be at least 1, got {args.cluster_workers}")
            results = reproduce_blimp(args.out, seeds=seeds, quick=args.quick, map_seeds=functools.partial(
                map_on_dask, scheduler=args.scheduler, workers=args.cluster_workers, label="blimp seeds"))
        print(format_results(results))
        print(f"written {args.out}/report.md, results.json and figures")
        return 0
    if args.paper == "blimp-settings":
        from validation.core.files import write_json
        from validation.reproduce.blimp_settings import choose_settings, format_settings

        if args.seed is not None or args.seeds is not None:
            raise BadInputError("the settings study has fixed seeds (campaign seed 0 and its validation flight)")
        results = choose_settings(quick=args.quick, progress=True)
        write_json(args.out / "settings.json", results)
        print(format_settings(results))
        print(f"written {args.out}/settings.json")
        return 0
    if args.seeds is not None or args.quick:
        raise BadInputError("--seeds and --quick apply to reproduce blimp only")
    from validation.reproduce.bo105 import format_results, reproduce_bo105

    if args.runs < 10:
        raise BadInputError(f"--runs must be at least 10 for meaningful bounds, got {args.runs}")
    results = reproduce_bo105(args.out, seed=0 if args.seed is None else args.seed, n_runs=args.runs,
                              beyond=not args.paper_only)
    print(format_results(results))
    print(f"written {args.out}/results.json and figures")
    return 0


def _run_rgblimp(args: argparse.Namespace) -> int:
    from validation.reproduce.rgblimp import reproduce_rgblimp
    from validation.reproduce.rgblimp_report import format_results

    if args.data is None:
        raise BadInputError(f"reproduce {args.paper} needs --data DIR, a folder of the source's data_N.csv "
                            "and data_info/")
    if args.seeds is not None or args.quick or args.paper_only:
        raise BadInputError(f"--seeds, --quick and --paper-only do not apply to reproduce {args.paper}")
    if args.paper in ("rgblimp-settings", "rgblimp-hybrid-settings"):
        from validation.core.files import write_json
        from validation.reproduce import rgblimp_settings

        hybrid = args.paper == "rgblimp-hybrid-settings"
        study = rgblimp_settings.study_hybrid_settings if hybrid else rgblimp_settings.study_settings
        describe = rgblimp_settings.format_hybrid_settings if hybrid else rgblimp_settings.format_settings
        name = "hybrid_settings.json" if hybrid else "settings.json"
        results = study(args.data, configurations=args.configurations, seed=0 if args.seed is None else args.seed,
                        progress=True)
        write_json(args.out / name, results)
        print(describe(results))
        print(f"written {args.out}/{name}")
        return 0
    if args.paper == "rgblimp-unseen":
        from validation.reproduce.rgblimp_unseen import DEFAULT_FOLDS, format_unseen, study_unseen

        if args.seed is not None:
            raise BadInputError("reproduce rgblimp-unseen has fixed seeds (the hybrid's setup)")
        results = study_unseen(args.data, args.out, folds=args.folds or DEFAULT_FOLDS,
                               configurations=args.configurations)
        print(format_unseen(results), end="")
        print(f"written {args.out}/report.md and results.json")
        return 0
    if args.paper == "rgblimp-diagnose":
        from validation.reproduce.rgblimp_diagnose import DEFAULT_CONFIGURATIONS, reproduce_rgblimp_diagnose
        from validation.reproduce.rgblimp_diagnose import format_results as format_diagnosis

        results = reproduce_rgblimp_diagnose(args.data, args.out,
                                             configurations=args.configurations or DEFAULT_CONFIGURATIONS,
                                             seed=0 if args.seed is None else args.seed, pooled=args.pooled,
                                             workers=args.workers)
        print(format_diagnosis(results))
        print(f"written {args.out}/report.md, results.json and diagnosis/")
        return 0
    results = reproduce_rgblimp(args.data, args.out, configurations=args.configurations,
                                seed=0 if args.seed is None else args.seed)
    print(format_results(results))
    print(f"written {args.out}/report.md, results.json and figures")
    return 0
