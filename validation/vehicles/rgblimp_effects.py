"""Named effects on the RGBlimp reference (:mod:`validation.vehicles.rgblimp`): its
:class:`~validation.vehicles.effects.EffectModel`, :class:`RGBlimpEffects`, which ``flightgp
diagnose --reference rgblimp`` fits to real flights.

The effect dicts are those of :mod:`validation.vehicles.effects` (docs/diagnose.md,
"diagnosis.json"); every RGBlimp effect names a *term* and gives its new value. They act on the
equations of :mod:`validation.vehicles.rgblimp_equations` (body axes, SI units) as follows:

- ``aerodynamic_coefficient``, terms ``c_d0 ... c_mz_beta``: a coefficient of the source's
  polynomial aerodynamics (:class:`~validation.vehicles.rgblimp_equations.RGBlimpParameters`,
  the same names; force coefficients dimensionless, moment coefficients in m, per rad^k of the
  angle they multiply);
- ``stability_derivative``, terms ``L_P``, ``M_Q``, ``N_R``: the linear rate damping
  ``dL/dP`` etc., N m s/rad (the source's ``K1, K2, K3``);
- ``control_derivative``, terms ``thrust_gain`` (a factor on both recorded thrusts, 1 in the
  model), ``thrust_asymmetry`` (``a``: the left thrust is ``(1 + a)`` and the right
  ``(1 - a)`` times the recorded one, 0 in the model), ``thrust_speed_loss`` (``k_T``, s/m:
  each thrust times ``1 - k_T U_a``, the propellers' loss with airspeed, 0 in the model, not
  negative) and ``thrust_line_y`` (m: the thrust line right of the centreline, which yaws the
  hull by ``-y_T`` times the total thrust, 0 in the model);
- ``force_offset``, term ``Z_0``: the net downward force, weight minus buoyancy, N, acting at
  the centre of buoyancy (set through the buoyancy);
- ``cg_offset``, terms ``x_G``, ``y_G``, ``z_G``: the hull's centre of gravity relative to the
  centre of buoyancy, m (the source's ``r``);
- ``added_mass``, terms ``X_Udot``, ``Y_Vdot``, ``Z_Wdot`` (kg) and ``K_Pdot``, ``M_Qdot``,
  ``N_Rdot`` (kg m^2): the fluid carried along, which the source's model lacks (Kirchhoff's
  equations, :mod:`validation.vehicles.rgblimp_equations`), 0 in the model, never negative;
- ``steady_wind``, terms ``wind_x``, ``wind_y``: a steady horizontal air motion in the room, m/s
  along the motion capture's x and y axes (:func:`~validation.vehicles.rgblimp_equations.advance`),
  0 in the model;
- ``draught_field``, terms ``wind_x_dx``, ``wind_y_dx``, ``wind_z_dx``, ``wind_x_dy``,
  ``wind_y_dy``, ``wind_z_dy``: a draught that varies across the room, the change of each air
  velocity component (m/s, earth axes, z down) per metre along the room's x or y, 1/s (the
  fields ``draught_gradient_x``, ``draught_gradient_y``), 0 in the model;
- ``gondola_offset``, terms ``gondola_dx``, ``gondola_dy``, ``gondola_dz``: the gondola's position
  from its recorded one, m, body axes (a mounting or calibration offset), added to the inputs, 0
  in the model.
- ``search_term`` ``<row>_<factor>`` (:mod:`validation.vehicles.polynomial_terms`; the terms the
  residual search of ``flightgp diagnose`` regresses on, :data:`SEARCH_LIBRARY`): an extra body
  acceleration ``value * factor`` of the row (``X``, ``Y``, ``Z``: surge, sway, heave in m/s^2;
  ``L``, ``M``, ``N``: roll, pitch, yaw in rad/s^2; per unit of the factor), the factor one of
  :data:`~validation.vehicles.rgblimp_equations.SEARCH_SIGNALS` (the body velocity relative to
  the steady air, the rates, roll and pitch) or its signed square or cube, or a product of two;
  at most :data:`SEARCH_SLOTS` per replay. An acceleration rather than a force: the hull's mass
  matrix couples surge with pitch and sway with roll and yaw through the gondola, so a force
  would move two rows and a term would no longer say which one the data need.

The cross-flow coefficients (``c_s_beta_abs``, ``c_l_alpha_abs``, ``c_my_alpha_abs``,
``c_mz_beta_abs``), the thrust loss, the thrust line and the draught field are the terms a
small airship's model may lack beyond the source's;
:mod:`validation.vehicles.rgblimp_equations` gives their equations and the literature.

Replays start at each recording's first recorded state (:meth:`RGBlimpEffects.start_state`),
as the source's free runs do, and step one RK4 step per 1/60 s sample, the source's integrator;
heading is carried continuously (diagnose compares it unwrapped). All members of a batch and all
recordings of a diagnosis are integrated together, as one array of shape (B, S, 12), by the
compiled free run of :mod:`validation.vehicles.rgblimp_jax` (a numpy step pays its overhead per
stage; ``compiled=False`` keeps that step, for the benchmark's ratio). A recording that ends
early is padded with its last inputs, and the padding is dropped.

Weights: the source's recordings are motion capture filtered so smoothly (noise estimates of
1e-6 m and rad, :func:`validation.diagnose.noise.estimate_noise_sd`) that any model misfits
them by 1e4-1e6 noise standard deviations; weighted by that noise, the output error would count
heave 2000 times more than surge. So residuals are weighted at least by :data:`MIN_NOISE_SD`,
the scales the identification of the same model uses
(:data:`validation.models.rgblimp_identification.STATE_SCALE`): 5 cm, 0.02 rad, 2 cm/s and
0.02 rad/s, at which position, attitude, velocity and rate errors of a free run count about
alike (not tuned).
"""
from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np

