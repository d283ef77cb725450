"""Build FMUs (runs in the flightgp environment, not inside an FMU).

- :func:`build_rate_predictor_fmu`: a trained GP-NARX model (:mod:`fmu_src.rate_predictor`);
- :func:`build_bo105_reference_fmu`: Padfield's linear Bo105 at a tabulated speed
  (:mod:`fmu_src.bo105_reference`);
- :func:`build_jsbsim_fmu`: a JSBSim aircraft (:mod:`fmu_src.jsbsim_aircraft`; the host needs
  the ``jsbsim`` package);
- :func:`build_blimp_rkgp_fmu`: a trained blimp grey-box model (``GreyBoxGP`` with the physics
  ``blimp_rk4``; :mod:`fmu_src.blimp_rkgp`);
- :func:`build_model_fmu`: the FMU of any trained model file, by its type (what
  ``flightgp build-fmu MODEL_FILE`` runs);
- :func:`build_reference_fmu`: either reference by its vehicle name (``bo105-80kt``,
  ``jsbsim:c172x``).

An FMU built here carries, under ``resources/``:

- ``<module>.py``: the slave script pythonfmu loads, generated per FMU: one class named after the
  FMU that subclasses the model's slave (e.g. :class:`fmu_src.rate_predictor.RatePredictor`) and
  sets its variable table, package and step as data;
- ``<module>_lib/``: a package holding copies of :mod:`fmu_src._base`, the model's slave module
  and what it imports (:mod:`fmu_src._runtime` for GP models), and the model file ``model.npz``
  (numpy arrays, no pickle).

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
import importlib
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
    "u": "forward velocity", "v": "lateral velocity", "w": "vertical velocity (positive down)",
    "elevator": "elevator (pitch stick) command", "aileron": "aileron (roll stick) command",
    "rudder": "rudder pedal command", "collective": "collective lever command",
    "longitudinal_cyclic": "longitudinal cyclic stick command",
    "lateral_cyclic": "lateral cyclic stick command", "pedal": "tail rotor pedal command",
}

_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}\Z")


def build_rate_predictor_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the GP-NARX rate predictor FMU of a trained model file.

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
        Bad ``name``; a model the FMU cannot run (an input lag 0, a signal without a known unit);
        ``out_dir`` is a file.
    """
    from validation.core.files import write_atomically

    target, trained, arrays, interface, description = rate_predictor_parts(model_path, out_dir, name=name)
    fmu_bytes = _build(target.stem, slave_module="rate_predictor", slave_class="RatePredictor",
                       variables_call=f"rate_predictor_variables(\n        inputs={interface['inputs']!r},"
                                      f"\n        outputs={interface['outputs']!r},\n    )",
                       attributes={"STEP_SIZE": float(trained.step)}, description=description,
                       arrays=arrays, support_modules=("_runtime",))
    return write_atomically(target, fmu_bytes)


def rate_predictor_parts(model_path, out_dir, *, name: str | None = None) -> tuple:
    """What every rate-predictor FMU (pythonfmu or native) is built from.

    Returns
    -------
    target : Path
        ``out_dir/<name>.fmu`` (name checked; default the model file's stem made into a name).
    trained : validation.models.narx.TrainedNarx
    arrays : dict
        :func:`export_narx_arrays` of the model.
    interface : dict
        ``inputs`` and ``outputs`` for :func:`fmu_src.rate_predictor.rate_predictor_variables`.
    description : str
        The FMU's one-line description.
    """
    from validation.models.narx import load_trained

    model_path = Path(model_path)
    target = _target(out_dir, _default_name(model_path.stem) if name is None else name)
    trained = load_trained(model_path)
    arrays = export_narx_arrays(trained)
    description = (f"GP-NARX predictor of {', '.join(trained.config.outputs)} with confidence bounds "
                   f"from {', '.join(trained.config.inputs)} and the previous outputs; NARX step "
                   f"{trained.step:g} s; {len(arrays['0/basis'])} basis points, "
                   f"{len(arrays['0/weights'])} hyperparameter samples; model {model_path.name}")
    return target, trained, arrays, _interface(trained.config), description


