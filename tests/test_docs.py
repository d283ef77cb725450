"""The Python examples of README.md and docs/*.md run as written, each in a scratch folder.

Every ```python block is one test, named by file and block number; blocks that are only
illustrations use another fence (```text, ```sh). Relative links between the pages must point at
files and headings that exist.
"""
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
_PYTHON_BLOCK = re.compile(r"^```python\n(.*?)^```", flags=re.S | re.M)


def _blocks():
    for page in PAGES:
        for index, block in enumerate(_PYTHON_BLOCK.findall(page.read_text(encoding="utf-8"))):
            yield pytest.param(page, index, block, id=f"{page.relative_to(ROOT)}-block{index}")


BLOCKS = list(_blocks())


def test_docs_have_python_examples():
    assert BLOCKS


@pytest.mark.parametrize(("page", "index", "block"), BLOCKS)
def test_python_example_runs(page, index, block, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    name = f"{page.relative_to(ROOT)} python block {index}"
    exec(compile(block, name, "exec"), {"__name__": "__docs__"})


_LINK = re.compile(r"\]\(([^)\s]+)\)")
_FENCED = re.compile(r"^```.*?^```", flags=re.S | re.M)


def _anchors(text: str) -> set:
    """The anchors GitHub gives the headings of a page: lower case, punctuation other than
    hyphens and underscores dropped, spaces turned into hyphens."""
    headings = re.findall(r"^#{1,6} (.+)$", _FENCED.sub("", text), flags=re.M)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in headings}


@pytest.mark.parametrize("page", PAGES, ids=lambda page: str(page.relative_to(ROOT)))
def test_relative_links_point_at_existing_files_and_headings(page):
    broken = []
    for link in _LINK.findall(_FENCED.sub("", page.read_text(encoding="utf-8"))):
        if "://" in link or link.startswith("mailto:"):
            continue
        path, _, anchor = link.partition("#")
        target = (page.parent / path).resolve() if path else page
        if not target.exists():
            broken.append(f"{link} (no such file)")
        elif anchor and target.suffix == ".md" and anchor not in _anchors(target.read_text(encoding="utf-8")):
            broken.append(f"{link} (no such heading)")
    assert not broken, f"{page.name}: broken links: {broken}"


_SHELL_BLOCK = re.compile(r"^```sh\n(.*?)^```", flags=re.S | re.M)
#: Marks of a synopsis (``flightgp bench [gp] ...``, ``RECORDING...``, ``bo105-<V>kt|blimp``),
#: which describes a command rather than being one.
_SYNOPSIS = re.compile(r"\[|\.\.\.|\||<")


def _commands():
    for page in PAGES:
        for block in _SHELL_BLOCK.findall(page.read_text(encoding="utf-8")):
            for line in block.replace("\\\n", " ").splitlines():
                command = " ".join(shlex.split(line, comments=True))
                if command.startswith("flightgp ") and not _SYNOPSIS.search(command):
                    yield pytest.param(command, id=f"{page.relative_to(ROOT)}: {command[:60]}")


@pytest.mark.parametrize("command", list(_commands()))
def test_shell_examples_are_valid_flightgp_command_lines(command):
    """Every ``flightgp`` line of a ```sh block parses with today's options (it is not run)."""
    from validation.cli.main import build_parser

    try:
        build_parser().parse_args(shlex.split(command)[1:])
    except SystemExit as exit_:
        pytest.fail(f"`{command}` does not parse (exit {exit_.code})")


#: A code comment or docstring citing a docs section: docs/page.md, "Heading" (or ("Heading")).
_CITATION = re.compile(r"docs/([\w-]+\.md)[,\s(]+\"([^\"]+)\"")


def _headings(page: Path) -> set:
    text = _FENCED.sub("", page.read_text(encoding="utf-8"))
    return {h.strip().replace("`", "") for h in re.findall(r"^#{1,6} (.+)$", text, flags=re.M)}


def test_code_cites_docs_sections_that_exist():
    sources = [path for package in ("gp_model", "validation", "fmu_src", "tests")
               for pattern in ("*.py", "*.c", "*.h") for path in (ROOT / package).rglob(pattern)
               if path != Path(__file__).resolve()]
    broken = []
    for source in sources:
        text = source.read_text(encoding="utf-8")
        for page, heading in _CITATION.findall(text):
            # A citation may wrap onto the next comment or docstring line.
            heading = re.sub(r"\s*\n\s*(?:#:?|//|\*)?\s*", " ", heading)
            target = ROOT / "docs" / page
            if not target.exists():
                broken.append(f"{source.relative_to(ROOT)}: docs/{page} does not exist")
            elif heading.replace("`", "") not in _headings(target):
                broken.append(f"{source.relative_to(ROOT)}: docs/{page} has no heading {heading!r}")
    assert not broken, "\n".join(broken)