from validation.core.errors import BadInputError
from validation.core.manoeuvres import time_grid
from validation.vehicles.effects import Hypothesis, search_axes_jacobian
from validation.vehicles.polynomial_terms import library, search_slots, search_term_description, search_term_unit
from validation.vehicles.rgblimp import RGBlimpReference, resting_state
from validation.vehicles.rgblimp_equations import (
    INPUT_NAMES,
    NOMINAL_GONDOLA_POSITION,
    SAMPLE_TIME,
    SEARCH_ROWS,
    SEARCH_SIGNALS,
    STATE_NAMES,
    RGBlimpParameters,
    body_accelerations,
    free_run,
    search_accelerations,
)
from validation.vehicles.rgblimp_jax import batched_free_runs

#: Aerodynamic-coefficient terms: the coefficient fields of :class:`RGBlimpParameters`.
AERODYNAMIC_TERMS = tuple(f.name for f in dataclasses.fields(RGBlimpParameters) if f.name.startswith("c_"))
#: Rate-damping terms -> body axis of ``rate_damping``.
STABILITY_TERMS = {"L_P": 0, "M_Q": 1, "N_R": 2}
#: Thrust terms applied to the inputs, and their model values (a factor and an asymmetry).
CONTROL_TERMS = {"thrust_gain": 1.0, "thrust_asymmetry": 0.0}
#: Thrust terms that are fields of :class:`RGBlimpParameters` -> (field, component).
THRUST_FIELD_TERMS = {"thrust_speed_loss": ("thrust_speed_loss", 0), "thrust_line_y": ("thrust_line_y", 0)}
#: Centre-of-gravity terms -> body axis of ``hull_cg``.
CG_TERMS = {"x_G": 0, "y_G": 1, "z_G": 2}
#: Added-mass terms -> (field of :class:`RGBlimpParameters`, body axis).
ADDED_MASS_TERMS = {"X_Udot": ("added_mass", 0), "Y_Vdot": ("added_mass", 1), "Z_Wdot": ("added_mass", 2),
                    "K_Pdot": ("added_inertia", 0), "M_Qdot": ("added_inertia", 1),
                    "N_Rdot": ("added_inertia", 2)}
#: Wind terms -> earth axis.
WIND_TERMS = {"wind_x": 0, "wind_y": 1}
#: Draught-field terms -> (field, earth component of the air velocity).
DRAUGHT_TERMS = {f"wind_{axis}_d{along}": (f"draught_gradient_{along}", component)
                 for along in ("x", "y") for component, axis in enumerate(("x", "y", "z"))}
