"""The base slave's policies that no built FMU triggers on demand (fmu_src/fmi/slave.py)."""
from __future__ import annotations

from pythonfmu.enums import Fmi2Status

from fmu_src.fmi.slave import FlightgpSlave, ModelFailure, Variable


def test_a_step_the_model_cannot_undo_stops_the_fmu_until_reset():
    """A model that cannot roll back a failed step (JSBSim inside an FMU) raises ModelFailure: that
    step and every later one are refused (fmi2Discard, logged Errors), never retried on a moved
    state. The slave is driven directly in Python, as pythonfmu's native layer would."""

    class Counter(FlightgpSlave):
        VARIABLES = (Variable("y", "output", "continuous", "exact", "1", "steps taken", 0.0),)

        def start_model(self):
            self.values["y"] = 0.0

        def advance_model(self, t, h):
            if self.values["y"] == 2.0:  # the third step
                raise ModelFailure("the simulator inside has moved on")
            self.values["y"] += 1.0

    slave = Counter(instance_name="counter")
    slave.setup_experiment(0.0)
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    assert slave.do_step(0.0, 0.1) and slave.do_step(0.1, 0.1)
    assert not slave.do_step(0.2, 0.1)
    assert not slave.do_step(0.2, 0.1)  # no retry on a state that has moved
    assert slave.values["y"] == 2.0
    errors = [m.msg for m in slave.log_queue if m.status == Fmi2Status.error]
    assert "the simulator inside has moved on" in errors[0] and "reset" in errors[0]
    assert "failed earlier" in errors[1]
