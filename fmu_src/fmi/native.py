"""Python-free native FMUs: compile a model's C with the FMI layer into a shared library and
package it (runs in the flightgp environment, not inside an FMU; docs/fmus.md, "Native FMUs (no
Python in the host)").

pythonfmu FMUs need the host's Python; C and C++ simulator hosts load only FMUs whose binary
has no such dependency. A native FMU has the interface of the pythonfmu FMU of the same model
(its ``modelDescription.xml`` is written by the same slave class) and its numbers (the model's C
repeats the Python formulas), but its binary needs only the C library and libm. What every
native FMU holds (:func:`package_native_fmu`):

- ``modelDescription.xml``: the pythonfmu FMU's, with ``needsExecutionTool="false"``, its own
  GUID and ``<SourceFiles>`` listing the C files, so that ``fmpy compile`` can rebuild the binary;
- ``binaries/linux64/<name>.so``: compiled here with the system ``gcc`` (:data:`COMPILE_FLAGS`)
  against the FMI 2.0 headers that fmpy ships (:func:`fmi_headers`);
- ``sources/``: ``fmi2_slave.c`` (this layer in C: call-sequence state machine, variables,
  logging, status policy, FMU state), ``gp_predict.c`` and ``gp_predict.h`` (GP prediction at one
  input: kernel row, mean, latent variance, for every model's GPs), ``greybox.c`` and
  ``greybox.h`` (the grey-box models' residual GPs and covariance propagation), the model's C file,
  ``model.h`` (the interface between layer and model) and the generated ``model_config.h`` (the
  FMU's GUID, variable table and the model's structure and constants, :func:`config_header`);
- ``resources/model.bin``: the model's arrays, read by each instance at ``fmi2Instantiate``
  (layout in the model's C file).
"""
from __future__ import annotations

import contextlib
import functools
import hashlib
import io
import os
import platform
import shutil
import subprocess
import tempfile
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from fmu_src.fmi.runtime import ENVELOPE_MARGIN
from fmu_src.fmi.slave import TIME_TOLERANCE
from validation.core.errors import BadInputError
from validation.core.files import write_atomically

#: The FMI 2.0 layer in C, compiled into every native FMU.
FMI_SOURCE = Path(__file__).with_name("fmi2_slave.c")
#: GP prediction at one input (kernel row, mean, latent variance), compiled into every native FMU.
GP_SOURCE = Path(__file__).with_name("gp_predict.c")
#: The grey-box (RKGP) models' residual GPs and covariance propagation, compiled into every native
#: FMU (dimensions are arguments, so it needs no model's constants).
GREYBOX_SOURCE = Path(__file__).with_name("greybox.c")
#: The interface between the FMI layer and a model's C file.
MODEL_HEADER = Path(__file__).with_name("model.h")
#: The headers of this layer every native FMU's sources carry.
LAYER_HEADERS = (MODEL_HEADER, Path(__file__).with_name("gp_predict.h"), Path(__file__).with_name("greybox.h"))
#: The generated header and the data file.
CONFIG_HEADER, DATA_FILE = "model_config.h", "model.bin"
#: Flags of the system gcc for the shared library (``-fvisibility=hidden``: only the FMI
#: functions, declared with ``FMI2_Export`` in fmi2Functions.h, are exported).
COMPILE_FLAGS = ("-O2", "-std=c99", "-Wall", "-Wextra", "-fPIC", "-shared", "-fvisibility=hidden")
#: The binaries folder of this platform (FMI 2.0.5, sec. 2.3, "FMU Distribution").
PLATFORM_FOLDER = "linux64"

_KINDS = {"Real": "KIND_REAL", "Boolean": "KIND_BOOLEAN"}


def _model_files(model_source) -> tuple[Path, ...]:
    return (model_source,) if isinstance(model_source, Path) else tuple(model_source)


def compiled_sources(model_source) -> tuple[Path, ...]:
    """The C files compiled into a native FMU of the model whose C is ``model_source`` (one C file,
    or a tuple of the model's files: its C files and its own headers), in the order its
    ``modelDescription.xml`` lists them."""
    return FMI_SOURCE, GP_SOURCE, GREYBOX_SOURCE, *(f for f in _model_files(model_source) if f.suffix == ".c")


def model_headers(model_source) -> tuple[Path, ...]:
    """The model's own headers among ``model_source`` (:func:`compiled_sources`), shipped with
    the layer's."""
    return tuple(f for f in _model_files(model_source) if f.suffix == ".h")


