"""Helpers of the QTG tests; their flights are tests/conftest.py's ``qtg_flights``."""


def write_spec(folder, text: str, *, name: str = "qtg.toml"):
    """``text`` as the spec ``folder/name``; returns its path."""
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path
