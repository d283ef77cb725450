"""``flightgp diagnose-bench``: the concealed-effect benchmark of ``flightgp diagnose``.

Each case flies the Bo105 reference with effects that :func:`validation.diagnose.pipeline.diagnose` is not
told about, records it with sensor noise, diagnoses it and scores the answer against the truth
(docs/diagnose.md, "The concealed-effect benchmark: `flightgp diagnose-bench`"):

- **single** named effects on several channels and at several magnitudes, all at or above
  realistic sizes (delay >= 40 ms, lag >= 50 ms, derivative changes >= 25 %, biases >= 3x the
  sensor noise; dead bands, limits and rate limits that bite on the manoeuvre's steps). A
  quadratic pitch damping ``M_q|q|`` and a cubic weathercock stiffness ``N_v^3`` are named
  effects (``nonlinear_damping``, ``nonlinear_stiffness``) and a pitch control power quadratic
  in deflection a term the residual search must find (``search_term``), all flown by RK4 of the
  continuous model rather than by the replay diagnose fits with;
- **measurement chain**: each sensor effect on the pitch-rate gyro at two values (a lag, a scale
  factor, a drifting bias, a cross-axis sensitivity to the roll rate), single cases
  (:func:`_measurement_chain_cases`);
- **pair**: two named effects at once (one of them nonlinear in one pair);
- **none**: the reference itself (any finding is a false finding);
- **ambiguous**: a dead band flown at one amplitude, which no data of that manoeuvre can tell
  from a gain or a limit: named or offered as the alternative, nothing false above
  :data:`AMBIGUOUS_CONFIDENCE`;
- **outside** (the blimp's; the FMU suites' where an effect cannot be named there): physics
  outside the named list, where the honest answer is ``unexplained``;
- **through_inputs**: a polynomial term of a linear reference's row (``M_q|q|``) diagnosed
  through an FMU, whose residual search can only add terms to its inputs: named when the
  search terms of the same factor, mapped onto the rows by the flying reference's control
  derivatives ``B``, give the truth's row within :data:`THROUGH_INPUTS_TOLERANCE` of the truth
  (their intervals are reported against it too, but the mapped term also moves the rows the
  inputs drive besides, so output error settles a little off the truth and the interval is not
  required to hold it);
- **turbulence**: the reference itself flown in light and in moderate Dryden turbulence
  (:func:`case_gusts`): nothing may be stated with confidence above
  :data:`TURBULENCE_CONFIDENCE`, and the diagnosis must say that the residual looks like
  atmospheric disturbance; concealed effects flown in the same air are ``single`` cases, scored
  as without it except that their held-out RMSEs are taken against the flight without the gusts
  (no model predicts the held-out flight's gusts);
- **changing**: a derivative that drifts during the flight (flown by RK4 with the derivative
  moving linearly in time): named, and said to change in the right direction
  (:mod:`validation.diagnose.over_time`); its value is the flight's average, which the interval
  of a constant need not hold. On every ``single`` and ``pair`` case, a finding said to change is
  a false finding.

Recordings (both :data:`DURATION` s from trim at the reference's
:attr:`~validation.vehicles.effects.EffectModel.sample_time`, every state measured with its
:attr:`~validation.vehicles.effects.EffectModel.sensor_noise_sd`): the diagnosed one flies its
:meth:`~validation.vehicles.effects.EffectModel.identification_manoeuvre` variant 0, the
held-out one variant 1 (other amplitudes, step times and order). On a Bo105 (:func:`bo105_cases`)
that is 100 Hz with the flight-test stand-in's sensor noise and the multi-axis manoeuvre of
:func:`validation.vehicles.bo105_effects.identification_manoeuvre`. Noise is seeded by the run's
seed, the recording and the case's name: each case is an independent trial, and running a case
alone gives what it gives in the whole suite.

The ``blimp`` suite (:func:`blimp_cases`, ``concealed_cases(reference="blimp")``) does the same on the blimp
ODE: 20 Hz (the mocap rate), all 12 states with the white noise of
:data:`validation.vehicles.blimp_effects.SENSOR_NOISE_STD`, the manoeuvres of
:func:`validation.vehicles.blimp_effects.identification_manoeuvre`; single effects of every kind the blimp
takes but the measurement chain's beyond a bias (those are benchmarked on the Bo105), a pair, no
effect, and a fan nonlinearity outside the named list (thrust quadratic in the command).

Scorecard columns, per case: every true effect named with the right effect kind and target
(``named``); the true value inside the reported interval (``in_interval``); the held-out RMSE of
the *affected output* (the one the true effects move most, relative to its noise, in the
noise-free held-out flight) for the reference and the corrected model, and the cut; findings
that match no true effect (``false``); wall-clock seconds of the diagnosis. A case passes when
all of its true effects are named with the value inside the interval, the cut is at least
:data:`REQUIRED_CUT`, and nothing false is found (for ``none``: no finding at all; for
``outside``: an ``unexplained`` finding; for ``turbulence``: the air named and nothing
confident).
"""
from __future__ import annotations

import math
import time as clock
import zlib
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from validation.core.errors import BadInputError
from validation.core.recordings import Recording
from validation.diagnose.pipeline import diagnose, take_input_terms
from validation.vehicles.blimp_equations import rk4
from validation.vehicles.bo105 import KNOT
from validation.vehicles.bo105_flight import TURBULENCE_MIN_ADVECTION_SPEED
from validation.vehicles.effect_vehicle import EffectVehicle, effect_model
from validation.vehicles.effects import TARGET_KEYS, EffectModel, dead_band_inputs, split_cross_axis
from validation.vehicles.fmu_reference import input_row
from validation.vehicles.linear_effects import simulate_linear_with_effects
from validation.vehicles.polynomial_terms import factor_values, parse_term
from validation.vehicles.turbulence import dryden_gusts, low_altitude_turbulence

#: Held-out RMSE cut of the affected output that a named effect must achieve: the corrected model
#: must remove most of the error the effect causes (docs/diagnose.md, "The concealed-effect
#: benchmark: `flightgp diagnose-bench`").
REQUIRED_CUT = 0.6
#: Recording length of every case, s (the runtime goal, docs/benchmarks.md, "`diagnose`", is per
#: 20 s recording).
DURATION = 20.0


@dataclass(frozen=True)
class ConcealedCase:
    """One benchmark case.

    Attributes
    ----------
    name : str
        Short identifier, e.g. ``"delay-theta_1s-60ms"``.
    kind : {"single", "pair", "none", "outside", "ambiguous", "changing", "turbulence", "through_inputs"}
    effects : tuple of dict
        The named effects applied (the truth), in the shape of diagnosis findings; empty for
        ``none``, ``outside`` and ``through_inputs``.
    outside : tuple, optional
        How the recordings are flown when not by the reference with ``effects``: a physics change
        outside the named list, ``(map, input, parameter)`` with a map of :data:`COMMAND_MAPS`
        (e.g. ``("dead_band", "theta_1s", half_width_rad)``), or
        ``("drifting_derivative", term, start, end)`` (RK4 of the continuous model with the
        derivative moving linearly in time over the recording, a ``changing`` case), or
        ``("polynomial_term", term, coefficient)`` (RK4 of the continuous model with a polynomial
        term, :mod:`validation.vehicles.polynomial_terms`; with a
        ``nonlinear_damping`` effect as the truth, the named effect flown by an integrator other
        than the one diagnose replays it with).
    description : str
        One line for the scorecard.
    turbulence : {"light", "moderate"}, optional
        Fly both recordings in Dryden turbulence of this intensity (:func:`case_gusts`); the
        ``turbulence`` kind is the reference itself in it.
    fit_variant : int
        The identification manoeuvre's variant the diagnosed recording flies (0; the Bo105's 2
        flies the longitudinal-cyclic 3-2-1-1 at two amplitudes). The held-out one flies 1.
    """

    name: str
    kind: str
    effects: tuple = ()
    outside: tuple | None = None
    description: str = ""
    fit_variant: int = 0
    turbulence: str | None = None


