"""Named physical effects added to a reference model: ground truth for diagnosis, and its output.

An *effect* is a dict in the shape of a ``flightgp diagnose`` finding (DESIGN.md,
"diagnosis.json")::

    {"effect": "time_delay", "input": "theta_1s", "value": 0.08}        # s
    {"effect": "input_lag", "input": "theta_1c", "value": 0.07}         # s, first-order time constant
    {"effect": "control_derivative", "term": "M_theta_1s", "value": -20.0}
    {"effect": "stability_derivative", "term": "L_q", "value": -3.35}   # new value, not a change
    {"effect": "sensor_bias", "output": "q", "value": 0.01}             # output units

Other keys (``unit``, ``interval``, ``statement`` ...) are ignored, so the findings of a
diagnosis can be fed back in unchanged. :class:`EffectVehicle` is a reference with a list of
effects applied (plus optional white sensor noise); it is both the concealed "real aircraft" of
tests and benchmarks and the corrected model that ``flightgp diagnose`` saves
(:meth:`EffectVehicle.save`, :meth:`EffectVehicle.load`: a small versioned JSON file).

The ``blimp`` reference takes delays, lags, fan thrust gains (``control_derivative``),
rotational damping (``stability_derivative``), ``quadratic_drag``, ``force_offset`` and sensor
biases; :mod:`validation.vehicles.blimp_effects` says how each enters its nonlinear ODE and names the
terms.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from validation.core.errors import BadInputError
from validation.core.files import write_json
from validation.core.recordings import Recording, column_unit
from validation.core.sampling import check_history, sampling_metadata
from validation.vehicles import blimp_effects
from validation.vehicles.blimp import BlimpReference
from validation.vehicles.bo105 import INPUT_NAMES, ROW_LETTERS, STATE_NAMES, Bo105Reference
from validation.vehicles.bo105_effects import simulate_bo105_with_effects
from validation.vehicles.registry import get_vehicle

#: Every effect name of the diagnosis.json contract (DESIGN.md).
EFFECT_KINDS = ("time_delay", "input_lag", "control_derivative", "stability_derivative",
                "sensor_bias", "quadratic_drag", "force_offset", "unexplained")
#: Every named effect kind (all but ``unexplained``) and the key naming its target.
TARGET_KEYS = {"time_delay": "input", "input_lag": "input", "control_derivative": "term",
               "stability_derivative": "term", "sensor_bias": "output", "quadratic_drag": "term",
               "force_offset": "term"}
#: The kinds each reference family takes (:func:`effect_kinds`).
_BO105_KINDS = ("time_delay", "input_lag", "control_derivative", "stability_derivative", "sensor_bias")
_BLIMP_KINDS = tuple(TARGET_KEYS)
#: Largest delay and lag accepted, s: far beyond any actuator or rotor (Bo105 flap time constant
#: 0.07 s, DESIGN.md), small enough to keep the augmented system well conditioned.
MAX_DELAY = 1.0
MAX_LAG = 2.0
_FILE_FORMAT = "flightgp-effect-vehicle"
_FILE_VERSION = 1
_ACCELERATION_UNITS = {"m/s": "m/s^2", "rad/s": "rad/s^2"}


def effect_target(effect: dict) -> str:
    """The input, term or output an effect acts on (``effect[TARGET_KEYS[effect['effect']]]``)."""
    return effect[TARGET_KEYS[effect["effect"]]]


def effect_kinds(reference) -> tuple:
    """The effect kinds ``reference`` (a Bo105 or blimp reference) takes."""
    return _BLIMP_KINDS if isinstance(reference, BlimpReference) else _BO105_KINDS


def model_value(reference, term: str) -> float:
    """The reference's own value of a derivative or term (``M_q`` of a Bo105, ``X_UU`` of the blimp)."""
    if isinstance(reference, BlimpReference):
        return blimp_effects.model_value(reference, term)
    return reference.derivative(term)


