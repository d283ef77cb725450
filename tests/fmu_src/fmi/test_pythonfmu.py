"""How a pythonfmu FMU carries its code (fmu_src/fmi/pythonfmu.py, "Shipping code"): the copies of
flightgp modules under flat names, their imports of each other made relative, and the refusal of
a module that imports what a simulator host does not have. The FMUs' own code is checked by the
FMU contract (tests/fmu_src/contract.py, test_runtime_is_self_contained)."""
from __future__ import annotations

import importlib
import sys

import pytest

from fmu_src.fmi.pythonfmu import NotShippableError, shipped_sources

PROBE = "fgp_probe"


@pytest.fixture
def probe(tmp_path, monkeypatch):
    """A throw-away project package ``fgp_probe``; ``probe(name, text)`` writes its module ``name``."""
    package = tmp_path / "probe_root" / PROBE
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(package.parent))

    def write(name: str, text: str) -> None:
        (package / f"{name}.py").write_text(text)
        importlib.invalidate_caches()

    yield write
    for name in [m for m in sys.modules if m == PROBE or m.startswith(f"{PROBE}.")]:
        del sys.modules[name]


def test_project_imports_become_relative_imports_of_flat_copies(probe, tmp_path, monkeypatch):
    """Module and function-level imports of other project modules point at their copies, which
    travel too (transitively); the copies run as a package of their own."""
    probe("a", "import math\n\nimport numpy as np\n\nfrom fgp_probe.b import twice\n\n\n"
               "def f(x):\n    from fgp_probe.c import (\n        half,\n    )\n\n"
               "    return twice(half(x)) + math.floor(np.float64(0.5))\n")
    probe("b", "from fgp_probe.c import half\n\n\ndef twice(x):\n    return 4 * half(x)\n")
    probe("c", "def half(x):\n    return x / 2\n")
    sources = shipped_sources([f"{PROBE}.a"], project_packages=(PROBE,))
    assert set(sources) == {"fgp_probe_a.py", "fgp_probe_b.py", "fgp_probe_c.py"}
    assert "from .fgp_probe_b import twice" in sources["fgp_probe_a.py"]
    assert "    from .fgp_probe_c import (\n" in sources["fgp_probe_a.py"]
    assert all("from fgp_probe" not in text for text in sources.values())
    shipped = tmp_path / "shipped" / "carried"
    shipped.mkdir(parents=True)
    (shipped / "__init__.py").write_text("")
    for name, text in sources.items():
        (shipped / name).write_text(text)
    monkeypatch.syspath_prepend(str(shipped.parent))
    importlib.invalidate_caches()
    try:
        assert importlib.import_module("carried.fgp_probe_a").f(3.0) == 3.0  # 4 * ((3 / 2) / 2) + 0
    finally:
        for name in [m for m in sys.modules if m == "carried" or m.startswith("carried.")]:
            del sys.modules[name]


@pytest.mark.parametrize("text, phrase", [
    ("import scipy\n", "imports scipy"),
    ("from scipy.linalg import expm\n", "imports scipy.linalg"),
    ("from . import b\n", "a relative import"),
    ("import fgp_probe.b\n", "imports fgp_probe.b"),
    ("from fgp_probe import b\n", "a package, not a module"),
    ("def f():\n    import matplotlib\n", "imports matplotlib"),
    ("from fgp_probe.b import g\n", "fgp_probe.b (line 1) imports scipy"),  # transitively
])
def test_a_module_that_imports_what_a_host_lacks_is_refused(probe, text, phrase):
    probe("a", text)
    probe("b", "import scipy\n\n\ndef g():\n    return scipy\n")
    with pytest.raises(NotShippableError, match="line") as refused:
        shipped_sources([f"{PROBE}.a"], project_packages=(PROBE,))
    assert phrase in str(refused.value) and "the standard library, numpy, pythonfmu" in str(refused.value)


def test_declared_runtime_packages_may_be_imported(probe):
    probe("a", "def load():\n    import jsbsim\n\n    return jsbsim\n")
    with pytest.raises(NotShippableError, match="imports jsbsim"):
        shipped_sources([f"{PROBE}.a"], project_packages=(PROBE,))
    assert set(shipped_sources([f"{PROBE}.a"], runtime_packages=("jsbsim",), project_packages=(PROBE,))) == {
        "fgp_probe_a.py"}
