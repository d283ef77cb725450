"""The examples of README.md and docs/*.md work as written (docs/architecture.md, "Tests").

Every ```python block is one test, named by file and block number, run in a scratch folder.
Every ``flightgp`` command line of a ```sh block (and every ``$ flightgp`` line of a transcript)
parses with the real parser; the ```sh run blocks (the README's first session) run in a fresh
clone. Relative links between the pages must point at files and headings that exist.
"""
import os
import re
import shlex
import subprocess
import sys
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


_FENCE = re.compile(r"^```(\S*)[ \t]*([^\n]*)\n(.*?)^```", flags=re.S | re.M)
#: A word of a synopsis (``[--seed N]``, ``RECORDING...``, ``bo105-<V>kt``, ``blimp|rgblimp``),
#: which describes a command rather than being one.
_SYNOPSIS_WORD = re.compile(r"^\[|\.\.\.|<\w+>|\w\|\w")
_FLIGHTGP = ("flightgp", ".venv/bin/flightgp")
#: The repository's own folders: a documented path into one of them must exist on a fresh clone.
_REPOSITORY_FOLDERS = {path.name for path in ROOT.iterdir()
                       if path.is_dir() and path.name != "build" and not path.name.startswith(".")}


def _shell_lines(block: str, *, prompt: str = "") -> list:
    """The command lines of a shell block, continuation lines joined and comment lines left out;
    with ``prompt`` (``"$ "`` in a transcript), only the lines that start with it, without it."""
    lines = block.replace("\\\n", " ").splitlines()
    commands = [line[len(prompt):] for line in lines if line.startswith(prompt)]
    return [command for command in commands if shlex.split(command, comments=True)]


def _flightgp_commands():
    """Every ``flightgp`` command line of a code block: all of a ```sh block, the ``$ `` lines of
    a transcript in any other block."""
    for page in PAGES:
        for language, _, block in _FENCE.findall(page.read_text(encoding="utf-8")):
            if language == "python":
                continue
            for line in _shell_lines(block, prompt="" if language == "sh" else "$ "):
                words = shlex.split(line, comments=True)
                if words[0] in _FLIGHTGP:
                    yield pytest.param(words, language, id=f"{page.relative_to(ROOT)}: {' '.join(words)[:60]}")


FLIGHTGP_COMMANDS = list(_flightgp_commands())


def test_docs_have_flightgp_commands():
    assert FLIGHTGP_COMMANDS


@pytest.mark.parametrize(("words", "language"), FLIGHTGP_COMMANDS)
def test_documented_flightgp_command_lines_are_valid(words, language):
    """Every documented ``flightgp`` command line parses with today's options (it is not run),
    is no synopsis (those are ```text) and names only repository files that exist."""
    from validation.cli.main import build_parser

    command = " ".join(words)
    synopsis = [word for word in words if _SYNOPSIS_WORD.search(word)]
    assert language != "sh" or not synopsis, f"`{command}` is a synopsis ({synopsis}): put it in a ```text block"
    try:
        build_parser().parse_args(words[1:])
    except SystemExit as exit_:
        pytest.fail(f"`{command}` does not parse (exit {exit_.code})")
    paths = [Path(word.partition("=")[2] or word) for word in words[1:]]
    missing = [str(path) for path in paths if path.parts and path.parts[0] in _REPOSITORY_FOLDERS
               and not (ROOT / path).exists()]
    assert not missing, f"`{command}` names repository files that do not exist: {missing}"


def _sessions():
    """The ```sh run blocks of each page, in page order: the commands the tests run."""
    for page in PAGES:
        lines = [line for language, attributes, block in _FENCE.findall(page.read_text(encoding="utf-8"))
                 if language == "sh" and "run" in attributes.split() for line in _shell_lines(block)]
        if lines:
            yield pytest.param(page, lines, id=str(page.relative_to(ROOT)))


SESSIONS = list(_sessions())


def test_readme_first_session_is_run():
    assert ROOT / "README.md" in [session.values[0] for session in SESSIONS]


def _fresh_clone(folder: Path) -> Path:
    """``folder`` made to look like a fresh clone of the repository: a link to each of its
    top-level entries but ``build/`` (the outputs) and hidden ones (``.git``, ``.venv``, caches).
    A documented command writes only to ``build/``, so nothing reaches the repository."""
    for entry in ROOT.iterdir():
        if entry.name != "build" and not entry.name.startswith("."):
            (folder / entry.name).symlink_to(entry)
    return folder


@pytest.mark.slow
@pytest.mark.parametrize(("page", "lines"), SESSIONS)
def test_shell_session_runs_as_written(page, lines, tmp_path):
    """Each command of the page's ```sh run blocks, in order, exits 0 in ``sh`` at the root of a
    fresh clone, with ``flightgp`` the console script of this Python's environment (as after
    ``make demo`` and ``. .venv/bin/activate``) running this checkout's code."""
    clone = _fresh_clone(tmp_path)
    environment = {**os.environ, "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ["PATH"]]),
                   "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    for line in lines:
        result = subprocess.run(line, shell=True, cwd=clone, env=environment, capture_output=True, text=True,
                                timeout=600)
        assert result.returncode == 0, (f"{page.name}: `{line}` exited {result.returncode}:\n"
                                        f"{result.stderr[-3000:]}")


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
