"""Build the Bo105 physics reference FMU (runs in the flightgp environment, not inside an FMU)."""
from __future__ import annotations

from pathlib import Path

from fmu_src.bo105_reference.slave import (
    INPUT_NAMES,
    STATE_NAMES,
    Bo105ReferenceSlave,
    bo105_reference_variables,
    pack_model,
)
from fmu_src.fmi.naming import fmu_target
from fmu_src.fmi.pythonfmu import build_pythonfmu
from fmu_src.fmi.signals import signal
from validation.vehicles import bo105


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
    if (bo105.INPUT_NAMES, bo105.STATE_NAMES) != (INPUT_NAMES, STATE_NAMES):
        raise RuntimeError(f"the FMU's signal order {INPUT_NAMES}, {STATE_NAMES} differs from "
                           f"validation.vehicles.bo105's {bo105.INPUT_NAMES}, {bo105.STATE_NAMES}")
    changed = "" if not derivatives else "; changed derivatives " + ", ".join(
        f"{key} = {reference.derivative(key):.6g}" for key in derivatives)
    source = f"Padfield (2007) linear 6-DOF model at {reference.speed_kt} kt{changed}"
    arrays = pack_model(A=reference.A, B=reference.B, speed_kt=reference.speed_kt, source=source)
    interface = {"inputs": tuple(signal(n, "input").row() for n in INPUT_NAMES),
                 "states": tuple(signal(n, "state").row() for n in STATE_NAMES)}
    description = (f"Bo105 physics reference: {source}, exact zero-order-hold discretisation at the "
                   "host's step; inputs theta_0, theta_1s, theta_1c, theta_0T, outputs u, w, q, theta, "
                   "v, p, phi, r (perturbations from trim)")
    return build_pythonfmu(target, slave_class=Bo105ReferenceSlave, variables=(bo105_reference_variables, interface),
                           attributes={}, description=description, arrays=arrays)
