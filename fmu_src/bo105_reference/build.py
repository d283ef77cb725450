"""Build the Bo105 physics reference FMU (runs in the flightgp environment, not inside an FMU)."""
from __future__ import annotations

from pathlib import Path

from fmu_src.bo105_reference.slave import (
    INPUT_NAMES,
    ROW_LETTERS,
    STATE_NAMES,
    Bo105ReferenceSlave,
    bo105_reference_variables,
    derivative_entries,
    pack_model,
)
from fmu_src.fmi.naming import fmu_target
from fmu_src.fmi.pythonfmu import build_pythonfmu
from fmu_src.fmi.signals import signal
from validation.core.recordings import column_unit
from validation.vehicles import bo105
from validation.vehicles.bo105_effects import Bo105Effects


def derivative_unit(name: str) -> str:
    """The FMU unit of derivative ``name`` (a key of :data:`fmu_src.fmi.slave.UNITS`): its row's
    rate (m/s^2 or rad/s^2) per its column's unit (``M_q``: 1/s, ``M_theta_1s``: 1/s2)."""
    letter, _, column = name.partition("_")
    row_unit = column_unit(ROW_LETTERS[letter])
    return {("m/s", "m/s"): "1/s", ("m/s", "rad/s"): "m/(s.rad)", ("m/s", "rad"): "m/(s2.rad)",
            ("rad/s", "m/s"): "rad/(m.s)", ("rad/s", "rad/s"): "1/s", ("rad/s", "rad"): "1/s2"}[
        (row_unit, column_unit(column))]


def build_bo105_reference_fmu(speed_kt: int, out_dir, *, name: str | None = None,
                              derivatives: dict | None = None) -> Path:
    """Build the Bo105 physics reference FMU (``bo105-<V>kt``, :mod:`fmu_src.bo105_reference.slave`).

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
    reference = bo105.Bo105Reference(speed_kt)
    if derivatives:
        reference = reference.with_derivatives(derivatives)
    target = fmu_target(out_dir, f"bo105_{reference.speed_kt}kt_reference" if name is None else name)
    if (bo105.INPUT_NAMES, bo105.STATE_NAMES, bo105.ROW_LETTERS) != (INPUT_NAMES, STATE_NAMES, ROW_LETTERS):
        raise RuntimeError(f"the FMU's signal order {INPUT_NAMES}, {STATE_NAMES}, {ROW_LETTERS} differs from "
                           f"validation.vehicles.bo105's")
    changed = "" if not derivatives else "; changed derivatives " + ", ".join(
        f"{key} = {reference.derivative(key):.6g}" for key in derivatives)
    source = f"Padfield (2007) linear 6-DOF model at {reference.speed_kt} kt{changed}"
    arrays = pack_model(A=reference.A, B=reference.B, speed_kt=reference.speed_kt, source=source)
    effects = Bo105Effects(reference)
    interface = {"inputs": tuple(signal(n, "input").row() for n in INPUT_NAMES),
                 "states": tuple(signal(n, "state").row() for n in STATE_NAMES),
                 "derivatives": tuple((name, derivative_unit(name), reference.derivative(name),
                                       f"{effects.term_description(name)}, the derivative {name}")
                                      for name, *_ in derivative_entries())}
    description = (f"Bo105 physics reference: {source}, exact zero-order-hold discretisation at the "
                   "host's step; inputs theta_0, theta_1s, theta_1c, theta_0T, outputs u, w, q, theta, "
                   "v, p, phi, r (perturbations from trim); every stability and control derivative a "
                   "parameter (M_q, L_theta_1c, ...)")
    return build_pythonfmu(target, slave_class=Bo105ReferenceSlave, variables=(bo105_reference_variables, interface),
                           attributes={}, description=description, arrays=arrays)
