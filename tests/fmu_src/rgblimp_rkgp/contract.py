"""The RGBlimp RKGP's own contract, which the pythonfmu and the native RGBlimp RKGP FMUs both pass
(:class:`RGBlimpRkgpContract`), the factory of their cases and the Python free run they equal."""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error

from tests.fmu_src.contract import FmuCase, Host
from validation.vehicles.rgblimp_equations import INPUT_NAMES, SAMPLE_TIME, STATE_NAMES

OUTPUTS = [*STATE_NAMES, *(f"{s}_sd" for s in STATE_NAMES)]


def rgblimp_reference(trained: dict, inputs: np.ndarray, start: np.ndarray) -> np.ndarray:
    """What an RGBlimp RKGP FMU must output flying ``inputs`` (n + 1, 5) from ``start`` (12,):
    ``GreyBoxGP.propagate``'s means and standard deviations (known start, noise included) with
    the physics step of the model file's description, shape (n + 1, 24)."""
    run = trained["model"].propagate(start, inputs[:-1], trained["description"].physics_step())
    return np.hstack([run.mean, run.sd])


def start_values(start: np.ndarray) -> dict:
    """The ``<state>_start`` parameters of the start state ``start`` (12,)."""
    return {f"{s}_start": float(v) for s, v in zip(STATE_NAMES, start)}


#: The sample of the test flight data_119 the standard run starts at (1 s in): its first state,
#: at launch, lies outside the training envelope of the 40 training transitions (the contract
#: needs a standard run inside it), the free run from sample 60 stays inside.
CASE_START = 60
#: Why libcosim cannot host an RGBlimp RKGP FMU: it counts time in whole nanoseconds, so its
#: communication points k * 16 666 667 ns drift from the FMU's t_k = k / 60 s by 1/3 ns a step and
#: leave the FMU's time tolerance (1e-6 of the step, docs/conventions.md, "FMU sampling
#: convention") at the 51st step, which the FMU then refuses.
NO_LIBCOSIM = ("libcosim counts time in whole nanoseconds: its 1/60 s steps drift from the FMU's "
               "communication points beyond their tolerance after 50 steps")


def rgblimp_rkgp_case(path, trained: dict, *, n_steps: int = 60) -> FmuCase:
    """The RGBlimp RKGP FMU at ``path`` of the model of ``trained`` (the ``rgblimp_trained``
    fixture), driven by ``n_steps`` inputs of the test flight data_119 (1 s) from its recorded
    state at :data:`CASE_START`, against :func:`rgblimp_reference`."""
    inputs, start = trained["inputs"][CASE_START:], trained["states"][CASE_START]

    @functools.cache
    def reference():
        return rgblimp_reference(trained, inputs[:n_steps + 1], start), 0

    # tolerance 1e-9: the same formulas as GreyBoxGP.propagate and GaussianProcess.predict evaluated
    # for one state (and its 24 moved copies) instead of a batch, and in C with libm instead of
    # numpy (different rounding, ~1e-16 relative per operation, divided by the central difference's
    # 2 * PROPAGATION_STEP in the Jacobian and grown by the dynamics along the run).
    return FmuCase(path=path, step=SAMPLE_TIME, n_steps=n_steps, inputs=lambda k: dict(zip(INPUT_NAMES, inputs[k])),
                   reference=reference, parameters=start_values(start),
                   # Trained on one configuration, so on one value of each input: any other is outside.
                   far_inputs={"thrust_left": 0.05, "gondola_x": 0.09}, bands=[], spreads=[],
                   bad_inputs=[("thrust_left", math.nan), ("gondola_x", math.inf), ("thrust_right", -math.inf)],
                   no_libcosim_reason=NO_LIBCOSIM)


class RGBlimpRkgpContract:
    """What every RGBlimp RKGP FMU does besides the FMU contract: its interface and units, its
    default start and its fixed step of one 1/60 s sample; run on the ``case`` fixture of the test
    module."""

    def test_declares_the_interface_and_steps_one_sample(self, case, tmp_path):
        description = read_model_description(str(case.path))
        variables = {v.name: v for v in description.modelVariables}
        by_causality = lambda c: [v.name for v in description.modelVariables if v.causality == c]  # noqa: E731
        assert by_causality("input") == list(INPUT_NAMES)
        assert by_causality("output") == OUTPUTS
        assert by_causality("parameter") == [f"{s}_start" for s in STATE_NAMES]
        assert [variables[n].unit for n in INPUT_NAMES] == ["N", "N", "m", "m", "m"]
        assert [variables[n].unit for n in ("x", "psi", "U", "R", "R_sd")] == ["m", "rad", "m/s", "rad/s", "rad/s"]
        assert all(float(variables[f"{s}_start"].start) == 0.0 for s in STATE_NAMES)  # at rest at the origin
        assert float(description.defaultExperiment.stepSize) == SAMPLE_TIME
        host = Host(extract(str(case.path), unzipdir=str(tmp_path / "unzipped")))
        try:
            host.fmu.setupExperiment(startTime=0.0)
            host.fmu.enterInitializationMode()
            host.fmu.exitInitializationMode()
            np.testing.assert_array_equal(host.get(), np.zeros(24))  # the default start; sd 0
            with pytest.raises(FMICallException) as refused:  # 50 Hz instead of the 60 Hz sample
                host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=0.02)
            assert refused.value.status == fmi2Discard
            errors = [message for status, _, message in host.messages if status == fmi2Error]
            assert "expected communicationStepSize" in errors[-1]
            host.fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=SAMPLE_TIME)  # then it steps
            assert np.all(np.isfinite(host.get()))
        finally:
            host.close()
