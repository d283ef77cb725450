"""Build FMUs from trained models (runs in the flightgp environment, not inside an FMU).

An FMU built here carries, under ``resources/``:

- ``<module>.py``: the slave script pythonfmu loads, generated per FMU: one class named after the
  FMU that subclasses the model's slave (:class:`fmu_src.rate_predictor.RatePredictor`) and sets
  its variable table, package and step as data;
- ``<module>_lib/``: a package holding copies of :mod:`fmu_src._base`, :mod:`fmu_src._runtime`,
  the model's slave module, and the model file ``model.npz`` (numpy arrays, no pickle).

``<module>`` is ``<name>_<hash>``, the hash (8 hex digits of SHA-256) taken over the model's arrays,
the copied code and the variable table. A Python host shares ``sys.modules`` with every FMU it
loads (DESIGN.md, "Layout and layers"), so two FMUs whose content differs never share a module
name, and two that share one run identical code on identical models.

The build itself runs pythonfmu in a child process of this Python (pythonfmu imports the slave
script and leaves it and its folder in ``sys.modules``/``sys.path``); the FMU is written to a
temporary file next to the target and renamed, so no half-written FMU is ever left behind.
"""
from __future__ import annotations

import hashlib
import io
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from . import _runtime

HERE = Path(__file__).parent

#: What the known signals are, for the variable descriptions (Padfield's Bo105 names).
SIGNAL_PHRASES = {
    "theta_0": "main rotor collective pitch", "theta_1s": "longitudinal cyclic pitch",
    "theta_1c": "lateral cyclic pitch", "theta_0T": "tail rotor collective pitch",
    "p": "roll rate", "q": "pitch rate", "r": "yaw rate",
    "phi": "roll angle", "theta": "pitch angle", "psi": "heading",
}

_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}\Z")


def build_rate_predictor_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the GP-NARX rate predictor FMU of a trained model file.

    Parameters
    ----------
    model_path : path
        A model file written by :func:`validation.narx.save_trained` (``flightgp train``).
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
    validation.errors.BadInputError
        Bad ``name``; a model the FMU cannot run (an input lag 0, a signal without a known unit);
        ``out_dir`` is a file.
    """
    from validation.errors import BadInputError
    from validation.files import write_atomically
    from validation.narx import load_trained

    model_path, out_dir = Path(model_path), Path(out_dir)
    name = _default_name(model_path) if name is None else name
    if not _NAME.match(name):
        raise BadInputError(f"FMU name {name!r} must start with a letter and hold only letters, "
                            "digits and underscores (at most 64); it becomes the FMI model identifier")
    if out_dir.exists() and not out_dir.is_dir():
        raise BadInputError(f"{out_dir} exists and is not a folder")
    trained = load_trained(model_path)
    arrays = export_narx_arrays(trained)
    interface = _interface(trained.config)
    description = (f"GP-NARX predictor of {', '.join(trained.config.outputs)} with confidence bounds "
                   f"from {', '.join(trained.config.inputs)} and the previous outputs; NARX step "
                   f"{trained.step:g} s; {len(arrays['0/basis'])} basis points, "
                   f"{len(arrays['0/weights'])} hyperparameter samples; model {model_path.name}")
    fmu_bytes = _build(name, slave_module="rate_predictor", slave_class="RatePredictor",
                       variables_call=f"rate_predictor_variables(\n        inputs={interface['inputs']!r},"
                                      f"\n        outputs={interface['outputs']!r},\n    )",
                       step=trained.step, description=description, arrays=arrays)
    return write_atomically(out_dir / f"{name}.fmu", fmu_bytes)


def export_narx_arrays(trained) -> dict:
    """The FMU model file's arrays (:mod:`fmu_src._runtime`) of a
    :class:`validation.narx.TrainedNarx`: every output's predictive forms (one per
    hyperparameter sample, as ``GaussianProcess.predict`` mixes them), kernel weights, signal
    and noise variances, scalers, the NARX structure and step, and the training envelope."""
    from validation.errors import BadInputError

    structure = trained.model.structure
    if 0 in structure.input_lags:
        raise BadInputError(f"the model uses input lag 0 (direct feedthrough: y(k) from u(k)); an FMU "
                            f"output cannot depend on the input set at the same communication point. "
                            f"Retrain with input lags >= 1 (got {structure.input_lags})")
    outputs = []
    for gp in trained.model.model.gps:
        forms = gp.predictive_forms(use_samples=True)
        thetas = np.array([form.theta for form in forms])
        basis = forms[0].basis
        if any(not np.array_equal(form.basis, basis) for form in forms):
            raise ValueError("the hyperparameter samples of one GP must share its basis points")
        outputs.append({
            "basis": basis,
            "weights": np.array([form.weights for form in forms]),
            "variance_factor": np.array([form.variance_factor for form in forms]),
            "kernel_weights": np.array([gp.kernel.weights(theta[:-1]) for theta in thetas]),
            "log_signal_variance": thetas[:, 0],
            "noise_variance": np.exp(thetas[:, -1]),
            "input_mean": gp.input_scaler_.mean_, "input_scale": gp.input_scaler_.scale_,
            "output_mean": gp.output_scaler_.mean_[0], "output_scale": gp.output_scaler_.scale_[0],
        })
    first = trained.model.model.gps[0]
    training = first.input_scaler_.inverse_transform(first.X_train_)
    return _runtime.pack_model(step=trained.step, input_names=structure.input_names,
                               output_names=structure.output_names, input_lags=structure.input_lags,
                               output_lags=structure.output_lags, envelope_low=training.min(axis=0),
                               envelope_high=training.max(axis=0), outputs=outputs)


def _interface(config) -> dict:
    """(name, unit, limit, phrase) of every input and output, from the recording conventions."""
    from validation.errors import BadInputError
    from validation.recordings import column_limit, column_unit

    from ._base import UNITS

    def describe(name, kind):
        unit = column_unit(name)
        if unit not in UNITS:
            raise BadInputError(f"the model's {kind} {name!r} has no known SI unit (got {unit!r}); an "
                                f"FMU variable needs one of {', '.join(UNITS)}")
        return (name, unit, column_limit(name), SIGNAL_PHRASES.get(name, f"{kind} {name}"))

    inputs = tuple(describe(n, "input") for n in config.inputs)
    outputs = tuple(describe(n, "output") for n in config.outputs)
    generated = {f"{n}{suffix}" for n in config.outputs for suffix in ("_prev", "_lower", "_upper")}
    reserved = generated | {"confidence_level", "free_run"}
    clash = sorted((set(config.inputs) | set(config.outputs)) & reserved)
    if clash:
        raise BadInputError(f"signal name(s) {', '.join(clash)} clash with the FMU's generated variables")
    return {"inputs": inputs, "outputs": outputs}


def _default_name(model_path: Path) -> str:
    name = re.sub(r"\W+", "_", model_path.stem).strip("_") or "model"
    return name if name[0].isalpha() else f"model_{name}"


_SCRIPT = '''"""{name}: {description}.

