"""The native (C, Python-free) GP-NARX rate predictor FMU (runs in the flightgp environment, not
inside an FMU; docs/fmus.md, "Native FMUs (no Python in the host)").

:func:`build_native_rate_predictor_fmu` writes an FMI 2.0 co-simulation FMU with the interface
of the pythonfmu rate predictor (:mod:`fmu_src.rate_predictor.slave`: the same variable table,
value references, units, descriptions, parameters, start values, default experiment and
sampling convention, since its ``modelDescription.xml`` is written by the same class) and the
same numbers (``narx_model.c``: the formulas of
:class:`fmu_src.rate_predictor.predictor.NarxPredictor`, free-run mode included: the belief over
the lagged outputs propagated by moment matching over the hyperparameter mixture, eqs. (1)-(6)
of :mod:`gp_model.uncertain_input`), packaged by :mod:`fmu_src.fmi.native`.

The FMU state holds the lag histories and the free-run belief (mean vector and covariance
matrix). ``resources/model.bin`` holds the GP arrays (every output's basis points, and per
hyperparameter sample its mean weights, kernel weights, signal and noise variance and variance
factor; layout in ``narx_model.c``). They are read at run time rather than compiled in because
the paper's model holds 400 x 3 variance factors of 32 x 32 (10 MB): as C initialisers they take
gcc long to compile, and the binary would not be rebuildable from small sources.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from fmu_src.fmi.native import (
    DATA_FILE,
    c_array,
    c_number,
    c_string,
    check_platform,
    config_header,
    envelope_lines,
    lower_triangular,
    package_native_fmu,
    packed_variance_factor,
    variable_table,
)
from fmu_src.rate_predictor.build import rate_predictor_parts
from fmu_src.rate_predictor.predictor import PER_OUTPUT, NarxPredictor
from fmu_src.rate_predictor.slave import RatePredictor, rate_predictor_variables

#: The model's C file, compiled with the FMI layer.
MODEL_SOURCE = Path(__file__).with_name("narx_model.c")
#: gcc flags of the FMU's one compile (``narx_model.c`` with the FMI layer): the model's loops
#: over the pair blocks of eq. 6 vectorise only under OpenMP's SIMD directive
#: (``FLIGHTGP_OPENMP_SIMD`` switches it on in the source), with fused multiply-adds allowed, and
#: the short loops of each block's set-up only at ``-O3`` (after the layer's ``-O2``, so it
#: wins): 670 against 1040 us per free-run step of the paper's model.
MODEL_FLAGS = ("-O3", "-fopenmp-simd", "-DFLIGHTGP_OPENMP_SIMD", "-ffp-contract=fast", "-pthread")

_DATA_MAGIC = b"FGPNARX2"


def build_native_rate_predictor_fmu(model_path, out_dir, *, name: str | None = None, extra_flags=()) -> Path:
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
    extra_flags : sequence of str, optional
        gcc flags added after :data:`MODEL_FLAGS`, e.g. ``("-pedantic", "-Werror")`` to build
        only if the sources compile without warnings under pedantic C99. Default: none.

    Returns
    -------
    Path
        ``out_dir/<name>.fmu``.

    Raises
    ------
    gp_model.ModelFileError
        The model file is missing, corrupt or not a GP-NARX model.
    validation.core.errors.BadInputError
        As :func:`fmu_src.rate_predictor.build.build_rate_predictor_fmu`; also no ``gcc`` on the
        path or a platform other than Linux x86-64.
    RuntimeError
        gcc failed to compile the generated sources (a bug: the message holds its output).
    """
    check_platform()
    parts = rate_predictor_parts(model_path, out_dir, name=name)
    predictor = parts.predictor
    variables = rate_predictor_variables(**parts.interface)
    identifier = parts.target.stem
    slave_class = type(identifier, (RatePredictor,), {
        "description": parts.description + " Built as native C (no Python at run time).", "VARIABLES": variables,
        "STEP_SIZE": parts.step})
    data = _narx_data(parts.arrays, predictor)
    n_doubles = (len(data) - len(_DATA_MAGIC) - 8) // 8  # after the magic and the count
    return package_native_fmu(
        parts.target, slave_class=slave_class, model_source=MODEL_SOURCE,
        config=lambda guid: _narx_config(guid, identifier, variables, predictor, parts.arrays, n_doubles),
        data=data, extra_flags=(*MODEL_FLAGS, *extra_flags))