def _single_case(effect: dict, name: str, description: str) -> ConcealedCase:
    """A case with one named effect."""
    return ConcealedCase(name, "single", (effect,), description=description)


def _scaled_case(reference: EffectModel, kind: str, term: str, factor: float, *,
                 description: str) -> ConcealedCase:
    """A case scaling ``term`` of ``reference`` by ``factor``, named ``<term><+-percent>%``."""
    old = reference.model_value(term)
    value = old * factor
    return ConcealedCase(f"{term}{round((factor - 1) * 100):+d}%", "single",
                         ({"effect": kind, "term": term, "value": value},),
                         description=f"{description}: {old:.4g} -> {value:.4g}")


def blimp_cases(*, reference: EffectModel | None = None) -> list[ConcealedCase]:
    """The blimp suite (module docstring): every effect kind the blimp takes (of the measurement
    chain, the bias) at sizes a real
    indoor blimp could show (delays of a radio link and fan spin-up, 15-30 % drag and thrust
    errors, a buoyancy imbalance of 0.3 g, a command limit and a slew limit), a pair, no effect,
    a fan nonlinearity outside the named list (:data:`COMMAND_MAPS`) and a pitch moment the
    residual search must find. ``reference``: the blimp's effect model
    (default: the ``blimp`` reference's)."""
    reference = reference or effect_model("blimp", purpose="diagnose-bench")
    noise = reference.sensor_noise_sd

    def scaled(kind, term, factor, description):
        return _scaled_case(reference, kind, term, factor, description=description)

    single = _single_case

    return [
        single({"effect": "time_delay", "input": "u_gondola", "value": 0.15}, "delay-u_gondola-150ms",
               "transport delay 150 ms on the gondola thrust command"),
        single({"effect": "time_delay", "input": "u_tail", "value": 0.1}, "delay-u_tail-100ms",
               "transport delay 100 ms on the tail-fan command"),
        single({"effect": "input_lag", "input": "u_tail", "value": 0.3}, "lag-u_tail-300ms",
               "fan spin-up lag 300 ms on the tail fan"),
        single({"effect": "input_lag", "input": "u_gondola", "value": 0.2}, "lag-u_gondola-200ms",
               "fan spin-up lag 200 ms on the gondola fans"),
        scaled("quadratic_drag", "X_UU", 1.3, "quadratic surge drag +30 %"),
        scaled("quadratic_drag", "Y_VV", 1.5, "quadratic sway drag +50 %"),
        scaled("control_derivative", "gondola_thrust_backward", 0.7, "gondola thrust backward -30 %"),
        scaled("control_derivative", "tail_thrust_negative", 0.6, "tail thrust pushing right -40 %"),
        scaled("stability_derivative", "N_R", 1.5, "yaw damping +50 %"),
        single({"effect": "force_offset", "term": "Z_0", "value": 0.003}, "Z_0-3mN",
               "buoyancy imbalance: 3 mN (0.3 g) heavy"),
        single({"effect": "force_offset", "term": "N_0", "value": 0.002}, "N_0-2mNm",
               "constant yaw moment 2 mN m (a bent fin)"),
        single({"effect": "sensor_bias", "output": "psi", "value": 5 * noise["psi"]},
               "bias-psi-5sd", "heading sensor bias 5x noise"),
        ConcealedCase("pair-delay+Z_0", "pair",
                      ({"effect": "time_delay", "input": "u_gondola", "value": 0.1},
                       {"effect": "force_offset", "term": "Z_0", "value": -0.002}),
                      description="100 ms delay on u_gondola and 2 mN excess buoyancy"),
        ConcealedCase("none", "none", description="the reference itself, with sensor noise"),
        ConcealedCase("outside-quadratic-thrust-u_tail", "outside", outside=("quadratic_thrust", "u_tail", None),
                      description="tail-fan thrust quadratic in its command, u|u| (not a named effect)"),
        single({"effect": "search_term", "term": "M_U", "value": 0.02}, "search-pitch-moment-M_U",
               "pitch moment linear in surge speed, 0.02 N m/(m/s) (10 mN m at 0.5 m/s): on no named list, "
               "the residual search must find it"),
        # The gondola steps of 0.8, -0.6 and 0.5: a limit at 0.6 bites the largest only.
        single({"effect": "saturation", "input": "u_gondola", "value": 0.6}, "saturation-u_gondola-0.6",
               "gondola thrust command limited at 60 % (the 0.8 steps clip)"),
        single({"effect": "rate_limit", "input": "u_tail", "value": 2.0}, "rate-limit-u_tail-2/s",
               "tail-fan command slewing at 2 /s (the doublet's 0.8 steps ramp over 0.4 s, its reversal 0.8 s)"),
    ]