def check_platform() -> None:
    """Raise :class:`validation.core.errors.BadInputError` unless this is Linux x86-64 (the only
    platform whose binary the native builders compile)."""
    if platform.system() != "Linux" or platform.machine() not in ("x86_64", "AMD64"):
        raise BadInputError(f"native FMUs are built for Linux x86-64 ({PLATFORM_FOLDER}); this is "
                            f"{platform.system()} {platform.machine()}. Build on Linux, or run `fmpy compile` "
                            "on the FMU's sources on the target")


def package_native_fmu(target: Path, *, slave_class, model_source, config, data: bytes,
                       extra_flags=()) -> Path:
    """Compile and package one native FMU (what every native builder ends with).

    Parameters
    ----------
    target : Path
        ``<out_dir>/<name>.fmu``, already checked; ``name`` is the model identifier.
    slave_class : type
        The pythonfmu slave class of the same FMU (variable table, description, step), whose
        ``modelDescription.xml`` the native FMU declares.
    model_source : Path or tuple of Path
        The model's C file (or its C files and headers), compiled with :data:`FMI_SOURCE`,
        :data:`GP_SOURCE` and :data:`GREYBOX_SOURCE` (:func:`compiled_sources`).
    config : callable
        ``config(guid) -> str``: the FMU's ``model_config.h`` (:func:`config_header`).
    data : bytes
        ``resources/model.bin``, the model constants read at ``fmi2Instantiate``.
    extra_flags : sequence of str
        gcc flags the model needs besides :data:`COMPILE_FLAGS` (named in its C file).

    Returns
    -------
    Path
        ``target``, written atomically.
    """
    c_files = compiled_sources(model_source)
    xml, guid = _model_description(slave_class, [path.name for path in c_files])
    sources = {path.name: path.read_bytes() for path in (*c_files, *LAYER_HEADERS, *model_headers(model_source))}
    sources[CONFIG_HEADER] = config(guid).encode()
    binary = compile_shared_library(sources, target.stem, extra_flags=extra_flags)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("modelDescription.xml", xml)
        archive.writestr(f"binaries/{PLATFORM_FOLDER}/{target.stem}.so", binary)
        for file, text in sources.items():
            archive.writestr(f"sources/{file}", text)
        archive.writestr(f"resources/{DATA_FILE}", data)
    return write_atomically(target, buffer.getvalue())


def fmi_headers() -> Path:
    """The folder of the FMI 2.0 headers (``fmi2Functions.h`` and the files it includes) that
    fmpy ships."""
    import fmpy

    folder = Path(fmpy.__file__).parent / "c-code"
    if not (folder / "fmi2Functions.h").is_file():
        raise RuntimeError(f"fmpy {fmpy.__version__} ships no fmi2Functions.h in {folder}")
    return folder


#: Environment variable naming a folder where :func:`compile_shared_library` keeps each compiled
#: object file under a digest of its content (unset: no cache, every build compiles everything).
CACHE_VARIABLE = "FLIGHTGP_NATIVE_CACHE_DIR"


def compile_shared_library(sources: dict, name: str, *, extra_flags=()) -> bytes:
    """Compile C sources into a shared library with the system gcc.

    Each ``.c`` file is compiled to an object file on its own, then the objects are linked (what
    gcc does given them all at once). When the environment variable :data:`CACHE_VARIABLE` names
    a folder, an object file is kept there under a digest of what determines it: the compiler
    (its path and version), the flags and the file as the preprocessor leaves it (its headers
    included, line markers left out), so a build of identical code (another FMU of the same
    model: the name and GUID appear only in the FMI layer's file) takes the object compiled
    before instead of compiling it again, and any change of code or flags compiles anew. Only
    successful compiles are kept; objects are written atomically, so processes may share the
    folder; a folder that cannot be read or written is passed over (compiled as without it).

    Parameters
    ----------
    sources : dict of str -> bytes
        File name -> content; every ``.c`` file is compiled, the headers are found next to them
        and in :func:`fmi_headers`.
    name : str
        Stem of the library, for messages.
    extra_flags : sequence of str
        Added after :data:`COMPILE_FLAGS` (e.g. ``-Werror`` in the tests).

    Returns
    -------
    bytes
        The ``.so``.

    Raises
    ------
    validation.core.errors.BadInputError
        No gcc on the path.
    RuntimeError
        gcc failed (the message holds its output).
    """
    gcc = shutil.which("gcc")
    if gcc is None:
        raise BadInputError("building a native FMU needs a C compiler: install gcc")
    cache = os.environ.get(CACHE_VARIABLE)
    flags = [*COMPILE_FLAGS, *extra_flags]
    with tempfile.TemporaryDirectory(prefix="flightgp_native_") as work:
        work = Path(work)
        for file, content in sources.items():
            (work / file).write_bytes(content)
        includes = [f"-I{work}", f"-I{fmi_headers()}"]
        objects = []
        for file in (f for f in sources if f.endswith(".c")):
            objects.append(work / f"{Path(file).stem}.o")
            command = [gcc, *flags, *includes, "-c", str(work / file), "-o", str(objects[-1])]
            kept = None if not cache else Path(cache) / f"{_object_key(gcc, [*flags, *includes], work / file, name)}.o"
            if kept is not None and _copied(kept, objects[-1]):
                continue
            _run_gcc(command, name)
            if kept is not None:
                _keep(objects[-1], kept)
        output = work / f"{name}.so"
        _run_gcc([gcc, *flags, *[str(o) for o in objects], "-o", str(output), "-lm"], name)
        if not output.is_file():
            raise RuntimeError(f"gcc failed to compile {name}.so: it wrote no library")
        return output.read_bytes()