def effect_unit(effect: dict) -> str:
    """Unit of ``effect["value"]``: s for delays and lags, the output's unit for a bias,
    (row acceleration)/(column unit) for Bo105 derivatives (``1/s`` when they cancel, e.g.
    ``M_q``), and the units of :data:`validation.vehicles.blimp_effects.TERM_UNITS` for blimp terms."""
    kind = effect["effect"]
    if kind in ("time_delay", "input_lag"):
        return "s"
    if kind == "sensor_bias":
        return column_unit(effect["output"])
    if effect["term"] in blimp_effects.TERM_UNITS:
        return blimp_effects.TERM_UNITS[effect["term"]]
    letter, _, column = effect["term"].partition("_")
    row_unit, column_unit_ = column_unit(ROW_LETTERS[letter]), column_unit(column)
    return "1/s" if row_unit == column_unit_ else f"({_ACCELERATION_UNITS[row_unit]})/({column_unit_})"


def _allowed_terms(reference, kind: str) -> list:
    if isinstance(reference, BlimpReference):
        return list(blimp_effects.TERMS[kind])
    columns = STATE_NAMES if kind == "stability_derivative" else INPUT_NAMES
    return [f"{letter}_{column}" for letter in ROW_LETTERS for column in columns]


def check_effects(effects, reference) -> list[dict]:
    """Validate effect dicts against ``reference`` (a Bo105 or the blimp reference); returns
    clean copies (``effect``, target, ``value``).

    Raises
    ------
    BadInputError
        Unknown effect or target, a derivative of the wrong kind (``M_q`` is a stability
        derivative, ``M_theta_1s`` a control derivative), a non-finite value, a delay or lag
        outside ``[0, MAX_DELAY]`` / ``[0, MAX_LAG]`` s, a blimp thrust term that is not
        positive, or two effects of the same kind on the same target.
    """
    checked, seen = [], set()
    kinds = effect_kinds(reference)
    for index, effect in enumerate(effects):
        where = f"effect {index + 1}"
        if not isinstance(effect, dict) or effect.get("effect") not in kinds:
            kind = effect.get("effect") if isinstance(effect, dict) else effect
            raise BadInputError(f"{where}: unknown effect {kind!r} for {reference.name}; "
                                f"known: {', '.join(kinds)}")
        kind = effect["effect"]
        key = TARGET_KEYS[kind]
        target = effect.get(key)
        allowed = {"input": reference.input_names, "output": reference.state_names}.get(key)
        if key == "term":
            allowed = _allowed_terms(reference, kind)
        if target not in allowed:
            raise BadInputError(f"{where} ({kind}): {key} {target!r} is not one of {', '.join(allowed)}")
        try:
            value = float(effect.get("value"))
        except (TypeError, ValueError):
            value = math.nan
        if not math.isfinite(value):
            raise BadInputError(f"{where} ({kind} on {target}): value must be a finite number, "
                                f"got {effect.get('value')!r}")
        limit = {"time_delay": MAX_DELAY, "input_lag": MAX_LAG}.get(kind)
        if limit is not None and not 0.0 <= value <= limit:
            raise BadInputError(f"{where} ({kind} on {target}): {value} s is outside 0 .. {limit} s")
        if target in blimp_effects.CONTROL_TERMS and not value > 0:
            raise BadInputError(f"{where} ({kind} on {target}): thrust per unit command must be "
                                f"positive, got {value} N")
        if (kind, target) in seen:
            raise BadInputError(f"{where}: a second {kind} on {target}; give each effect once")
        seen.add((kind, target))
        checked.append({"effect": kind, key: target, "value": value})
    return checked


def batches_simulations(reference) -> bool:
    """Whether :func:`simulate_many` integrates its members together (the blimp) rather than
    one after the other (the Bo105's exact discretisation is fast enough alone)."""
    return isinstance(reference, BlimpReference)


