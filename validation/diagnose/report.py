"""Report: the diagnosis assembled (:class:`Diagnosis`, exactly diagnosis.json), its
plain-language statements, ``report.md`` with its plots, and the files a diagnosis writes
(docs/diagnose.md)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from validation.core.files import check_output_folder, json_text, write_files_atomically
from validation.core.plots import png_bytes
from validation.core.recordings import column_phrase, column_unit
from validation.diagnose.carry_over import LEFT_OUT, CarryOver, HeldOutEffect
from validation.diagnose.data import PreparedData
from validation.diagnose.explain import Explanation, NamedEffect
from validation.diagnose.fitting import FAMILY_ALPHA
from validation.diagnose.locate import Location
from validation.diagnose.model import Models
from validation.diagnose.prove import MODEL_KEYS, Proof
from validation.diagnose.replicate import Replication
from validation.diagnose.scope import Scope
from validation.vehicles.effect_vehicle import EffectVehicle
from validation.vehicles.effects import TARGET_KEYS, EffectModel, split_cross_axis

#: Why a named nonlinear term is physics no linear derivative holds, closing its statement. A
#: stiffness term may also be a cube of a rate (any state its row depends on), so its words speak
#: of the excursion, not of a restoring force.
_NONLINEAR_WHY = {
    "nonlinear_stiffness": "It grows with the cube of the excursion, so the response hardens or softens with "
                           "its size, which no linear derivative can follow.",
    "nonlinear_damping": "The damping grows with the rate's size, so the large excursions are damped more than "
                         "any linear derivative can damp them.",
    "quadratic_stiffness": "It grows with the square of the excursion, keeping its sign, so the response stiffens "
                           "or softens with its size, which no linear derivative can follow.",
}
#: The term effect kinds of the contract (:data:`validation.vehicles.effects.TARGET_KEYS`) in words,
#: where the name with spaces would not do.
_KIND_WORDS = {"quadratic_drag": "quadratic drag derivative", "cg_offset": "centre-of-gravity position",
               "added_mass": "added-mass term", "fmu_parameter": "parameter", "draught_field": "draught-field term",
               "gondola_offset": "gondola position offset"}
_MODEL_LABELS = {"reference": "reference", "corrected": "corrected", "corrected_gp": "corrected + GP"}
#: Share of a named effect's signal that a GP on the uncorrected residual must reproduce for the
#: report to warn that a residual GP alone would hide the effect (half: it would carry more of
#: the effect than it leaves).
HIDDEN_BY_GP = 0.5


@dataclass
class Diagnosis:
    """Result of :func:`validation.diagnose.pipeline.diagnose`.

    ``as_dict()`` is exactly ``diagnosis.json`` (docs/diagnose.md, "diagnosis.json"): ``reference``, ``verdict``,
    ``mismatch``, ``findings``, ``fit``, plus ``locate`` (noise, bands, coherence), ``untestable``,
    ``ignored_columns`` (recording columns none of the reference's variables, left out),
    ``search`` (what was tested and the last rejected hypothesis) and ``disturbance`` (whether
    the residual looks like atmospheric turbulence, :func:`disturbance_statement`), and ``replication`` (the
    folds' findings) when the search was replicated. The other attributes feed the report and the
    corrected-model file.

    Attributes
    ----------
    reference : str
    verdict : {"missing_physics", "consistent"}
    findings : list of dict
        Ranked, most important first; empty when ``verdict == "consistent"``.
    corrected : EffectVehicle
        The reference with the named effects that carry over and are shared (the model file
        :func:`write_diagnosis` saves).
    named_effects : list of dict
        Every named effect, in the order found (those of ``corrected`` among them).
    holdout_traces : dict of str -> dict
        Per output: ``time``, ``measured``, ``reference``, ``corrected``, ``corrected_gp``
        (ndarrays over the held-out samples, recordings concatenated) for the plots.
    """

    reference: str
    verdict: str
    mismatch: list
    findings: list
    fit: dict
    locate: dict
    untestable: list
    search: dict
    corrected: EffectVehicle
    named_effects: list = field(default_factory=list)
    holdout_traces: dict = field(repr=False, default_factory=dict)
    replication: dict | None = None
    fidelity: dict | None = None
    ignored_columns: list = field(default_factory=list)
    disturbance: dict | None = None

    def as_dict(self) -> dict:
        result = {"reference": self.reference, "verdict": self.verdict, "mismatch": self.mismatch,
                  "findings": self.findings, "fit": self.fit, "locate": self.locate,
                  "untestable": self.untestable, "ignored_columns": self.ignored_columns, "search": self.search,
                  "disturbance": self.disturbance}
        if self.fidelity is not None:
            result["fidelity"] = self.fidelity
        if self.replication is not None:
            result["replication"] = self.replication
        return result


def assemble_diagnosis(reference: EffectModel, data: PreparedData, location: Location,
                       explanation: Explanation, models: Models, proof: Proof, *, scopes: Scope,
                       carried: CarryOver, replication: Replication | None = None,
                       fidelity: dict | None = None) -> Diagnosis:
    """The diagnosis of the stages' results (nothing is written: :func:`write_diagnosis` does
    that): one finding per named effect (most important first, each with its scope, its
    carry-over and its ``replication`` when the search was replicated), then the
    ``unexplained`` ones of the model and the prove stage, each with its :func:`statement`."""
    findings = [_named_finding(named, data.output_names[named.main_output], held_out, absorbs, gp_rmse,
                               scope=scopes.of(named.effect), left_out=left_out)
                for named, held_out, absorbs, gp_rmse, left_out in zip(
                    explanation.named, carried.effects, models.gp_absorbs, proof.rmse_reference_gp, carried.left_out)]
    if replication is not None:
        for finding in findings:
            finding["replication"] = replication.of(finding)
    disturbance = dict(explanation.disturbance) if explanation.disturbance else None
    unexplained = models.unexplained
    if disturbance is not None and disturbance["looks_like_turbulence"]:
        # The air accounts for the fitted residual: it is not unexplained.
        disturbance["accounts_for"] = [f["output"] for f in unexplained]
        unexplained = []
    if disturbance is not None:
        disturbance["statement"] = disturbance_statement(disturbance, n_named=len(explanation.named))
    findings += unexplained + proof.unexplained
    fitted = [m for m, held in zip(data.measured, data.held_out) if not held]
    extent = {name: (float(min(m[:, i].min() for m in fitted)), float(max(m[:, i].max() for m in fitted)))
              for i, name in enumerate(data.output_names)} if fitted else {}
    for finding in findings:
        finding["statement"] = statement(finding, proof.fit, reference, extent=extent)
    return Diagnosis(reference=reference.name,
                     verdict="missing_physics" if findings else "consistent", mismatch=location.mismatch,
                     findings=findings, fit=proof.fit, locate=location.summary,
                     untestable=data.untestable + proof.untestable, search=explanation.search,
                     corrected=models.corrected, named_effects=explanation.effects, holdout_traces=proof.traces,
                     replication=replication.summary() if replication is not None else None, fidelity=fidelity,
                     ignored_columns=data.ignored_columns, disturbance=disturbance)


def disturbance_statement(disturbance: dict, *, n_named: int) -> str | None:
    """The plain-words sentence of diagnosis.json's ``disturbance``
    (:func:`validation.diagnose.disturbance.describe`): None where it was not tested."""
    if not disturbance["tested"]:
        return None
    if not disturbance["looks_like_turbulence"]:
        if disturbance["time_constant"] is None:
            return "The residual shows no atmospheric disturbance: still air explains it as well as gusts do."
        if disturbance["input_p_value"] is not None and disturbance["input_p_value"] < FAMILY_ALPHA:
            return (f"Gusts of {_number(disturbance['intensity'])} m/s RMS would whiten the residual "
                    f"(likelihood ratio {disturbance['likelihood_ratio']:.3g} against still air), but what is left "
                    f"follows the inputs (p = {disturbance['input_p_value']:.2g}), which gusts do not: it does not "
                    "look like atmospheric disturbance.")
        return (f"Gusts of {_number(disturbance['intensity'])} m/s RMS would explain part of the residual "
                f"(likelihood ratio {disturbance['likelihood_ratio']:.3g} against still air), but not down to the "
                f"sensor noise (whitened innovations {disturbance['innovation_ratio']:.3g} times the noise): "
                "it does not look like atmospheric disturbance alone.")
    sigma = disturbance["sigma"]
    scale = (f", a scale length of {disturbance['scale_length']:.0f} m" if disturbance["scale_length"] is not None
             else "")
    named = ("No effect is named: every one output error would take was weighed against the air and lost."
             if n_named == 0 else
             f"The {n_named} named effect{'s' if n_named > 1 else ''} won against it.")
    return (f"The residual looks like atmospheric disturbance: the model's response to Dryden turbulence of "
            f"{_number(disturbance['intensity'])} m/s RMS (sigma_u {_number(sigma['u'])}, sigma_v "
            f"{_number(sigma['v'])}, sigma_w {_number(sigma['w'])} m/s; time constant "
            f"{disturbance['time_constant']:.3g} s{scale}) accounts for it down to "
            f"{disturbance['innovation_ratio']:.3g} times the sensor noise (likelihood ratio "
            f"{disturbance['likelihood_ratio']:.3g} against still air). {named}")


def _named_finding(named: NamedEffect, main_output: str, held_out: HeldOutEffect, gp_absorbs: float,
                   rmse_reference_gp: float, *, scope: dict | None, left_out: str | None) -> dict:
    """The diagnosis.json finding of a named effect (docs/diagnose.md, "findings"), keys in
    contract order. Its confidence is capped by its predictive weight on the held-out data when
    it does not carry over (:mod:`validation.diagnose.carry_over`)."""
    finding = {**named.effect, "unit": named.unit, "interval": named.interval}
    if named.model_value is not None:
        finding["model_value"] = named.model_value
    confidence = (min(named.confidence, held_out.predictive_weight) if held_out.carries_over is False
                  else named.confidence)
    finding.update({"confidence": confidence, "likelihood_ratio": named.likelihood_ratio,
                    "p_value": named.p_value, "alternatives": named.alternatives, "main_output": main_output,
                    **held_out.as_finding(), "scope": scope, "in_corrected_model": left_out is None,
                    "left_out": left_out,
                    "rmse_reference_gp": rmse_reference_gp, "gp_absorbs": gp_absorbs, "found_by": named.found_by})
    if named.amplitude_check is not None:
        finding["amplitude_check"] = named.amplitude_check
    if named.time_check is not None:
        finding["time_check"] = named.time_check
    return finding


def _number(value: float) -> str:
    return f"{value + 0.0:.3g}"  # + 0.0 turns -0.0 into 0.0


def _span(interval) -> str:
    return f"({_number(interval[0])} to {_number(interval[1])})"


def _input_words(name: str) -> str:
    """``"theta_1s, the longitudinal cyclic pitch"`` (:func:`validation.core.recordings.column_phrase`);
    ``name`` alone for a column without a phrase."""
    phrase = column_phrase(name)
    return name if phrase == name else f"{name}, the {phrase}"


def _improvement(finding: dict, fit: dict) -> str:
    """``" It carries over to the held-out flights: in the final model it removes 72.7% of the
    held-out misfit; alone it takes ..."`` (:mod:`validation.diagnose.carry_over`)."""
    name = finding.get("main_output")
    if name is None or name not in fit["rmse_reference"]:
        return ""
    before, after = fit["rmse_reference"][name], finding["rmse_effect_alone"]
    words, unit = column_phrase(name), column_unit(name)
    alone = f"alone it takes the held-out {words} RMSE from {_number(before)} to {_number(after)} {unit}"
    gain = finding["holdout_gain_in_model"]
    in_model = (f"in the final model it removes {gain:.1%} of the held-out misfit" if gain > 0 else
                f"in the final model it multiplies the held-out misfit by {1 - gain:.3g}")
    if finding.get("carries_over") is None:
        text = (f" The held-out data do not exercise it (held-out {words} RMSE {_number(before)} {unit} with or "
                "without it).")
    elif finding["carries_over"]:
        text = f" It carries over to the held-out flights: {in_model}; {alone}."
    else:
        text = (f" But it fits only the flights it saw: {in_model}; {alone}. So it is specific to the diagnosed "
                "data (e.g. a drift that differs between flights) or stands in for physics outside the named list.")
    left_out = finding.get("left_out")
    if left_out is None:
        return text + " The corrected model holds it."
    return text + f" The corrected model leaves it out: {LEFT_OUT[left_out]}."


def _scope_words(finding: dict) -> str:
    """Whether the diagnosed flights share it (:mod:`validation.diagnose.scope`); empty when one
    diagnosed recording cannot tell."""
    scope = finding.get("scope")
    if scope is None:
        return ""
    values = ", ".join(_number(v) for v in scope["values"])
    if scope["kind"] == "shared":
        return f" Every diagnosed flight shares it ({values} {finding['unit']} flight by flight)."
    spread = f"{_number(scope['spread'])} {finding['unit']}"
    if scope["kind"] == "varies":
        return (f" It differs between the diagnosed flights ({values}; spread {spread}) around a shared "
                f"{_number(scope['mean'])}: a property of the vehicle that varies from flight to flight.")
    return (f" It differs per flight ({values} {finding['unit']}; spread {spread}) with no shared part beyond "
            "that spread: a difference between flights (e.g. buoyancy, launch or battery), not a property of the "
            "vehicle.")


def statement(finding: dict, fit: dict, reference: EffectModel, *, extent: dict | None = None) -> str:
    """The plain-language sentence of one finding (what a flight-test engineer would write): the
    columns in the words of :func:`validation.core.recordings.column_phrase`, a term in those of
    ``reference`` (:meth:`~validation.vehicles.effects.EffectModel.term_description`) and, where
    the reference has ``value_context``, its value in perspective over ``extent`` (output ->
    (min, max) over the diagnosed recordings); ``fit`` is diagnosis.json's ``fit``."""
    kind, value = finding["effect"], finding["value"]
    if kind == "unexplained":
        name = finding["output"]
        words = column_phrase(name)
        if finding.get("data") == "holdout":
            within = "the noise" if not reference.min_noise_sd.get(name) else "its misfit scale"
            return (f"The corrected model fits the diagnosed {words} to {within} "
                    f"({finding['fit_noise_ratio']:.2f}x) but misses the held-out {words} by "
                    f"{_number(value)} {column_unit(name)} RMS, {finding['noise_ratio']:.1f}x "
                    f"{_noise_words(name, reference)}: physics outside the named list that the named "
                    "effects only mimic on the diagnosed manoeuvre (unexplained; e.g. an amplitude-dependent "
                    "nonlinearity). A residual GP on the reference's residual gives held-out RMSE "
                    f"{_number(fit['rmse_reference'][name])} -> {_number(finding['rmse_reference_gp'])} "
                    f"{column_unit(name)}.")
        gp = fit["rmse_corrected_gp"].get(name)
        corrected = fit["rmse_corrected"].get(name)
        gp_text = (f" A residual GP models it: held-out RMSE {_number(corrected)} -> {_number(gp)} "
                   f"{column_unit(name)}." if gp is not None else "")
        return (f"The {words} still differs from the corrected model by {_number(value)} "
                f"{column_unit(name)} RMS, {finding['noise_ratio']:.1f}x {_noise_words(name, reference)}, "
                f"and no named effect accounts for it (unexplained).{gp_text}")
    interval = _span(finding["interval"])
    unit = finding["unit"]
    if kind in ("time_delay", "input_lag"):
        words = column_phrase(finding.get("main_output", ""))
        control = _input_words(finding["input"])
        if kind == "time_delay":
            text = (f"The {words} response lags the model by {_number(value)} s {interval}: a transport "
                    f"delay on {control}.")
        else:
            text = (f"The {words} response is smoothed by a first-order lag of {_number(value)} s "
                    f"{interval} on {control}: unmodelled actuator or rotor dynamics.")
    elif kind == "dead_band":
        text = (f"A dead band on {_input_words(finding['input'])}: nothing passes within "
                f"{_number(value)} {unit} {interval} of where it started, and beyond that the input arrives short "
                "by as much.")
    elif kind == "backlash":
        text = (f"Free play (backlash) in the path of {_input_words(finding['input'])}: what it drives stays put "
                f"until the command has moved {_number(2 * value)} {unit} back across the play, and then follows it "
                f"{_number(value)} {unit} {interval} behind, so after a step and back it rests that far off where it "
                "started (a hysteresis; a linkage with friction and a spring does the same).")
    elif kind == "saturation":
        text = (f"A position limit (saturation) on {_input_words(finding['input'])}: it stops at {_number(value)} "
                f"{unit} {interval} from trim.")
    elif kind == "rate_limit":
        text = (f"A rate limit on {_input_words(finding['input'])}: it moves no faster than {_number(value)} "
                f"{unit} {interval}, so its actuator ramps where the command steps, longer on larger steps.")
    elif kind == "input_gain":
        text = (f"A control-effectiveness (gain) error on {_input_words(finding['input'])}: it acts "
                f"{_number(value)} times as strongly as the model has it {interval}.")
    elif kind == "output_scale":
        text = (f"The recorded {column_phrase(finding['output'])} reads {_number(value)} times the vehicle's "
                f"{interval}: a scale-factor error of the {finding['output']} sensor.")
    elif kind == "sensor_lag":
        name = finding["output"]
        text = (f"The recorded {column_phrase(name)} lags the vehicle's by {_number(value)} s {interval}: a "
                f"first-order lag (a filter) of the {name} sensor, which no other output shows.")
    elif kind == "sensor_drift":
        name = finding["output"]
        text = (f"The recorded {column_phrase(name)}'s bias grows by {_number(value)} {unit} {interval}, from 0 "
                f"at the first sample: a drifting {name} sensor.")
    elif kind == "sensor_cross_axis":
        recorded, source = split_cross_axis(finding["output"], reference.state_names)
        text = (f"The recorded {column_phrase(recorded)} sees {_number(value)} {interval} of the vehicle's "
                f"{column_phrase(source)} {source}: a misaligned or cross-coupled {recorded} sensor.")
    elif kind == "sensor_bias":
        name = finding["output"]
        text = (f"The {column_phrase(name)} sensor reads {_number(abs(value))} {unit} "
                f"{interval} {'high' if value > 0 else 'low'}: a sensor bias on {name}.")
    elif kind == "search_term":
        term = finding["term"]
        text = (f"Found by search of the residual, not a named effect: the {reference.term_description(term)}, "
                f"{term} = {_number(value)} {unit} {interval}, a term the model does not have.")
    elif kind in _NONLINEAR_WHY:
        term = finding["term"]
        text = (f"The {reference.term_description(term)}: {term} = {_number(value)} {unit} {interval}, a term "
                f"the linear model does not have. {_NONLINEAR_WHY[kind]}")
    else:
        term, model_value = finding["term"], finding["model_value"]
        description = reference.term_description(term)
        named = term if description == term else f"{term} ({description})"
        change = (f"{(value - model_value) / abs(model_value):+.0%}" if model_value != 0 else "missing in the model")
        kind_words = _KIND_WORDS.get(kind, kind.replace("_", " "))
        text = (f"The {kind_words} {named} is {_number(value)} {unit} {interval}, not the "
                f"model's {_number(model_value)} ({change}).")
        context = getattr(reference, "value_context", None)
        note = context(term, value, extent) if context is not None and extent else None
        if note:
            text += f" {note}"
    check = finding.get("amplitude_check")
    if check and check["amplitude_dependent"]:
        words = column_phrase(finding.get("main_output", ""))
        text += (f" But the data want {_number(check['value_large'])} on the larger {words} excursions and "
                 f"{_number(check['value_small'])} on the smaller (likelihood ratio {check['likelihood_ratio']:.3g}): "
                 "the response depends on amplitude, so this is not a linear error for certain; a nonlinearity "
                 "(a damping or stiffness that grows with size, a dead band, a limit) may be behind it.")
    text += _change_words(finding)
    alternatives = finding.get("alternatives") or []
    if alternatives:
        alternative = alternatives[0]
        target = alternative[TARGET_KEYS[alternative["effect"]]]
        text += (f" Next best: {alternative['effect'].replace('_', ' ')} on {target} "
                 f"({_number(alternative['value'])}), which the data disfavour {alternative['evidence_ratio']:.3g}:1.")
        text += (_amplitude_advice(finding, alternative) + _lag_advice(finding, alternative)
                 + _play_advice(finding, alternative))
    return text + _scope_words(finding) + _improvement(finding, fit) + _replication_words(finding)


def _change_words(finding: dict) -> str:
    """``" But it changes during the flights: ..."`` when :mod:`validation.diagnose.over_time`
    finds it changing; empty otherwise."""
    check = finding.get("time_check")
    if not check or not check["changes"]:
        return ""
    target = finding[TARGET_KEYS[finding["effect"]]]
    unit = finding["unit"]
    thirds = ", ".join("-" if v is None else _number(v) for v in check["values"])
    text = (f" But it changes during the flights: fitted on each of {len(check['values'])} consecutive parts of "
            f"the diagnosed flights it is {thirds} {unit} (a constant is rejected, p = {check['p_value']:.2g}), so "
            "the value above is an average.")
    if check["drifts"]:
        start, end = check["drift_start"], check["drift_end"]
        verb = "grows" if abs(end) > abs(start) else "shrinks"
        text += (f" {target} {verb} from {_number(start)} to {_number(end)} {unit} over the flights, as a drift "
                 "linear in time does (e.g. a rotor speed, a temperature or a battery that changes).")
    else:
        text += " No steady drift fits it: it moves between the parts (e.g. a condition that came and went)."
    return text


#: Evidence ratio below which a dead band and a gain on the same input are stated as
#: indistinguishable (Jeffreys' "barely worth mentioning", 10^(1/2); Kass & Raftery, JASA 1995);
#: the same for a saturation.
INDISTINGUISHABLE = 10 ** 0.5


def _amplitude_advice(finding: dict, alternative: dict) -> str:
    """What the data cannot tell apart and the manoeuvre that would: two of a dead band, a gain
    and a saturation on the same input whose evidence ratio is under :data:`INDISTINGUISHABLE`
    (on an input that moves between trim and one amplitude, a dead band of ``w`` on steps of
    ``A`` is a gain of ``1 - w/A`` and a limit ``L`` one of ``L/A``); empty otherwise."""
    kinds = [finding["effect"], alternative["effect"]]
    same_input = finding.get("input") == alternative.get("input")
    if not (set(kinds) <= set(_AMPLITUDE_WORDS) and kinds[0] != kinds[1] and same_input
            and alternative["evidence_ratio"] < INDISTINGUISHABLE):
        return ""
    name = finding["input"]
    return (f" These data cannot tell {_AMPLITUDE_WORDS[kinds[0]]} on {name} from {_AMPLITUDE_WORDS[kinds[1]]}: "
            "the input moves between trim and one amplitude only, where a dead band of w on steps of A is a gain "
            f"of 1 - w/A and a limit L a gain of L/A. Repeat the manoeuvre on {name} at twice the amplitude to "
            "tell them apart (a dead band costs the larger steps less, a limit more, a gain the same).")


def _play_advice(finding: dict, alternative: dict) -> str:
    """What the data cannot tell apart and the manoeuvre that would: free play and a dead band on
    the same input whose evidence ratio is under :data:`INDISTINGUISHABLE`. Both take ``w`` off a
    step away from where the input started; only on the way back do they differ (a dead band
    returns to the start, free play stays ``w`` short of it), so an input that never comes back
    cannot tell them apart (:func:`validation.vehicles.effects.backlash_inputs`). Empty
    otherwise."""
    kinds = {finding["effect"], alternative["effect"]}
    if (kinds != {"backlash", "dead_band"} or finding.get("input") != alternative.get("input")
            or alternative["evidence_ratio"] >= INDISTINGUISHABLE):
        return ""
    name = finding["input"]
    return (f" These data cannot tell free play on {name} from a dead band: both take as much off every step away "
            f"from where {name} started, and only on the way back do they differ (a dead band returns to the start, "
            f"free play stays short of it). Step {name} away and back to where it started, and hold it there, "
            "to tell them apart.")


def _lag_advice(finding: dict, alternative: dict) -> str:
    """What the data cannot tell apart and what would: a lag of an output's sensor and a lag on
    an input whose evidence ratio is under :data:`INDISTINGUISHABLE`. A linear response through
    a first-order lag is the same whether the lag filters the input or the output (the two
    transfer functions commute), so where the recorded output is the only one the input moves
    measurably the two are one effect; another recorded output the input drives tells them apart
    (an input lag slows it too, a sensor lag does not). Empty otherwise."""
    kinds = {finding["effect"]: finding, alternative["effect"]: alternative}
    if set(kinds) != {"sensor_lag", "input_lag"} or alternative["evidence_ratio"] >= INDISTINGUISHABLE:
        return ""
    output, control = kinds["sensor_lag"]["output"], kinds["input_lag"]["input"]
    return (f" These data cannot tell a lag of the {output} sensor from a lag on {control}: where {output} is the "
            f"only recorded output {control} moves, a first-order lag gives the same recording whether it filters "
            f"the input or the output. Record another output {control} drives to tell them apart (a lag on "
            f"{control} slows it too, a lag of the {output} sensor does not).")


#: The input effects that one amplitude cannot tell apart, in the words of :func:`_amplitude_advice`.
_AMPLITUDE_WORDS = {"dead_band": "a dead band", "input_gain": "a lower gain", "saturation": "a saturation"}


def _replication_words(finding: dict) -> str:
    """``" Named again on each of the 2 folds ..."`` or why it is not stated with confidence;
    empty without replication (:mod:`validation.diagnose.replicate`)."""
    replication = finding.get("replication")
    if replication is None:
        return ""
    values = ", ".join("not named" if v is None else _number(v) for v in replication["values"])
    if replication["replicated"]:
        return (f" Replicated: each of the {replication['folds']} folds of the diagnosed recordings names it "
                f"on its own ({values} {finding['unit']}).")
    if replication["named_in"] == replication["folds"]:
        return (f" Not replicated, so not stated with confidence: every fold of the diagnosed recordings names it "
                f"on its own, but not moved the same way from the model's value ({values}).")
    return (f" Not replicated, so not stated with confidence: {replication['named_in']} of "
            f"{replication['folds']} folds of the diagnosed recordings name it on their own ({values}).")


def _noise_words(name: str, reference: EffectModel) -> str:
    """What an output's residual is measured against in words: the sensor noise, or the
    reference's floor under it (:attr:`~validation.vehicles.effects.EffectModel.min_noise_sd`)."""
    floor = reference.min_noise_sd.get(name)
    if not floor:
        return "the sensor noise"
    return f"the misfit scale the {reference.name} reference weighs it by ({_number(floor)} {column_unit(name)})"


def _output_figure(name: str, trace: dict, fit: dict) -> Figure:
    """Held-out before/after plot of one output: measured, reference, corrected (+ GP)."""
    figure = Figure(figsize=(8, 3.2), layout="constrained")
    FigureCanvasAgg(figure)
    axis = figure.subplots()
    axis.plot(trace["time"], trace["measured"], color="0.6", lw=0.8, label="measured (held out)")
    styles = {"reference": ("C3", "--"), "corrected": ("C0", "-"), "corrected_gp": ("C2", ":")}
    for key, (colour, style) in styles.items():
        axis.plot(trace["time"], trace[key], color=colour, ls=style, lw=1.4,
                  label=f"{_MODEL_LABELS[key]} (RMSE {_number(fit['rmse_' + key][name])})")
    axis.set_xlabel("time [s]")
    axis.set_ylabel(f"{name} [{column_unit(name)}]")
    axis.grid(True, alpha=0.3)
    axis.legend(loc="upper right", fontsize="small")
    axis.set_title(f"{column_phrase(name)} on held-out data")
    return figure


def report_markdown(diagnosis: Diagnosis, plot_names: dict) -> str:
    """``report.md``: its title and verdict, the fidelity scorecard, the findings in plain
    words, then the held-out fit table, the findings in detail, what was tested, locate results
    and the plots (``plot_names``: output -> PNG file name)."""
    result = diagnosis.as_dict()
    lines = [f"# Diagnosis of {result['reference']} against recordings", "",
             f"Verdict: **{result['verdict']}**.", ""]
    lines += _fidelity_lines(result.get("fidelity"))
    disturbance = result.get("disturbance") or {}
    turbulent = bool(disturbance.get("looks_like_turbulence"))
    if result["findings"]:
        lines += [f"- {finding['statement']}" for finding in result["findings"]]
    elif turbulent:
        lines.append(f"- The simulation ({result['reference']}) is consistent with the recordings once the air's "
                     "motion is allowed for: no named effect is significant against it.")
    else:
        lines.append(f"- The simulation ({result['reference']}) is consistent with the recordings: no "
                     "named effect is significant and the residual is at the sensor-noise level.")
    if turbulent:
        lines.append(f"- {disturbance['statement']}")
    lines += [""]
    lines += _fit_table(result["fit"])
    lines += ["", "## Findings in detail", ""]
    for finding in result["findings"]:
        lines += _finding_details(finding)
    if not result["findings"]:
        lines.append("None.")
    lines += _search_notes(result["search"], result["untestable"])
    if result["ignored_columns"]:
        lines.append(f"- Left out: {ignored_columns_phrase(result['ignored_columns'], result['reference'])}.")
    lines += ["", "## Where the reference misfits (locate)", ""]
    lines += _locate_notes(result["mismatch"], result["locate"])
    lines += ["", "## Held-out plots", ""]
    for name, file_name in plot_names.items():
        lines.append(f"![{name}]({file_name})")
    lines += ["", "The corrected model is `corrected_model.json` (load it with "
              "`validation.vehicles.effect_vehicle.EffectVehicle.load` and call `.simulate(time, inputs)`).", ""]
    return "\n".join(lines)


def _fidelity_lines(fidelity: dict | None) -> list[str]:
    """The head of the report, after its title and verdict: which outputs pass their tolerance
    bands before and after correction, and the scorecard table (:mod:`validation.diagnose.fidelity`)."""
    if not fidelity:
        return []
    banded = {name: entry for name, entry in fidelity["outputs"].items() if entry["tolerance"] is not None}

    def passing(key):
        return ", ".join(n for n, e in banded.items() if e[key]["passes"]) or "none"

    lines = [f"**Fidelity** ({fidelity['tolerance_source']}; held-out data): inside their tolerance bands "
             f"before correction: {passing('reference')}; after: {passing('corrected')}; with the residual "
             f"GP: {passing('corrected_gp')} (of {', '.join(banded) or 'no output with a band'}).", "",
             "| output | band | max error ref. -> corr. -> corr. + GP | inside band | Theil U | "
             "frequency cost J (input) |", "|---|---|---|---|---|---|"]
    for name, entry in fidelity["outputs"].items():
        models = [entry[key] for key in MODEL_KEYS]
        band = _band_words(name, entry)
        inside = " -> ".join(f"{m['inside_share']:.1%}" for m in models) if entry["tolerance"] is not None else "-"
        cost = " -> ".join("-" if m["frequency_cost"] is None else f"{m['frequency_cost']:.3g}" for m in models)
        errors = " -> ".join(_number(m["max_error"]) for m in models)
        theil = " -> ".join(_number(m["theil"]) for m in models)
        source = entry["frequency_input"] or "-"
        lines.append(f"| {name} | {band} | {errors} | {inside} | {theil} | {cost} ({source}) |")
    pose = fidelity.get("pose")
    if pose:
        scores = " -> ".join(f"{pose[key]['score']:.3g}" for key in MODEL_KEYS)
        positions = " -> ".join(f"{pose[key]['position_rmse_m']:.3g}" for key in MODEL_KEYS)
        lines += ["", f"**The RGBlimp's flight score** (the source's score, each pose column over its range in "
                      f"{pose['ranges_from']}), reference -> corrected -> corrected + GP: {scores}; position RMSE "
                      f"{positions} m."]
    return lines + [""]


def _band_words(name: str, entry: dict) -> str:
    """An output's tolerance band as its source states it, with the SI half-width the scorecard
    computes with: ``"+-2 deg/s (0.0349 rad/s)"`` for a band of Table C2A, ``"+-0.035 rad/s"``
    for one given in SI (a tolerance file), ``"-"`` without a band."""
    if entry["tolerance"] is None:
        return "-"
    si = f"{_number(entry['tolerance'])} {column_unit(name)}"
    stated = entry["tolerance_as_stated"]
    return f"+-{stated} ({si})" if stated else f"+-{si}"


def _fit_table(fit: dict) -> list[str]:
    """The held-out fit section of ``report.md``: RMSE and Theil U per output and model."""
    lines = [f"## Held-out fit ({fit['holdout']})", "",
             "| output | noise sd | RMSE reference | RMSE corrected | RMSE corrected + GP | Theil U ref. | "
             "Theil U corr. | Theil U corr. + GP |",
             "|---|---|---|---|---|---|---|---|"]
    for name in fit["outputs"]:
        lines.append(f"| {name} [{column_unit(name)}] | {_number(fit['noise_sd'][name])} | "
                     + " | ".join(_number(fit[f"{metric}_{key}"][name]) for metric in ("rmse", "theil")
                                  for key in MODEL_KEYS) + " |")
    return lines


def _finding_details(finding: dict) -> list[str]:
    """The lines of one finding in the detail section of ``report.md``."""
    target = finding.get(TARGET_KEYS.get(finding["effect"], "output"), finding.get("output"))
    if finding["effect"] == "unexplained":
        data = "held-out" if finding.get("data") == "holdout" else "diagnosed"
        return [f"- unexplained on {target} ({data} data): residual RMS {_number(finding['value'])} "
                f"{finding['unit']}, {finding['noise_ratio']:.2f}x noise"]
    lines = [f"- {finding['effect']} on {target}: {_number(finding['value'])} {finding['unit']}, "
             f"95 % interval {_span(finding['interval'])}, likelihood ratio "
             f"{finding['likelihood_ratio']:.4g} (p = {finding['p_value']:.2g}), confidence "
             f"(Akaike weight) {finding['confidence']:.3f}"]
    for alternative in finding["alternatives"]:
        alt_target = alternative[TARGET_KEYS[alternative["effect"]]]
        lines.append(f"  - alternative: {alternative['effect']} on {alt_target} = "
                     f"{_number(alternative['value'])}; data prefer the finding "
                     f"{alternative['evidence_ratio']:.3g}:1")
    flag = " **A residual GP alone would hide this effect.**" if finding["gp_absorbs"] >= HIDDEN_BY_GP else ""
    lines.append(f"  - a GP fitted to the uncorrected {finding['main_output']} residual absorbs "
                 f"{finding['gp_absorbs']:.0%} of what this effect explains (in-sample); held-out "
                 f"RMSE reference + GP {_number(finding['rmse_reference_gp'])} vs reference + "
                 f"this effect {_number(finding['rmse_effect_alone'])}.{flag}")
    return lines


def ignored_columns_phrase(columns: list, reference: str) -> str:
    """What the diagnosis left out of the recordings, in words (report and command line)."""
    return (f"column(s) {', '.join(columns)} of the recordings, which are none of {reference}'s variables: "
            "the diagnosis does not use them (inputs among them act on the vehicle outside the model)")


def _search_notes(search: dict, untestable: list) -> list[str]:
    """The "What was tested" section of ``report.md``."""
    lines = ["", "## What was tested", "",
             f"{search['hypotheses_tested']} hypotheses (delay and lag per excited input, every control "
             "and stability term of the reference, a bias per output), forward stepwise by likelihood ratio; "
             f"weighted RSS {search['null_rss']:.1f} (reference) -> {search['final_rss']:.1f} "
             f"for {search['n_residuals']} residuals."]
    if search["rejected"]:
        rejected = search["rejected"]
        target = rejected[TARGET_KEYS[rejected["effect"]]]
        lines.append(f"Best hypothesis not accepted: {rejected['effect']} on {target} "
                     f"(LR {rejected['likelihood_ratio']:.3g} below the threshold {rejected['threshold']:.3g}).")
    for dropped in search.get("taken_back", []):
        after = dropped["after"]
        lines.append(f"Taken back: {dropped['effect']} on {dropped[TARGET_KEYS[dropped['effect']]]}, accepted at an "
                     f"earlier step, once {after['effect']} on {after[TARGET_KEYS[after['effect']]]} was in "
                     f"(LR {dropped['likelihood_ratio']:.3g} below the threshold {dropped['threshold']:.3g}).")
    return lines + [f"- Not testable: {note}" for note in untestable]


#: Mismatch windows listed in ``report.md`` (diagnosis.json has them all).
MAX_REPORTED_WINDOWS = 40


def _locate_notes(mismatch: list, locate: dict) -> list[str]:
    """The locate section of ``report.md``: mismatch windows, bands and coherent inputs."""
    lines = []
    if mismatch:
        lines += ["| recording | output | t_start [s] | t_end [s] | RMS error |", "|---|---|---|---|---|"]
        for item in mismatch[:MAX_REPORTED_WINDOWS]:
            lines.append(f"| {item['recording']} | {item['output']} | {item['t_start']:.2f} | "
                         f"{item['t_end']:.2f} | {_number(item['rms_error'])} |")
        if len(mismatch) > MAX_REPORTED_WINDOWS:
            lines.append(f"| ... | {len(mismatch) - MAX_REPORTED_WINDOWS} more in diagnosis.json | | | |")
    else:
        lines.append("No time window exceeds the sensor noise.")
    for name, bands in locate["bands"].items():
        text = ", ".join(f"{b['f_low']:.2f}-{b['f_high']:.2f} Hz (x{b['peak_ratio']:.3g})" for b in bands)
        coherent = ", ".join(f"{c['input']} ({c['coherence']:.2f} at {c['frequency']:.2f} Hz)"
                             for c in locate["coherent_inputs"].get(name, [])) or "none"
        lines.append(f"- {name}: residual PSD above noise in {text}; coherent with {coherent}")
    return lines


#: What :func:`write_diagnosis` writes in its folder (names and shell patterns), which ``flightgp
#: diagnose`` checks before its long work (:func:`validation.core.files.check_output_folder`).
DIAGNOSIS_FILES = ("diagnosis.json", "report.md", "corrected_model.json", "holdout_*.png")


def diagnosis_files(diagnosis: Diagnosis, out_dir, *, figures: bool = True) -> dict:
    """``{path: str or bytes}`` of everything :func:`write_diagnosis` writes to ``out_dir``
    (without ``figures``: no PNGs, and a report that names none)."""
    out_dir = Path(out_dir)
    files, plot_names = {}, {}
    for name, trace in diagnosis.holdout_traces.items() if figures else ():
        file_name = f"holdout_{name}.png"
        files[out_dir / file_name] = png_bytes(_output_figure(name, trace, diagnosis.fit))
        plot_names[name] = file_name
    files[out_dir / "diagnosis.json"] = json_text(diagnosis.as_dict())
    files.update(diagnosis.corrected.model_files(out_dir / "corrected_model.json"))
    files[out_dir / "report.md"] = report_markdown(diagnosis, plot_names)
    return files


def write_diagnosis(diagnosis: Diagnosis, out_dir) -> list[Path]:
    """Write ``diagnosis.json``, ``report.md`` with its PNGs and ``corrected_model.json``
    (load with :meth:`validation.vehicles.effect_vehicle.EffectVehicle.load`) to ``out_dir``, all
    or nothing (:func:`validation.core.files.write_files_atomically`). Returns the paths written."""
    out_dir = check_output_folder(out_dir)
    return write_files_atomically(diagnosis_files(diagnosis, out_dir))