def _copied(kept: Path, target: Path) -> bool:
    """Whether the cached object ``kept`` was copied to ``target``; False where it is not there
    or cannot be read (then the file is compiled: the cache only saves time, it never fails a
    build)."""
    try:
        shutil.copyfile(kept, target)
    except OSError:
        return False
    return True


def _keep(built: Path, kept: Path) -> None:
    """Keep the object ``built`` in the cache as ``kept``, atomically (a copy under a name of
    this process, then renamed), so processes may share the folder; a folder that cannot be
    written is left alone (the build goes on without the cache)."""
    partial = kept.with_name(f"{kept.stem}.{os.getpid()}.partial")
    try:
        kept.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(built, partial)
        os.replace(partial, kept)
    except OSError:
        with contextlib.suppress(OSError):
            partial.unlink()


def _run_gcc(command: list, name: str) -> None:
    """Run one gcc command of :func:`compile_shared_library`; RuntimeError with its output if it
    fails."""
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"gcc failed to compile {name}.so (exit {result.returncode}): "
                           f"{result.stderr.strip()[-3000:]}")


def _object_key(gcc: str, flags: list, source: Path, name: str) -> str:
    """The cache key of one object file of :func:`compile_shared_library`: a SHA-256 digest of
    the compiler's path and version, the flags (the include folders left out: their headers
    count through the preprocessed text) and the preprocessed ``source`` without line markers
    (which would name the temporary folder)."""
    compile_flags = [f for f in flags if not f.startswith("-I")]
    preprocessed = subprocess.run([gcc, *flags, "-E", "-P", str(source)], capture_output=True)
    if preprocessed.returncode != 0:
        raise RuntimeError(f"gcc failed to compile {name}.so (exit {preprocessed.returncode}): "
                           f"{preprocessed.stderr.decode(errors='replace').strip()[-3000:]}")
    digest = hashlib.sha256()
    for part in (gcc, _compiler_version(gcc), "\0".join(compile_flags)):
        digest.update(part.encode() + b"\0")
    digest.update(preprocessed.stdout)
    return digest.hexdigest()


@functools.cache
def _compiler_version(gcc: str) -> str:
    """``gcc --version``'s output (the compiler's identity in :func:`_object_key`)."""
    return subprocess.run([gcc, "--version"], capture_output=True, text=True, check=True).stdout


def _model_description(slave_class, c_files: list) -> tuple[bytes, str]:
    """The pythonfmu FMU's ``modelDescription.xml`` (its slave class writes it), made native: no
    execution tool, the C sources listed. Returns the XML and its GUID."""
    root = slave_class(instance_name="build").to_xml({
        "needsExecutionTool": False, "canHandleVariableCommunicationStepSize": False,
        "canGetAndSetFMUstate": True, "canSerializeFMUstate": True})
    root.set("generationTool", "flightgp native C exporter (fmu_src/fmi/native.py)")
    co_simulation = root.find("CoSimulation")
    files = ElementTree.SubElement(co_simulation, "SourceFiles")
    for file in c_files:
        ElementTree.SubElement(files, "File", {"name": file})
    ElementTree.indent(root, space="  ")
    return ElementTree.tostring(root, encoding="UTF-8", xml_declaration=True), root.get("guid")


