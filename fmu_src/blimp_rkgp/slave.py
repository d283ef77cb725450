"""The blimp RKGP FMU (Ko et al., ICRA 2007, sec. IV-B): motor commands in; the full state and its
standard deviations, propagated along the run, out; the blimp ODE integrated by RK4 plus a GP on
its one-step residual inside (:mod:`fmu_src.blimp_rkgp.model`). docs/fmus.md, "Blimp RKGP",
lists the variables.

Every blimp RKGP FMU carries a copy of this file (:mod:`fmu_src.fmi.pythonfmu`), so it imports
only the FMI layer (:mod:`fmu_src.fmi.greybox`, whose slave runs every grey-box FMU), the model,
numpy and the standard library. The per-FMU slave script that
:func:`fmu_src.blimp_rkgp.build.build_blimp_rkgp_fmu` generates subclasses :class:`BlimpRKGP`
with the FMU's variable table (:func:`fmu_src.fmi.greybox.greybox_variables`), its package name
and its default step.

Timing (docs/conventions.md, "FMU sampling convention")
-------------------------------------------------------
The model was trained on frame pairs with the frame interval as its input column ``dt``
(:func:`validation.models.blimp_identification.recording_arrays`): the physics integrates over ``dt``
and the GP sees it. The FMU does exactly that with ``dt = h``, the communication step: the host
chooses ``h`` (the default experiment's step is the median training frame interval), the first
``fmi2DoStep`` fixes it until reset, and a step outside the training range of ``dt`` (widened by
the envelope margin) is refused (logged Error, ``fmi2Discard``): the residual of another step
length is not what the GP learned. The commands set at ``t_k`` are held over ``[t_k, t_{k+1})``;
``fmi2DoStep(t_k, h)`` sets the state outputs to

    s(t_{k+1}) = RK4_blimp(s(t_k), u(t_k), h) + E[residual | s(t_k), u(t_k), h, z(k)]

(each step cut into equal RK4 substeps no longer than ``max_step``), which is
``GreyBoxGP.rollout`` (the mean rollout: the mean is fed back). ``z(k)`` are the lagged fan
commands when the model's GP sees them (``validation.models.blimp_greybox``): hidden states that
start at 0 (fans at rest) at the start time and advance with ``u(t_k)`` over each step. The
outputs at ``t0`` are the start state, the ``<state>_start`` parameters (default: at rest at the
origin hanging in the static attitude of the model's parameters, as
:class:`validation.vehicles.blimp.BlimpReference` starts).

Standard deviations
-------------------
``<state>_sd`` at ``t_{k+1}`` is the standard deviation of the state propagated along the run
from the known start (0 at ``t0``): ``GreyBoxGP.propagate`` with the GPs' noise included, the
first-order propagation of the state covariance through the linearised one-step map
(:mod:`fmu_src.fmi.greybox` says how and what it is not). The covariance (12 x 12) is a hidden
state.

Envelope: when a GP input leaves the training range (by more than 10 % of the range), the FMU
logs a Warning once per excursion; the GP then extrapolates, and the sd outputs grow faster.
"""
from __future__ import annotations

from fmu_src.blimp_rkgp.model import RKGPModel
from fmu_src.fmi.greybox import GreyBoxSlave
from validation.vehicles.blimp_equations import INPUT_NAMES, STATE_NAMES

#: The default start state, for the start parameters' descriptions.
START_DEFAULT = "at rest at the origin, hanging"


class BlimpRKGP(GreyBoxSlave):
    """Blimp RKGP (the class the build generates sets its description, PACKAGE, VARIABLES and
    DEFAULT_STEP_SIZE); the hidden state beyond mean and covariance is the lagged commands."""

    STATE_NAMES, INPUT_NAMES = STATE_NAMES, INPUT_NAMES
    MODEL = RKGPModel
    MODEL_PHRASE = "blimp RKGP model"

    def step_problem(self, h: float) -> str | None:
        low, high = self._model.step_range()
        if not low <= h <= high:
            return (f"communicationStepSize {h:.16g} s is outside {low:.6g} .. {high:.6g} s, the "
                    "frame intervals the GP residual was trained on (plus 10 %); step with the "
                    "default experiment's step size")
        return None
