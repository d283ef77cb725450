"""The one exception type for bad user input.

Everything the user controls (recording files, command-line values, model files handed to a
command) is checked where it enters; a problem raises :class:`BadInputError` with one line that
says what is wrong and where (file, row, column), and the CLI turns it into exit code 2.
"""


class BadInputError(ValueError):
    """Bad user input: the message is one line naming what is wrong and where."""


def unknown_name_message(name: str, known, *, what: str = "key") -> str:
    """The words that refuse ``name`` because it is not one of ``known``: ``"unknown key 'qq'
    (did you mean 'q'?); known: u, w, q"``, the nearest known name by
    :func:`difflib.get_close_matches` when one is close. ``what`` names the kind of name
    (``"key"``, ``"field"``, ``"output"``)."""
    import difflib

    known = list(known)
    close = difflib.get_close_matches(str(name), known, n=1, cutoff=0.6)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"unknown {what} {name!r}{hint}; known: {', '.join(known)}"


def check_count(value, name: str, *, minimum: int = 1) -> int:
    """``value`` if it is a whole number (an ``int``, not a ``bool``) of at least ``minimum``;
    otherwise :class:`BadInputError`: ``"<name> must be a whole number of at least 1, got 2.5"``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise BadInputError(f"{name} must be a whole number of at least {minimum}, got {value!r}")
    return value