def export_narx_arrays(trained) -> dict:
    """The FMU model file's arrays (:mod:`fmu_src._runtime`) of a
    :class:`validation.models.narx.TrainedNarx`: every output's predictive forms (one per
    hyperparameter sample, as ``GaussianProcess.predict`` mixes them), kernel weights, signal
    and noise variances, scalers, the NARX structure and step, and the training envelope."""
    from validation.core.errors import BadInputError

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


def build_bo105_reference_fmu(speed_kt: int, out_dir, *, name: str | None = None,
                              derivatives: dict | None = None) -> Path:
    """Build the Bo105 physics reference FMU (``bo105-<V>kt``, :mod:`fmu_src.bo105_reference`).

    Parameters
    ----------
    speed_kt : int
        Trim speed, kt; one of Padfield's 0, 20, ..., 140.
    out_dir : path
        Folder for the FMU (created if missing).
    name : str, optional
        Model identifier and file name; default ``bo105_<V>kt_reference``.
    derivatives : dict of str -> float, optional
        Derivatives to replace (``Bo105Reference.with_derivatives``, e.g. ``{"M_q": -2.4}``);
        the FMU then runs the corrected model.

    Returns
    -------
    Path
        ``out_dir/<name>.fmu``.

    Raises
    ------
    validation.core.errors.BadInputError
        An untabulated speed, an unknown or non-finite derivative, a bad ``name``, ``out_dir`` a
        file.
    """
    from validation.core.files import write_atomically
    from validation.vehicles.bo105 import INPUT_NAMES, STATE_NAMES, Bo105Reference

    from . import bo105_reference

    reference = Bo105Reference(speed_kt)
    if derivatives:
        reference = reference.with_derivatives(derivatives)
    target = _target(out_dir, f"bo105_{reference.speed_kt}kt_reference" if name is None else name)
    assert (INPUT_NAMES, STATE_NAMES) == (bo105_reference.INPUT_NAMES, bo105_reference.STATE_NAMES)
    changed = "" if not derivatives else "; changed derivatives " + ", ".join(
        f"{key} = {reference.derivative(key):.6g}" for key in derivatives)
    source = f"Padfield (2007) linear 6-DOF model at {reference.speed_kt} kt{changed}"
    arrays = bo105_reference.pack_model(A=reference.A, B=reference.B, speed_kt=reference.speed_kt,
                                        source=source)
    inputs = tuple(_signal(n, "input") for n in INPUT_NAMES)
    states = tuple(_signal(n, "state") for n in STATE_NAMES)
    description = (f"Bo105 physics reference: {source}, exact zero-order-hold discretisation at the "
                   "host's step; inputs theta_0, theta_1s, theta_1c, theta_0T, outputs u, w, q, theta, "
                   "v, p, phi, r (perturbations from trim)")
    fmu_bytes = _build(target.stem, slave_module="bo105_reference", slave_class="Bo105ReferenceSlave",
                       variables_call=f"bo105_reference_variables(\n        inputs={inputs!r},"
                                      f"\n        states={states!r},\n    )",
                       attributes={}, description=description, arrays=arrays)
    return write_atomically(target, fmu_bytes)


#: Travel of each normalised JSBSim command (``fcs/<control>-cmd-norm``).
_COMMAND_TRAVEL = {"fcs/collective-cmd-norm": (0.0, 1.0)}  # every other command: -1..1


