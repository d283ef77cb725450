"""A second FMI host: the Open Simulation Platform's libcosim, through ``libcosimpy``.

fmpy is flightgp's main host; running every FMU in libcosim as well checks that nothing depends
on fmpy's habits (call order, step handling, logging). libcosim's times and step sizes are
integer nanoseconds (DESIGN.md, "FMU rules"), so the step grid ``k * step`` is converted once
with rounding, never accumulated.
"""
from __future__ import annotations

import numpy as np

from .errors import BadInputError

NANOSECONDS_PER_SECOND = 1_000_000_000


def simulate_in_libcosim(fmu_path, *, step_size: float, n_steps: int, inputs: dict | None = None,
                         start_values: dict | None = None, outputs=()) -> dict:
    """Co-simulate one FMU in libcosim on a fixed step grid.

    Parameters
    ----------
    fmu_path : path
        The FMU (FMI 2.0 co-simulation).
    step_size : float
        Communication step, s (converted to integer nanoseconds).
    n_steps : int
        Steps to take; the results hold the values after each step.
    inputs : dict of name -> ndarray, shape (n_steps,)
        Real inputs, value ``k`` applied over step ``k`` (set before it is taken).
    start_values : dict of name -> float
        Real parameters or start values set before initialisation.
    outputs : sequence of str
        Real variables to record after every step.

    Returns
    -------
    dict of name -> ndarray, shape (n_steps,)
        ``"time"`` (s, the end of each step) and each output observed there. libcosim
        initialises the FMU inside its first step, so the start time itself is not observed.
    """
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    step_ns = int(round(step_size * NANOSECONDS_PER_SECOND))
    if step_ns <= 0:
        raise BadInputError(f"step size {step_size} s is below libcosim's 1 ns resolution")
    execution = CosimExecution.from_step_size(step_size=step_ns)
    index = execution.add_local_slave(local_slave=CosimLocalSlave(fmu_path=str(fmu_path), instance_name="fmu"))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer=observer)
    manipulator = CosimManipulator.create_override()
    execution.add_manipulator(manipulator=manipulator)
    references = {v.name.decode(): v.reference for v in execution.slave_variables(slave_index=index)}
    unknown = [n for n in (*(inputs or {}), *(start_values or {}), *outputs) if n not in references]
    if unknown:
        raise BadInputError(f"{fmu_path}: no variable(s) {', '.join(unknown)}")
    for name, value in (start_values or {}).items():
        execution.real_initial_value(slave_index=index, variable_reference=references[name], value=float(value))
    inputs = {name: np.asarray(values, dtype=float) for name, values in (inputs or {}).items()}

    recorded = {name: np.empty(n_steps) for name in outputs}
    output_references = [references[n] for n in outputs]
    for k in range(n_steps):
        if inputs:
            manipulator.slave_real_values(index, [references[n] for n in inputs],
                                          [float(v[k]) for v in inputs.values()])
        execution.step()
        for name, value in zip(outputs, observer.last_real_values(
                slave_index=index, variable_references=output_references)):
            recorded[name][k] = value
    recorded["time"] = np.arange(1, n_steps + 1) * step_ns / NANOSECONDS_PER_SECOND
    return recorded
