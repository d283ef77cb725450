"""What the RGBlimp RKGP's physics step adds to the RGBlimp's equations: numpy, the standard
library and plain project modules.

The RKGP steps the identified model (:meth:`validation.models.rgblimp_identification.RGBlimpModel.step`,
:func:`validation.vehicles.rgblimp_equations.advance`: one RK4 sample with a thrust factor and a
steady wind) with yaw carried continuously (:func:`carry_yaw`,
:func:`validation.models.rgblimp_greybox.physics_step`), and its model file describes that step
in plain JSON data (:func:`parameters_as_dict`;
:class:`validation.models.rgblimp_greybox.RGBlimpStepDescription`). Like the equations, this
module imports no scipy, so an FMU carries it as it is (:mod:`fmu_src.fmi.pythonfmu`): the
RGBlimp RKGP FMU steps with these very functions (docs/fmus.md, "RGBlimp RKGP").
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from validation.vehicles.rgblimp_equations import STATE_NAMES, RGBlimpParameters

_YAW = STATE_NAMES.index("psi")


def carry_yaw(states, moved) -> np.ndarray:
    """``moved`` (..., 12), the step of ``states`` (..., 12) by a step that wraps ``psi`` into
    [-pi, pi] as the source's does, with yaw carried continuously instead: the current yaw plus
    the wrapped yaw change (a step never turns the blimp by half a turn). A new array."""
    states = np.asarray(states, dtype=float)
    moved = np.array(moved, dtype=float)
    change = moved[..., _YAW] - states[..., _YAW]
    moved[..., _YAW] = states[..., _YAW] + (change + np.pi) % (2 * np.pi) - np.pi
    return moved


def parameters_as_dict(params: RGBlimpParameters) -> dict:
    """Every field of ``params`` as plain JSON data: name -> float, or [x, y, z] for the triples."""
    return {field.name: (list(value) if isinstance(value, tuple) else value)
            for field in dataclasses.fields(RGBlimpParameters) for value in [getattr(params, field.name)]}


#: The :class:`RGBlimpParameters` fields a model file may lack: the terms added after the first
#: model files were written (cross-flow coefficients, thrust loss with airspeed, thrust line,
#: draught field), all zero in those files' models.
LATER_FIELDS = ("c_s_beta_abs", "c_l_alpha_abs", "c_my_alpha_abs", "c_mz_beta_abs", "thrust_speed_loss",
                "thrust_line_y", "draught_gradient_x", "draught_gradient_y")


def parameters_from_dict(values) -> RGBlimpParameters:
    """Inverse of :func:`parameters_as_dict` (the same doubles).

    Model files written before the fields of :data:`LATER_FIELDS` existed lack them; they take
    their defaults (zero: the terms those files' models did not have).

    Raises
    ------
    ValueError
        ``values`` is not a dict naming exactly the fields of :class:`RGBlimpParameters` (those
        of :data:`LATER_FIELDS` optional) with finite numbers (triples where the field has one);
        the message says which.
    """
    names = [field.name for field in dataclasses.fields(RGBlimpParameters)]
    if not isinstance(values, dict):
        raise ValueError(f"the RGBlimp parameters must be a JSON object of {len(names)} fields, got {values!r}")
    defaults = RGBlimpParameters()
    values = {**{name: getattr(defaults, name) for name in LATER_FIELDS}, **values}
    missing, unknown = sorted(set(names) - set(values)), sorted(set(values) - set(names))
    if missing or unknown:
        raise ValueError(f"the RGBlimp parameters lack {missing} and hold unknown {unknown}; expected exactly "
                         f"the fields of RGBlimpParameters")
    checked = {}
    for name in names:
        value = values[name]
        numbers = list(value) if isinstance(value, (list, tuple)) else [value]
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in numbers):
            raise ValueError(f"RGBlimp parameter {name} must hold finite numbers, got {value!r}")
        checked[name] = tuple(float(v) for v in numbers) if isinstance(value, (list, tuple)) else float(value)
    try:
        return RGBlimpParameters(**checked)
    except ValueError as error:  # RGBlimpParameters' own check (a triple's width), a BadInputError
        raise ValueError(str(error)) from None
