"""A reference with named effects applied, and the effect model of each reference.

:class:`EffectVehicle` is a reference with a list of effects (:mod:`validation.vehicles.effects`)
applied, plus optional white sensor noise; it is both the concealed "real aircraft" of tests and
benchmarks and the corrected model that ``flightgp diagnose`` saves (:meth:`EffectVehicle.save`,
:meth:`EffectVehicle.load`: a small versioned JSON file; docs/vehicles.md, "Named effects").

:data:`EFFECT_MODELS` is the one place that says which references take effects and through
which :class:`~validation.vehicles.effects.EffectModel`; :func:`effect_model` looks one up by
registry name for every caller (diagnose, its bench, :class:`EffectVehicle`).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from validation.core.errors import BadInputError
from validation.core.files import json_text, read_document, write_files_atomically
from validation.core.recordings import Recording
from validation.core.sampling import check_history, sampling_metadata
from validation.vehicles.blimp_effects import BlimpEffects
from validation.vehicles.bo105_effects import Bo105Effects
from validation.vehicles.effects import EffectModel, check_effects
from validation.vehicles.fmu_reference import FMUEffects
from validation.vehicles.linear_effects import LinearEffects
from validation.vehicles.registry import get_vehicle
from validation.vehicles.rgblimp_effects import RGBlimpEffects
from validation.vehicles.state_space import state_space_from_dict

#: The references that take effects, as messages name them -> (the registry names they cover, a
#: full-match regular expression; their effect model's class, called with the registry's vehicle
#: of that name). A registry name no pattern matches (flight-test stand-ins, JSBSim aircraft)
#: takes no effects.
EFFECT_MODELS = {"bo105-<V>kt": (r"bo105-\d+kt", Bo105Effects), "blimp": (r"blimp", BlimpEffects),
                 "rgblimp": (r"rgblimp", RGBlimpEffects), "state-space FILE.json": (r".+\.json", LinearEffects),
                 "FILE.fmu": (r".+\.fmu", FMUEffects)}
#: The references that take effects, as messages name them: "bo105-<V>kt, blimp, rgblimp,
#: state-space FILE.json and FILE.fmu".
EFFECT_REFERENCES = ", ".join(list(EFFECT_MODELS)[:-1]) + " and " + list(EFFECT_MODELS)[-1]
#: Suffix of the registry names of flight-test stand-ins (docs/vehicles.md, "Names and interface").
_STAND_IN_SUFFIX = "-flight"
_FILE_FORMAT = "flightgp-effect-vehicle"
_FILE_VERSION = 1


def takes_effects(name: str) -> bool:
    """Whether the reference called ``name`` takes named effects (:data:`EFFECT_MODELS`)."""
    return any(re.fullmatch(pattern, name) for pattern, _ in EFFECT_MODELS.values())


def effect_model(name: str, *, purpose: str) -> EffectModel:
    """The effect model of the reference called ``name`` (:data:`EFFECT_MODELS`).

    Parameters
    ----------
    name : str
        A registry name (:func:`validation.vehicles.registry.get_vehicle`).
    purpose : str
        What the caller needs the effect model for, the subject of the error message
        (``"diagnose"``, ``"diagnose-bench"``, ``"applying effects"``).

    Raises
    ------
    BadInputError
        An unknown name (the registry's message), a flight-test stand-in (naming its reference),
        or a vehicle that takes no effects.
    """
    vehicle = get_vehicle(name)
    for pattern, model_class in EFFECT_MODELS.values():
        if re.fullmatch(pattern, name):
            return model_class(vehicle)
    needs = f"{purpose} needs one of the {EFFECT_REFERENCES} references"
    if name.endswith(_STAND_IN_SUFFIX):
        raise BadInputError(f"{needs}; {name!r} is a flight-test stand-in: use its physics reference "
                            f"{name.removesuffix(_STAND_IN_SUFFIX)}")
    raise BadInputError(f"{needs}; named effects are not implemented for {name!r} yet")


def is_effect_vehicle_file(path) -> bool:
    """Whether ``path`` names a readable JSON file of :class:`EffectVehicle`'s format (a
    diagnosis's ``corrected_model.json``), and not, for instance, a state-space model."""
    if Path(path).suffix != ".json":
        return False
    try:
        content = read_document(path, what="model file")
    except (BadInputError, OSError):  # not one: what reads it next says why
        return False
    return isinstance(content, dict) and content.get("format") == _FILE_FORMAT


class EffectVehicle:
    """A reference vehicle with named effects applied (module docstring).

    Parameters
    ----------
    reference : str or EffectModel
        A reference that takes effects, by name (:data:`EFFECT_REFERENCES`) or as the effect
        model a diagnosis used.
    effects : sequence of dict
        ``{"effect", "input" | "term" | "output", "value"}`` each; extra keys are ignored.
    noise_sd : dict of str to float, optional
        White Gaussian sensor noise, standard deviation per state (state units), e.g. the
        reference's :attr:`~validation.vehicles.effects.EffectModel.sensor_noise_sd`; states not
        named are noise-free.
    reference_model : dict, optional
        A state-space model in the JSON format of :mod:`validation.vehicles.state_space`, the
        reference instead of ``reference`` (a model file carries it, so it does not depend on
        the JSON file the diagnosis read).

    Attributes
    ----------
    name : str
        ``"<reference>+effects"``.
    reference_name : str
    effects : list of dict
        The checked effects (copies).
    input_names, state_names : tuple of str
    sample_time : float
        The reference's default recording interval, s.
    """

    def __init__(self, reference, effects=(), *, noise_sd: dict | None = None,
                 reference_model: dict | None = None):
        if reference_model is not None:
            reference = LinearEffects(state_space_from_dict(reference_model, source="reference_model"))
        elif isinstance(reference, str):
            reference = effect_model(reference, purpose="applying effects")
        self._reference = reference
        self.reference_name = reference.name
        self.name = f"{reference.name}+effects"
        self.input_names, self.state_names = reference.input_names, reference.state_names
        self.sample_time = reference.sample_time
        self._effects = check_effects(list(effects), reference)
        self._noise_sd = {}
        for name, value in (noise_sd or {}).items():
            if name not in self.state_names or not (math.isfinite(float(value)) and float(value) >= 0):
                raise BadInputError(f"noise_sd: {name!r}: {value!r} must be a state of "
                                    f"{reference.name} with a standard deviation >= 0")
            self._noise_sd[name] = float(value)

    @property
    def effects(self) -> list[dict]:
        """The applied effects (copies)."""
        return [dict(effect) for effect in self._effects]

    @property
    def noise_sd(self) -> dict:
        return dict(self._noise_sd)

    def simulate_states(self, time, inputs) -> np.ndarray:
        """Noise-free recorded states (through the measurement chain), shape (n, n_states); see
        :meth:`validation.vehicles.effects.EffectModel.simulate_many`."""
        return self._reference.simulate_many([self._effects], time, inputs)[0]

    def replay_states(self, recording) -> np.ndarray:
        """Noise-free states (n, n_states) along ``recording``'s inputs and times, from the state
        the reference replays it from (:meth:`validation.vehicles.effects.EffectModel.start_state`:
        the RGBlimp's first recorded state; the Bo105's and blimp's own trim)."""
        start = self._reference.start_state(recording)
        return self._reference.simulate_many([self._effects], recording.time, recording.inputs, start=start)[0]

    def simulate(self, time, inputs, *, seed: int = 0) -> Recording:
        """Fly ``inputs`` from trim; returns every state as recorded, with sensor noise drawn
        from ``np.random.default_rng(seed)``.

        ``time`` must be evenly spaced for a reference that needs it (a Bo105: its exact
        discretisation has one step); the blimp also takes unevenly spaced times (e.g. jittered
        motion-capture frames), and the recording's metadata then says ``uneven_sampling`` with
        the nominal interval (:func:`validation.core.sampling.nominal_step`) as
        ``sample_time_nominal`` (docs/conventions.md, "Recording files")."""
        time, inputs, _ = check_history(time, inputs, self.input_names,
                                        evenly_sampled=self._reference.needs_even_sampling)
        outputs = self.simulate_states(time, inputs)
        rng = np.random.default_rng(seed)
        noise = np.array([self._noise_sd.get(name, 0.0) for name in self.state_names])
        outputs = outputs + rng.standard_normal(outputs.shape) * noise
        sampling = sampling_metadata(time)
        # "vehicle" is the reference, so the columns read back as its recording (the sidecar
        # still names the effects; diagnose never reads them).
        metadata = {"vehicle": self.reference_name, "simulator": self.name, **sampling,
                    "seed": seed, "effects": self.effects, "sensor_noise_std": self.noise_sd}
        return Recording(time, inputs, self.input_names, outputs, self.state_names, metadata)

    def as_dict(self) -> dict:
        """The model file's content (see :meth:`save`)."""
        content = {"format": _FILE_FORMAT, "version": _FILE_VERSION, "reference": self.reference_name,
                   "effects": self.effects, "noise_sd": self.noise_sd}
        if self._reference.family == LinearEffects.family:  # a user's state-space model: carried along
            content["reference_model"] = self._reference.reference.as_dict()
        return content

    def model_files(self, path) -> dict:
        """The model file at ``path`` as ``{path: text}`` (:meth:`as_dict` as indented JSON), for
        :func:`validation.core.files.write_files_atomically` with any other files of the same
        step (as ``flightgp diagnose`` writes its corrected model with the report)."""
        return {Path(path): json_text(self.as_dict())}

    def save(self, path) -> Path:
        """Write the model file (:meth:`model_files`) atomically; :meth:`load` reads it back."""
        return write_files_atomically(self.model_files(path))[0]

    @classmethod
    def from_dict(cls, content: dict, *, source: str = "model") -> EffectVehicle:
        """The model :meth:`as_dict` describes; BadInputError naming ``source`` otherwise."""
        if not isinstance(content, dict) or content.get("format") != _FILE_FORMAT:
            raise BadInputError(f"{source}: not a flightgp effect-vehicle model "
                                f"(expected \"format\": \"{_FILE_FORMAT}\")")
        if content.get("version") != _FILE_VERSION:
            raise BadInputError(f"{source}: model file version {content.get('version')!r}; this "
                                f"flightgp reads version {_FILE_VERSION}")
        return cls(content.get("reference", ""), content.get("effects", []),
                   noise_sd=content.get("noise_sd") or None, reference_model=content.get("reference_model"))

    @classmethod
    def load(cls, path) -> EffectVehicle:
        """Read a model written by :meth:`save`."""
        return cls.from_dict(read_document(path, what="model file"), source=str(path))
