"""The RGBlimp RKGP FMU: the RGBlimp's propeller thrusts and gondola position in; its 12 states and
their standard deviations, propagated along the run, out; the identified RGBlimp model stepped
by RK4 plus GPs on its one-step residual inside (:mod:`fmu_src.rgblimp_rkgp.model`).
docs/fmus.md, "RGBlimp RKGP", lists the variables.

Every RGBlimp RKGP FMU carries a copy of this file (:mod:`fmu_src.fmi.pythonfmu`), so it imports
only the FMI layer (:mod:`fmu_src.fmi.greybox`, whose slave runs every grey-box FMU), the model,
numpy and the standard library. The per-FMU slave script that
:func:`fmu_src.rgblimp_rkgp.build.build_rgblimp_rkgp_fmu` generates subclasses
:class:`RGBlimpRKGP` with the FMU's variable table (:func:`fmu_src.fmi.greybox.greybox_variables`)
and its package name.

Timing (docs/conventions.md, "FMU sampling convention")
-------------------------------------------------------
The model steps one motion-capture sample, 1/60 s (the source's integrator:
:data:`validation.vehicles.rgblimp_equations.SAMPLE_TIME`), so that is the FMU's communication
step (:attr:`RGBlimpRKGP.STEP_SIZE`; any other is refused, logged Error, ``fmi2Discard``). The
inputs set at ``t_k`` are held over ``[t_k, t_{k+1})``; ``fmi2DoStep(t_k, h)`` sets the state
outputs to

    s(t_{k+1}) = f(s(t_k), u(t_k)) + E[residual | s(t_k), u(t_k)]

with ``f`` the identified model's RK4 step, yaw carried continuously (``psi`` is not wrapped into
[-pi, pi]; :func:`validation.models.rgblimp_greybox.physics_step`), which is the mean of
``GreyBoxGP.propagate``. The outputs at ``t0`` are the start state, the ``<state>_start``
parameters (default all 0: at rest at the origin, level); a free run of a recorded flight starts
from its first recorded state, as ``flightgp reproduce rgblimp`` runs its models.

Standard deviations
-------------------
``<state>_sd`` at ``t_{k+1}`` is the standard deviation of the state propagated along the run
from the known start (0 at ``t0``): ``GreyBoxGP.propagate`` with the GPs' noise included, the
first-order propagation of the state covariance through the linearised one-step map
(:mod:`fmu_src.fmi.greybox` says how and what it is not). The covariance (12 x 12) is a hidden
state.

Envelope: when a GP input leaves the training range (by more than 10 % of the range), the FMU
logs a Warning once per excursion; the GP then extrapolates, and the sd outputs grow faster. A
model fitted on the flights of one configuration saw one value of each input, so any other
thrust or gondola position is outside its envelope.
"""
from __future__ import annotations

from fmu_src.fmi.greybox import GreyBoxSlave
from fmu_src.rgblimp_rkgp.model import RGBlimpRKGPModel
from validation.vehicles.rgblimp_equations import INPUT_NAMES, SAMPLE_TIME, STATE_NAMES

#: The default start state, for the start parameters' descriptions.
START_DEFAULT = "0, at rest at the origin, level; set the first recorded state of a flight"


class RGBlimpRKGP(GreyBoxSlave):
    """RGBlimp RKGP (the class the build generates sets its description, PACKAGE and VARIABLES)."""

    STATE_NAMES, INPUT_NAMES = STATE_NAMES, INPUT_NAMES
    MODEL = RGBlimpRKGPModel
    MODEL_PHRASE = "RGBlimp RKGP model"
    STEP_SIZE = SAMPLE_TIME