def bo105_cases(*, reference: EffectModel) -> list[ConcealedCase]:
    """The Bo105 suite (module docstring) on ``reference``, a Bo105's effect model.

    Derivative changes are relative to the reference's own values, so the suite works at every
    tabulated speed; the off-axis ``L_q``/``M_p`` values are the wake-distortion changes that the
    flight-test stand-in applies at 80 kt (Keller, JAHS 1996; :mod:`validation.vehicles.bo105`).
    """
    def scaled(kind, term, factor):
        return _scaled_case(reference, kind, term, factor,
                            description=f"{term} ({round((factor - 1) * 100):+d} %)")

    single = _single_case
    noise = reference.sensor_noise_sd
    cases = [
        single({"effect": "time_delay", "input": "theta_1s", "value": 0.06}, "delay-theta_1s-60ms",
               "transport delay 60 ms on longitudinal cyclic"),
        single({"effect": "time_delay", "input": "theta_1c", "value": 0.04}, "delay-theta_1c-40ms",
               "transport delay 40 ms on lateral cyclic"),
        single({"effect": "time_delay", "input": "theta_0T", "value": 0.1}, "delay-theta_0T-100ms",
               "transport delay 100 ms on tail-rotor collective"),
        single({"effect": "input_lag", "input": "theta_1s", "value": 0.08}, "lag-theta_1s-80ms",
               "first-order lag 80 ms on longitudinal cyclic"),
        single({"effect": "input_lag", "input": "theta_1c", "value": 0.05}, "lag-theta_1c-50ms",
               "first-order lag 50 ms on lateral cyclic"),
        single({"effect": "input_lag", "input": "theta_0", "value": 0.15}, "lag-theta_0-150ms",
               "first-order lag 150 ms on main collective"),
        scaled("control_derivative", "M_theta_1s", 0.7),
        scaled("control_derivative", "L_theta_1c", 1.3),
        scaled("control_derivative", "N_theta_0T", 0.75),
        scaled("stability_derivative", "M_q", 0.6),
        scaled("stability_derivative", "L_p", 0.7),
        scaled("stability_derivative", "N_r", 1.5),
        single({"effect": "stability_derivative", "term": "L_q", "value": -3.35}, "L_q-wake",
               f"off-axis coupling L_q {reference.model_value('L_q'):.3g} -> -3.35 (wake distortion)"),
        single({"effect": "stability_derivative", "term": "M_p", "value": 1.13}, "M_p-wake",
               f"off-axis coupling M_p {reference.model_value('M_p'):.3g} -> 1.13 (wake distortion)"),
        single({"effect": "sensor_bias", "output": "q", "value": 3 * noise["q"]}, "bias-q-3sd",
               f"pitch-rate sensor bias {3 * noise['q']:g} rad/s (3x noise)"),
        single({"effect": "sensor_bias", "output": "phi", "value": -5 * noise["phi"]}, "bias-phi-5sd",
               f"roll-attitude sensor bias {-5 * noise['phi']:g} rad (5x noise)"),
        ConcealedCase("pair-delay+bias", "pair",
                      ({"effect": "time_delay", "input": "theta_1s", "value": 0.06},
                       {"effect": "sensor_bias", "output": "r", "value": 4 * noise["r"]}),
                      description="60 ms delay on theta_1s and a yaw-rate bias of 4x noise"),
        ConcealedCase("pair-lag+M_q", "pair",
                      ({"effect": "input_lag", "input": "theta_1c", "value": 0.08},
                       {"effect": "stability_derivative", "term": "M_q",
                        "value": reference.model_value("M_q") * 0.7}),
                      description="80 ms lag on theta_1c and M_q -30 %"),
        # Two pitch effects at once: fitted alone, the damping soaks up part of the control
        # power, and a first step can take a term that explains part of both; the search must
        # take it back and name the two.
        ConcealedCase("pair-M_q+M_theta_1s", "pair",
                      ({"effect": "stability_derivative", "term": "M_q", "value": reference.model_value("M_q") * 0.7},
                       {"effect": "control_derivative", "term": "M_theta_1s",
                        "value": reference.model_value("M_theta_1s") * 0.75}),
                      description="M_q -30 % and M_theta_1s -25 % at once"),
        ConcealedCase("none", "none", description="the reference itself, with sensor noise"),
        # A dead band of 30 % of the 1 deg steps: on one amplitude it is exactly a lower control
        # derivative (the honest answer says so); flown at 1 and 2 deg it must be named.
        ConcealedCase("dead-band-theta_1s-one-amplitude", "ambiguous",
                      ({"effect": "dead_band", "input": "theta_1s", "value": math.radians(0.3)},),
                      description="+/-0.3 deg dead band on longitudinal cyclic, 1 deg steps only"),
        ConcealedCase("dead-band-theta_1s-two-amplitudes", "single",
                      ({"effect": "dead_band", "input": "theta_1s", "value": math.radians(0.3)},),
                      description="+/-0.3 deg dead band on longitudinal cyclic, 1 and 2 deg steps", fit_variant=2),
        # Free play in the longitudinal-cyclic linkage, 10 and 25 % of the 1 deg steps: each step
        # away from trim loses it as a dead band's would, but after the 3-2-1-1 the rotor stays
        # that far off trim, which a dead band, a gain or a limit cannot do.
        *(ConcealedCase(f"backlash-theta_1s-{width}deg", "single",
                        ({"effect": "backlash", "input": "theta_1s", "value": math.radians(width)},),
                        description=f"+/-{width} deg free play in the longitudinal-cyclic linkage")
          for width in (0.1, 0.25)),
        # A limit at 70 % of the larger steps: it bites the 2 deg steps only.
        ConcealedCase("saturation-theta_1s-1.4deg", "single",
                      ({"effect": "saturation", "input": "theta_1s", "value": math.radians(1.4)},),
                      description="longitudinal cyclic limited at +/-1.4 deg, 1 and 2 deg steps", fit_variant=2),
        # A lateral-cyclic actuator slewing at 10 deg/s: the 1 deg steps ramp over 0.1 s, the
        # 2 deg reversals over 0.2 s; alone, and a 15 deg/s limit beside a linear error.
        ConcealedCase("rate-limit-theta_1c-10deg/s", "single",
                      ({"effect": "rate_limit", "input": "theta_1c", "value": math.radians(10.0)},),
                      description="lateral cyclic rate limited at 10 deg/s"),
        ConcealedCase("pair-rate-limit+M_q", "pair",
                      ({"effect": "rate_limit", "input": "theta_1s", "value": math.radians(15.0)},
                       {"effect": "stability_derivative", "term": "M_q", "value": reference.model_value("M_q") * 0.7}),
                      description="longitudinal cyclic rate limited at 15 deg/s and M_q -30 %"),
        # Flown by RK4 of x_dot = A x + B u + e_q c q|q| (outside), not by the replay diagnose
        # fits with: the named effect must be found in a flight its own discretisation did not make.
        ConcealedCase("quadratic-damping-M_q|q|", "single",
                      ({"effect": "nonlinear_damping", "term": "M_q|q|", "value": -40.0},),
                      outside=("polynomial_term", "M_q|q|", -40.0),
                      description="quadratic pitch damping M_q|q| = -40 (rad/s^2)/(rad/s)^2, flown by RK4"),
        # Weathercock stiffness cubic in the sideslip velocity (at the 2.5 m/s the manoeuvre
        # reaches, c v^3 is 0.094 rad/s^2 against N_v v = 0.32), flown by RK4: a linear N_v must
        # not be taken for it.
        ConcealedCase("cubic-stiffness-N_v^3", "single",
                      ({"effect": "nonlinear_stiffness", "term": "N_v^3", "value": 0.006},),
                      outside=("polynomial_term", "N_v^3", 0.006),
                      description="yaw moment cubic in lateral velocity N_v^3 = 0.006 (rad/s^2)/(m/s)^3, flown by RK4"),
        # The same stiffness growing with the signed square (c v|v| = 0.094 rad/s^2 at 2.5 m/s, as
        # the cube's), flown by RK4: neither N_v nor the cube may be taken for it.
        ConcealedCase("quadratic-stiffness-N_v|v|", "single",
                      ({"effect": "quadratic_stiffness", "term": "N_v|v|", "value": 0.015},),
                      outside=("polynomial_term", "N_v|v|", 0.015),
                      description="yaw moment quadratic in lateral velocity N_v|v| = 0.015 (rad/s^2)/(m/s)^2, "
                                  "flown by RK4"),
        # Pitch damping weakening during the flight (a rotor speed or a temperature that drifts):
        # M_q from the model's value to 60 % of it over the 20 s, flown by RK4 of x_dot = A(t) x +
        # B u. The truth's value is the flight's average; the finding must say that it changes,
        # in the right direction.
        ConcealedCase("M_q-drift", "changing",
                      ({"effect": "stability_derivative", "term": "M_q", "value": reference.model_value("M_q") * 0.8},),
                      outside=("drifting_derivative", "M_q", reference.model_value("M_q"),
                               reference.model_value("M_q") * 0.6),
                      description=f"pitch damping M_q drifting from {reference.model_value('M_q'):.3g} to "
                                  f"{reference.model_value('M_q') * 0.6:.3g} over the flight, flown by RK4"),
        # Not a named effect: pitch control power growing with deflection, c u|u| (+30 % of the
        # linear M_theta_1s u at 2 deg), flown by RK4 at 1 and 2 deg. The residual search must
        # find it (a gain, a dead band or a limit fits neither amplitude).
        ConcealedCase("control-power-M_theta_1s|theta_1s|", "single",
                      ({"effect": "search_term", "term": "M_theta_1s|theta_1s|", "value": 400.0},),
                      outside=("polynomial_term", "M_theta_1s|theta_1s|", 400.0), fit_variant=2,
                      description="pitch control power quadratic in deflection, M_theta_1s|theta_1s| = 400 "
                                  "(rad/s^2)/rad^2, 1 and 2 deg steps, flown by RK4; found by search"),
    ]
    return cases + _measurement_chain_cases(noise) + _turbulence_cases(reference)


