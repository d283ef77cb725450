"""``python -m validation.cli``: the ``flightgp`` command line."""
import sys

from validation.cli.main import main

sys.exit(main())
