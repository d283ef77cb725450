"""The RGBlimp hybrid FMU: the RGBlimp's propeller thrusts and gondola position in; its 12 states
and their standard deviations out; the identified RGBlimp model plus the rollout-trained
correction of its accelerations, stepped by RK4, inside (:mod:`fmu_src.rgblimp_hybrid.model`).
docs/fmus.md, "RGBlimp hybrid", lists the variables.

Every RGBlimp hybrid FMU carries a copy of this file (:mod:`fmu_src.fmi.pythonfmu`), so it
imports only the FMI layer (:mod:`fmu_src.fmi.greybox`, whose slave runs every grey-box FMU),
the model, numpy and the standard library. The per-FMU slave script that
:func:`fmu_src.rgblimp_hybrid.build.build_rgblimp_hybrid_fmu` generates subclasses
:class:`RGBlimpHybrid` with the FMU's variable table and its package name.

Timing as the RGBlimp RKGP FMU's (:mod:`fmu_src.rgblimp_rkgp.slave`): one motion-capture sample,
1/60 s, per communication step (any other is refused); the inputs set at ``t_k`` held over
``[t_k, t_{k+1})``; the outputs at ``t_{k+1}`` the hybrid's free run ``RolloutHybrid.simulate``,
started from the ``<state>_start`` parameters. ``<state>_sd`` is the first-order spread of the
hybrid's band (:mod:`fmu_src.rgblimp_hybrid.model`, "Standard deviations"); 0 at ``t0``.

Envelope: when a feature of the correction leaves the range it was fitted on (by more than 10 %
of the range), the FMU logs a Warning once per excursion; there the correction fades to the
physics.
"""
from __future__ import annotations

from fmu_src.fmi.greybox import GreyBoxSlave
from fmu_src.rgblimp_hybrid.model import RGBlimpHybridModel
from validation.vehicles.rgblimp_equations import INPUT_NAMES, SAMPLE_TIME, STATE_NAMES

#: What the state outputs and their standard deviations are (the variables' descriptions).
MEAN_PHRASE = "identified physics plus the rollout-trained correction of its accelerations (free run)"
SD_PHRASE = ("from the band's random acceleration propagated along the run to first order from the known "
             "start (0 at the start)")


class RGBlimpHybrid(GreyBoxSlave):
    """RGBlimp hybrid (the class the build generates sets its description, PACKAGE and VARIABLES)."""

    STATE_NAMES, INPUT_NAMES = STATE_NAMES, INPUT_NAMES
    MODEL = RGBlimpHybridModel
    MODEL_PHRASE = "RGBlimp hybrid model"
    ENVELOPE_CONSEQUENCE = "the correction fades to the physics there"
    STEP_SIZE = SAMPLE_TIME
