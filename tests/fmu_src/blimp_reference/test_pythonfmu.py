"""The blimp physics reference FMU (fmu_src/blimp_reference): the FMU contract on the default
blimp, then what is particular to it: the host's step and a given start state, the physical
parameters (declared with units and words, each one running the reference with that parameter
changed) and the FMU as a diagnose reference."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from fmpy import extract, read_model_description

from fmu_src import build_blimp_reference_fmu
from fmu_src.fmi.slave import UNITS
from tests.fmu_src.contract import FmuCase, FmuContract, Host, run_in_fmpy, standard_run
from validation.core.manoeuvres import doublet, step
from validation.vehicles.blimp import INPUT_NAMES, STATE_NAMES, BlimpParameters, BlimpReference
from validation.vehicles.blimp_effects import TERM_DESCRIPTIONS, BlimpEffects
from validation.vehicles.effect_vehicle import effect_model

STEP = BlimpReference.sample_time  # 0.05 s, the reference's motion-capture interval


def blimp_commands(time: np.ndarray) -> np.ndarray:
    """All three commands moving, shape (len(time), 3): a gondola thrust step forward, a
    thrust-angle doublet while it pushes, a tail-fan doublet."""
    return np.column_stack([step(time, amplitude=0.8, start=0.5),
                            doublet(time, amplitude=0.4, step_time=0.5, start=1.5),
                            doublet(time, amplitude=0.6, step_time=0.5, start=2.5)])


@pytest.fixture(scope="module")
def blimp_reference_fmu(tmp_path_factory):
    return build_blimp_reference_fmu(tmp_path_factory.mktemp("fmu"))


@pytest.fixture(scope="module")
def case(blimp_reference_fmu):
    n = 80
    time = np.arange(n + 1) * STEP
    commands = blimp_commands(time)

    def reference():
        return BlimpReference().simulate_states(time, commands), 0

    # tolerance 1e-9, the contract's: the FMU runs the reference's own RK4 (a copy of
    # validation.vehicles.blimp_equations) over the same substeps; only the step's last bits differ
    # (h against time[k + 1] - time[k]).
    return FmuCase(path=blimp_reference_fmu, step=STEP, n_steps=n, inputs=lambda k: dict(zip(INPUT_NAMES, commands[k])),
                   reference=reference, far_inputs={"u_gondola": -0.9}, bands=[], training_envelope=False,
                   bad_inputs=[("u_gondola", float("nan")), ("mu", float("inf")),
                               ("u_tail", 1.5)])  # beyond the declared -1..1


class TestBlimpReferenceFmu(FmuContract):
    """The FMU contract on the blimp reference."""


def test_blimp_reference_starts_at_the_given_state_and_follows_the_hosts_step(case, tmp_path):
    """The host picks the step (0.02 s: two RK4 substeps of 0.01 s; after a reset 0.1 s: ten);
    the first step fixes it: BlimpReference.simulate_states from the same start state."""
    start = dict(zip(STATE_NAMES, [0.5, -0.2, 0.1, 0.05, -0.03, 0.4, 0.3, 0.05, -0.02, 0.02, -0.01, 0.03]))
    host = Host(extract(str(case.path), unzipdir=str(tmp_path / "u")))
    try:
        for h in (0.02, 0.1):
            n = round(3.0 / h)
            time = np.arange(n + 1) * h
            commands = blimp_commands(time)
            run = replace(case, step=h, n_steps=n,
                          inputs=lambda k: dict(zip(INPUT_NAMES, commands[k])),  # noqa: B023
                          parameters={f"{name}_start": value for name, value in start.items()})
            outputs = standard_run(run, host)
            np.testing.assert_array_equal(outputs[0], list(start.values()))
            expected = BlimpReference().simulate_states(time, commands, initial_state=list(start.values()))
            # 1e-9 as the contract: the same RK4 code and substeps.
            np.testing.assert_allclose(outputs, expected, rtol=0, atol=1e-9)
            host.fmu.reset()
    finally:
        host.close()
    assert host.statuses() == {0}


def test_every_physical_parameter_is_declared_with_its_unit_and_words(case):
    """The 30 entries of BlimpParameters.to_vector() are fixed parameters with the reference's
    values: by the blimp's effect-term names, signs, units and words where an entry is one
    (X_UU = -quadratic_drag_x, ...), else by their entry names."""
    variables = {v.name: v for v in read_model_description(str(case.path)).modelVariables}
    physical = {name: v for name, v in variables.items()
                if v.causality == "parameter" and not name.endswith("_start")}
    assert len(physical) == len(BlimpParameters.vector_names()) == 30
    assert all(v.variability == "fixed" and v.unit in UNITS and v.description for v in physical.values())
    params = BlimpParameters()
    assert float(physical["X_UU"].start) == -params.quadratic_drag[0] and physical["X_UU"].unit == "N.s2/m2"
    assert physical["X_UU"].description.startswith(TERM_DESCRIPTIONS["X_UU"])
    assert float(physical["N_R"].start) == -params.rotational_damping[2] and physical["N_R"].unit == "N.m.s/rad"
    assert float(physical["Z_0"].start) == -params.net_lift and physical["Z_0"].unit == "N"
    assert float(physical["gondola_thrust_forward"].start) == params.gondola_thrust_forward
    assert (float(physical["mass"].start), physical["mass"].unit) == (params.mass, "kg")
    assert (float(physical["inertia_y"].start), physical["inertia_y"].unit) == (params.inertia[1], "kg.m2")
    assert (physical["fin_lift"].unit, physical["linear_drag_x"].unit) == ("kg/m", "N.s/m")
    assert physical["cg_position_z"].description.endswith("along body z (down)")
    assert {"quadratic_drag_x", "rotational_damping_z", "net_lift"}.isdisjoint(variables)


def test_changed_parameters_run_the_reference_with_those_parameters(case):
    """An effect term, a negated one and an entry by its own name, set before initialisation:
    BlimpReference with the same BlimpParameters changed (1e-9, as the contract)."""
    changes = {"X_UU": -0.16, "N_R": -0.03, "inertia_y": 0.07}
    params = BlimpParameters()
    changed = replace(params, quadratic_drag=(0.16, *params.quadratic_drag[1:]),
                      rotational_damping=(*params.rotational_damping[:2], 0.03),
                      inertia=(params.inertia[0], 0.07, params.inertia[2]))
    time = np.arange(case.n_steps + 1) * case.step
    commands = blimp_commands(time)
    outputs = run_in_fmpy(case.path, dict(zip(INPUT_NAMES, commands.T)), step=case.step, outputs=STATE_NAMES,
                          start_values=changes)
    expected = BlimpReference(params=changed).simulate_states(time, commands)
    np.testing.assert_allclose(outputs, expected, rtol=0, atol=1e-9)
    assert np.abs(expected - case.reference()[0]).max() > 1e-2  # the changes matter


def test_as_a_diagnose_reference_the_parameters_are_fmu_parameter_terms(case):
    """effect_model of the FMU lists every physical parameter as an fmu_parameter term with the
    built-in blimp's values and words, and a replay with a term changed through the FMU is the
    built-in blimp's effect model with that term changed: to 1e-5, because the built-in effect
    model takes one RK4 step per 0.05 s interval and the FMU five substeps, as BlimpReference
    (measured 4.4e-6 over these 4 s, far below the blimp's sensor noise of 1 mm and 6 mm/s)."""
    through_fmu, built_in = effect_model(str(case.path), purpose="test"), BlimpEffects(BlimpReference())
    through_fmu.workers = 1
    assert set(through_fmu.terms["fmu_parameter"]) == {v.name for v in read_model_description(str(case.path))
                                                       .modelVariables if v.causality == "parameter"
                                                       and not v.name.endswith("_start")}
    for term in ("X_UU", "N_R", "Z_0", "tail_thrust_negative"):
        assert through_fmu.model_value(term) == built_in.model_value(term)
        assert through_fmu.term_description(term).startswith(built_in.term_description(term))
    time = np.arange(case.n_steps + 1) * case.step
    commands = blimp_commands(time)
    replays = through_fmu.simulate_many([[], [{"effect": "fmu_parameter", "term": "X_UU", "value": -0.16}]],
                                        time, commands)
    np.testing.assert_allclose(replays[0], BlimpReference().simulate_states(time, commands), rtol=0, atol=1e-9)
    expected = built_in.simulate_many([[{"effect": "quadratic_drag", "term": "X_UU", "value": -0.16}]], time,
                                      commands)[0]
    np.testing.assert_allclose(replays[1], expected, rtol=0, atol=1e-5)
    assert np.abs(replays[1] - replays[0]).max() > 1e-3  # the change matters
