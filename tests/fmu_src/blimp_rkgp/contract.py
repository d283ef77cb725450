"""The blimp RKGP's own contract, which the pythonfmu and the native blimp RKGP FMUs both pass
(:class:`BlimpRkgpContract`, and :class:`BlimpRkgpLaggedContract` for a model whose GPs see
lagged fan commands), the factory of their cases and the Python reference they equal."""
from __future__ import annotations

import functools

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import fmi2Discard, fmi2Error

from tests.fmu_src.contract import FmuCase, Host, check_state_save_restore, standard_run
from validation.models.blimp_greybox import BlimpStepDescription, lagged_commands
from validation.vehicles.blimp import INPUT_NAMES as BLIMP_INPUTS
from validation.vehicles.blimp import STATE_NAMES as BLIMP_STATES
from validation.vehicles.blimp_flight import BlimpFlightTest

BLIMP_HOLD = 10  # frames each random command level is held (0.5 s at 20 Hz)


def blimp_reference(trained: dict, commands: np.ndarray, start: np.ndarray, *, step: float | None = None):
    """What a blimp RKGP FMU must output flying ``commands`` (n + 1, 3) from ``start`` (12,) at the
    communication step ``step`` (default the stand-in's frame interval): ``GreyBoxGP.rollout``'s
    means and ``GreyBoxGP.propagate``'s standard deviations (from a known start, noise included),
    shape (n + 1, 24), with the lagged commands from rest as GP inputs when the model
    (``trained["command_lags"]``) has them."""
    h = BlimpFlightTest.sample_time if step is None else step
    n = len(commands) - 1
    lags = trained.get("command_lags", ())
    steps = np.column_stack([commands[:n], np.full(n, h),
                             lagged_commands(commands[:n], np.full(n, h), time_constants=lags)])
    physics = BlimpStepDescription(trained["params"], command_lags=lags).physics_step()
    mean = trained["model"].rollout(start, steps, physics)
    return np.hstack([mean, trained["model"].propagate(start, steps, physics).sd])


def blimp_rkgp_case(path, trained: dict, *, n_steps: int = 80) -> FmuCase:
    """The blimp RKGP FMU at ``path`` of the model of ``trained`` (the ``blimp_trained`` or
    ``blimp_lagged`` fixture), driven by the first ``n_steps`` of its training commands (4 s:
    inside the envelope) from the training flight's first state, against
    :func:`blimp_reference`."""
    h = BlimpFlightTest.sample_time
    commands, start = trained["commands"], trained["states"][0]

    # tolerance 1e-9: the same formulas as GreyBoxGP.rollout, GreyBoxGP.propagate and
    # GaussianProcess.predict evaluated for one state (and its 24 moved copies) instead of a batch
    # (different rounding, ~1e-16 relative per step, divided by the central difference's
    # 2 * PROPAGATION_STEP in the Jacobian and grown by the dynamics over 80 steps). The reference
    # is computed once per case (the propagated sds take about a second; the native contract
    # compares six runs with it).
    return FmuCase(path=path, step=h, n_steps=n_steps, inputs=lambda k: dict(zip(BLIMP_INPUTS, commands[k])),
                   reference=functools.cache(lambda: (blimp_reference(trained, commands[:n_steps + 1], start), 0)),
                   parameters={f"{s}_start": v for s, v in zip(BLIMP_STATES, start)},
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


class BlimpRkgpLaggedContract:
    """What every blimp RKGP FMU does with a model whose GPs see the fans' lagged commands
    (validation.models.blimp_greybox; one GP per state): run on the ``lagged_case`` fixture of the
    test module (:func:`blimp_rkgp_case` of the ``blimp_lagged`` fixture) and ``blimp_lagged``."""

    def test_a_lagged_model_equals_the_rollout_and_the_propagated_sds(self, lagged_case, blimp_lagged, tmp_path):
        """Over 40 steps of changing commands: the means equal GreyBoxGP.rollout's and the sds
        GreyBoxGP.propagate's (lags from rest, known start, noise included) to 1e-9 (measured 6e-16
        and 2e-13); the lags matter (without them the means differ); the sds are propagated, not
        one-step: those of position and yaw grow along the free run, the positions' far beyond a
        one-step sd."""
        host = Host(extract(str(lagged_case.path), unzipdir=str(tmp_path / "unzipped")))
        try:
            outputs = standard_run(lagged_case, host)
        finally:
            host.close()
        expected, _ = lagged_case.reference()
        np.testing.assert_allclose(outputs, expected, rtol=0, atol=lagged_case.tolerance)
        assert host.statuses() <= {0}  # inside the envelope
        commands, start = blimp_lagged["commands"][:lagged_case.n_steps + 1], blimp_lagged["states"][0]
        assert len(np.unique(commands[:-1], axis=0)) >= 4  # changing commands
        sd = outputs[:, 12:]
        # Position and yaw, which nothing pulls back, grow every 10 steps (not every step: their
        # correlations with the attitude and the velocities can take some away for a step).
        assert np.all(np.diff(sd[::10, [0, 1, 2, 5]], axis=0) > 0), sd[::10]
        n, h, time_constants = len(commands) - 1, lagged_case.step, blimp_lagged["command_lags"]
        lags = lagged_commands(commands[:-1], np.full(n, h), time_constants=time_constants)
        steps = np.column_stack([commands[:-1], np.full(n, h), lags])
        physics = BlimpStepDescription(blimp_lagged["params"], command_lags=time_constants).physics_step()
        _, one_step = blimp_lagged["model"].predict_one_step(outputs[-2:-1, :12], steps[-1:], physics,
                                                             include_noise=True)
        assert np.all(sd[-1, :3] > 5 * np.sqrt(one_step[0, :3])), (sd[-1, :3], np.sqrt(one_step[0, :3]))
        zero_lags = blimp_lagged["model"].rollout(start, np.column_stack([steps[:, :4], 0 * lags]), physics)
        assert np.abs(zero_lags - outputs[:, :12]).max() > 1e-4  # the FMU really feeds the lags in

    def test_reset_and_a_restored_state_restart_the_lags_where_they_were(self, lagged_case, tmp_path):
        """The lagged commands are hidden states: reset starts them from rest again (the run
        repeats), and a saved state restores them (step/save/step/restore/step identical)."""
        unzipdir = extract(str(lagged_case.path), unzipdir=str(tmp_path / "unzipped"))
        host = Host(unzipdir)
        try:
            first = standard_run(lagged_case, host)
            host.fmu.reset()
            np.testing.assert_array_equal(standard_run(lagged_case, host), first)
            host.fmu.reset()
            check_state_save_restore(lagged_case, unzipdir, host)
        finally:
            host.close()
