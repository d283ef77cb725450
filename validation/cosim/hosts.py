"""A second FMI host: the Open Simulation Platform's libcosim, through ``libcosimpy``.

fmpy is flightgp's main host; running every FMU in libcosim as well checks that nothing depends
on fmpy's habits (call order, step handling, logging). libcosim's times and step sizes are
integer nanoseconds (libcosim's ``cosim::duration``), so the step grid ``k * step`` is converted
once with rounding, never accumulated.
"""
from __future__ import annotations

import functools

import numpy as np

from validation.core.errors import BadInputError

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


@functools.lru_cache(maxsize=1)
def _c_host():
    """The C host (``native_host.c``), compiled with the system gcc once per process into a
    folder removed at exit. Returns its path."""
    import atexit
    import shutil
    import subprocess
    import tempfile
    from pathlib import Path

    from fmu_src import fmi_headers

    work = Path(tempfile.mkdtemp(prefix="flightgp_c_host_bin_"))
    atexit.register(shutil.rmtree, work, ignore_errors=True)
    host = work / "native_host"
    compiled = subprocess.run(["gcc", "-O2", "-std=c99", "-Wall", "-Wextra", f"-I{fmi_headers()}",
                               str(Path(__file__).with_name("native_host.c")), "-o", str(host), "-ldl"],
                              capture_output=True, text=True)
    if compiled.returncode != 0:
        raise RuntimeError(f"gcc failed to compile the C host: {compiled.stderr.strip()}")
    return host


def simulate_in_c_host(fmu_path, *, step_size: float, n_steps: int, inputs: dict, outputs,
                       start_values: dict | None = None, repeats: int = 1) -> dict:
    """Co-simulate one FMU in a plain C program (``validation/cosim/native_host.c``, compiled here
    with the system gcc) that loads the FMU's binary with ``dlopen`` and calls the FMI 2.0
    functions itself: no Python in the process, so only a native (Python-free) FMU runs there.

    Parameters
    ----------
    fmu_path : path
        The FMU (FMI 2.0 co-simulation, with a ``binaries/linux64`` binary).
    step_size : float
        Communication step, s; communication points ``t_k = k step_size``.
    n_steps : int
    inputs : dict of name -> ndarray, shape (n_steps + 1,)
        Real inputs; value ``k`` is set at ``t_k`` (value 0 also before initialisation).
    outputs : sequence of str
        Real variables read after initialisation and after every step.
    start_values : dict of name -> float or bool
        Parameters and start values set before initialisation (Boolean variables by their type).
    repeats : int
        Runs (``fmi2Reset`` between them) for the timing; outputs are the first run's.

    Returns
    -------
    dict
        ``"time"`` (n_steps + 1,), s; each output, shape (n_steps + 1,); ``"us_per_step"``
        (best over the repeats of ``fmi2SetReal`` + ``fmi2DoStep`` + ``fmi2GetReal``, microseconds);
        ``"python_in_process"`` (whether a libpython was mapped into the host process).

    Raises
    ------
    RuntimeError
        The host failed (its standard error, including the FMU's log, is in the message).
    """
    import shutil
    import subprocess
    import tempfile
    from pathlib import Path

    from fmpy import extract, read_model_description


    description = read_model_description(str(fmu_path))
    variables = {v.name: v for v in description.modelVariables}
    identifier = description.coSimulation.modelIdentifier
    with tempfile.TemporaryDirectory(prefix="flightgp_c_host_") as work:
        work = Path(work)
        host = _c_host()
        unzipdir = Path(extract(str(fmu_path), unzipdir=str(work / "fmu")))
        starts = {n: v for n, v in (start_values or {}).items() if variables[n].type != "Boolean"}
        booleans = {n: v for n, v in (start_values or {}).items() if variables[n].type == "Boolean"}
        rows = np.column_stack([np.asarray(inputs[n], dtype=float) for n in inputs]) if inputs \
            else np.zeros((n_steps + 1, 0))
        script = [str(len(starts)), *(f"{variables[n].valueReference} {float(v)!r}" for n, v in starts.items()),
                  str(len(booleans)), *(f"{variables[n].valueReference} {int(bool(v))}" for n, v in booleans.items()),
                  str(len(inputs)), *(str(variables[n].valueReference) for n in inputs),
                  str(len(outputs)), *(str(variables[n].valueReference) for n in outputs),
                  f"{n_steps} {float(step_size)!r} {repeats}",
                  *(" ".join(repr(float(x)) for x in row) for row in rows[:n_steps + 1])]
        binary = unzipdir / "binaries" / "linux64" / f"{identifier}.so"
        result = subprocess.run([str(host), str(binary), identifier, description.guid,
                                 (unzipdir / "resources").as_uri()],
                                input="\n".join(script) + "\n", capture_output=True, text=True, timeout=600)
        shutil.rmtree(unzipdir, ignore_errors=True)
    if result.returncode != 0:
        raise RuntimeError(f"the C host failed on {fmu_path}: {result.stderr.strip()[-2000:]}")
    lines = result.stdout.strip().splitlines()
    values = np.array([[float(x) for x in line.split()] for line in lines[:n_steps + 1]]).reshape(n_steps + 1, -1)
    recorded = {name: values[:, i] for i, name in enumerate(outputs)}
    recorded["time"] = np.arange(n_steps + 1) * step_size
    recorded["us_per_step"] = float(lines[n_steps + 1].split()[1])
    recorded["python_in_process"] = lines[n_steps + 2].split()[1] == "1"
    recorded["log"] = result.stderr
    return recorded