#: Gondola-offset terms -> body axis (added to the recorded gondola position).
GONDOLA_TERMS = {"gondola_dx": 0, "gondola_dy": 1, "gondola_dz": 2}
#: Terms that set one component of a field of :class:`RGBlimpParameters` (0 for a scalar field).
_FIELD_TERMS = {**ADDED_MASS_TERMS, **THRUST_FIELD_TERMS, **DRAUGHT_TERMS}
#: Search terms one replay holds at most (a diagnosis names at most four effects, the candidate
#: of its last step among them): a fixed size, so that the compiled replay compiles once.
SEARCH_SLOTS = 4
#: The residual search's library on the RGBlimp: every row's terms linear in each of
#: :data:`~validation.vehicles.rgblimp_equations.SEARCH_SIGNALS` and its polynomial terms
#: (:func:`~validation.vehicles.polynomial_terms.library`). The linear ``L_P``, ``M_Q`` and ``N_R``
#: are the named damping: the search regresses on them (its base columns) but never offers them.
SEARCH_LIBRARY = tuple(f"{letter}_{signal}" for letter in SEARCH_ROWS for signal in SEARCH_SIGNALS) + tuple(
    library(SEARCH_ROWS, SEARCH_SIGNALS))
#: The search terms an effect may name: the library less the named damping.
SEARCH_TERMS = tuple(term for term in SEARCH_LIBRARY if term not in STABILITY_TERMS)
TERMS = {"aerodynamic_coefficient": AERODYNAMIC_TERMS, "stability_derivative": tuple(STABILITY_TERMS),
         "control_derivative": (*CONTROL_TERMS, *THRUST_FIELD_TERMS), "force_offset": ("Z_0",),
         "cg_offset": tuple(CG_TERMS), "added_mass": tuple(ADDED_MASS_TERMS), "steady_wind": tuple(WIND_TERMS),
         "draught_field": tuple(DRAUGHT_TERMS), "gondola_offset": tuple(GONDOLA_TERMS), "search_term": SEARCH_TERMS}

_AERODYNAMIC_WORDS = {
    "c_d0": "drag coefficient at zero angle of attack and sideslip",
    "c_d_alpha2": "growth of drag with the square of the angle of attack",
    "c_d_beta2": "growth of drag with the square of the sideslip",
    "c_s0": "side-force coefficient at zero angle of attack and sideslip",
    "c_s_alpha2": "growth of side force with the square of the angle of attack",
    "c_s_beta": "side force per radian of sideslip",
    "c_l0": "lift coefficient at zero angle of attack",
    "c_l_alpha": "lift-curve slope, the growth of lift with angle of attack",
    "c_l_beta2": "growth of lift with the square of the sideslip",
    "c_mx0": "rolling-moment coefficient at zero angle of attack and sideslip",
    "c_mx_alpha": "rolling moment per radian of angle of attack",
    "c_mx_beta": "rolling moment per radian of sideslip, the dihedral effect",
    "c_my0": "pitching-moment coefficient at zero angle of attack, the pitch trim",
    "c_my_alpha": "pitching moment per radian of angle of attack, the static pitch stability",
    "c_my_beta4": "pitching moment with the fourth power of the sideslip",
    "c_mz0": "yawing-moment coefficient at zero angle of attack and sideslip",
    "c_mz_alpha": "yawing moment per radian of angle of attack",
    "c_mz_beta": "yawing moment per radian of sideslip, the weathercock stability",
    "c_s_beta_abs": "side force with the sideslip times its size, the hull's cross-flow drag in sideslip",
    "c_l_alpha_abs": "lift with the angle of attack times its size, the hull's cross-flow drag in pitch",
    "c_my_alpha_abs": "pitching moment with the angle of attack times its size, the hull's cross-flow moment",
    "c_mz_beta_abs": "yawing moment with the sideslip times its size, the hull's cross-flow moment in sideslip",
}
#: Every term in words, for the statements of a diagnosis.
TERM_DESCRIPTIONS = {
    **_AERODYNAMIC_WORDS,
    "L_P": "roll damping", "M_Q": "pitch damping", "N_R": "yaw damping",
    "thrust_gain": "thrust per recorded thrust, the propellers' effectiveness",
    "thrust_asymmetry": "left/right thrust asymmetry a: left thrust 1 + a, right 1 - a times the recorded",
    "Z_0": "buoyancy imbalance (net downward force)",
    "x_G": "hull centre of gravity ahead of the centre of buoyancy",
    "y_G": "hull centre of gravity right of the centre of buoyancy",
    "z_G": "hull centre of gravity below the centre of buoyancy",
    "X_Udot": "added mass in surge", "Y_Vdot": "added mass in sway", "Z_Wdot": "added mass in heave",
    "K_Pdot": "added inertia in roll", "M_Qdot": "added inertia in pitch", "N_Rdot": "added inertia in yaw",
    "wind_x": "steady wind along the room's x axis", "wind_y": "steady wind along the room's y axis",
    "thrust_speed_loss": "thrust lost per m/s of airspeed, the propellers' advance-ratio loss",
    "thrust_line_y": "thrust line right of the centreline, a yawing moment that grows with the thrust",
    **{term: f"draught across the room: change of the air's {term[5]} velocity per metre along the room's "
             f"{term[-1]} axis" for term in DRAUGHT_TERMS},
    "gondola_dx": "gondola ahead of its recorded position", "gondola_dy": "gondola right of its recorded position",
    "gondola_dz": "gondola below its recorded position",
}


