"""Build the blimp physics reference FMU (runs in the flightgp environment, not inside an FMU)."""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from fmu_src.blimp_reference.slave import BlimpReferenceSlave, blimp_reference_variables, pack_model
from fmu_src.fmi.naming import fmu_target
from fmu_src.fmi.pythonfmu import build_pythonfmu
from fmu_src.fmi.signals import signal
from fmu_src.fmi.slave import UNITS
from validation.vehicles.blimp import INPUT_NAMES, STATE_NAMES, BlimpParameters, BlimpReference, hanging_state
from validation.vehicles.blimp_effects import (
    CONTROL_TERMS,
    DRAG_TERMS,
    STABILITY_TERMS,
    TERM_DESCRIPTIONS,
    TERM_UNITS,
    model_value,
)
from validation.vehicles.blimp_equations import AXIS_SUFFIXES

#: The words for the three entries of a translational, a rotational and a position triple.
TRANSLATION = ("surge", "sway", "heave")
ROTATION = ("roll", "pitch", "yaw")
BODY_AXES = ("along body x (forward)", "along body y (right)", "along body z (down)")

#: The :class:`~validation.vehicles.blimp.BlimpParameters` fields that are no effect term: unit
#: (as flightgp writes units in words, :func:`fmu_unit` makes it an FMU unit), phrase, and for an
#: (x, y, z) triple the words for its three axes (``{axis}`` in the phrase). Units and meanings
#: as the ``BlimpParameters`` docstring.
FIELD_WORDS = {
    "mass": ("kg", "rigid-body mass, helium included", None),
    "added_mass": ("kg", "added mass in {axis}", TRANSLATION),
    "inertia": ("kg m^2", "moment of inertia in {axis} about the centre of buoyancy", ROTATION),
    "added_inertia": ("kg m^2", "added moment of inertia in {axis}", ROTATION),
    "linear_drag": ("N s/m", "linear {axis} drag (force proportional to the velocity)", TRANSLATION),
    "cg_position": ("m", "centre of gravity relative to the centre of buoyancy, {axis}", BODY_AXES),
    "gondola_arm": ("m", "distance of the gondola fan shaft below the centre of buoyancy", None),
    "tail_arm": ("m", "distance of the tail fan and tail fins behind the centre of buoyancy", None),
    "fin_lift": ("kg/m", "tail-fin lift per unit forward speed and cross-flow velocity at the fins", None),
}


def fmu_unit(text: str) -> str:
    """An FMU unit (a key of :data:`fmu_src.fmi.slave.UNITS`) from a unit as flightgp writes it
    in words: products by ``.``, no ``^`` (``"N s^2/m^2"`` -> ``"N.s2/m2"``)."""
    unit = text.replace(" ", ".").replace("^", "")
    if unit not in UNITS:
        raise RuntimeError(f"the unit {text!r} ({unit!r}) is not in fmu_src.fmi.slave.UNITS")
    return unit


def effect_terms() -> dict[str, tuple[str, float]]:
    """The ``BlimpParameters.vector_names()`` entries that are effect terms of the blimp
    (:mod:`validation.vehicles.blimp_effects`): entry -> (term, sign), the term's value being
    ``sign * entry`` (the fan thrusts as they are; rotational damping, quadratic drag and net lift
    negated: ``L_P = -rotational_damping_x``, ``X_UU = -quadratic_drag_x``, ``Z_0 = -net_lift``)."""
    terms = {name: (name, 1.0) for name in CONTROL_TERMS}
    terms.update({f"rotational_damping{AXIS_SUFFIXES[axis]}": (term, -1.0) for term, axis in STABILITY_TERMS.items()})
    terms.update({f"quadratic_drag{AXIS_SUFFIXES[axis]}": (term, -1.0) for term, axis in DRAG_TERMS.items()})
    terms["net_lift"] = ("Z_0", -1.0)
    return terms