def simulate_many(reference, effect_lists, time: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """:func:`simulate_with_effects` for each of B lists of checked effects, shape (B, n, n_states)."""
    if isinstance(reference, BlimpReference):
        return blimp_effects.simulate_batch(reference, effect_lists, time, inputs)
    return np.stack([simulate_bo105_with_effects(reference, effects, time, inputs) for effects in effect_lists])


def simulate_with_effects(reference, effects: list[dict], time: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """States (plus sensor biases) of ``reference`` with ``effects`` applied, from trim.

    Parameters
    ----------
    reference : Bo105Reference or BlimpReference
    effects : list of dict
        Already checked (:func:`check_effects`).
    time : ndarray, shape (n,)
        Sample times, s: evenly spaced for a Bo105, strictly increasing for the blimp.
    inputs : ndarray, shape (n, n_inputs)
        Commanded inputs (reference units), zero-order hold (row k acts from ``time[k]`` to
        ``time[k+1]``).

    Returns
    -------
    ndarray, shape (n, n_states)
        The reference's states as recorded (biases added), SI units: Bo105 ``u, w, q, theta, v,
        p, phi, r``; blimp ``x, y, z, phi, theta, psi, U, V, W, P, Q, R``
        (:func:`validation.vehicles.blimp_effects.simulate_batch`).
    """
    if isinstance(reference, BlimpReference):
        return blimp_effects.simulate_batch(reference, [effects], time, inputs)[0]
    return simulate_bo105_with_effects(reference, effects, time, inputs)


class EffectVehicle:
    """A reference vehicle with named effects applied (the module docstring lists them).

    Parameters
    ----------
    reference_name : str
        ``bo105-<V>kt`` or ``blimp``.
    effects : sequence of dict
        ``{"effect", "input" | "term" | "output", "value"}`` each; extra keys are ignored.
    noise_sd : dict of str to float, optional
        White Gaussian sensor noise, standard deviation per state (state units), e.g.
        :data:`validation.vehicles.bo105.SENSOR_NOISE_STD` or
        :data:`validation.vehicles.blimp_effects.SENSOR_NOISE_STD`; states not named are noise-free.

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

    def __init__(self, reference_name: str, effects=(), *, noise_sd: dict | None = None):
        reference = get_vehicle(reference_name)
        if not isinstance(reference, (Bo105Reference, BlimpReference)):
            raise BadInputError(f"effects can be applied to the bo105-<V>kt and blimp references only, "
                                f"not {reference_name!r}")
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
        """Noise-free recorded states (biases included), shape (n, n_states); see
        :func:`simulate_with_effects`."""
        return simulate_with_effects(self._reference, self._effects, time, inputs)

    def simulate(self, time, inputs, *, seed: int = 0) -> Recording:
        """Fly ``inputs`` from trim; returns every state as recorded, with sensor noise drawn
        from ``np.random.default_rng(seed)``.

        ``time`` must be evenly spaced for a Bo105 (its exact discretisation has one step); the
        blimp also takes unevenly spaced times (e.g. jittered motion-capture frames), and the
        recording's metadata then says ``uneven_sampling`` with the median interval as
        ``sample_time_nominal`` (DESIGN.md, "Recording files")."""
        blimp = isinstance(self._reference, BlimpReference)
        time, inputs, step = check_history(time, inputs, self.input_names, evenly_sampled=not blimp)
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
        return {"format": _FILE_FORMAT, "version": _FILE_VERSION, "reference": self.reference_name,
                "effects": self.effects, "noise_sd": self.noise_sd}

    def save(self, path) -> Path:
        """Write the model as versioned JSON (atomically); :meth:`load` reads it back."""
        return write_json(path, self.as_dict())

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
                   noise_sd=content.get("noise_sd") or None)

    @classmethod
    def load(cls, path) -> EffectVehicle:
        """Read a model written by :meth:`save`."""
        path = Path(path)
        try:
            content = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise BadInputError(f"{path}: no such model file") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise BadInputError(f"{path}: not a JSON model file ({error})") from None
        return cls.from_dict(content, source=str(path))