def build_jsbsim_fmu(aircraft: str, out_dir, *, name: str | None = None) -> Path:
    """Build the FMU of a JSBSim aircraft (``jsbsim:<aircraft>``, :mod:`fmu_src.jsbsim_aircraft`).

    The FMU reaches the starting condition of :class:`validation.vehicles.jsbsim_vehicle.JSBSimVehicle`
    (fixed-wing: trimmed level cruise; ``ah1s``: hover from its flight-test script) with the same
    recipe, whose numbers travel in the model file. The host's Python needs the ``jsbsim``
    package.

    Parameters
    ----------
    aircraft : str
        An aircraft that ships with the ``jsbsim`` package, e.g. ``"c172x"``, ``"ah1s"``.
    out_dir : path
        Folder for the FMU (created if missing).
    name : str, optional
        Model identifier and file name; default ``jsbsim_<aircraft>``.

    Returns
    -------
    Path
        ``out_dir/<name>.fmu``.

    Raises
    ------
    validation.core.errors.BadInputError
        JSBSim has no such aircraft (the message names similar ones) or cannot trim it; a bad
        ``name``; ``out_dir`` a file.
    """
    import jsbsim

    from validation.core.files import write_atomically
    from validation.vehicles import jsbsim as jsbsim_vehicle

    from . import jsbsim_aircraft

    vehicle = jsbsim_vehicle.JSBSimVehicle(aircraft)
    target = _target(out_dir, _default_name(f"jsbsim_{aircraft}") if name is None else name)
    # Reaching the starting condition here raises BadInputError for an aircraft JSBSim cannot trim.
    steady = vehicle.simulate(np.array([0.0, vehicle.sample_time]), np.zeros((2, len(vehicle.input_names))))
    # The recipe of JSBSimVehicle._start, as data (tests/test_fmu.py proves the FMU flies the same).
    hover = jsbsim_vehicle.HOVER_SCRIPTS.get(aircraft)
    properties = (jsbsim_vehicle.HELICOPTER_CONTROLS if hover else jsbsim_vehicle.FIXED_WING_CONTROLS)
    controls = [(n, properties[n], *_COMMAND_TRAVEL.get(properties[n], (-1.0, 1.0)))
                for n in vehicle.input_names]
    states = [(n, *jsbsim_vehicle.STATE_PROPERTIES[n]) for n in vehicle.state_names]
    if hover:
        recipe = {"start": "script", "script": hover[0], "script_time": hover[1],
                  "after_start": [("simulation/test-variant", 0.0)]}
        condition = f"hovering, {hover[1]:g} s into its flight-test script {hover[0]}"
    else:
        recipe = {"start": "trim",
                  "initial_conditions": [("ic/h-sl-ft", jsbsim_vehicle.CRUISE_ALTITUDE_FT),
                                         ("ic/vc-kts", jsbsim_vehicle.CRUISE_AIRSPEED_KT),
                                         ("ic/gamma-deg", 0.0), ("ic/psi-true-deg", 90.0)]}
        condition = (f"trimmed in level flight at {jsbsim_vehicle.CRUISE_AIRSPEED_KT:g} kt calibrated, "
                     f"{jsbsim_vehicle.CRUISE_ALTITUDE_FT:g} ft, heading east")
    arrays = jsbsim_aircraft.pack_model(aircraft=aircraft, jsbsim_version=jsbsim.__version__,
                                        controls=controls, states=states, **recipe)
    trim = ", ".join(f"{k} {v:.4g}" for k, v in steady.metadata["trim"].items())
    description = (f"JSBSim {aircraft} {condition} (trim: {trim}); inputs {', '.join(vehicle.input_names)} "
                   f"(normalised command perturbations), outputs {', '.join(vehicle.state_names)} (SI, "
                   f"absolute); step a multiple of 0.01 s. Needs the jsbsim Python package "
                   f"({jsbsim.__version__}) in the host's Python")
    inputs = tuple((n, low, high, SIGNAL_PHRASES[n]) for n, _, low, high in controls)
    outputs = tuple((n, _signal(n, "state")[1], SIGNAL_PHRASES[n], float(steady.output(n)[0]))
                    for n in vehicle.state_names)
    fmu_bytes = _build(target.stem, slave_module="jsbsim_aircraft", slave_class="JSBSimAircraft",
                       variables_call=f"jsbsim_variables(\n        inputs={inputs!r},"
                                      f"\n        states={outputs!r},\n    )",
                       attributes={}, description=description, arrays=arrays)
    return write_atomically(target, fmu_bytes)



