"""Python-free native FMUs: the GP-NARX rate predictor as C, compiled into a shared library
(runs in the flightgp environment, not inside an FMU).

DESIGN.md, "FMU rules": pythonfmu FMUs need the host's Python; C and C++ simulator hosts load
only FMUs whose binary has no such dependency. :func:`build_native_rate_predictor_fmu` writes an
FMI 2.0 co-simulation FMU with the same interface as the pythonfmu rate predictor
(:mod:`fmu_src.rate_predictor`: the same variable table, value references, units, descriptions,
parameters, start values, default experiment and sampling convention, since its
``modelDescription.xml`` is written by the same code) and the same one-step numbers (the
formulas of :class:`fmu_src._runtime.NarxPredictor`, free-run mode included: the belief over
the lagged outputs propagated by moment matching over the hyperparameter mixture, eqs. (1)-(6)
of :mod:`gp_model.uncertain_input`), but whose binary needs only the C library and libm.
The FMI layer (``fmi2_slave.c``), :func:`package_native_fmu` and :func:`compile_shared_library`
also build the native blimp RKGP (:mod:`fmu_src.native_blimp`).

What the FMU holds
------------------
- ``modelDescription.xml``: the pythonfmu rate predictor's (:meth:`FlightgpSlave.to_xml` of the
  same generated class), with ``needsExecutionTool="false"``, its own GUID and
  ``<SourceFiles>`` listing the C files, so that ``fmpy compile`` can rebuild the binary.
- ``binaries/linux64/<name>.so``: compiled here with the system ``gcc`` (:data:`COMPILE_FLAGS`)
  against the FMI 2.0 headers that fmpy ships (``fmpy/c-code``).
- ``sources/``: ``fmi2_slave.c`` (the FMI 2.0 layer: call-sequence state machine, variables,
  logging, status policy, FMU state), ``narx_model.c`` (the GP-NARX prediction), ``model.h``
  (their interface) and the generated ``model_config.h`` (the FMU's GUID, variable table, NARX
  structure, training envelope and array sizes). The FMU state holds the lag histories and the
  free-run belief (mean vector and covariance matrix).
- ``resources/model.bin``: the GP arrays (every output's basis points, and per hyperparameter
  sample its mean weights, kernel weights, signal and noise variance and variance factor), read
  by each instance at ``fmi2Instantiate`` (layout in ``narx_model.c``). Read at run time rather
  than compiled in because the paper's model holds 400 x 3 variance factors of 32 x 32 (10 MB):
  as C initialisers they take gcc long to compile, and the binary would not be rebuildable
  from small sources.
"""
from __future__ import annotations

import io
import platform
import shutil
import struct
import subprocess
import tempfile
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from . import _base, _runtime
from .rate_predictor import RatePredictor, rate_predictor_variables

#: The C sources of every native rate predictor (``fmu_src/native_c``); the first two are
#: compiled, ``model.h`` is their shared interface.
C_SOURCES = ("fmi2_slave.c", "narx_model.c")
C_HEADERS = ("model.h",)
#: The generated header and the data file.
CONFIG_HEADER, DATA_FILE = "model_config.h", "model.bin"
#: Flags of the system gcc for the shared library (``-fvisibility=hidden``: only the FMI
#: functions, declared with ``FMI2_Export`` in fmi2Functions.h, are exported).
COMPILE_FLAGS = ("-O2", "-std=c99", "-Wall", "-Wextra", "-fPIC", "-shared", "-fvisibility=hidden")
#: fmpy's folder name for the binaries of this platform (FMI 2.0, 2.2.1).
PLATFORM_FOLDER = "linux64"

_NATIVE_C = Path(__file__).parent / "native_c"
_DATA_MAGIC = b"FGPNARX1"
_KINDS = {"Real": "KIND_REAL", "Boolean": "KIND_BOOLEAN"}