Generated by flightgp build-fmu; do not edit. The code is in the package {package}
(copies of fmu_src), the model in {package}/model.npz.
"""
import ctypes

from {package}.{slave_module} import {slave_class}, {variables_function}

# pythonfmu 0.7's native loader runs this script again in this module's namespace at every
# fmi2Instantiate and then releases a reference to that namespace it never took. Unless the
# script takes one per run, the namespace is freed after the first instance and the next
# fmi2Instantiate crashes the host (tests/test_fmu.py, two instances in one process).
ctypes.pythonapi.Py_IncRef(ctypes.py_object(globals()))


class {name}({slave_class}):
    """{description}."""

    description = {description!r}
    PACKAGE = {package!r}
    STEP_SIZE = {step!r}
    VARIABLES = {variables_call}
'''


def _build(name: str, *, slave_module: str, slave_class: str, variables_call: str, step: float,
           description: str, arrays: dict) -> bytes:
    """Stage the slave script and package, run pythonfmu, return the FMU's bytes."""
    sources = {"__init__.py": f'"""Runtime of the {name} FMU (copies of flightgp\'s fmu_src)."""\n'}
    for module in ("_base", "_runtime", slave_module):
        sources[f"{module}.py"] = (HERE / f"{module}.py").read_text(encoding="utf-8")
    digest = hashlib.sha256()
    for key in sorted(arrays):
        value = np.ascontiguousarray(arrays[key])
        digest.update(f"{key}|{value.dtype.str}|{value.shape}|".encode())
        digest.update(value.tobytes())
    for file_name in sorted(sources):
        digest.update(file_name.encode() + sources[file_name].encode())
    digest.update(f"{name}|{slave_class}|{variables_call}|{step!r}|{description}".encode())
    module = f"{name}_{digest.hexdigest()[:8]}"
    package = f"{module}_lib"
    script = _SCRIPT.format(name=name, description=description, package=package,
                            slave_module=slave_module, slave_class=slave_class,
                            variables_function=variables_call.split("(", 1)[0],
                            variables_call=variables_call, step=float(step))
    with tempfile.TemporaryDirectory(prefix="flightgp_fmu_") as staging:
        staging = Path(staging)
        package_dir = staging / package
        package_dir.mkdir()
        for file_name, text in sources.items():
            (package_dir / file_name).write_text(text, encoding="utf-8")
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        (package_dir / "model.npz").write_bytes(buffer.getvalue())
        (staging / f"{module}.py").write_text(script, encoding="utf-8")
        out = staging / "out"
        command = [sys.executable, "-m", "pythonfmu", "build", "-f", str(staging / f"{module}.py"),
                   "-d", str(out), "--no-variable-step", "--handle-state", "--serialize-state",
                   str(package_dir)]
        result = subprocess.run(command, cwd=staging, capture_output=True, text=True)
        fmu = out / f"{name}.fmu"
        if result.returncode != 0 or not fmu.is_file():
            raise RuntimeError(f"pythonfmu failed to build {name}.fmu (exit {result.returncode}): "
                               f"{(result.stderr or result.stdout).strip()[-2000:]}")
        return fmu.read_bytes()
