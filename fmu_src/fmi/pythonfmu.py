"""Build a pythonfmu FMU from a slave class, its variable table and its model arrays (runs in the
flightgp environment, not inside an FMU).

An FMU built by :func:`build_pythonfmu` carries, under ``resources/``:

- ``<module>.py``: the slave script pythonfmu loads, generated per FMU: one class named after the
  FMU that subclasses the model's slave (e.g. :class:`fmu_src.rate_predictor.slave.RatePredictor`)
  and sets its variable table, package and step as data;
- ``<module>_lib/``: a package holding the model file ``model.npz`` (numpy arrays, no pickle) and
  copies of the slave's module and of every flightgp module it imports (:func:`shipped_sources`).

``<module>`` is ``<name>_<hash>``, the hash (8 hex digits of SHA-256) taken over the model's
arrays, the copied code and the variable table. A Python host shares ``sys.modules`` with every
FMU it loads (docs/fmus.md, "The FMUs"), so two FMUs whose content differs never share a module
name, and two that share one run identical code on identical models.

Shipping code
-------------
The modules an FMU carries are ordinary flightgp modules that import each other absolutely
(``from fmu_src.fmi.slave import FlightgpSlave``, ``from gp_model.uncertain_input import
MomentMatcher``, ``from validation.vehicles.blimp_equations import rk4_advance``). The copy of
module ``a.b.c`` is ``a_b_c.py`` in the FMU's package (:func:`flat_name`), and every import of
another flightgp module becomes a relative import of that module's copy
(``from .fmu_src_fmi_slave import FlightgpSlave``), so the FMU runs where flightgp is not
installed. A module may travel only if it imports nothing but the standard library, numpy,
pythonfmu, the FMU's declared run-time packages (``jsbsim``) and other modules that may travel,
by ``from <module> import <names>``; anything else is refused at build time
(:class:`NotShippableError`), before any FMU is written.

The build itself runs pythonfmu in a child process of this Python (pythonfmu imports the slave
script and leaves it and its folder in ``sys.modules``/``sys.path``); the FMU is written to a
temporary file next to the target and renamed, so no half-written FMU is ever left behind.
"""
from __future__ import annotations

import ast
import hashlib
import importlib.util
import io
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from fmu_src.fmi.slave import MODEL_FILE
from validation.core.files import write_atomically

#: The top-level packages of flightgp: their modules travel as copies.
PROJECT_PACKAGES = ("fmu_src", "gp_model", "validation")
#: What every pythonfmu FMU's host has besides the standard library.
HOST_PACKAGES = ("numpy", "pythonfmu")


class NotShippableError(ValueError):
    """A module an FMU would carry imports something a simulator host does not have."""


def flat_name(module: str) -> str:
    """The name of ``module``'s copy in an FMU's package: its dotted name with ``_`` for ``.``."""
    return module.replace(".", "_")


def shipped_sources(roots, *, runtime_packages=(), project_packages=PROJECT_PACKAGES) -> dict[str, str]:
    """The copies an FMU carries of the modules ``roots`` and of every project module they
    import, transitively, with those imports made relative (module docstring).

    Parameters
    ----------
    roots : sequence of str
        Dotted module names, e.g. ``("fmu_src.rate_predictor.slave",)``.
    runtime_packages : sequence of str
        Packages the FMU needs in the host besides :data:`HOST_PACKAGES` (e.g. ``("jsbsim",)``).
    project_packages : sequence of str
        Top-level packages whose modules are copied (:data:`PROJECT_PACKAGES`).

    Returns
    -------
    dict of str -> str
        File name (``<flat name>.py``) -> source text.

    Raises
    ------
    NotShippableError
        A module imports something else, imports relatively, imports a package rather than a
        module, or two modules would share a file name.
    """
    allowed = set(sys.stdlib_module_names) | set(HOST_PACKAGES) | set(runtime_packages)
    sources, imports, pending = {}, {}, list(roots)
    while pending:
        module = pending.pop()
        if module in sources:
            continue
        sources[module] = Path(importlib.util.find_spec(module).origin).read_text(encoding="utf-8")
        imports[module] = _project_imports(module, sources[module], allowed, project_packages)
        pending += [node.module for node in imports[module]]
    files = {f"{flat_name(module)}.py": module for module in sources}
    if len(files) != len(sources):
        raise NotShippableError(f"modules {sorted(sources)} do not have distinct flat names")
    return {file: _relative_imports(sources[module], imports[module]) for file, module in files.items()}