def _turbulence_cases(reference: EffectModel) -> list[ConcealedCase]:
    """The Bo105's turbulence cases (:func:`case_gusts`): the reference itself in light and in
    moderate turbulence (nothing missing: the residual is the air's doing), and concealed
    effects of the suite in the same air: the 60 ms delay on longitudinal cyclic in light and in
    moderate turbulence, the pitch control power -30 % and the pitch damping -40 % in moderate
    turbulence (a control derivative leaves the gust response as it is, a stability derivative
    changes it)."""
    delay = {"effect": "time_delay", "input": "theta_1s", "value": 0.06}
    damping = {"effect": "stability_derivative", "term": "M_q", "value": reference.model_value("M_q") * 0.6}
    power = {"effect": "control_derivative", "term": "M_theta_1s", "value": reference.model_value("M_theta_1s") * 0.7}
    cases = [ConcealedCase(f"turbulence-{level}", "turbulence", turbulence=level,
                           description=f"the reference itself in {level} Dryden turbulence, with sensor noise")
             for level in ("light", "moderate")]
    for level in ("light", "moderate"):
        cases.append(ConcealedCase(f"delay-theta_1s-60ms-{level}-turbulence", "single", (delay,), turbulence=level,
                                   description=f"transport delay 60 ms on longitudinal cyclic in {level} turbulence"))
    cases.append(ConcealedCase("M_theta_1s-30%-moderate-turbulence", "single", (power,), turbulence="moderate",
                               description=f"M_theta_1s (-30 %): {reference.model_value('M_theta_1s'):.4g} -> "
                                           f"{power['value']:.4g} in moderate turbulence"))
    cases.append(ConcealedCase("M_q-40%-moderate-turbulence", "single", (damping,), turbulence="moderate",
                               description=f"M_q (-40 %): {reference.model_value('M_q'):.4g} -> "
                                           f"{damping['value']:.4g} in moderate turbulence"))
    return cases


def _measurement_chain_cases(noise: dict) -> list[ConcealedCase]:
    """The Bo105's measurement-chain cases, each effect on the pitch-rate gyro at two values: a
    sensor lag of 50 and 150 ms (a filter that moves ``q`` alone, not the attitude or the
    velocities an input lag on longitudinal cyclic would), a scale factor of 1.1 and 0.9, a bias
    drifting to 3 and 6 noise standard deviations over :data:`DURATION` s, and a cross-axis
    sensitivity to the roll rate of 0.02 and 0.05 (a gyro misaligned by 1.1 and 2.9 deg)."""
    single = _single_case
    cases = []
    for value in (0.05, 0.15):
        cases.append(single({"effect": "sensor_lag", "output": "q", "value": value},
                            f"sensor-lag-q-{round(value * 1000)}ms",
                            f"pitch-rate gyro lagging by {round(value * 1000)} ms (first-order filter)"))
    for value in (1.1, 0.9):
        cases.append(single({"effect": "output_scale", "output": "q", "value": value}, f"scale-q-{value:g}",
                            f"pitch-rate gyro scale factor {value:g}"))
    for multiple in (3, 6):
        rate = multiple * noise["q"] / DURATION
        cases.append(single({"effect": "sensor_drift", "output": "q", "value": rate}, f"drift-q-{multiple}sd",
                            f"pitch-rate gyro bias drifting by {rate:.3g} rad/s per s ({multiple}x noise "
                            f"after {DURATION:g} s)"))
    for value in (0.02, 0.05):
        cases.append(single({"effect": "sensor_cross_axis", "output": "q_from_p", "value": value},
                            f"cross-axis-q_from_p-{value:g}",
                            f"pitch-rate gyro seeing {value:g} of the roll rate (misaligned by "
                            f"{math.degrees(math.asin(value)):.1f} deg)"))
    return cases


def fmu_cases(*, reference: EffectModel) -> list[ConcealedCase]:
    """The suite of an FMU reference (``--reference FILE.fmu``): effects on the FMU's own inputs
    and outputs, whatever the vehicle: a 100 ms delay on its first input, a 150 ms lag on its
    second, a rate-sensor bias of 5x the noise on its first output among ``q``, ``p``, ``r``
    (else its first output), and none. On a JSBSim fixed-wing FMU (inputs ``elevator``,
    ``aileron``, ``rudder``) that is an elevator delay, an aileron lag and a pitch-rate bias."""
    inputs, noise = reference.input_names, reference.sensor_noise_sd
    rate = next((n for n in ("q", "p", "r") if n in reference.state_names), reference.state_names[0])
    cases = [_single_case({"effect": "time_delay", "input": inputs[0], "value": 0.1}, f"delay-{inputs[0]}-100ms",
                          f"transport delay 100 ms on {inputs[0]}")]
    if len(inputs) > 1:
        cases.append(_single_case({"effect": "input_lag", "input": inputs[1], "value": 0.15},
                                  f"lag-{inputs[1]}-150ms", f"first-order lag 150 ms on {inputs[1]}"))
    cases += [_single_case({"effect": "sensor_bias", "output": rate, "value": 5 * noise[rate]}, f"bias-{rate}-5sd",
                           f"{rate} sensor bias {5 * noise[rate]:g} (5x noise)"),
              ConcealedCase("none", "none", description="the reference itself, with sensor noise")]
    return cases


#: The concealed-effect suite of each family of references
#: (:attr:`validation.vehicles.effects.EffectModel.family`), called with the reference's effect model.
SUITES = {"bo105": bo105_cases, "blimp": blimp_cases, "fmu": fmu_cases}


def diagnosed_truth(case: ConcealedCase, model: EffectModel, *, flown_on: EffectModel | None = None) -> ConcealedCase:
    """``case`` as a diagnosis through ``model`` names it, when the recordings are flown on
    another reference (``diagnose-bench --through``): a derivative is an FMU's parameter of the
    same name (:class:`~validation.vehicles.fmu_reference.FMUEffects`), and a dead band outside
    the flying reference's list is a named ``dead_band`` where ``model`` takes one. An effect
    ``model`` cannot name makes the case an ``outside`` one where its recordings are flown apart
    from its effects (the RK4-flown quadratic damping through an FMU), else a BadInputError; a
    polynomial term flown on a linear reference (``flown_on``) through an FMU that takes search
    terms on its inputs is a ``through_inputs`` case (module docstring)."""
    if (case.outside is not None and case.outside[0] == "polynomial_term" and "search_term" in model.kinds
            and model.family == "fmu" and hasattr(getattr(flown_on, "reference", None), "row_letters")):
        return replace(case, kind="through_inputs", effects=(),
                       description=f"{case.description} (through the inputs of {model.name})")
    effects = []
    for effect in case.effects:
        kind = effect["effect"]
        if kind not in model.kinds and "term" in effect and effect["term"] in model.terms.get("fmu_parameter", ()):
            effect = {"effect": "fmu_parameter", "term": effect["term"], "value": effect["value"]}
        elif kind not in model.kinds or not _takes_target(model, kind, effect[TARGET_KEYS[kind]]):
            if case.outside is not None:  # flown apart from the effects: outside this model's list
                return replace(case, kind="outside", effects=(),
                               description=f"{case.description} (not a named effect of {model.name})")
            raise BadInputError(f"case {case.name}: {model.name} cannot name {kind} "
                                f"{effect[TARGET_KEYS[kind]]}")
        effects.append(effect)
    if case.outside and case.outside[0] == "dead_band" and "dead_band" in model.kinds:
        effect = {"effect": "dead_band", "input": case.outside[1], "value": case.outside[2]}
        return replace(case, kind="single", effects=(effect,), outside=None,
                       description=case.description.replace(" (not a named effect)", ""))
    return replace(case, effects=tuple(effects))