def build_blimp_rkgp_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """Build the blimp RKGP FMU (:mod:`fmu_src.blimp_rkgp`) of a trained grey-box model file.

    Parameters
    ----------
    model_path : path
        A ``GreyBoxGP`` saved by :func:`gp_model.save_model` with
        ``physics=blimp_physics_description(params)``, trained on 12 blimp states and the inputs
        ``u_gondola, mu, u_tail, dt`` (:func:`validation.models.blimp_identification.recording_arrays`).
    out_dir : path
        Folder for the FMU (created if missing).
    name : str, optional
        Model identifier and file name; default the model file's stem, made into a name.

    Returns
    -------
    Path
        ``out_dir/<name>.fmu``.

    Raises
    ------
    gp_model.ModelFileError
        Missing, corrupt or not a grey-box model file.
    validation.core.errors.BadInputError
        Other physics than ``blimp_rk4``; hyperparameter samples; a bad ``name`` or ``out_dir``.
    """
    from validation.core.files import write_atomically

    target, arrays, interface, description, nominal_step = blimp_rkgp_parts(model_path, out_dir, name=name)
    fmu_bytes = _build(target.stem, slave_module="blimp_rkgp", slave_class="BlimpRKGP",
                       variables_call=f"blimp_rkgp_variables(\n        inputs={interface['inputs']!r},"
                                      f"\n        states={interface['states']!r},\n    )",
                       attributes={"DEFAULT_STEP_SIZE": nominal_step}, description=description,
                       arrays=arrays, support_modules=("_runtime",))
    return write_atomically(target, fmu_bytes)