def _project_imports(module: str, text: str, allowed: set, project_packages) -> list[ast.ImportFrom]:
    """The ``from <project module> import ...`` statements of ``module`` (at any depth); raises
    :class:`NotShippableError` for any import a host could not satisfy."""
    found = []
    for node in ast.walk(ast.parse(text, filename=module)):
        if isinstance(node, ast.Import):
            problems = [alias.name for alias in node.names if alias.name.split(".")[0] not in allowed]
        elif isinstance(node, ast.ImportFrom) and node.level:
            problems = [f"{'.' * node.level}{node.module or ''} (a relative import)"]
        elif isinstance(node, ast.ImportFrom) and node.module.split(".")[0] in project_packages:
            problems = [] if _is_plain_module(node.module) else [f"{node.module} (a package, not a module)"]
            found.append(node)
        elif isinstance(node, ast.ImportFrom):
            problems = [] if node.module.split(".")[0] in allowed else [node.module]
        else:
            continue
        if problems:
            raise NotShippableError(
                f"{module} (line {node.lineno}) imports {', '.join(problems)}: an FMU carries only modules "
                f"that import the standard library, {', '.join(sorted(allowed - set(sys.stdlib_module_names)))} "
                f"and modules of {', '.join(project_packages)} that follow the same rule, by "
                "`from <module> import <names>`")
    return found


def _is_plain_module(name: str) -> bool:
    spec = importlib.util.find_spec(name)
    return spec is not None and spec.submodule_search_locations is None and str(spec.origin).endswith(".py")


def _relative_imports(text: str, imports: list) -> str:
    """``text`` with each of ``imports`` (``from a.b.c import ...``) made ``from .a_b_c import ...``."""
    lines = text.splitlines(keepends=True)
    for node in imports:
        line = lines[node.lineno - 1]
        pattern = re.compile(rf"from\s+{re.escape(node.module)}\b")
        match = pattern.match(line, node.col_offset)
        if match is None:
            raise NotShippableError(f"cannot rewrite line {node.lineno} ({line.strip()!r}): write "
                                    f"`from {node.module} import ...` on one line")
        lines[node.lineno - 1] = line[:match.start()] + f"from .{flat_name(node.module)}" + line[match.end():]
    return "".join(lines)


_SCRIPT = '''"""{name}: {description}.

Generated by flightgp build-fmu; do not edit. The code is in the package {package}
(copies of flightgp modules), the model in {package}/{model_file}.
"""
import ctypes

{imports}

# pythonfmu 0.7's native loader runs this script again in this module's namespace at every
# fmi2Instantiate and then releases a reference to that namespace it never took. Unless the
# script takes one per run, the namespace is freed after the first instance and the next
# fmi2Instantiate crashes the host (tested: two instances in one process).
ctypes.pythonapi.Py_IncRef(ctypes.py_object(globals()))


class {name}({slave_class}):
    """{description}."""

    description = {description!r}
    PACKAGE = {package!r}
{attributes}    VARIABLES = {variables_call}
'''


