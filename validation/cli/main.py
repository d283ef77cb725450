"""The ``flightgp`` command line.

Each subcommand lives in its own module, which exposes ``register(subparsers)``; that function
adds the subparser and sets ``func`` (called with the parsed arguments, returns an exit code).

Exit codes (docs/conventions.md, "Exit codes"): 0 success, 2 bad input or usage (one line on
stderr, no traceback), 1 internal error.
"""
from __future__ import annotations

import argparse
import logging
import os
import sys

from validation.core.errors import BadInputError

#: The commands, in the order ``--help`` lists them: name, its module in :mod:`validation.cli`,
#: and the one line ``--help`` shows for it (the module's ``register`` gives its subparser the
#: same). :func:`main` imports only the module of the command it runs (each pulls in its own
#: numerical stack), so ``flightgp COMMAND`` starts without importing the others.
COMMANDS = (
    ("demo", "demo", "run the built-in Bo105 case end to end"),
    ("record", "record", "fly a test manoeuvre on a vehicle and write the recording"),
    ("inspect", "inspect", "check a recording and print a summary"),
    ("train", "train", "train a GP-NARX model on recordings"),
    ("predict", "predict", "predict a recording with a GP-NARX model"),
    ("reproduce", "reproduce", "reproduce a seed paper's experiment"),
    ("cosim", "cosim", "co-simulate a GP FMU and a reference FMU against a recording"),
    ("bench", "bench", "speed benchmarks, each as a ratio against a peer run in the same process"),
    ("build-fmu", "build_fmu", "build an FMI 2.0 co-simulation FMU from a trained model or a reference"),
    ("diagnose", "diagnose", "locate a simulation/recording mismatch, name the missing physics, model it"),
    ("diagnose-bench", "diagnose_bench", "score flightgp diagnose on recordings with concealed effects"),
    ("state-space", "state_space", "write a built-in linear reference as a state-space JSON file"),
    ("qtg", "qtg", "run a qualification test guide (QTG) against an FMU or a reference"),
    ("campaign", "campaign", "run many co-simulations, diagnoses, bench cases, reproductions or QTGs on Dask"),
)


def _command_module(module_name: str):
    """The command module named ``module_name`` (:data:`COMMANDS`), imported on first use; each
    import is written out, so that the layer and cycle checks see it."""
    match module_name:
        case "demo":
            from validation.cli import demo as module
        case "record":
            from validation.cli import record as module
        case "inspect":
            from validation.cli import inspect as module
        case "train":
            from validation.cli import train as module
        case "predict":
            from validation.cli import predict as module
        case "reproduce":
            from validation.cli import reproduce as module
        case "cosim":
            from validation.cli import cosim as module
        case "bench":
            from validation.cli import bench as module
        case "build_fmu":
            from validation.cli import build_fmu as module
        case "diagnose":
            from validation.cli import diagnose as module
        case "diagnose_bench":
            from validation.cli import diagnose_bench as module
        case "state_space":
            from validation.cli import state_space as module
        case "qtg":
            from validation.cli import qtg as module
        case "campaign":
            from validation.cli import campaign as module
        case _:
            raise ValueError(f"no command module {module_name!r}")
    return module


def build_parser(*, only: str | None = None) -> argparse.ArgumentParser:
    """The ``flightgp`` parser with every command's subparser; with ``only`` (a command name),
    that command's in full and the others' name and help line alone (what ``--help`` lists),
    so only ``only``'s module is imported."""
    parser = argparse.ArgumentParser(
        prog="flightgp",
        description="Gaussian-process flight-dynamics models, FMU export and simulation diagnosis.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name, help_line in COMMANDS:
        if only is None or name == only:
            _command_module(module_name).register(subparsers)
        else:
            subparsers.add_parser(name, help=help_line)
    return parser


def _command_word(argv: list[str]) -> str | None:
    """The command ``argv`` names: its first word that is not an option (the options before the
    command take no value), if that is a command's name."""
    names = {name for name, _, _ in COMMANDS}
    word = next((word for word in argv if not word.startswith("-")), None)
    return word if word in names else None


def _is_model_file_error(error: BaseException) -> bool:
    """Whether ``error`` is a :class:`gp_model.ModelFileError` (without importing gp_model where
    the command never did: then none can have been raised)."""
    gp_model = sys.modules.get("gp_model")
    return gp_model is not None and isinstance(error, gp_model.ModelFileError)


def main(argv: list[str] | None = None) -> int:
    """Run ``flightgp``; returns the exit code (also used by the console script)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    # Every command listed, only the one named built in full (and its module imported); with
    # none named (--help, a typo) the help lines alone, which is all argparse then shows.
    parser = build_parser(only=_command_word(argv) or "")
    args = parser.parse_args(argv)  # usage errors exit 2 with argparse's one-line message
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args.func(args) or 0)
    except BadInputError as error:
        print(f"flightgp {args.command}: error: {error}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader went away (`flightgp inspect x.csv | head`): nothing left to say.
        sys.stdout = open(os.devnull, "w")
        return 0
    except OSError as error:
        # A path the user gave cannot be read or written (missing folder, a file where a folder
        # should be, no permission, disk full): bad input, not a flightgp fault.
        where = f": {error.filename}" if error.filename else ""
        print(f"flightgp {args.command}: error: {error.strerror or error}{where}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"flightgp {args.command}: error: out of memory; ask for fewer samples or runs",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"flightgp {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as error:  # noqa: BLE001 - last line of defence: say what broke, exit 1
        if _is_model_file_error(error):  # a ValueError: no other clause above takes it
            print(f"flightgp {args.command}: error: {error}", file=sys.stderr)
            return 2
        if args.verbose:
            raise
        print(
            f"flightgp {args.command}: internal error: {type(error).__name__}: {error} "
            "(run with -v for the traceback and please report it)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
