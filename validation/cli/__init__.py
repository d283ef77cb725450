"""The ``flightgp`` command line: :func:`main` (the console script), one module per command,
shared argument helpers in :mod:`validation.cli.arguments`."""
from validation.cli.main import main

__all__ = ["main"]
