"""The architecture rules of docs/architecture.md, checked on the source with ``ast``.

Imports are read at module and function level alike (an import inside a function is still a
dependency). The rules:

1. Imports point one way, down the layers of :data:`LAYERS`: a module imports only modules of
   its own layer or of lower ones (``gp_model`` imports nothing of the other two packages).
2. No cycle between modules, within a layer either.
3. No module imports another module's private name (``from a import _b``) or reaches one
   through an imported module (``import gp_model`` then ``gp_model._gp``), and a private module
   (``a/b/_m.py``) is imported only from inside its own package (``a.b``).
4. No import by string (``importlib.import_module``, ``__import__``): every dependency is an
   import statement this test can read.
5. ``gp_model`` is mathematics: numpy, scipy and the standard library only.
6. ``validation`` keeps at most a dozen top-level modules; the rest lives in subpackages.

A package's ``__init__`` re-exports from its own submodules; importing ``a.b.c`` also runs
``a/b/__init__``, which is not counted as a dependency (it would make every package that
re-exports its submodules a cycle).
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("gp_model", "validation", "fmu_src")

#: Layers, lowest first; a module belongs to the longest prefix that names it.
LAYERS = (
    ("gp_model",),
    ("validation.core",),
    ("validation.vehicles",),
    ("validation.models",),
    ("fmu_src",),
    ("validation.cosim",),
    ("validation.diagnose",),
    ("validation.qtg",),
    ("validation.reproduce",),
    ("validation.campaign",),
    ("validation.bench",),
    ("validation.cli",),
)


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(path): path for package in PACKAGES for path in (ROOT / package).rglob("*.py")}


def _is_package(name: str) -> bool:
    return MODULES.get(name, Path()).name == "__init__.py"


def _imports(name: str) -> list[tuple[str, str, int]]:
    """``(imported module, imported name or "", line)`` of every project import in module ``name``."""
    path = MODULES[name]
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, "", node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:
                base = name.split(".") if _is_package(name) else name.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                module = ".".join(base + ([module] if module else []))
            for alias in node.names:
                submodule = f"{module}.{alias.name}"
                if submodule in MODULES:  # `from package import module`
                    found.append((submodule, "", node.lineno))
                else:
                    found.append((module, alias.name, node.lineno))
    return [(module, imported, line) for module, imported, line in found
            if module.split(".")[0] in PACKAGES]


def _layer(name: str) -> int:
    ranks = [(len(prefix), rank) for rank, prefixes in enumerate(LAYERS) for prefix in prefixes
             if name == prefix or name.startswith(prefix + ".")]
    if not ranks:
        return -1  # the empty ``validation`` package itself
    return max(ranks)[1]


EDGES = {name: sorted({module for module, _, _ in _imports(name)} - {name}) for name in MODULES}


def test_every_module_belongs_to_a_layer():
    assert [name for name in MODULES if _layer(name) < 0] == ["validation"]


@pytest.mark.parametrize("name", sorted(MODULES))
def test_imports_point_down_the_layers(name):
    upward = [f"{module} (line {line})" for module, _, line in _imports(name)
              if _layer(module) > _layer(name)]
    assert not upward, f"{name} (layer {_layer(name)}) imports higher layers: {', '.join(upward)}"


def test_no_import_cycles():
    """Depth-first search for a back edge; the message shows the cycle."""
    state, stack = {}, []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for target in EDGES.get(node, ()):
            if target not in MODULES:
                continue
            if state.get(target) == "open":
                cycle = stack[stack.index(target):] + [target]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if target not in state:
                visit(target)
        stack.pop()
        state[node] = "done"

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(MODULES)))
    for name in sorted(MODULES):
        if name not in state:
            visit(name)


def _private(part: str) -> bool:
    return part.startswith("_") and not part.startswith("__")


def _tree(name: str) -> ast.Module:
    return ast.parse(MODULES[name].read_text(encoding="utf-8"), filename=str(MODULES[name]))


@pytest.mark.parametrize("name", sorted(MODULES))
def test_no_private_names_from_other_modules(name):
    bad = []
    for module, imported, line in _imports(name):
        if _private(imported) and module != name:
            bad.append(f"{imported} from {module} (line {line})")
        parts = module.split(".")
        for depth, part in enumerate(parts[1:], start=1):
            owner = ".".join(parts[:depth])  # the package the private module belongs to
            if _private(part) and not (name == owner or name.startswith(owner + ".")):
                bad.append(f"private module {module} of {owner} (line {line})")
    assert not bad, f"{name} imports private names: {', '.join(bad)}"


@pytest.mark.parametrize("name", sorted(MODULES))
def test_no_private_names_reached_through_imported_modules(name):
    """``import gp_model`` then ``gp_model._gp.GaussianProcess`` is a private import too."""
    tree = _tree(name)
    bound = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] in PACKAGES:
                    bound[alias.asname or alias.name.split(".")[0]] = alias.name
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr):
            root = node.value
            while isinstance(root, ast.Attribute):
                root = root.value
            if isinstance(root, ast.Name) and root.id in bound:
                bad.append(f"{ast.unparse(node)} (line {node.lineno})")
    assert not bad, f"{name} reaches private names of other modules: {', '.join(bad)}"


@pytest.mark.parametrize("name", sorted(MODULES))
def test_no_imports_by_string(name):
    bad = []
    for node in ast.walk(_tree(name)):
        if isinstance(node, ast.Call):
            called = ast.unparse(node.func)
            if called in ("__import__", "importlib.import_module", "import_module"):
                bad.append(f"{called}(...) (line {node.lineno})")
    assert not bad, f"{name} imports by string, which the layer and cycle checks cannot see: {', '.join(bad)}"


def test_gp_model_is_mathematics_only():
    allowed = {"numpy", "scipy", "gp_model"} | set(sys.stdlib_module_names)
    bad = []
    for name, path in MODULES.items():
        if not name.startswith("gp_model"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                roots = [alias.name.split(".")[0] for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                roots = [node.module.split(".")[0]]
            else:
                continue
            bad += [f"{name}: {root}" for root in roots if root not in allowed]
    assert not bad


def test_validation_keeps_at_most_a_dozen_top_level_modules():
    top = [path.name for path in (ROOT / "validation").iterdir()
           if path.suffix == ".py" or (path / "__init__.py").is_file()]
    assert len(top) <= 12, sorted(top)