def build_pythonfmu(target: Path, *, slave_class: type, variables, attributes: dict, description: str,
                    arrays: dict, runtime_packages=()) -> Path:
    """Stage the slave script and package, run pythonfmu, write the FMU.

    Parameters
    ----------
    target : Path
        ``<out_dir>/<name>.fmu``, already checked (:func:`fmu_src.fmi.naming.fmu_target`); ``name``
        is the model identifier and the generated class's name.
    slave_class : type
        The model's slave (a :class:`fmu_src.fmi.slave.FlightgpSlave`); its module and every
        project module it imports travel in the FMU. Whether the FMU claims
        ``canGetAndSetFMUstate`` (and ``canSerializeFMUstate``) is its ``CAN_GET_AND_SET_FMU_STATE``.
    variables : (callable, dict)
        The function that makes the variable table (in a module that may travel) and its
        keyword arguments, which must have an exact ``repr``.
    attributes : dict
        Class attribute name -> value (with an exact ``repr``) set on the generated class.
    description : str
        One line for the model description.
    arrays : dict of str -> ndarray
        The model file's arrays (``model.npz``).
    runtime_packages : sequence of str
        Packages the FMU needs in the host besides numpy and pythonfmu (:func:`shipped_sources`).

    Returns
    -------
    Path
        ``target``, written atomically.
    """
    name = target.stem
    function, arguments = variables
    roots = {slave_class.__module__: [slave_class.__name__]}
    roots.setdefault(function.__module__, []).append(function.__name__)
    sources = {"__init__.py": f'"""Runtime of the {name} FMU (copies of flightgp modules)."""\n',
               **shipped_sources(list(roots), runtime_packages=runtime_packages)}
    variables_call = (f"{function.__name__}(\n"
                      + "".join(f"        {key}={value!r},\n" for key, value in arguments.items()) + "    )")
    lines = "".join(f"    {key} = {value!r}\n" for key, value in attributes.items())
    digest = hashlib.sha256()
    for key in sorted(arrays):
        value = np.ascontiguousarray(arrays[key])
        digest.update(f"{key}|{value.dtype.str}|{value.shape}|".encode())
        digest.update(value.tobytes())
    for file_name in sorted(sources):
        digest.update(file_name.encode() + sources[file_name].encode())
    digest.update(f"{name}|{slave_class.__name__}|{variables_call}|{lines}|{description}".encode())
    module = f"{name}_{digest.hexdigest()[:8]}"
    package = f"{module}_lib"
    imports = "\n".join(f"from {package}.{flat_name(origin)} import {', '.join(names)}"
                        for origin, names in roots.items())
    script = _SCRIPT.format(name=name, description=description, package=package, model_file=MODEL_FILE,
                            imports=imports, slave_class=slave_class.__name__, variables_call=variables_call,
                            attributes=lines)
    state = ["--handle-state", "--serialize-state"] if slave_class.CAN_GET_AND_SET_FMU_STATE else []
    return write_atomically(target, _run_pythonfmu(module, script, sources, arrays, state_options=state))


def _run_pythonfmu(module: str, script: str, sources: dict, arrays: dict, *, state_options: list) -> bytes:
    """Stage ``<module>.py`` and the package ``<module>_lib`` (``sources`` and the model file of
    ``arrays``) in a temporary folder, run ``pythonfmu build`` on them and return the FMU's bytes."""
    with tempfile.TemporaryDirectory(prefix="flightgp_fmu_") as staging:
        staging = Path(staging)
        package_dir = staging / f"{module}_lib"
        package_dir.mkdir()
        for file_name, text in sources.items():
            (package_dir / file_name).write_text(text, encoding="utf-8")
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        (package_dir / MODEL_FILE).write_bytes(buffer.getvalue())
        (staging / f"{module}.py").write_text(script, encoding="utf-8")
        out = staging / "out"
        command = [sys.executable, "-m", "pythonfmu", "build", "-f", str(staging / f"{module}.py"),
                   "-d", str(out), "--no-variable-step", *state_options, str(package_dir)]
        result = subprocess.run(command, cwd=staging, capture_output=True, text=True)
        built = list(out.glob("*.fmu")) if out.is_dir() else []
        if result.returncode != 0 or len(built) != 1:
            raise RuntimeError(f"pythonfmu failed to build the FMU of {module}.py (exit {result.returncode}): "
                               f"{(result.stderr or result.stdout).strip()[-2000:]}")
        return built[0].read_bytes()