def _takes_target(model: EffectModel, kind: str, target: str) -> bool:
    """Whether ``model`` takes an effect of ``kind`` on ``target`` (a cross-axis target names two
    of its states, :func:`validation.vehicles.effects.split_cross_axis`)."""
    key = TARGET_KEYS[kind]
    if kind == "sensor_cross_axis":
        return split_cross_axis(target, model.state_names) is not None
    return target in (model.terms[kind] if key == "term" else
                      (model.input_names if key == "input" else model.state_names))


def concealed_cases(*, reference: str = "bo105-80kt") -> list[ConcealedCase]:
    """The benchmark suite for the reference called ``reference`` (:data:`SUITES`): the Bo105
    suite for every ``bo105-<V>kt``, :func:`blimp_cases` for ``blimp``.

    Raises
    ------
    BadInputError
        A reference that takes no effects (:func:`validation.vehicles.effect_vehicle.effect_model`)
        or whose family has no suite.
    """
    reference = effect_model(reference, purpose="diagnose-bench")
    suite = SUITES.get(reference.family)
    if suite is None:
        raise BadInputError(f"diagnose-bench has no concealed-effect suite for {reference.name!r}; suites "
                            f"exist for the {', '.join(SUITES)} references")
    return suite(reference=reference)


@dataclass(frozen=True)
class CaseRecordings:
    """The recordings of one case (:func:`case_recordings`).

    Attributes
    ----------
    fit, holdout : Recording
        The diagnosed recording (identification manoeuvre variant 0) and the held-out one
        (variant 1), with sensor noise.
    truth_states : ndarray, shape (n, n_states)
        Noise-free states of the held-out flight with the concealed physics (for scoring), in
        the reference's state units and order.
    """

    fit: Recording
    holdout: Recording
    truth_states: np.ndarray


#: Height above ground the turbulence cases are flown at, m (500 ft: the low-altitude Dryden
#: model's, :func:`validation.vehicles.turbulence.low_altitude_turbulence`; at it ``L_w = 152 m``,
#: ``L_u = L_v = 288 m``, ``sigma_u = sigma_v = 1.24 sigma_w``).
TURBULENCE_ALTITUDE = 152.4


def case_gusts(case: ConcealedCase, reference: EffectModel, time: np.ndarray, *, seed: int,
               variant: int) -> np.ndarray:
    """Dryden gust velocities (n, 3), m/s, for one recording of a turbulence case: the
    low-altitude model at :data:`TURBULENCE_ALTITUDE` and the case's intensity (light: ``W_20 =
    15 kt``, ``sigma_w = 0.77 m/s``; moderate: 30 kt, 1.54 m/s;
    :func:`validation.vehicles.turbulence.low_altitude_turbulence`), flown through at the Bo105
    reference's trim speed (at least the stand-in's 5 m/s in hover), one gust per sample held
    over its interval, drawn from their own stream (seeded by the run's seed, the recording and
    the case's name) so that the sensor noise is the same draw as without turbulence."""
    speed = getattr(getattr(reference, "reference", None), "speed_kt", None)
    if speed is None:
        raise BadInputError(f"case {case.name}: turbulence is flown on the Bo105 references only, not on "
                            f"{reference.name}")
    sigma, length = low_altitude_turbulence(case.turbulence, altitude_m=TURBULENCE_ALTITUDE)
    rng = np.random.default_rng([seed, variant, zlib.crc32(case.name.encode()), 1])
    step = float(time[1] - time[0])
    return dryden_gusts(sigma, length, max(speed * KNOT, TURBULENCE_MIN_ADVECTION_SPEED), step, len(time), rng)


def case_recordings(case: ConcealedCase, *, reference: str = "bo105-80kt", seed: int = 0,
                    duration: float = DURATION, sample_time: float | None = None) -> CaseRecordings:
    """The diagnosed and the held-out recording of ``case`` on the reference called
    ``reference`` (``duration`` s each, sampled every ``sample_time`` s, by default the
    reference's sample time), and the held-out truth (module docstring). A case with
    ``turbulence`` is flown in the gusts of :func:`case_gusts`; its held-out truth is the flight
    without them (what a model can predict)."""
    reference = effect_model(reference, purpose="diagnose-bench")
    sample_time = reference.sample_time if sample_time is None else sample_time
    vehicle = EffectVehicle(reference, case.effects, noise_sd=reference.sensor_noise_sd)
    recordings = []
    for variant in (case.fit_variant, 1):
        time, inputs = reference.identification_manoeuvre(duration=duration, sample_time=sample_time,
                                                          variant=variant)
        if case.outside is None:
            states = vehicle.simulate_states(time, inputs)
        else:
            states = _outside_states(case.outside, vehicle, time, inputs)
        truth = states
        if case.turbulence:
            if case.outside is not None:
                raise BadInputError(f"case {case.name}: turbulence is flown with named effects only")
            gusts = case_gusts(case, reference, time, seed=seed, variant=variant)
            states = simulate_linear_with_effects(reference.reference, vehicle.effects, time, inputs, gusts=gusts)
        # Each case draws its own noise (seeded by its name), so the cases of one run are
        # independent trials of diagnose rather than one noise draw seen through many effects.
        rng = np.random.default_rng([seed, variant, zlib.crc32(case.name.encode())])
        noise = np.array([reference.sensor_noise_sd[name] for name in vehicle.state_names])
        measured = states + rng.standard_normal(states.shape) * noise
        metadata = {"vehicle": reference.name, "simulator": f"diagnose-bench case {case.name}",
                    "sample_time": sample_time, "seed": seed,
                    "sensor_noise_std": dict(reference.sensor_noise_sd)}
        recordings.append((Recording(time, inputs, vehicle.input_names, measured, vehicle.state_names, metadata),
                           truth))
    (fit, _), (holdout, truth_states) = recordings
    return CaseRecordings(fit, holdout, truth_states)


#: Static command nonlinearities outside the named list, ``(command, parameter) -> effective
#: command``: a dead band of half-width ``w`` (the command loses ``w`` and nothing passes below
#: it; outside the list of references that take no dead band); thrust quadratic in the command,
#: ``u |u|`` (a fixed-pitch fan's thrust goes with its speed squared when the command sets the
#: speed; the parameter is unused).
COMMAND_MAPS = {
    "dead_band": lambda u, width: dead_band_inputs(u, width),
    "quadratic_thrust": lambda u, _: u * np.abs(u),
}