def _aerodynamic_unit(term: str) -> str:
    """``"1"`` or ``"m"`` (moment coefficients carry the reference length), per rad^k of the
    angle the coefficient multiplies (``c_l_alpha``: 1/rad, ``c_my_beta4``: m/rad^4, the
    cross-flow ``c_mz_beta_abs``: m/rad^2)."""
    base = "m" if term.startswith("c_m") else "1"
    if term.endswith("_abs"):  # angle times its size
        return f"{base}/rad^2"
    power = term.rsplit("_", 1)[-1].lstrip("alphbet")
    if term.endswith("0"):
        return base
    per = "rad" if power == "" else f"rad^{power}"
    return f"{base}/{per}" if base == "m" else f"1/{per}"


TERM_UNITS = {**{term: _aerodynamic_unit(term) for term in AERODYNAMIC_TERMS},
              **dict.fromkeys(STABILITY_TERMS, "N m s/rad"), **dict.fromkeys(CONTROL_TERMS, "1"),
              "Z_0": "N", **dict.fromkeys(CG_TERMS, "m"), "X_Udot": "kg", "Y_Vdot": "kg", "Z_Wdot": "kg",
              "K_Pdot": "kg m^2", "M_Qdot": "kg m^2", "N_Rdot": "kg m^2", **dict.fromkeys(WIND_TERMS, "m/s"),
              "thrust_speed_loss": "s/m", "thrust_line_y": "m", **dict.fromkeys(DRAUGHT_TERMS, "1/s"),
              **dict.fromkeys(GONDOLA_TERMS, "m")}
_SEARCH_ROW_UNITS = {**dict.fromkeys("XYZ", "m/s^2"), **dict.fromkeys("LMN", "rad/s^2")}
_SEARCH_ROW_WORDS = {"X": "surge acceleration", "Y": "sway acceleration", "Z": "heave acceleration",
                     "L": "roll acceleration", "M": "pitch acceleration", "N": "yaw acceleration"}
_SEARCH_SIGNAL_UNITS = {**dict.fromkeys(("U", "V", "W"), "m/s"), **dict.fromkeys(("P", "Q", "R"), "rad/s"),
                        "phi": "rad", "theta": "rad"}

#: Floor under the noise that weighs each state's residuals (module docstring), state units.
MIN_NOISE_SD = {**dict.fromkeys(("x", "y", "z"), 0.05), **dict.fromkeys(("phi", "theta", "psi"), 0.02),
                **dict.fromkeys(("U", "V", "W"), 0.02), **dict.fromkeys(("P", "Q", "R"), 0.02)}