def blimp_rkgp_parts(model_path, out_dir, *, name: str | None = None) -> tuple:
    """What every blimp RKGP FMU (pythonfmu or native) is built from.

    Returns
    -------
    target : Path
        ``out_dir/<name>.fmu`` (name checked; default the model file's stem made into a name).
    arrays : dict
        The FMU model file's arrays (:func:`fmu_src.blimp_rkgp.pack_model`): the physics
        parameters, the longest RK4 substep, the GP inputs and their training envelope, and per
        GP part (one shared, or one per state) its point-hyperparameter predictive form.
    interface : dict
        ``inputs`` and ``states`` for :func:`fmu_src.blimp_rkgp.blimp_rkgp_variables`.
    description : str
        The FMU's one-line description.
    nominal_step : float
        The default experiment's step: the median training frame interval, s.

    Raises
    ------
    As :func:`build_blimp_rkgp_fmu`.
    """
    from gp_model import GreyBoxGP, ModelFileError, load_model, read_header
    from validation.core.errors import BadInputError
    from validation.models.blimp_identification import blimp_physics_from_description
    from validation.vehicles.blimp import INPUT_NAMES, STATE_NAMES, hanging_state

    from . import blimp_rkgp

    model_path = Path(model_path)
    target = _target(out_dir, _default_name(model_path.stem) if name is None else name)
    model = load_model(model_path)
    if not isinstance(model, GreyBoxGP):
        raise ModelFileError(f"{model_path}: a {type(model).__name__}, not a GreyBoxGP; the blimp RKGP "
                             "FMU needs a grey-box model")
    physics = read_header(model_path)["physics"]
    params, _ = blimp_physics_from_description(physics)
    if (model.n_states_, model.n_inputs_) != (len(STATE_NAMES), len(INPUT_NAMES) + 1):
        raise BadInputError(f"the model has {model.n_states_} states and {model.n_inputs_} inputs; the "
                            f"blimp RKGP FMU needs {len(STATE_NAMES)} and {len(INPUT_NAMES) + 1} "
                            "(u_gondola, mu, u_tail, dt)")
    gps = [model.gp_] if model.shared else model.gp_.gps
    parts = []
    for gp in gps:
        if gp.theta_samples_ is not None:
            raise BadInputError("the blimp RKGP FMU evaluates point hyperparameters; this model mixes "
                                f"{len(gp.theta_samples_)} samples. Train it by maximum likelihood")
        form = gp.predictive_forms(use_samples=False)[0]
        parts.append({"basis": form.basis, "weights": form.weights.reshape(len(form.basis), -1),
                      "variance_factor": form.variance_factor,
                      "kernel_weights": gp.kernel.weights(form.theta[:-1]),
                      "log_signal_variance": form.theta[0],
                      "input_mean": gp.input_scaler_.mean_, "input_scale": gp.input_scaler_.scale_,
                      "output_mean": gp.output_scaler_.mean_, "output_scale": gp.output_scaler_.scale_})
    X = gps[0].input_scaler_.inverse_transform(gps[0].X_train_)
    arrays = blimp_rkgp.pack_model(
        parameter_names=physics["parameter_names"], parameters=physics["parameters"],
        max_step=physics["max_step"], state_columns=model.state_columns_,
        envelope_low=X.min(axis=0), envelope_high=X.max(axis=0), parts=parts)
    nominal_step = float(np.median(X[:, -1]))
    start = hanging_state(params)
    inputs = tuple((n, *_signal(n, "input")[1:3], _BLIMP_PHRASES[n]) for n in INPUT_NAMES)
    states = tuple((n, *_signal(n, "state")[1:3], _BLIMP_PHRASES[n], float(s))
                   for n, s in zip(STATE_NAMES, start))
    gp_inputs = [STATE_NAMES[c] for c in model.state_columns_] + [*INPUT_NAMES, "dt"]
    description = (f"Blimp RKGP (Ko et al. 2007): RK4 blimp ODE plus a GP residual "
                   f"({'shared' if model.shared else 'one GP per state'}, {len(X)} points, inputs "
                   f"{', '.join(gp_inputs)}); commands u_gondola, mu, u_tail in, the 12 states and their "
                   f"one-step standard deviations out; communication step = frame interval dt "
                   f"(trained {X[:, -1].min():.4g} .. {X[:, -1].max():.4g} s); model {model_path.name}")
    return target, arrays, {"inputs": inputs, "states": states}, description, nominal_step


#: What the blimp's signals are (validation.vehicles.blimp, module docstring: NED earth, body axes).
_BLIMP_PHRASES = {
    "u_gondola": "gondola fan command (positive pushes forward)",
    "mu": "gondola thrust angle (positive tilts the thrust up)",
    "u_tail": "tail fan command (positive yaws the nose right)",
    "x": "north position", "y": "east position", "z": "down position",
    "phi": "roll angle", "theta": "pitch angle", "psi": "heading",
    "U": "forward body velocity", "V": "rightward body velocity", "W": "downward body velocity",
    "P": "roll rate", "Q": "pitch rate", "R": "yaw rate",
}


def build_model_fmu(model_path, out_dir, *, name: str | None = None) -> Path:
    """The FMU of a trained model file, by its type: a ``GreyBoxGP`` (blimp physics) gives the
    blimp RKGP FMU (:func:`build_blimp_rkgp_fmu`), anything else the GP-NARX rate predictor
    (:func:`build_rate_predictor_fmu`, which says when the file is not a GP-NARX model)."""
    from gp_model import read_header

    if read_header(model_path).get("type") == "GreyBoxGP":
        return build_blimp_rkgp_fmu(model_path, out_dir, name=name)
    return build_rate_predictor_fmu(model_path, out_dir, name=name)