def build_native_rate_predictor_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the native (C, Python-free) GP-NARX rate predictor FMU of a trained model file.

    Parameters
    ----------
    model_path : path
        A model file written by :func:`validation.models.narx.save_trained` (``flightgp train``).
    out_dir : path
        Folder for the FMU (created if missing).
    name : str, optional
        The FMU's model identifier and file name (``<name>.fmu``): a letter, then letters,
        digits or underscores. Default: the model file's stem, made into such a name.

    Returns
    -------
    Path
        ``out_dir/<name>.fmu``.

    Raises
    ------
    gp_model.ModelFileError
        The model file is missing, corrupt or not a GP-NARX model.
    validation.core.errors.BadInputError
        As :func:`fmu_src.builder.build_rate_predictor_fmu`; also no ``gcc`` on the path or a
        platform other than Linux x86-64.
    RuntimeError
        gcc failed to compile the generated sources (a bug: the message holds its output).
    """
    from .builder import rate_predictor_parts

    check_platform()
    model_path = Path(model_path)
    target, _, arrays, interface, description = rate_predictor_parts(model_path, out_dir, name=name)
    predictor = _runtime.NarxPredictor(arrays)  # checks shapes and finiteness
    variables = rate_predictor_variables(**interface)
    slave_class = type(target.stem, (RatePredictor,), {
        "description": description + "; native C (no Python at run time)", "VARIABLES": variables,
        "STEP_SIZE": float(predictor.step)})
    return package_native_fmu(
        target, slave_class=slave_class, c_sources=C_SOURCES,
        config=lambda guid: _narx_config(guid, target.stem, variables, predictor, arrays),
        data=_narx_data(arrays, len(predictor.output_names)))


def check_platform() -> None:
    """Raise :class:`validation.core.errors.BadInputError` unless this is Linux x86-64 (the only
    platform whose binary the native builders compile)."""
    from validation.core.errors import BadInputError

    if platform.system() != "Linux" or platform.machine() not in ("x86_64", "AMD64"):
        raise BadInputError(f"native FMUs are built for Linux x86-64 ({PLATFORM_FOLDER}); this is "
                            f"{platform.system()} {platform.machine()}. Build on Linux, or run `fmpy compile` "
                            "on the FMU's sources on the target")


def package_native_fmu(target: Path, *, slave_class, c_sources: tuple, config, data: bytes) -> Path:
    """Compile and package one native FMU (what every native builder ends with).

    Parameters
    ----------
    target : Path
        ``<out_dir>/<name>.fmu``, already checked; ``name`` is the model identifier.
    slave_class : type
        The pythonfmu slave class of the same FMU (variable table, description, step), whose
        ``modelDescription.xml`` the native FMU declares (:func:`_model_description`).
    c_sources : tuple of str
        The C files in ``fmu_src/native_c`` to compile: ``fmi2_slave.c`` and the model's.
    config : callable
        ``config(guid) -> str``: the FMU's ``model_config.h``.
    data : bytes
        ``resources/model.bin``, the model constants read at ``fmi2Instantiate``.

    Returns
    -------
    Path
        ``target``, written atomically.
    """
    from validation.core.files import write_atomically

    xml, guid = _model_description(slave_class, c_sources)
    sources = {file: (_NATIVE_C / file).read_bytes() for file in (*c_sources, *C_HEADERS)}
    sources[CONFIG_HEADER] = config(guid).encode()
    binary = compile_shared_library(sources, target.stem)
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


def compile_shared_library(sources: dict, name: str, *, extra_flags=()) -> bytes:
    """Compile C sources into a shared library with the system gcc.

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
    from validation.core.errors import BadInputError

    gcc = shutil.which("gcc")
    if gcc is None:
        raise BadInputError("building a native FMU needs a C compiler: install gcc")
    with tempfile.TemporaryDirectory(prefix="flightgp_native_") as work:
        work = Path(work)
        for file, content in sources.items():
            (work / file).write_bytes(content)
        output = work / f"{name}.so"
        command = [gcc, *COMPILE_FLAGS, *extra_flags, f"-I{work}", f"-I{fmi_headers()}",
                   *[str(work / f) for f in sources if f.endswith(".c")], "-o", str(output), "-lm"]
        result = subprocess.run(command, capture_output=True, text=True)
        if result.returncode != 0 or not output.is_file():
            raise RuntimeError(f"gcc failed to compile {name}.so (exit {result.returncode}): "
                               f"{result.stderr.strip()[-3000:]}")
        return output.read_bytes()