def _narx_config(guid: str, name: str, variables: tuple, predictor: NarxPredictor, arrays: dict,
                 n_doubles: int) -> str:
    """``model_config.h``: identity, variable table and NARX structure of one FMU whose
    ``model.bin`` holds ``n_doubles`` doubles."""
    reference = {v.name: vr for vr, v in enumerate(variables)}
    outputs = predictor.output_names
    parts = [_part(arrays, j) for j in range(len(outputs))]
    rows, _, pairs = _mixture_layout(predictor)
    return config_header(name, guid, generator="fmu_src/rate_predictor/native.py", body=[
        "/* Communication step = NARX step, s */",
        f"#define STEP_SIZE {c_number(predictor.step)}", "",
        *variable_table(variables, "fmu_src/rate_predictor/slave.py, rate_predictor_variables"),
        "/* NARX structure (fmu_src/rate_predictor/predictor.py): regressors = every input at every",
        "   input lag, then every output at every output lag */",
        f"#define N_INPUTS {len(predictor.input_names)}",
        f"#define N_OUTPUTS {len(outputs)}",
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
        f"#define FREE_RUN_VR {reference['free_run']}",
        f"#define EXACT_MOMENTS_VR {reference['exact_moments']}",
        f"#define PARALLEL_VR {reference['parallel']}", "",
        *envelope_lines("REGRESSOR_NAMES", predictor.envelope), "",
        f"/* GP arrays in resources/{DATA_FILE} (layout: narx_model.c) */",
        f"#define DATA_FILE {c_string(DATA_FILE)}",
        f"#define DATA_DOUBLES {n_doubles}",
        c_array("int", "BASIS_POINTS", [len(p["basis"]) for p in parts]).rstrip(),
        "/* Hyperparameter mixture: joint samples, distinct samples per output, distinct sample",
        "   pairs per output pair (0, 1), (0, 2), ..., (1, 2), ... */",
        f"#define JOINT_SAMPLES {predictor.n_samples}",
        c_array("int", "DISTINCT_SAMPLES", [len(r) for r in rows]).rstrip(),
        f"#define N_PAIRS {len(pairs)}",
        c_array("int", "PAIR_COUNT", [len(c) for _, _, c in pairs]).rstrip(),
        c_array("int", "LOWER_TRIANGULAR", [int(lower_triangular(p["variance_factor"])) for p in parts]).rstrip()])


def _part(arrays: dict, j: int) -> dict:
    return {key: np.asarray(arrays[f"{j}/{key}"], dtype=float) for key in PER_OUTPUT}


def _mixture_layout(predictor: NarxPredictor) -> tuple[list, list, list]:
    """What the native FMU stores of the hyperparameter mixture: per output the rows of its
    distinct samples; the joint table (S, n_outputs) of which distinct sample each joint sample
    is; per output pair a < b the distinct sample pairs and their counts (rows_a, rows_b, counts)
    (:class:`gp_model.uncertain_input.MomentMatcher`, which computes each once)."""
    distinct = predictor.matcher.distinct_samples()
    pairs = list(predictor.matcher.sample_pairs().values())
    return [rows for rows, _ in distinct], [index for _, index in distinct], pairs


def _narx_data(arrays: dict, predictor: NarxPredictor) -> bytes:
    """``model.bin``: magic, count, and the doubles in the layout of ``narx_model.c``
    (little-endian): every output's distinct samples, the joint table, the sample pairs."""
    rows, index, pairs = _mixture_layout(predictor)
    chunks = []
    for j, distinct in enumerate(rows):
        p = _part(arrays, j)
        # one storage for every sample: packed when all of them are lower triangular
        triangular = lower_triangular(p["variance_factor"])
        chunks += [p["input_mean"], p["input_scale"], [p["output_mean"], p["output_scale"]], p["basis"].ravel()]
        for s in distinct:
            chunks += [p["weights"][s], p["kernel_weights"][s],
                       [p["log_signal_variance"][s], p["noise_variance"][s]],
                       packed_variance_factor(p["variance_factor"][s], triangular=triangular)]
    chunks.append(np.column_stack(index).ravel())
    chunks += [np.column_stack(pair).ravel() for pair in pairs]
    data = np.concatenate([np.ravel(np.asarray(c, dtype="<f8")) for c in chunks])
    return _DATA_MAGIC + struct.pack("<Q", len(data)) + data.tobytes()