def reference_fmu_names() -> list[str]:
    """The names :func:`build_reference_fmu` accepts (``jsbsim:<aircraft>`` as a pattern)."""
    from validation.vehicles.bo105 import BO105_SPEEDS_KT

    return [f"bo105-{v}kt" for v in BO105_SPEEDS_KT] + ["jsbsim:<aircraft>"]


def build_reference_fmu(reference: str, out_dir, *, name: str | None = None) -> Path:
    """Build the FMU of a physics reference by its vehicle name (DESIGN.md): ``bo105-<V>kt``
    (:func:`build_bo105_reference_fmu`) or ``jsbsim:<aircraft>`` (:func:`build_jsbsim_fmu`).

    Raises
    ------
    validation.core.errors.BadInputError
        Any other name (the message lists the valid ones), or what the builder raises.
    """
    from validation.core.errors import BadInputError
    from validation.vehicles.bo105 import BO105_SPEEDS_KT

    match = re.fullmatch(r"bo105-(\d+)kt", reference)
    if match and int(match.group(1)) in BO105_SPEEDS_KT:
        return build_bo105_reference_fmu(int(match.group(1)), out_dir, name=name)
    if reference.startswith("jsbsim:") and reference != "jsbsim:":
        return build_jsbsim_fmu(reference.split(":", 1)[1], out_dir, name=name)
    raise BadInputError(f"no reference FMU {reference!r}; valid: {', '.join(reference_fmu_names())} "
                        "(e.g. jsbsim:c172x, jsbsim:ah1s; flight-test stand-ins and the blimp have none)")


def _signal(name: str, kind: str) -> tuple:
    """(name, unit, limit, phrase) of a signal, from the recording conventions."""
    from validation.core.errors import BadInputError
    from validation.core.recordings import column_limit, column_unit

    from ._base import UNITS

    unit = column_unit(name)
    if unit not in UNITS:
        raise BadInputError(f"the model's {kind} {name!r} has no known SI unit (got {unit!r}); an "
                            f"FMU variable needs one of {', '.join(UNITS)}")
    return (name, unit, column_limit(name), SIGNAL_PHRASES.get(name, f"{kind} {name}"))


def _interface(config) -> dict:
    """(name, unit, limit, phrase) of every input and output, from the recording conventions."""
    from validation.core.errors import BadInputError

    inputs = tuple(_signal(n, "input") for n in config.inputs)
    outputs = tuple(_signal(n, "output") for n in config.outputs)
    generated = {f"{n}{suffix}" for n in config.outputs for suffix in ("_prev", "_lower", "_upper")}
    reserved = generated | {"confidence_level", "free_run"}
    clash = sorted((set(config.inputs) | set(config.outputs)) & reserved)
    if clash:
        raise BadInputError(f"signal name(s) {', '.join(clash)} clash with the FMU's generated variables")
    return {"inputs": inputs, "outputs": outputs}


def _default_name(text: str) -> str:
    """``text`` made into an FMU name (see :func:`_target`)."""
    name = re.sub(r"\W+", "_", text).strip("_") or "model"
    return name if name[0].isalpha() else f"model_{name}"