# -- model_config.h ------------------------------------------------------------------------------
def config_header(name: str, guid: str, *, generator: str, body: list) -> str:
    """``model_config.h`` of one native FMU: include guard, the FMU's identity, the FMI layer's
    relative time tolerance (:data:`fmu_src.fmi.slave.TIME_TOLERANCE`), then ``body`` (lines of
    the model's constants, e.g. :func:`variable_table` and :func:`envelope_lines`).

    Parameters
    ----------
    name, guid : str
        The FMU's model identifier and GUID.
    generator : str
        The module that writes the model's lines (named in the header's first comment).
    body : list of str
    """
    return "\n".join([
        f"/* {name}: generated by flightgp ({generator}); do not edit. */",
        "#ifndef FLIGHTGP_MODEL_CONFIG_H", "#define FLIGHTGP_MODEL_CONFIG_H", "",
        "#include <float.h>", '#include "model.h"', "",
        "/* Identity (modelDescription.xml) */",
        f"#define MODEL_IDENTIFIER {c_string(name)}",
        f"#define MODEL_GUID {c_string(guid)}",
        "/* Relative tolerance on the communication point and step (fmu_src/fmi/slave.py) */",
        f"#define TIME_TOLERANCE {c_number(TIME_TOLERANCE)}", "",
        *body, "", "#endif", ""])


def variable_table(variables: tuple, source: str) -> list:
    """Lines of ``model_config.h`` declaring the variable table (model.h, VariableInfo), made
    by the function named in ``source``."""
    rows = []
    for v in variables:
        minimum = "-DBL_MAX" if v.minimum is None else c_number(v.minimum)
        maximum = "DBL_MAX" if v.maximum is None else c_number(v.maximum)
        rows.append(f"    {{{c_string(v.name)}, {_KINDS[v.kind]}, CAUSALITY_{v.causality.upper()}, "
                    f"VARIABILITY_{v.variability.upper()}, {c_string(v.unit or '')}, "
                    f"{c_number(float(v.start))}, {minimum}, {maximum}}},")
    return [f"/* Variable table ({source}): row = value reference */", f"#define N_VARIABLES {len(variables)}",
            "static const VariableInfo VARIABLES[N_VARIABLES] = {", *rows, "};", ""]


def envelope_lines(names_array: str, envelope) -> list:
    """Lines of ``model_config.h`` declaring a model's training envelope
    (:class:`fmu_src.fmi.runtime.Envelope`): its input names as the C array ``names_array``,
    ``ENVELOPE_LOW``, ``ENVELOPE_HIGH`` and ``ENVELOPE_MARGIN``."""
    return ["/* Training envelope of each model input (physical units) and its margin (fmu_src/fmi/runtime.py) */",
            c_array("char *const", names_array, envelope.names, c_string).rstrip(),
            c_array("double", "ENVELOPE_LOW", envelope.low, c_number).rstrip(),
            c_array("double", "ENVELOPE_HIGH", envelope.high, c_number).rstrip(),
            f"#define ENVELOPE_MARGIN {c_number(ENVELOPE_MARGIN)}"]


def c_string(text: str) -> str:
    """``text`` as a C string literal; only printable ASCII without quotes or backslashes."""
    if not (text.isascii() and text.isprintable()) or '"' in text or "\\" in text:
        raise ValueError(f"{text!r} cannot be a plain C string literal")
    return f'"{text}"'


def c_number(value: float) -> str:
    """``value`` as a C double literal that reads back as the same double."""
    if not np.isfinite(value):
        raise ValueError(f"model constant {value} is not finite")
    return repr(float(value))  # shortest round-trip form: strtod reads back the same double


def c_array(c_type: str, name: str, values, form=str) -> str:
    """``static const <type> <name>[n] = {...};`` (one placeholder element when empty: ISO C
    has no zero-length arrays)."""
    values = list(values)
    items = ", ".join(form(v) for v in values) if values else "0"
    return f"static const {c_type} {name}[{max(len(values), 1)}] = {{{items}}};\n"


def lower_triangular(factors: np.ndarray) -> bool:
    """Whether every variance factor (..., m, m) is zero above its diagonal (an exact GP's L^-1)."""
    return not np.any(np.triu(factors, k=1))


def packed_variance_factor(factor: np.ndarray, *, triangular: bool) -> np.ndarray:
    """A variance factor ``V`` (m, m) as the native models read it (``gp_predict.h``): by columns;
    if ``triangular`` (``V`` lower triangular, :func:`lower_triangular`), column ``c`` only from
    row ``c`` on (m (m + 1) / 2 doubles), else whole (m m doubles)."""
    m = len(factor)
    rows, columns = np.triu_indices(m)[::-1] if triangular else np.indices((m, m)).reshape(2, -1)[::-1]
    return factor[rows, columns]