class ParameterRow(NamedTuple):
    """One physical parameter as the FMU declares it: its name, unit (a key of
    :data:`fmu_src.fmi.slave.UNITS`), the reference's value and what it is; and the
    ``BlimpParameters`` vector entry it sets, ``entry = sign * value``."""

    name: str
    unit: str
    value: float
    phrase: str
    entry: str
    sign: float


def parameter_rows(reference: BlimpReference) -> list[ParameterRow]:
    """Every physical parameter of ``reference``, in ``BlimpParameters.vector_names()`` order:
    the effect term where the entry is one (:func:`effect_terms`), else the entry by its name
    (:data:`FIELD_WORDS`)."""
    terms = effect_terms()
    rows = []
    for entry, value in zip(BlimpParameters.vector_names(), reference.params.to_vector().tolist()):
        if entry in terms:
            term, sign = terms[entry]
            if model_value(reference, term) != sign * value:
                raise RuntimeError(f"the effect term {term} is {model_value(reference, term)}, not {sign:+g} * "
                                   f"{entry} = {sign * value}: effect_terms() differs from "
                                   "validation.vehicles.blimp_effects")
            phrase = TERM_DESCRIPTIONS[term] + (f", the effect term {term} = -{entry}" if sign < 0 else "")
            # + 0.0: a zero entry negated is 0.0, not -0.0
            rows.append(ParameterRow(term, fmu_unit(TERM_UNITS[term]), sign * value + 0.0, phrase, entry, sign))
            continue
        field, axis = (entry[:-2], AXIS_SUFFIXES.index(entry[-2:])) if entry not in FIELD_WORDS else (entry, None)
        unit, phrase, axes = FIELD_WORDS[field]
        rows.append(ParameterRow(entry, fmu_unit(unit), value,
                                 phrase if axes is None else phrase.format(axis=axes[axis]), entry, 1.0))
    return rows


def build_blimp_reference_fmu(out_dir, *, name: str | None = None) -> Path:
    """Build the blimp physics reference FMU (``blimp``, :mod:`fmu_src.blimp_reference.slave`).

    Parameters
    ----------
    out_dir : path
        Folder for the FMU (created if missing).
    name : str, optional
        Model identifier and file name; default ``blimp_reference``.

    Returns
    -------
    Path
        ``out_dir/<name>.fmu``.

    Raises
    ------
    validation.core.errors.BadInputError
        A bad ``name``, ``out_dir`` a file.
    """
    reference = BlimpReference()
    target = fmu_target(out_dir, "blimp_reference" if name is None else name)
    rows = parameter_rows(reference)
    start = hanging_state(reference.params).tolist()
    source = ("Ko et al. (2007) indoor blimp; EPFL parameters (Zufferey et al. 2006) scaled to Ko's 0.35 kg "
              "blimp")
    arrays = pack_model(entry_names=[row.entry for row in rows], parameter_names=[row.name for row in rows],
                        signs=[row.sign for row in rows], max_step=reference.max_step, source=source)
    interface = {"inputs": tuple(signal(n, "input").row() for n in INPUT_NAMES),
                 "states": tuple(signal(n, "state").row() + (value,) for n, value in zip(STATE_NAMES, start)),
                 "parameters": tuple((row.name, row.unit, row.value, row.phrase) for row in rows)}
    description = (f"Blimp physics reference: {source}; RK4 in equal substeps of at most {reference.max_step:g} s "
                   "per communication step; inputs u_gondola, mu, u_tail, outputs x, y, z, phi, theta, psi, U, V, "
                   "W, P, Q, R; every physical parameter a parameter (X_UU, N_R, mass, ...)")
    return build_pythonfmu(target, slave_class=BlimpReferenceSlave, variables=(blimp_reference_variables, interface),
                           attributes={"DEFAULT_STEP_SIZE": reference.sample_time}, description=description,
                           arrays=arrays)