def _model_description(slave_class, c_sources: tuple) -> tuple[bytes, str]:
    """The pythonfmu FMU's ``modelDescription.xml`` (its slave class writes it), made native: no
    execution tool, the C sources listed. Returns the XML and its GUID."""
    root = slave_class(instance_name="build").to_xml({
        "needsExecutionTool": False, "canHandleVariableCommunicationStepSize": False,
        "canGetAndSetFMUstate": True, "canSerializeFMUstate": True})
    root.set("generationTool", "flightgp native C exporter (fmu_src/native.py)")
    co_simulation = root.find("CoSimulation")
    files = ElementTree.SubElement(co_simulation, "SourceFiles")
    for file in c_sources:
        ElementTree.SubElement(files, "File", {"name": file})
    ElementTree.indent(root, space="  ")
    return ElementTree.tostring(root, encoding="UTF-8", xml_declaration=True), root.get("guid")


def c_string(text: str) -> str:
    if not (text.isascii() and text.isprintable()) or '"' in text or "\\" in text:
        raise ValueError(f"{text!r} cannot be a plain C string literal")
    return f'"{text}"'


def c_number(value: float) -> str:
    if not np.isfinite(value):
        raise ValueError(f"model constant {value} is not finite")
    return repr(float(value))  # shortest round-trip form: strtod reads back the same double


def c_array(c_type: str, name: str, values, form=str) -> str:
    """``static const <type> <name>[n] = {...};`` (one placeholder element when empty: ISO C
    has no zero-length arrays)."""
    values = list(values)
    items = ", ".join(form(v) for v in values) if values else "0"
    return f"static const {c_type} {name}[{max(len(values), 1)}] = {{{items}}};\n"


def _narx_config(guid: str, name: str, variables: tuple, predictor, arrays: dict) -> str:
    """``model_config.h``: identity, variable table and NARX structure of one FMU."""
    reference = {v.name: vr for vr, v in enumerate(variables)}
    outputs = predictor.output_names
    n_out = len(outputs)
    parts = [_part(arrays, j) for j in range(n_out)]
    lines = [
        f"/* {name}: generated by flightgp (fmu_src/native.py); do not edit. */",
        "#ifndef FLIGHTGP_MODEL_CONFIG_H", "#define FLIGHTGP_MODEL_CONFIG_H", "",
        "#include <float.h>", '#include "model.h"', "",
        "/* Identity (modelDescription.xml) */",
        f"#define MODEL_IDENTIFIER {c_string(name)}",
        f"#define MODEL_GUID {c_string(guid)}",
        "/* Communication step = NARX step, s; relative time tolerance (fmu_src/_base.py) */",
        f"#define STEP_SIZE {c_number(predictor.step)}",
        f"#define TIME_TOLERANCE {c_number(_base.TIME_TOLERANCE)}", "",
        *variable_table(variables, "fmu_src/rate_predictor.py, rate_predictor_variables"),
        "/* NARX structure (fmu_src/_runtime.py): regressors = every input at every input lag, then",
        "   every output at every output lag */",
        f"#define N_INPUTS {len(predictor.input_names)}",
        f"#define N_OUTPUTS {n_out}",
        f"#define N_INPUT_LAGS {len(predictor.input_lags)}",
        f"#define N_OUTPUT_LAGS {len(predictor.output_lags)}",
        f"#define MAX_LAG {predictor.max_lag}",
        f"#define N_REGRESSORS {len(predictor.regressor_names)}",
        f"#define MAX_OUTPUT_LAG {max(predictor.output_lags)}",
        "/* Hidden state: lag histories, envelope flag, free-run belief mean and covariance (narx_model.c) */",
        "#define BELIEF_SIZE (MAX_OUTPUT_LAG * N_OUTPUTS)",
        "#define MODEL_STATE_SIZE (MAX_LAG * (N_INPUTS + N_OUTPUTS) + 1 + BELIEF_SIZE * (BELIEF_SIZE + 1))",
        c_array("int", "INPUT_LAGS", predictor.input_lags).rstrip(),
        c_array("int", "OUTPUT_LAGS", predictor.output_lags).rstrip(),
        "/* Value references: controls, *_prev inputs, means, lower and upper bounds, parameters */",
        c_array("unsigned", "CONTROL_VR", [reference[n] for n in predictor.input_names]).rstrip(),
        c_array("unsigned", "PREVIOUS_VR", [reference[f"{n}_prev"] for n in outputs]).rstrip(),
        c_array("unsigned", "MEAN_VR", [reference[n] for n in outputs]).rstrip(),
        c_array("unsigned", "LOWER_VR", [reference[f"{n}_lower"] for n in outputs]).rstrip(),
        c_array("unsigned", "UPPER_VR", [reference[f"{n}_upper"] for n in outputs]).rstrip(),
        f"#define CONFIDENCE_LEVEL_VR {reference['confidence_level']}",
        f"#define FREE_RUN_VR {reference['free_run']}", "",
        "/* Training envelope of each regressor (physical units) and its margin */",
        c_array("char *const", "REGRESSOR_NAMES", predictor.regressor_names, c_string).rstrip(),
        c_array("double", "ENVELOPE_LOW", predictor.envelope.low, c_number).rstrip(),
        c_array("double", "ENVELOPE_HIGH", predictor.envelope.high, c_number).rstrip(),
        f"#define ENVELOPE_MARGIN {c_number(_runtime.ENVELOPE_MARGIN)}", "",
        f"/* GP arrays in resources/{DATA_FILE} (layout: narx_model.c) */",
        f"#define DATA_FILE {c_string(DATA_FILE)}",
        f"#define DATA_DOUBLES {sum(_part_size(p) for p in parts)}",
        c_array("int", "BASIS_POINTS", [len(p["basis"]) for p in parts]).rstrip(),
        c_array("int", "HYPERPARAMETER_SAMPLES", [len(p["weights"]) for p in parts]).rstrip(),
        c_array("int", "LOWER_TRIANGULAR", [int(lower_triangular(p["variance_factor"])) for p in parts]).rstrip(),
        "", "#endif", ""]
    return "\n".join(lines)


