"""Which FMU a model file or a reference name gives (what ``flightgp build-fmu`` runs; runs in
the flightgp environment, not inside an FMU; docs/fmus.md, "Building: `flightgp build-fmu`")."""
from __future__ import annotations

import re
from pathlib import Path

from fmu_src.blimp_reference.build import build_blimp_reference_fmu
from fmu_src.blimp_rkgp.build import build_blimp_rkgp_fmu
from fmu_src.blimp_rkgp.native import build_native_blimp_rkgp_fmu
from fmu_src.bo105_reference.build import build_bo105_reference_fmu
from fmu_src.jsbsim_aircraft.build import build_jsbsim_fmu
from fmu_src.rate_predictor.build import build_rate_predictor_fmu
from fmu_src.rate_predictor.native import build_native_rate_predictor_fmu
from fmu_src.rgblimp_hybrid.build import build_rgblimp_hybrid_fmu
from fmu_src.rgblimp_hybrid.native import build_native_rgblimp_hybrid_fmu
from fmu_src.rgblimp_rkgp.build import build_rgblimp_rkgp_fmu
from fmu_src.rgblimp_rkgp.native import build_native_rgblimp_rkgp_fmu
from gp_model import read_header
from validation.core.errors import BadInputError
from validation.models.blimp_greybox import BLIMP_PHYSICS
from validation.models.rgblimp_greybox import RGBLIMP_PHYSICS
from validation.vehicles.bo105 import BO105_SPEEDS_KT

#: The FMU of a grey-box model file by the physics it describes (its header's ``physics.kind``):
#: what it is, its pythonfmu builder and its native builder.
GREYBOX_FMUS = {
    BLIMP_PHYSICS: ("the blimp RKGP", build_blimp_rkgp_fmu, build_native_blimp_rkgp_fmu),
    RGBLIMP_PHYSICS: ("the RGBlimp RKGP", build_rgblimp_rkgp_fmu, build_native_rgblimp_rkgp_fmu),
}


def build_model_fmu(model_path, out_dir, *, name: str | None = None, native: bool = False) -> Path:
    """The FMU of a trained model file, by its type: a ``.json`` file the RGBlimp hybrid's
    (:func:`build_rgblimp_hybrid_fmu`, which says when it is not such a model); a ``GreyBoxGP``
    the grey-box FMU of the physics it describes (:data:`GREYBOX_FMUS`: ``blimp_rk4`` the blimp
    RKGP, ``rgblimp_rk4`` the RGBlimp RKGP); anything else the GP-NARX rate predictor (which says
    when the file is not a GP-NARX model).

    Parameters
    ----------
    model_path, out_dir, name
        As :func:`fmu_src.rate_predictor.build.build_rate_predictor_fmu`.
    native : bool
        Build the native FMU (C, no Python at run time; e.g.
        :func:`build_native_rgblimp_rkgp_fmu`); else the pythonfmu FMU (e.g.
        :func:`build_rgblimp_rkgp_fmu`).

    Returns
    -------
    Path
        ``out_dir/<name>.fmu``.

    Raises
    ------
    validation.core.errors.BadInputError
        A grey-box model of other physics (the message names those flightgp builds), or what the
        builder raises.
    gp_model.ModelFileError
        Missing or unreadable model file.
    """
    if Path(model_path).suffix.lower() == ".json":
        build = build_native_rgblimp_hybrid_fmu if native else build_rgblimp_hybrid_fmu
        return build(model_path, out_dir, name=name)
    header = read_header(model_path)
    if header.get("type") == "GreyBoxGP":
        physics = header.get("physics")
        kind = physics.get("kind") if isinstance(physics, dict) else None
        if kind not in GREYBOX_FMUS:
            known = "; ".join(f"{name!r} ({what})" for name, (what, *_) in GREYBOX_FMUS.items())
            raise BadInputError(f"{Path(model_path).name}: a grey-box model of physics {kind!r}; flightgp builds "
                                f"the FMUs of grey-box models with the physics {known}")
        _, python_build, native_build = GREYBOX_FMUS[kind]
        build = native_build if native else python_build
    else:
        build = build_native_rate_predictor_fmu if native else build_rate_predictor_fmu
    return build(model_path, out_dir, name=name)


def reference_fmu_names() -> list[str]:
    """The names :func:`build_reference_fmu` accepts (``jsbsim:<aircraft>`` as a pattern)."""
    return [f"bo105-{v}kt" for v in BO105_SPEEDS_KT] + ["blimp", "jsbsim:<aircraft>"]


def build_reference_fmu(reference: str, out_dir, *, name: str | None = None) -> Path:
    """Build the FMU of a physics reference by its vehicle name (docs/conventions.md, "Vehicle
    and reference names"): ``bo105-<V>kt`` (:func:`build_bo105_reference_fmu`), ``blimp``
    (:func:`build_blimp_reference_fmu`) or ``jsbsim:<aircraft>`` (:func:`build_jsbsim_fmu`).

    Raises
    ------
    validation.core.errors.BadInputError
        Any other name (the message lists the valid ones), or what the builder raises.
    """
    match = re.fullmatch(r"bo105-(\d+)kt", reference)
    if match and int(match.group(1)) in BO105_SPEEDS_KT:
        return build_bo105_reference_fmu(int(match.group(1)), out_dir, name=name)
    if reference == "blimp":
        return build_blimp_reference_fmu(out_dir, name=name)
    if reference.startswith("jsbsim:") and reference != "jsbsim:":
        return build_jsbsim_fmu(reference.split(":", 1)[1], out_dir, name=name)
    raise BadInputError(f"no reference FMU {reference!r}; valid: {', '.join(reference_fmu_names())} "
                        "(e.g. jsbsim:c172x, jsbsim:ah1s; flight-test stand-ins and the RGBlimp have none)")