def _outside_states(outside: tuple, vehicle: EffectVehicle, time, inputs) -> np.ndarray:
    """Noise-free states of the reference with a change outside the named list."""
    kind = outside[0]
    if kind in COMMAND_MAPS:
        _, name, parameter = outside
        flown = inputs.copy()
        column = vehicle.input_names.index(name)
        flown[:, column] = COMMAND_MAPS[kind](flown[:, column], parameter)
        return vehicle.simulate_states(time, flown)
    if kind == "polynomial_term":
        return _polynomial_term_states(vehicle.reference_name, outside[1], outside[2], time, inputs)
    if kind == "drifting_derivative":
        return _drifting_derivative_states(vehicle.reference_name, *outside[1:], time, inputs)
    raise ValueError(f"unknown outside effect {kind!r}")


def _drifting_derivative_states(reference: str, term: str, start: float, end: float, time, inputs) -> np.ndarray:
    """``x_dot = A(t) x + B(t) u`` with derivative ``term`` moving linearly in time from ``start``
    at the first sample to ``end`` at the last (every other entry the reference's), integrated by
    classical RK4 at the recording interval with the inputs held over each interval (time is
    integrated as one more state, ``t_dot = 1``, so the steps are those of
    :func:`validation.vehicles.blimp_equations.rk4`). ``reference`` names a linear reference
    (``bo105-<V>kt``)."""
    linear = effect_model(reference, purpose="diagnose-bench").reference
    first, last = linear.with_derivatives({term: start}), linear.with_derivatives({term: end})
    span = float(time[-1] - time[0])

    def derivative(augmented, u):
        x, share = augmented[:-1], (augmented[-1] - time[0]) / span
        dx = ((1 - share) * first.A + share * last.A) @ x + ((1 - share) * first.B + share * last.B) @ u
        return np.append(dx, 1.0)

    step = float(time[1] - time[0])
    augmented = np.zeros((len(time), len(linear.state_names) + 1))
    augmented[0, -1] = time[0]
    for k in range(len(time) - 1):
        augmented[k + 1] = rk4(partial(derivative, u=inputs[k]), augmented[k], step)
    return augmented[:, :-1]


def _polynomial_term_states(reference: str, term: str, coefficient: float, time, inputs) -> np.ndarray:
    """``x_dot = A x + B u + e_row c f(x, u)`` with ``f`` the factor of polynomial ``term``
    (:mod:`validation.vehicles.polynomial_terms`: ``M_q|q|`` adds ``c q|q|`` to the pitch
    acceleration), integrated by classical RK4 at the recording interval with the inputs held
    over each interval. ``reference`` names a linear reference (``bo105-<V>kt``)."""
    linear = effect_model(reference, purpose="diagnose-bench").reference
    names = linear.state_names + linear.input_names
    parsed = parse_term(term, linear.row_letters, names)
    if parsed is None:
        raise ValueError(f"{term!r} is not a polynomial term of {reference}")
    row = linear.state_names.index(linear.row_letters[parsed.letter])
    A, B = linear.A, linear.B

    def derivative(x, u):
        dx = A @ x + B @ u
        dx[row] += coefficient * factor_values([parsed], names, np.concatenate((x, u)))[0]
        return dx

    step = float(time[1] - time[0])
    states = np.zeros((len(time), len(linear.state_names)))
    for k in range(len(time) - 1):
        states[k + 1] = rk4(partial(derivative, u=inputs[k]), states[k], step)
    return states


#: Confidence above which a finding counts as certain: a false finding above it fails an
#: ``ambiguous`` case (the data cannot tell the truth from its alternative, so neither may be
#: stated as near-certain).
AMBIGUOUS_CONFIDENCE = 0.9
#: Confidence above which a false finding fails a ``turbulence`` case: in turbulence with nothing
#: missing, no finding may be stated with more confidence than its absence.
TURBULENCE_CONFIDENCE = 0.5
#: Relative error within which the search terms found through an FMU's inputs, mapped onto the
#: rows by the control derivatives, must give the truth's row to name it (a ``through_inputs`` case).
THROUGH_INPUTS_TOLERANCE = 0.1


@dataclass
class CaseScore:
    """The scorecard row of one case (module docstring)."""

    case: ConcealedCase
    found: list = field(default_factory=list)
    named: bool = False
    in_interval: bool = False
    affected_output: str | None = None
    rmse_reference: float | None = None
    rmse_corrected: float | None = None
    rmse_corrected_gp: float | None = None
    false_findings: list = field(default_factory=list)
    says_unexplained: bool = False
    seconds: float = 0.0
    certain_false: list = field(default_factory=list)
    offered: set = field(default_factory=set)
    changing: list = field(default_factory=list)
    drift_direction_right: bool = False
    says_turbulence: bool = False
    confident_false: list = field(default_factory=list)

    @property
    def cut(self) -> float | None:
        if self.rmse_reference is None or not self.rmse_reference > 0:
            return None
        return 1.0 - self.rmse_corrected / self.rmse_reference

    @property
    def passed(self) -> bool:
        kind = self.case.kind
        if kind == "none":
            return not self.found
        if kind == "turbulence":  # nothing stated with confidence, and the air named
            return self.says_turbulence and not self.confident_false
        if kind == "outside":
            return self.says_unexplained
        if kind == "through_inputs":  # the mapped term named, nothing else, the flight cut
            return self.named and not self.false_findings and self.cut is not None and self.cut >= REQUIRED_CUT
        if kind == "ambiguous":  # the truth named or offered as an alternative, nothing false certain
            return not self.certain_false and self.offered == {_target(e) for e in self.case.effects}
        if kind == "changing":  # named, said to drift the right way; its average value may miss
            return self.named and self.drift_direction_right and not self.false_findings
        return (self.named and self.in_interval and not self.false_findings
                and self.cut is not None and self.cut >= REQUIRED_CUT)

    def as_dict(self) -> dict:
        return {"case": self.case.name, "kind": self.case.kind, "description": self.case.description,
                "truth": list(self.case.effects), "outside": list(self.case.outside or ()),
                "found": self.found, "named": self.named, "in_interval": self.in_interval,
                "affected_output": self.affected_output, "rmse_reference": self.rmse_reference,
                "rmse_corrected": self.rmse_corrected, "rmse_corrected_gp": self.rmse_corrected_gp,
                "cut": self.cut, "false_findings": self.false_findings,
                "says_unexplained": self.says_unexplained, "seconds": self.seconds,
                "certain_false": self.certain_false, "offered": sorted(" ".join(key) for key in self.offered),
                "changing": self.changing, "drift_direction_right": self.drift_direction_right,
                "turbulence": self.case.turbulence, "says_turbulence": self.says_turbulence,
                "confident_false": self.confident_false, "passed": self.passed}


def _target(effect: dict) -> tuple:
    kind = effect["effect"]
    return kind, effect.get(TARGET_KEYS.get(kind, "output"))