def variable_table(variables: tuple, source: str) -> list:
    """Lines of ``model_config.h`` declaring the variable table (model.h, VariableInfo)."""
    rows = []
    for v in variables:
        minimum = "-DBL_MAX" if v.minimum is None else c_number(v.minimum)
        maximum = "DBL_MAX" if v.maximum is None else c_number(v.maximum)
        rows.append(f"    {{{c_string(v.name)}, {_KINDS[v.kind]}, CAUSALITY_{v.causality.upper()}, "
                    f"VARIABILITY_{v.variability.upper()}, {c_string(v.unit or '')}, "
                    f"{c_number(float(v.start))}, {minimum}, {maximum}}},")
    return [f"/* Variable table ({source}): row = value reference */", f"#define N_VARIABLES {len(variables)}",
            "static const VariableInfo VARIABLES[N_VARIABLES] = {", *rows, "};", ""]


def _part(arrays: dict, j: int) -> dict:
    return {key: np.asarray(arrays[f"{j}/{key}"], dtype=float) for key in _runtime.PER_OUTPUT}


def _part_size(part: dict) -> int:
    (m, d), S = part["basis"].shape, len(part["weights"])
    factor = m * (m + 1) // 2 if lower_triangular(part["variance_factor"]) else m * m
    return 2 * d + 2 + m * d + S * (m + d + 2 + factor)


def lower_triangular(factors: np.ndarray) -> bool:
    """Whether every variance factor (S, m, m) is zero above its diagonal (an exact GP's L^-1)."""
    return not np.any(np.triu(factors, k=1))


def _narx_data(arrays: dict, n_outputs: int) -> bytes:
    """``model.bin``: magic, count, and the doubles of every output in the layout of
    ``narx_model.c`` (little-endian)."""
    chunks = []
    for j in range(n_outputs):
        p = _part(arrays, j)
        m = len(p["basis"])
        # columns of V_s; of a lower triangular one only rows c .. m - 1 of column c
        columns = (np.triu_indices(m)[::-1] if lower_triangular(p["variance_factor"])
                   else tuple(np.indices((m, m)).reshape(2, -1)[::-1]))
        chunks += [p["input_mean"], p["input_scale"], [p["output_mean"], p["output_scale"]], p["basis"].ravel()]
        for s in range(len(p["weights"])):
            chunks += [p["weights"][s], p["kernel_weights"][s],
                       [p["log_signal_variance"][s], p["noise_variance"][s]],
                       p["variance_factor"][s][columns]]
    data = np.concatenate([np.ravel(np.asarray(c, dtype="<f8")) for c in chunks])
    return _DATA_MAGIC + struct.pack("<Q", len(data)) + data.tobytes()
