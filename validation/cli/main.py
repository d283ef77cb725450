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

from gp_model import ModelFileError
from validation.cli import (
    bench,
    build_fmu,
    campaign,
    cosim,
    demo,
    diagnose,
    diagnose_bench,
    inspect,
    predict,
    qtg,
    record,
    reproduce,
    state_space,
    train,
)
from validation.core.errors import BadInputError

#: The command modules, in the order ``--help`` lists their commands.
COMMAND_MODULES = (demo, record, inspect, train, predict, reproduce, cosim, bench, build_fmu, diagnose,
                   diagnose_bench, state_space, qtg, campaign)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="flightgp",
        description="Gaussian-process flight-dynamics models, FMU export and simulation diagnosis.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in COMMAND_MODULES:
        module.register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``flightgp``; returns the exit code (also used by the console script)."""
    parser = build_parser()
    args = parser.parse_args(argv)  # usage errors exit 2 with argparse's one-line message
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args.func(args) or 0)
    except (BadInputError, ModelFileError) as error:
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