def score_case(case: ConcealedCase, diagnosis: dict, *, truth_states: np.ndarray, holdout: Recording,
               reference: str, seconds: float, diagnosed_on: str | None = None) -> CaseScore:
    """Score one diagnosis against the case's truth (module docstring).

    Parameters
    ----------
    case : ConcealedCase
    diagnosis : dict
        ``Diagnosis.as_dict()`` of the case's fit recording.
    truth_states : ndarray, shape (n, n_states)
        :attr:`CaseRecordings.truth_states`.
    holdout : Recording
        :attr:`CaseRecordings.holdout`.
    reference : str
        The registry name of the reference the case was flown on.
    seconds : float
        Wall-clock seconds of the diagnosis.
    diagnosed_on : str, optional
        The reference the diagnosis ran on when not ``reference`` (``--through``): its findings
        are flown on it.
    """
    findings = diagnosis["findings"]
    score = CaseScore(case, seconds=seconds)
    score.found = [{"effect": f["effect"], **{key: f[key] for key in ("input", "term", "output") if key in f},
                    "value": f.get("value"), "interval": f.get("interval")} for f in findings]
    score.says_unexplained = any(f["effect"] == "unexplained" for f in findings)
    named = [f for f in findings if f["effect"] != "unexplained"]
    truth = {_target(effect): effect for effect in case.effects}
    flown_on = effect_model(reference, purpose="diagnose-bench")
    if case.kind == "through_inputs":
        mapped, score.named, score.in_interval = _mapped_through_inputs(named, case.outside, flown_on.reference)
        truth = {_target(f): f for f in mapped}
    matched = {}
    for finding in named:
        key = _target(finding)
        if key in truth:
            matched[key] = finding
        else:
            score.false_findings.append(f"{key[0]} {key[1]}")
            if finding.get("confidence", 1.0) > AMBIGUOUS_CONFIDENCE:
                score.certain_false.append(f"{key[0]} {key[1]}")
        if key not in truth and finding.get("confidence", 1.0) > TURBULENCE_CONFIDENCE:
            score.confident_false.append(f"{key[0]} {key[1]}")
        offered = [_target(alternative) for alternative in finding.get("alternatives") or []]
        score.offered.update(key for key in [_target(finding)] + offered if key in truth)
    score.says_turbulence = bool((diagnosis.get("disturbance") or {}).get("looks_like_turbulence"))
    if case.kind not in ("outside", "ambiguous", "changing"):
        # An unexplained residual next to the true effects is a false finding too (not next to
        # a drift, which the constant correction leaves partly unexplained).
        score.false_findings += [f"unexplained {f['output']}" for f in findings if f["effect"] == "unexplained"]
    score.changing = [" ".join(_target(f)) for f in named if (f.get("time_check") or {}).get("changes")]
    if case.kind == "changing":
        _, _, start, end = case.outside
        check = (matched.get(_target(case.effects[0])) or {}).get("time_check") or {}
        score.drift_direction_right = bool(check.get("drifts") and (check["drift_end"] - check["drift_start"])
                                           * (end - start) > 0)
    elif case.kind in ("single", "pair"):
        # Constant physics said to change during the flight is a false finding.
        score.false_findings += [f"changing {key}" for key in score.changing]
    if truth and case.kind != "through_inputs":
        score.named = set(matched) == set(truth)
        score.in_interval = score.named and all(
            f.get("interval") is not None and f["interval"][0] <= truth[key]["value"] <= f["interval"][1]
            for key, f in matched.items())
    # The affected output: the one the concealed physics moves most, relative to its noise.
    reference = flown_on
    replay = reference.simulate_many([[]], holdout.time, holdout.inputs)[0]
    noise_sd, names = reference.sensor_noise_sd, reference.state_names
    outputs = diagnosis["fit"]["outputs"]
    if case.kind not in ("none", "turbulence"):
        energy = [np.sum(((truth_states[:, names.index(n)] - replay[:, names.index(n)])
                          / noise_sd[n]) ** 2) for n in outputs]
        name = outputs[int(np.argmax(energy))]
        score.affected_output = name
        fit = diagnosis["fit"]
        score.rmse_reference = fit["rmse_reference"][name]
        score.rmse_corrected = fit["rmse_corrected"][name]
        score.rmse_corrected_gp = fit["rmse_corrected_gp"][name]
        if case.turbulence:
            # No model predicts the gusts of the held-out flight: the RMSEs are against its
            # noise-free flight without them (truth_states), of the reference and of the
            # corrected model (the findings it holds), and there is no GP's.
            column = names.index(name)
            corrected = [{"effect": f["effect"], TARGET_KEYS[f["effect"]]: _target(f)[1], "value": f["value"]}
                         for f in named if f.get("in_corrected_model")]
            flown = EffectVehicle(diagnosed_on or reference, corrected).simulate_states(holdout.time, holdout.inputs)
            rms = lambda error: float(np.sqrt(np.mean(error ** 2)))  # noqa: E731
            score.rmse_reference = rms(truth_states[:, column] - replay[:, column])
            score.rmse_corrected = rms(truth_states[:, column] - flown[:, column])
            score.rmse_corrected_gp = None
    return score


def _mapped_through_inputs(findings: list, outside: tuple, linear) -> tuple[list, bool, bool]:
    """The search terms among ``findings`` that carry the truth ``outside`` (``("polynomial_term",
    term, coefficient)``) through a linear reference's inputs: of its factor, on an input
    (``<input>_<factor>``, :func:`~validation.vehicles.fmu_reference.input_row`) whose control
    derivative on the truth's row is not zero; whether, mapped onto the row by those derivatives,
    they give the truth within :data:`THROUGH_INPUTS_TOLERANCE`; and whether the interval their
    intervals map to holds it."""
    term, coefficient = outside[1], outside[2]
    letter, _, factor = term.partition("_")
    row = linear.B[linear.state_names.index(linear.row_letters[letter])]
    on_row = {input_row(name): row[j] for j, name in enumerate(linear.input_names) if row[j] != 0}
    found = [f for f in findings if f["effect"] == "search_term" and f["term"].partition("_")[2] == factor
             and f["term"].partition("_")[0] in on_row]
    if not found:
        return [], False, False
    derivatives = np.array([on_row[f["term"].partition("_")[0]] for f in found])
    value = float(derivatives @ [f["value"] for f in found])
    ends = np.array([f["interval"] for f in found]) * derivatives[:, None]
    low, high = float(np.sum(ends.min(axis=1))), float(np.sum(ends.max(axis=1)))
    return found, abs(value - coefficient) <= THROUGH_INPUTS_TOLERANCE * abs(coefficient), low <= coefficient <= high


def run_case(case: ConcealedCase, *, reference: str = "bo105-80kt", through: str | None = None, seed: int = 0,
             duration: float = DURATION, workers: int | None = None, input_terms: bool = False) -> CaseScore:
    """Fly, diagnose and score one case.

    Parameters
    ----------
    case : ConcealedCase
    reference : str
        The reference the case is flown on: ``bo105-<V>kt``, ``blimp`` or an FMU file.
    through : str, optional
        Diagnose through this reference instead (an FMU or a state-space JSON of the same
        vehicle, named like ``reference``'s variables); the truth is the case as it names it
        (:func:`diagnosed_truth`). Default: ``reference`` itself.
    seed : int
        Sensor-noise seed (the held-out recording uses its own stream) and the diagnosis seed.
    duration : float
        Length of each recording, s.
    workers : int, optional
        Replay processes of an FMU reference (:func:`validation.diagnose.diagnose`).
    input_terms : bool
        Through an FMU, let the search add terms through its inputs (:func:`validation.diagnose.diagnose`).
    """
    recordings = case_recordings(case, reference=reference, seed=seed, duration=duration)
    truth = case
    if through:
        model = effect_model(through, purpose="diagnose-bench")
        if input_terms:
            take_input_terms(model)
        truth = diagnosed_truth(case, model, flown_on=effect_model(reference, purpose="diagnose-bench"))
    start = clock.perf_counter()
    diagnosis = diagnose([recordings.fit], reference=through or reference, holdout=[recordings.holdout], seed=seed,
                         workers=workers, input_terms=input_terms).as_dict()
    seconds = clock.perf_counter() - start
    return score_case(truth, diagnosis, truth_states=recordings.truth_states, holdout=recordings.holdout,
                      reference=reference, seconds=seconds, diagnosed_on=through)