#: The states diagnose's residual GPs see: all but position and yaw (a residual cannot depend on
#: where the blimp is or which way it faces; Ko et al., ICRA 2007, sec. IV-B, as the RKGP's,
#: :data:`validation.models.rgblimp_greybox.GP_STATE_COLUMNS`).
RESIDUAL_GP_STATES = ("phi", "theta", "U", "V", "W", "P", "Q", "R")
#: White noise of the concealed-effect bench's RGBlimp recordings, state units: about the
#: largest noise estimate of the excerpt's positions (6e-5 m, data_117.csv), rounded up.
SENSOR_NOISE_STD = dict.fromkeys(STATE_NAMES, 1e-4)
#: Screening steps of terms whose model value is zero or tiny, in their units: 1 mN of net
#: force, 2 mm of CG, thrust line or gondola position, 0.01 kg (7 % of the displaced air) of added
#: mass, 0.001 kg m^2 (about a tenth of the smallest moment of inertia) of added inertia, 1 cm/s
#: of wind or of wind per metre, 2 % of thrust asymmetry, 0.05 s/m of thrust loss (2.5 % of the
#: thrust at the flights' 0.5 m/s), 0.001 of a coefficient.
_ABSOLUTE_STEPS = {"Z_0": 1e-3, "cg_offset": 2e-3, "added_mass": 0.01, "added_inertia": 1e-3, "steady_wind": 0.01,
                   "thrust_asymmetry": 0.02, "coefficient": 1e-3, "thrust_speed_loss": 0.05, "thrust_line_y": 2e-3,
                   "draught_field": 0.01, "gondola_offset": 2e-3}
#: Air speed, m/s, above which a room's air is no longer still: the draught limits of ISO
#: 7730:2005, Annex A (mean air velocity 0.12-0.25 m/s by comfort category and season), their top.
STILL_AIR_LIMIT = 0.25
#: Relative screening step of terms with a model value (5 %, as for the blimp's).
_RELATIVE_STEP = 0.05
#: Largest thrust asymmetry: the weaker propeller keeps a tenth of its thrust.
_MAX_ASYMMETRY = 0.9
#: Bounds of the terms that have them: added mass and inertia, the thrust gain and the thrust
#: loss with airspeed are never negative; the asymmetry stays within :data:`_MAX_ASYMMETRY`.
_BOUNDS = {**dict.fromkeys((*ADDED_MASS_TERMS, "thrust_gain", "thrust_speed_loss"), (0.0, math.inf)),
           "thrust_asymmetry": (-_MAX_ASYMMETRY, _MAX_ASYMMETRY)}


def _screening_step(kind: str, term: str, value: float) -> float:
    """A term's screening step: :data:`_ABSOLUTE_STEPS` of the term, of its field (added mass or
    inertia) or of its kind, where there is one; else :data:`_RELATIVE_STEP` of the model's value
    (at least 0.001 of a coefficient)."""
    if term == "thrust_gain":
        return _RELATIVE_STEP
    for key in (term, ADDED_MASS_TERMS.get(term, (None,))[0], kind):
        if key in _ABSOLUTE_STEPS:
            return _ABSOLUTE_STEPS[key]
    return max(_RELATIVE_STEP * abs(value), _ABSOLUTE_STEPS["coefficient"])


def model_value(params: RGBlimpParameters, term: str) -> float:
    """The model's value of ``term`` (module docstring for units and signs)."""
    if term in AERODYNAMIC_TERMS:
        return float(getattr(params, term))
    if term in STABILITY_TERMS:
        return float(params.rate_damping[STABILITY_TERMS[term]])
    if term in CONTROL_TERMS:
        return CONTROL_TERMS[term]
    if term == "Z_0":
        return (params.hull_mass + params.gondola_mass - params.buoyancy_mass) * params.gravity
    if term in CG_TERMS:
        return float(params.hull_cg[CG_TERMS[term]])
    if term in _FIELD_TERMS:
        field, axis = _FIELD_TERMS[term]
        return float(np.atleast_1d(getattr(params, field))[axis])
    if term in WIND_TERMS or term in GONDOLA_TERMS or term in SEARCH_TERMS:
        return 0.0  # no wind, offset or term beyond the model's
    raise KeyError(term)


