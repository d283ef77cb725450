"""The blimp RKGP's own contract, which the pythonfmu and the native blimp RKGP FMUs both pass
(:class:`BlimpRkgpContract`), and the factory of their ``case``."""
from __future__ import annotations

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error

from tests.fmu_src.contract import FmuCase, Host
from validation.models.blimp_identification import physics_step
from validation.vehicles.blimp import INPUT_NAMES as BLIMP_INPUTS
from validation.vehicles.blimp import STATE_NAMES as BLIMP_STATES
from validation.vehicles.blimp_flight import BlimpFlightTest

BLIMP_HOLD = 10  # frames each random command level is held (0.5 s at 20 Hz)


def blimp_rkgp_case(path, trained: dict) -> FmuCase:
    """The blimp RKGP FMU at ``path`` of the model of ``trained`` (the ``blimp_trained`` fixture),
    driven by the first 4 s of its training commands (inside the envelope) from the training
    flight's first state, against ``GreyBoxGP.rollout`` and ``predict_one_step``'s sds."""
    h, n = BlimpFlightTest.sample_time, 80  # the training commands' first 4 s: inside the envelope
    commands, start = trained["commands"], trained["states"][0]

    def reference():
        physics = physics_step(trained["params"])
        steps = np.column_stack([commands[:n], np.full(n, h)])  # dt column = the FMU's step
        mean = trained["model"].rollout(start, steps, physics)
        _, var = trained["model"].predict_one_step(mean[:-1], steps, physics)
        return np.hstack([mean, np.vstack([np.zeros(12), np.sqrt(var)])]), 0

    # tolerance 1e-9: the same formulas as GreyBoxGP.rollout and GaussianProcess.predict evaluated
    # for one state instead of a batch (different rounding, ~1e-16 relative per step, grown by the
    # dynamics over 80 steps; measured 4e-11 on the states, 2e-11 on the sds).
    return FmuCase(path=path, step=h, n_steps=n, inputs=lambda k: dict(zip(BLIMP_INPUTS, commands[k])),
                   reference=reference, parameters={f"{s}_start": v for s, v in zip(BLIMP_STATES, start)},
                   far_inputs={"u_gondola": -1.0, "mu": 1.5},  # trained on 0.2 .. 0.8 and -0.2 .. 0.4
                   bands=[], spreads=[f"{s}_sd" for s in ("U", "V", "W", "P", "Q", "R")],
                   bad_inputs=[("u_gondola", float("nan")), ("mu", float("inf")),
                               ("u_tail", 1.5)])  # beyond the declared -1 .. 1


class BlimpRkgpContract:
    """What every blimp RKGP FMU does besides the FMU contract: its interface, its default start
    and step, and the refusal of steps it was not trained for; run on the ``case`` fixture of the
    test module."""

    def test_declares_the_interface_and_refuses_steps_it_was_not_trained_for(self, case, tmp_path):
        description = read_model_description(str(case.path))
        by_causality = lambda c: [v.name for v in description.modelVariables if v.causality == c]  # noqa: E731
        assert by_causality("input") == list(BLIMP_INPUTS)
        assert by_causality("output") == list(BLIMP_STATES) + [f"{s}_sd" for s in BLIMP_STATES]
        assert by_causality("parameter") == [f"{s}_start" for s in BLIMP_STATES]
        # The default start is the reference parameters' hanging equilibrium: CG on the z axis, level.
        assert all(float(v.start) == 0.0 for v in description.modelVariables if v.causality == "parameter")
        # Default step: the median training frame interval (20 Hz).
        assert abs(float(description.defaultExperiment.stepSize) - 0.05) < 1e-12
        host = Host(extract(str(case.path), unzipdir=str(tmp_path / "unzipped")))
        try:
            host.fmu.setupExperiment(startTime=0.0)
            host.fmu.enterInitializationMode()
            host.fmu.exitInitializationMode()
            np.testing.assert_array_equal(host.get(), np.zeros(24))  # at rest, hanging; sd 0
            with pytest.raises(FMICallException) as refused:  # twice the frame interval
                host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.1)
            assert refused.value.status == fmi2Discard
            errors = [message for status, _, message in host.messages if status == fmi2Error]
            assert "frame intervals the GP residual was trained on" in errors[-1]
            host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.05)  # then it steps
            assert np.all(np.isfinite(host.get()))
        finally:
            host.close()
