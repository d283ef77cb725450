"""The one exception type for bad user input.

Everything the user controls (recording files, command-line values, model files handed to a
command) is checked where it enters; a problem raises :class:`BadInputError` with one line that
says what is wrong and where (file, row, column), and the CLI turns it into exit code 2.
"""


class BadInputError(ValueError):
    """Bad user input: the message is one line naming what is wrong and where."""