def identification_manoeuvre(*, duration: float = 20.0, sample_time: float = SAMPLE_TIME,
                             variant: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """An RGBlimp input history as the source's flights hold them: constant thrusts and gondola.

    Variant 0 thrusts 0.03 N left and 0.045 N right (a right-hand spiral) with the gondola at
    :data:`~validation.vehicles.rgblimp_equations.NOMINAL_GONDOLA_POSITION`; variant 1 the
    thrusts the other way round with the gondola 2 cm further forward (the source's flights
    hold 0.01-0.06 N and move the gondola by -1 .. 4 cm, docs/rgblimp.md).

    Returns
    -------
    time : ndarray, shape (n,)
    inputs : ndarray, shape (n, 5)
    """
    time = time_grid(duration=duration, sample_time=sample_time)
    gondola = np.array(NOMINAL_GONDOLA_POSITION) + (np.array([0.02, 0.0, 0.0]) if variant else 0.0)
    thrusts = (0.045, 0.03) if variant else (0.03, 0.045)
    return time, np.tile(np.concatenate([thrusts, gondola]), (len(time), 1))


class _MemberValues:
    """The parameters of B effect lists as arrays, for states of shape (B, S, 12) (the
    broadcasting of :func:`validation.models.rgblimp_identification.batched_parameters`)."""

    def __init__(self, params: RGBlimpParameters, effect_lists):
        n = len(effect_lists)
        self.fields = {f.name: np.tile(np.asarray(getattr(params, f.name), dtype=float), (n, 1))
                       for f in dataclasses.fields(RGBlimpParameters)}
        self.gain, self.asymmetry, self.wind = np.ones(n), np.zeros(n), np.zeros((n, 2))
        self.gondola_offset = np.zeros((n, 3))
        self.slots = search_slots(effect_lists, SEARCH_ROWS, SEARCH_SIGNALS, SEARCH_SLOTS)
        self.changed = set()
        for member, effects in enumerate(effect_lists):
            for effect in effects:
                if effect.get("effect") != "search_term":
                    self._set(member, effect["term"], float(effect["value"]))

    def _set(self, member: int, term: str, value: float) -> None:
        if term in AERODYNAMIC_TERMS:
            field, axis = term, 0
        elif term in STABILITY_TERMS:
            field, axis = "rate_damping", STABILITY_TERMS[term]
        elif term == "Z_0":  # (m + m_b - B) g = value
            field, axis = "buoyancy_mass", 0
            value = self.fields["hull_mass"][member, 0] + self.fields["gondola_mass"][member, 0] \
                - value / self.fields["gravity"][member, 0]
        elif term in CG_TERMS:
            field, axis = "hull_cg", CG_TERMS[term]
        elif term in _FIELD_TERMS:
            field, axis = _FIELD_TERMS[term]
        elif term in GONDOLA_TERMS:
            self.gondola_offset[member, GONDOLA_TERMS[term]] = value
            return
        elif term == "thrust_gain":
            self.gain[member] = value
            return
        elif term == "thrust_asymmetry":
            self.asymmetry[member] = value
            return
        else:
            self.wind[member, WIND_TERMS[term]] = value
            return
        self.fields[field][member, axis] = value
        self.changed.add(field)

    def namespace(self, params: RGBlimpParameters) -> SimpleNamespace:
        """The fields, batched where any member changed them: scalars (B, 1) (they multiply
        angles (B, S)), the buoyancy (B, 1, 1) (it multiplies a direction (B, S, 3)), triples
        (B, 1, 3)."""
        values = {f.name: getattr(params, f.name) for f in dataclasses.fields(RGBlimpParameters)}
        for field in self.changed:
            array = self.fields[field]
            if array.shape[1] == 3:
                values[field] = array[:, None, :]
            elif field == "buoyancy_mass":
                values[field] = array[:, :, None]
            else:
                values[field] = array
        return SimpleNamespace(**values)

    def arrays(self) -> dict:
        """Every member's parameters for :func:`validation.vehicles.rgblimp_jax.batched_free_runs`:
        the fields (B,) or (B, 3), the thrust factor 1 (applied to the inputs), the wind (B, 2) and
        the search terms' slots (B, :data:`SEARCH_SLOTS`)."""
        values = {name: array if array.shape[1] == 3 else array[:, 0] for name, array in self.fields.items()}
        return {**values, "thrust_gain": np.ones(len(self.gain)), "wind": self.wind, **self.slots}

    def search_acceleration(self):
        """The search terms' accelerations of every member for the numpy free run (states (B, S,
        12)), or None when no member has one."""
        if not np.any(self.slots["search_value"]):
            return None
        slots = {key: array[:, None, :] for key, array in self.slots.items()}
        return lambda state, inputs: search_accelerations(np, state, slots)

    def member_parameters(self, member: int) -> RGBlimpParameters:
        """Member ``member``'s parameters as an :class:`RGBlimpParameters`."""
        return RGBlimpParameters(**{name: (tuple(array[member]) if array.shape[1] == 3 else float(array[member, 0]))
                                    for name, array in self.fields.items()})


class RGBlimpEffects:
    """The :class:`~validation.vehicles.effects.EffectModel` of the ``rgblimp`` reference (module
    docstring): replays from each recording's first state, batched over members and recordings,
    evenly sampled at 60 Hz.

    Parameters
    ----------
    reference : RGBlimpReference
    compiled : bool
        Replay with the compiled free run (the default) or the numpy step (module docstring).

    The attributes and methods are those of the protocol.
    """

    family = "rgblimp"
    kinds = tuple(TERMS)
    terms = TERMS
    search_rows = SEARCH_ROWS
    search_signals = SEARCH_SIGNALS
    search_library = SEARCH_LIBRARY
    max_search_terms = SEARCH_SLOTS
    batches_simulations = True
    absolute_inputs = True
    needs_even_sampling = True
    sensor_noise_sd = SENSOR_NOISE_STD
    min_noise_sd = MIN_NOISE_SD
    residual_gp_states = RESIDUAL_GP_STATES
    pose_score = True

    def __init__(self, reference: RGBlimpReference, *, compiled: bool = True):
        self.reference, self.compiled = reference, compiled
        self.name, self.sample_time = reference.name, reference.sample_time
        self.input_names, self.state_names = reference.input_names, reference.state_names

    def model_value(self, term: str) -> float:
        return model_value(self.reference.params, term)

    def term_unit(self, term: str) -> str:
        """:data:`TERM_UNITS`; a search term's, its row's acceleration per unit of its factor
        (``rad/s^2/(rad/s)^2`` for ``L_P|P|``)."""
        if term in TERM_UNITS:
            return TERM_UNITS[term]
        return search_term_unit(term, SEARCH_ROWS, SEARCH_SIGNALS, row_units=_SEARCH_ROW_UNITS,
                                signal_units=_SEARCH_SIGNAL_UNITS)

    def term_description(self, term: str) -> str:
        """:data:`TERM_DESCRIPTIONS`; a search term's ``"<row> acceleration proportional to
        <factor>"``; ``term`` itself for another."""
        if term not in TERM_DESCRIPTIONS and term in SEARCH_TERMS:
            return search_term_description(term, _SEARCH_ROW_WORDS)
        return TERM_DESCRIPTIONS.get(term, term)

    def term_value_problem(self, term: str, value: float) -> str | None:
        """The thrust gain must be positive, an asymmetry below :data:`_MAX_ASYMMETRY` in size,
        an added mass or inertia or a thrust loss with airspeed not negative."""
        if term == "thrust_gain" and not value > 0:
            return f"the thrust gain must be positive, got {value}"
        if term == "thrust_speed_loss" and value < 0:
            return f"a propeller's thrust falls with airspeed: the thrust loss cannot be negative, got {value} s/m"
        if term == "thrust_asymmetry" and not abs(value) <= _MAX_ASYMMETRY:
            return f"the thrust asymmetry must lie within +-{_MAX_ASYMMETRY}, got {value}"
        if term in ADDED_MASS_TERMS and value < 0:
            return f"an added mass or inertia cannot be negative, got {value} {TERM_UNITS[term]}"
        return None

    def value_context(self, term: str, value: float, extent: dict) -> str | None:
        """For a draught-field term, the change of the air's velocity it means across the
        diagnosed flights (``extent``: output -> (min, max) over them), and whether that is more
        than a room's air moves (:data:`STILL_AIR_LIMIT`); None for other terms."""
        if term not in DRAUGHT_TERMS or term[-1] not in extent:
            return None
        low, high = extent[term[-1]]
        change = abs(value) * (high - low)
        text = (f"Across the {high - low:.1f} m the diagnosed flights cover along the room's {term[-1]} axis, the "
                f"air's {term[5]} velocity would change by {change:.2g} m/s")
        if change > STILL_AIR_LIMIT:
            return text + (f", more than the air of a room moves (draught limits up to {STILL_AIR_LIMIT} m/s, "
                           "ISO 7730): it may stand in for something else.")
        return text + "."

    def term_hypotheses(self, excited_inputs) -> list[Hypothesis]:
        """Every term of :data:`TERMS`, whatever moves: the inputs are absolute thrusts and
        positions, not perturbations, so they act in every flight (screening steps 5 % of the
        model's value, or :data:`_ABSOLUTE_STEPS` where it is zero or tiny)."""
        hypotheses = []
        for kind, terms in TERMS.items():
            for term in terms if kind != "search_term" else ():  # the residual search offers those
                value = self.model_value(term)
                lower, upper = _BOUNDS.get(term, (-math.inf, math.inf))
                hypotheses.append(Hypothesis(kind, term, value, lower, upper, _screening_step(kind, term, value)))
        return hypotheses

    def start_state(self, recording) -> np.ndarray:
        """The recording's first row of all 12 states, in :data:`STATE_NAMES` order;
        BadInputError when it does not measure them all (a free run needs its start)."""
        missing = [n for n in STATE_NAMES if n not in recording.output_names]
        if missing:
            raise BadInputError(f"the {self.name} reference replays each recording from its first recorded "
                                f"state, so it needs all 12 states; missing {', '.join(missing)}")
        return np.array([recording.outputs[0, recording.output_names.index(n)] for n in STATE_NAMES])

    def simulate_recordings(self, effect_lists, times, inputs, starts) -> list[np.ndarray]:
        """Replays of every recording with every effect list, integrated together (module
        docstring): a list of arrays (B, n_r, 12), heading continuous."""
        for time in times:
            self._check_time(np.asarray(time, dtype=float))
        lengths = [len(u) for u in inputs]
        longest = max(lengths)
        padded = np.stack([np.vstack([u, np.repeat(u[-1:], longest - len(u), axis=0)]) for u in inputs])
        members = _MemberValues(self.reference.params, effect_lists)
        factors = members.gain[:, None] * (1.0 + np.outer(members.asymmetry, [1.0, -1.0]))  # (B, 2)
        batch_inputs = np.broadcast_to(padded, (len(effect_lists),) + padded.shape).copy()  # (B, S, L, 5)
        batch_inputs[..., :2] *= factors[:, None, None, :]
        batch_inputs[..., 2:5] += members.gondola_offset[:, None, None, :]
        first = np.stack([np.tile(start, (len(effect_lists), 1)) if start is not None else
                          np.stack([resting_state(batch_inputs[b, s, 0, 2:5], members.member_parameters(b))
                                    for b in range(len(effect_lists))])
                          for s, start in enumerate(starts)], axis=1)  # (B, S, 12)
        if self.compiled:  # yaw carried continuously
            path = batched_free_runs(members.arrays(), first, batch_inputs)
        else:
            with np.errstate(over="ignore", invalid="ignore"):
                path = free_run(first, batch_inputs, members.namespace(self.reference.params),
                                wind=members.wind[:, None, :], extra_acceleration=members.search_acceleration())
                path[..., 5] = np.unwrap(path[..., 5], axis=-1)
        return [path[:, s, :n] for s, n in enumerate(lengths)]

    def search_jacobian(self, states, inputs) -> np.ndarray:
        """How strongly each search signal drives each search row, for the residual search's
        axes: :func:`~validation.vehicles.effects.search_axes_jacobian` of the body accelerations
        (rows :data:`~validation.vehicles.rgblimp_equations.SEARCH_ROWS`, signals
        :data:`~validation.vehicles.rgblimp_equations.SEARCH_SIGNALS`) at the replayed ``states``
        (a list of (n_r, 12)) with the recordings' ``inputs`` (a list of (n_r, 5)); shape (6, 8)."""
        params = self.reference.params
        return search_axes_jacobian(lambda x, u: body_accelerations(x, u, params), states, inputs, SEARCH_SIGNALS,
                                    STATE_NAMES, INPUT_NAMES)

    def simulate_many(self, effect_lists, time, inputs, *, start=None) -> np.ndarray:
        """:meth:`simulate_recordings` of one recording, shape (B, n, 12); from ``start``, or
        at rest (:func:`~validation.vehicles.rgblimp.resting_state`) without one."""
        return self.simulate_recordings(effect_lists, [time], [np.asarray(inputs, dtype=float)], [start])[0]

    def _check_time(self, time: np.ndarray) -> None:
        steps = np.diff(time)
        if len(steps) == 0 or np.max(np.abs(steps - SAMPLE_TIME)) > 1e-6 * SAMPLE_TIME + 1e-9:
            raise BadInputError(f"the {self.name} model steps at 1/60 s (the source's RK4 step and motion-capture "
                                "rate); resample the recordings to 60 Hz")

    identification_manoeuvre = staticmethod(identification_manoeuvre)