def _target(out_dir, name: str) -> Path:
    """``out_dir/<name>.fmu`` after checking ``name`` and ``out_dir`` (BadInputError)."""
    from validation.core.errors import BadInputError
    from validation.core.files import check_output_folder

    out_dir = Path(out_dir)
    if not _NAME.match(name):
        raise BadInputError(f"FMU name {name!r} must start with a letter and hold only letters, "
                            "digits and underscores (at most 64); it becomes the FMI model identifier")
    check_output_folder(out_dir)
    return out_dir / f"{name}.fmu"


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
{attributes}    VARIABLES = {variables_call}
'''


def _build(name: str, *, slave_module: str, slave_class: str, variables_call: str, attributes: dict,
           description: str, arrays: dict, support_modules: tuple = ()) -> bytes:
    """Stage the slave script and package, run pythonfmu, return the FMU's bytes.

    ``attributes`` (class attribute name -> value with an exact ``repr``) are set on the generated
    class; ``support_modules`` are the fmu_src modules the slave module imports besides ``_base``.
    The numpy-only gp_model modules they import are copied too (:func:`_vendor_gp_model_imports`).
    Whether the FMU claims ``canGetAndSetFMUstate`` (and ``canSerializeFMUstate``) is the slave
    class's ``CAN_GET_AND_SET_FMU_STATE``.
    """
    slave = getattr(importlib.import_module(f"{__package__}.{slave_module}"), slave_class)
    sources = {"__init__.py": f'"""Runtime of the {name} FMU (copies of flightgp\'s fmu_src)."""\n'}
    for module in ("_base", *support_modules, slave_module):
        sources[f"{module}.py"] = (HERE / f"{module}.py").read_text(encoding="utf-8")
    _vendor_gp_model_imports(sources)
    digest = hashlib.sha256()
    for key in sorted(arrays):
        value = np.ascontiguousarray(arrays[key])
        digest.update(f"{key}|{value.dtype.str}|{value.shape}|".encode())
        digest.update(value.tobytes())
    for file_name in sorted(sources):
        digest.update(file_name.encode() + sources[file_name].encode())
    lines = "".join(f"    {key} = {value!r}\n" for key, value in attributes.items())
    digest.update(f"{name}|{slave_class}|{variables_call}|{lines}|{description}".encode())
    module = f"{name}_{digest.hexdigest()[:8]}"
    package = f"{module}_lib"
    script = _SCRIPT.format(name=name, description=description, package=package,
                            slave_module=slave_module, slave_class=slave_class,
                            variables_function=variables_call.split("(", 1)[0],
                            variables_call=variables_call, attributes=lines)
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
        state = ["--handle-state", "--serialize-state"] if slave.CAN_GET_AND_SET_FMU_STATE else []
        command = [sys.executable, "-m", "pythonfmu", "build", "-f", str(staging / f"{module}.py"),
                   "-d", str(out), "--no-variable-step", *state, str(package_dir)]
        result = subprocess.run(command, cwd=staging, capture_output=True, text=True)
        fmu = out / f"{name}.fmu"
        if result.returncode != 0 or not fmu.is_file():
            raise RuntimeError(f"pythonfmu failed to build {name}.fmu (exit {result.returncode}): "
                               f"{(result.stderr or result.stdout).strip()[-2000:]}")
        return fmu.read_bytes()


_GP_MODEL_IMPORT = re.compile(r"^from gp_model\.(\w+) import ", re.MULTILINE)


def _vendor_gp_model_imports(sources: dict) -> None:
    """Copy into ``sources`` every gp_model module that a source imports (``from gp_model.<m>
    import ...``) and point those imports at the copy (``from .<m> import ...``).

    Only self-contained gp_model modules qualify (numpy and the standard library, no relative
    imports), such as :mod:`gp_model.uncertain_input`: a host has no gp_model, and one copy of
    the maths serves flightgp and its FMUs alike.
    """
    import gp_model

    pending = [name for name in sources]
    while pending:
        text = sources[pending.pop()]
        for module in _GP_MODEL_IMPORT.findall(text):
            file_name = f"{module}.py"
            if file_name in sources:
                continue
            copied = (Path(gp_model.__file__).parent / file_name).read_text(encoding="utf-8")
            if re.search(r"^\s*from \.", copied, re.MULTILINE):
                raise ValueError(f"gp_model.{module} imports other gp_model modules; an FMU cannot "
                                 "carry it")
            sources[file_name] = copied
            pending.append(file_name)
    for file_name, text in sources.items():
        sources[file_name] = _GP_MODEL_IMPORT.sub(r"from .\1 import ", text)