def bench_report(rows, *, reference: str, through: str | None, seed: int, duration: float) -> dict:
    """The scorecard report (JSON-ready) of one seed's scored cases.

    Parameters
    ----------
    rows : sequence of dict
        ``CaseScore.as_dict()`` of each case, in the suite's order.
    reference, through, seed, duration
        As :func:`run_case` ran them.
    """
    rows = list(rows)
    return {"reference": reference, "through": through, "seed": seed, "duration_s": duration,
            "sample_time_s": effect_model(reference, purpose="diagnose-bench").sample_time,
            "required_cut": REQUIRED_CUT, "cases": rows,
            "passed": sum(row["passed"] for row in rows), "total": len(rows),
            "max_seconds": max((row["seconds"] for row in rows), default=0.0)}


def run_bench(cases, *, reference: str = "bo105-80kt", through: str | None = None, seed: int = 0,
              duration: float = DURATION, workers: int | None = None, input_terms: bool = False,
              progress=None) -> dict:
    """:func:`run_case` of every case, one after the other; returns the scorecard report
    (:func:`bench_report`). ``progress``, optional, is called as ``progress(1, case=name)`` after
    each case; the other parameters are :func:`run_case`'s."""
    rows = []
    for case in cases:
        rows.append(run_case(case, reference=reference, through=through, seed=seed, duration=duration,
                             workers=workers, input_terms=input_terms).as_dict())
        if progress:
            progress(1, case=case.name)
    return bench_report(rows, reference=reference, through=through, seed=seed, duration=duration)


def format_scorecard(report: dict) -> str:
    """The scorecard as a plain-text table."""
    width = max([26, *(len(row["case"]) for row in report["cases"])])
    through = f" through {report['through']}" if report.get("through") else ""
    lines = [f"diagnose-bench on {report['reference']}{through} ({report['duration_s']:g} s at "
             f"{1 / report['sample_time_s']:g} Hz, seed {report['seed']}): {report['passed']} of "
             f"{report['total']} cases pass",
             f"{'case':<{width}} {'named':>5} {'in CI':>5} {'output':>6} {'ref RMSE':>9} {'corr.':>9} "
             f"{'cut':>5} {'false':>5} {'s':>5}  verdict / found"]
    for row in report["cases"]:
        cut = "-" if row["cut"] is None else f"{row['cut']:.0%}"
        found = ", ".join(f"{f['effect']} {f.get('input') or f.get('term') or f.get('output')}"
                          for f in row["found"]) or "consistent"
        if row.get("says_turbulence"):
            found += " (the residual looks like atmospheric disturbance)"
        yes = lambda flag: "yes" if flag else "no"  # noqa: E731
        shown = row["truth"] or row["kind"] == "through_inputs"
        named = yes(row["named"]) if shown else "-"
        in_ci = yes(row["in_interval"]) if shown else "-"
        number = lambda v: "-" if v is None else f"{v:.4f}"  # noqa: E731
        lines.append(f"{row['case']:<{width}} {named:>5} {in_ci:>5} {row['affected_output'] or '-':>6} "
                     f"{number(row['rmse_reference']):>9} {number(row['rmse_corrected']):>9} {cut:>5} "
                     f"{len(row['false_findings']):>5} {row['seconds']:>5.1f}  "
                     f"{'PASS' if row['passed'] else 'FAIL'}: {found}")
    return "\n".join(lines)


def summarise_seeds(reports: list) -> dict:
    """Per-case rates over runs of :func:`run_bench` with different seeds (JSON-ready).

    A single seed shows one noise draw; 95 % intervals miss the truth in about one case in
    twenty and a family-wise 1 % test raises a false finding about once in a hundred steps, so
    the rates over several seeds are the measure. Per case: ``runs``, ``passed``, ``named``
    (every true effect named), ``in_interval`` (named with every true value inside its
    interval), ``with_false_findings``, ``says_unexplained``, ``says_turbulence`` (the residual
    said to look like atmospheric disturbance), ``with_confident_false`` (a false finding above
    :data:`TURBULENCE_CONFIDENCE`), the median ``cut`` and the largest ``seconds``.
    """
    names = [row["case"] for row in reports[0]["cases"]]
    cases = []
    for name in names:
        rows = [row for report in reports for row in report["cases"] if row["case"] == name]
        cuts = [row["cut"] for row in rows if row["cut"] is not None]
        cases.append({"case": name, "kind": rows[0]["kind"], "runs": len(rows),
                      "passed": sum(row["passed"] for row in rows),
                      "named": sum(row["named"] for row in rows),
                      "in_interval": sum(row["in_interval"] for row in rows),
                      "with_false_findings": sum(bool(row["false_findings"]) for row in rows),
                      "says_unexplained": sum(row["says_unexplained"] for row in rows),
                      "says_turbulence": sum(bool(row.get("says_turbulence")) for row in rows),
                      "with_confident_false": sum(bool(row.get("confident_false")) for row in rows),
                      "median_cut": float(np.median(cuts)) if cuts else None,
                      "max_seconds": max(row["seconds"] for row in rows)})
    named_runs = [c for c in cases if c["kind"] in ("single", "pair")]
    return {"reference": reports[0]["reference"], "through": reports[0].get("through"),
            "seeds": [report["seed"] for report in reports],
            "cases": cases, "passed": sum(c["passed"] for c in cases),
            "total": sum(c["runs"] for c in cases),
            "interval_coverage": (sum(c["in_interval"] for c in named_runs)
                                  / max(sum(c["named"] for c in named_runs), 1)),
            "max_seconds": max(c["max_seconds"] for c in cases)}


def format_seed_summary(summary: dict) -> str:
    """:func:`summarise_seeds` as a plain-text table (counts out of the runs per case)."""
    width = max([26, *(len(c["case"]) for c in summary["cases"])])
    seeds = summary["seeds"]
    through = f" through {summary['through']}" if summary.get("through") else ""
    lines = [f"diagnose-bench on {summary['reference']}{through} over seeds {', '.join(map(str, seeds))}: "
             f"{summary['passed']} of {summary['total']} runs pass; true value inside the interval "
             f"in {summary['interval_coverage']:.0%} of the runs that name the effects",
             f"{'case':<{width}} {'pass':>5} {'named':>5} {'in CI':>5} {'false':>5} {'unexp.':>6} "
             f"{'cut':>5} {'max s':>6}"]
    for c in summary["cases"]:
        count = {key: f"{c[key]}/{c['runs']}" for key in ("passed", "named", "in_interval",
                                                          "with_false_findings", "says_unexplained")}
        cut = "-" if c["median_cut"] is None else f"{c['median_cut']:.0%}"
        named = count["named"] if c["kind"] in ("single", "pair", "through_inputs") else "-"
        in_ci = count["in_interval"] if c["kind"] in ("single", "pair", "through_inputs") else "-"
        lines.append(f"{c['case']:<{width}} {count['passed']:>5} {named:>5} {in_ci:>5} "
                     f"{count['with_false_findings']:>5} {count['says_unexplained']:>6} {cut:>5} "
                     f"{c['max_seconds']:>6.1f}")
    return "\n".join(lines)
