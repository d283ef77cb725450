"""Co-simulation of a GP rate-predictor FMU and a physics reference FMU in fmpy, compared with
a recording.

Both FMUs are driven by the same control inputs on the GP model's NARX step grid
(``t_k = t0 + k h``); the GP FMU runs in free-run mode (it feeds back its own predictions,
started from the recording's first rates), the reference FMU from trim. Every FMU follows the
sampling convention of docs/conventions.md ("FMU sampling convention"): outputs at ``t_{k+1}``
come from inputs at ``t_k``, so row ``k`` of every result is comparable with the recording at
``t_k``.

Results are written in the layout of the FMI Cross-Check repository: for each FMU a folder with
``<model>_in.csv`` (the inputs it was given), ``<model>_ref.csv`` (its outputs) and
``<model>_ref.opt`` (start time, stop time, step size, tolerance), so other tools can replay and
compare them.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from validation.core.errors import BadInputError
from validation.core.files import json_text, write_files_atomically
from validation.core.metrics import rmse
from validation.core.plots import png_bytes
from validation.core.recordings import Recording
from validation.vehicles.fmu_reference import read_cosimulation_fmu

#: The summary and the plot :func:`cosimulate` writes in ``out_dir`` (besides a folder of
#: Cross-Check files per FMU).
COSIM_FILES = ("cosim.json", "cosim.png")


@dataclass
class FmuRun:
    """One FMU's co-simulation result.

    Attributes
    ----------
    name : str
        The FMU's model name.
    time : ndarray, shape (n,)
    inputs : dict of str -> ndarray, shape (n,)
    outputs : dict of str -> ndarray, shape (n,)
    """

    name: str
    time: np.ndarray
    inputs: dict
    outputs: dict = field(default_factory=dict)


class OpenFmu:
    """An FMU extracted and instantiated once for many runs of :func:`simulate`, reset between
    them (``fmi2Reset``): one instantiation per FMU however many recordings it replays. Use it as
    a context manager (or call :meth:`close`), which frees the instance and removes the extracted
    files.

    Parameters
    ----------
    path : path
        An FMI 2.0 co-simulation FMU.

    Attributes
    ----------
    path : Path
    description : fmpy ModelDescription
    unzipdir : str
        The folder the FMU is extracted to.
    messages : list of str
        What the FMU logged, oldest first.
    instantiations : int
        How often the FMU was instantiated: 1, plus one per run after which it could not be reset
        (a Fatal status).
    """

    def __init__(self, path):
        from fmpy import extract, read_model_description

        self.path = Path(path)
        self.description = read_model_description(str(self.path))
        self.messages = []
        self.instantiations = 0
        self.unzipdir = extract(str(self.path))
        self._instance = None
        self._used = False

    def _logger(self, component, instance, status, category, message):
        self.messages.append(message.decode(errors="replace") if isinstance(message, bytes) else str(message))

    def instance(self):
        """The instance, ready for a run: instantiated at the first call, reset before each later
        one (instantiated afresh when it cannot be reset)."""
        from fmpy import instantiate_fmu

        if self._instance is not None and self._used:
            try:
                self._instance.reset()
            except Exception:  # noqa: BLE001 - after a Fatal status the instance cannot be reset
                self._instance.freeInstance()
                self._instance = None
        if self._instance is None:
            self._instance = instantiate_fmu(self.unzipdir, self.description, fmi_type="CoSimulation",
                                             logger=self._logger)
            self.instantiations += 1
        self._used = True
        return self._instance

    def close(self) -> None:
        """Free the instance and remove the extracted files."""
        import shutil

        if self._instance is not None:
            self._instance.freeInstance()
            self._instance = None
        shutil.rmtree(self.unzipdir, ignore_errors=True)

    def __enter__(self) -> OpenFmu:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def simulate(fmu, *, time: np.ndarray, inputs: dict, outputs, start_values: dict | None = None) -> FmuRun:
    """Run one FMU in fmpy on the grid ``time`` (evenly spaced) with the given inputs.

    Parameters
    ----------
    fmu : path or OpenFmu
        A path is extracted and instantiated for this run alone; an :class:`OpenFmu` runs its
        kept instance (reset since its last run), so many runs instantiate it once.
    time : ndarray, shape (n,)
        Communication points, s; the step is ``time[1] - time[0]``.
    inputs : dict of str -> ndarray, shape (n,)
        Input values at each communication point (held over the step that follows).
    outputs : sequence of str
    start_values : dict, optional
        Parameters and start values.
    """
    if not isinstance(fmu, OpenFmu):
        with OpenFmu(fmu) as opened:
            return simulate(opened, time=time, inputs=inputs, outputs=outputs, start_values=start_values)
    import fmpy

    description = fmu.description
    names = {v.name for v in description.modelVariables}
    missing = [n for n in (*inputs, *outputs, *(start_values or {})) if n not in names]
    if missing:
        raise BadInputError(f"{fmu.path}: the FMU has no variable(s) {', '.join(missing)}")
    signal = np.zeros(len(time), dtype=[("time", float)] + [(n, float) for n in inputs])
    signal["time"] = time
    for name, values in inputs.items():
        signal[name] = values
    step = float(time[1] - time[0])
    logged = len(fmu.messages)
    try:
        result = fmpy.simulate_fmu(fmu.unzipdir, model_description=description, fmu_instance=fmu.instance(),
                                   start_time=float(time[0]), stop_time=float(time[-1]),
                                   step_size=step, output_interval=step, input=signal,
                                   output=list(outputs), start_values=start_values or {})
    except Exception as error:  # fmpy raises plain Exceptions for FMI error statuses
        detail = f" ({fmu.messages[-1]})" if len(fmu.messages) > logged else ""
        raise BadInputError(f"{fmu.path}: co-simulation failed: {error}{detail}") from None
    rows = np.searchsorted(result["time"], time - 1e-9 * step)
    return FmuRun(description.modelName, time, dict(inputs),
                  {name: np.asarray(result[name])[rows] for name in outputs})


def cross_check_files(run: FmuRun, out_dir: Path) -> dict:
    """The FMI Cross-Check files of ``run`` as ``{path: text}`` (written by the caller)."""
    folder = Path(out_dir) / run.name
    step = float(run.time[1] - run.time[0])

    def table(columns: dict) -> str:
        header = ",".join(["time", *columns])
        rows = np.column_stack([run.time, *columns.values()])
        return "\n".join([header] + [",".join(map(repr, row)) for row in rows.tolist()]) + "\n"

    options = (f"StartTime, {float(run.time[0])!r}\nStopTime, {float(run.time[-1])!r}\n"
               f"StepSize, {step!r}\nRelTol, 1e-06\n")
    return {folder / f"{run.name}_in.csv": table(run.inputs),
            folder / f"{run.name}_ref.csv": table(run.outputs),
            folder / f"{run.name}_ref.opt": options}


@dataclass
class CosimResult:
    """GP FMU, reference FMU and recording on one time grid.

    Attributes
    ----------
    time : ndarray, shape (n,)
    axes : tuple of str
        The compared outputs (e.g. ``("p", "q", "r")``).
    measured : ndarray, shape (n, n_axes)
    gp : FmuRun
    reference : FmuRun or None
    confidence_level : float or None
        The probability of the GP FMU's band between its lower and upper bounds, as run (its
        ``confidence_level``, e.g. 0.95); None for an FMU without that parameter.
    """

    time: np.ndarray
    axes: tuple
    measured: np.ndarray
    gp: FmuRun
    reference: FmuRun | None
    confidence_level: float | None = None

    @property
    def band_words(self) -> str:
        """The GP FMU's band in words: ``"95 % band"`` (``"bounds"`` without a confidence level)."""
        return "bounds" if self.confidence_level is None else f"{100 * self.confidence_level:.4g} % band"

    def rmse(self) -> dict:
        """RMSE per axis against the recording, from the first predicted step on (rad/s)."""
        def rmse_of(values):
            per_axis = rmse(self.measured[1:], np.column_stack(values)[1:], axis=0)
            return {axis: float(v) for axis, v in zip(self.axes, per_axis)}

        table = {"gp": rmse_of([self.gp.outputs[a] for a in self.axes])}
        if self.reference is not None:
            table["reference"] = rmse_of([self.reference.outputs[a] for a in self.axes])
        return table

    def coverage(self) -> dict:
        """Fraction of recorded samples (after the first) inside the GP FMU's bounds (its
        :attr:`confidence_level` band)."""
        result = {}
        for j, axis in enumerate(self.axes):
            lower, upper = self.gp.outputs[f"{axis}_lower"][1:], self.gp.outputs[f"{axis}_upper"][1:]
            inside = (self.measured[1:, j] >= lower) & (self.measured[1:, j] <= upper)
            result[axis] = float(np.mean(inside))
        return result


@dataclass
class FreeRun:
    """A flightgp GP rate-predictor FMU run in free-run mode against a recording (:func:`free_run`).

    Attributes
    ----------
    run : FmuRun
        Its outputs (each axis with ``<axis>_lower`` and ``<axis>_upper``) on its step grid.
    axes : tuple of str
        The rates it predicts (outputs with a ``<name>_prev`` input), e.g. ``("p", "q", "r")``.
    controls : tuple of str
        The control inputs it takes.
    step : float
        Its communication step (the NARX step), s.
    rows : slice
        The recording's samples at its step grid (``recording.time[rows]`` is ``run.time``).
    measured : ndarray, shape (n, n_axes)
        The recorded rates at those samples.
    parameters : dict of str -> bool
        ``exact_moments`` and ``parallel`` as run, for an FMU that has them.
    confidence_level : float or None
        Its band's probability (its ``confidence_level`` start value), None without one.
    """

    run: FmuRun
    axes: tuple
    controls: tuple
    step: float
    rows: slice
    measured: np.ndarray
    parameters: dict
    confidence_level: float | None


def rate_predictor_axes(description) -> tuple:
    """The outputs of an FMU's description that have a ``<name>_prev`` input: a flightgp GP
    rate predictor's rates (docs/fmus.md, "GP-NARX rate predictor"); empty for any other FMU."""
    variables = {v.name: v for v in description.modelVariables}
    return tuple(v.name for v in description.modelVariables
                 if v.causality == "output" and f"{v.name}_prev" in variables)


def rate_predictor_controls(description) -> tuple:
    """The inputs of a GP rate predictor's description that are controls (not the ``<name>_prev``
    rates it starts from or is fed)."""
    return tuple(v.name for v in description.modelVariables if v.causality == "input" and not v.name.endswith("_prev"))


def free_run(gp_fmu, recording: Recording, *, exact_moments: bool | None = None,
             parallel: bool | None = None) -> FreeRun:
    """Run a GP rate-predictor FMU in free-run mode under a recording's controls, started from the
    recording's first rates, on its own step grid (docs/fmus.md, "GP-NARX rate predictor").

    Parameters
    ----------
    gp_fmu : path or OpenFmu
        A rate-predictor FMU (``flightgp build-fmu``); its default experiment step is the NARX
        step, and the recording is sampled on that grid.
    recording : Recording
        Evenly sampled, its step dividing the FMU's; it must hold the FMU's controls and rates.
    exact_moments, parallel : bool, optional
        The FMU's parameters of these names (as :func:`cosimulate`); None: the FMU's default.
    """
    description = gp_fmu.description if isinstance(gp_fmu, OpenFmu) else read_cosimulation_fmu(gp_fmu, purpose="cosim")
    path = gp_fmu.path if isinstance(gp_fmu, OpenFmu) else gp_fmu
    variables = {v.name: v for v in description.modelVariables}
    axes = rate_predictor_axes(description)
    controls = rate_predictor_controls(description)
    asked = {name: value for name, value in (("exact_moments", exact_moments), ("parallel", parallel))
             if value is not None}
    lacking = [name for name in asked if name not in variables or variables[name].causality != "parameter"]
    if lacking:
        raise BadInputError(f"{path}: no parameter {', '.join(lacking)} (a rate-predictor FMU of this "
                            "flightgp has it)")
    step = description.defaultExperiment.stepSize if description.defaultExperiment else None
    if not axes or not step:
        raise BadInputError(f"{path}: not a flightgp rate-predictor FMU (it needs outputs with <name>_prev inputs "
                            "and a default experiment step); a physics FMU goes after --reference")
    step = float(step)
    sample = float(np.mean(np.diff(recording.time)))
    decimation = int(round(step / sample))
    if decimation < 1 or abs(decimation * sample - step) > 1e-6 * step:
        raise BadInputError(f"the recording is sampled every {sample:g} s, which does not divide the "
                            f"FMU's step of {step:g} s")
    # As run: the values asked for, else the FMU's defaults.
    run_with = {name: asked.get(name, variables[name].start in ("true", True))
                for name in ("exact_moments", "parallel")
                if name in variables and variables[name].causality == "parameter"}
    missing = [c for c in (*controls, *axes) if c not in (*recording.input_names, *recording.output_names)]
    if missing:
        raise BadInputError(f"the recording has no column(s) {', '.join(missing)} the FMU needs")
    rows = slice(None, None, decimation)
    time = recording.time[rows] - recording.time[0]
    measured = np.column_stack([recording.output(a) for a in axes])[rows]
    # In free-run mode the *_prev inputs are read only at initialisation; they are still given
    # (held at their start values) so that no host warns about undriven inputs.
    held = {f"{a}_prev": np.full(len(time), measured[0, j]) for j, a in enumerate(axes)}
    run = simulate(gp_fmu, time=time, inputs={**{c: recording.input(c)[rows] for c in controls}, **held},
                   outputs=[n for a in axes for n in (a, f"{a}_lower", f"{a}_upper")],
                   start_values={"free_run": True, **asked,
                                 **{f"{a}_prev": float(measured[0, j]) for j, a in enumerate(axes)}})
    level = getattr(variables.get("confidence_level"), "start", None)  # not set here: the FMU's start value
    return FreeRun(run, axes, controls, step, rows, measured, run_with, None if level is None else float(level))


def cosimulate(gp_fmu, recording: Recording, *, reference_fmu=None, out_dir=None,
               exact_moments: bool | None = None, parallel: bool | None = None) -> CosimResult:
    """Co-simulate the GP rate predictor (free run) and a reference FMU under a recording's
    inputs and compare both with it.

    Parameters
    ----------
    gp_fmu : path
        A rate-predictor FMU (``flightgp build-fmu``); its default experiment step is the
        NARX step, and the recording is sampled on that grid (:func:`free_run`).
    recording : Recording
        Inputs to apply and outputs to compare with (evenly sampled, step dividing the FMU's).
    reference_fmu : path, optional
        A physics FMU whose inputs are the recording's inputs and whose outputs include the
        GP's outputs (e.g. ``flightgp build-fmu --reference bo105-80kt``).
    out_dir : path, optional
        Where to write the Cross-Check files, ``cosim.json`` and ``cosim.png`` (atomically).
    exact_moments, parallel : bool, optional
        The GP FMU's parameters of these names (docs/fmus.md, "GP-NARX rate predictor"): the
        moment matching in double precision throughout; the free run on two threads (native
        FMU). None (default): the FMU's own default, which for ``exact_moments`` its build chose
        by measuring its fast path. Given for an FMU that lacks the parameter: refused.
        ``cosim.json`` records the values run.
    """
    read_cosimulation_fmu(gp_fmu, purpose="cosim")
    if reference_fmu is not None:
        read_cosimulation_fmu(reference_fmu, purpose="cosim")
    gp = free_run(gp_fmu, recording, exact_moments=exact_moments, parallel=parallel)
    time = gp.run.time
    reference = None
    if reference_fmu is not None:
        reference = simulate(reference_fmu, time=time,
                             inputs={c: recording.input(c)[gp.rows] for c in recording.input_names},
                             outputs=list(gp.axes))
    result = CosimResult(time, gp.axes, gp.measured, gp.run, reference, confidence_level=gp.confidence_level)
    if out_dir is not None:
        out_dir = Path(out_dir)
        files = cross_check_files(gp.run, out_dir)
        if reference is not None:
            files.update(cross_check_files(reference, out_dir))
        summary = {"step_s": gp.step, "axes": list(gp.axes), "rmse": result.rmse(),
                   "coverage": result.coverage(), "coverage_level": result.confidence_level,
                   "gp_fmu": str(gp_fmu),
                   "gp_parameters": gp.parameters,
                   "reference_fmu": str(reference_fmu) if reference_fmu else None}
        summary_name, plot_name = COSIM_FILES
        files[out_dir / summary_name] = json_text(summary)
        files[out_dir / plot_name] = png_bytes(_figure(result))
        write_files_atomically(files)
    return result


def _figure(result: CosimResult) -> Figure:
    figure = Figure(figsize=(8, 2.3 * len(result.axes) + 0.4), layout="constrained")
    FigureCanvasAgg(figure)
    panels = figure.subplots(len(result.axes), 1, sharex=True, squeeze=False)[:, 0]
    for j, (panel, axis) in enumerate(zip(panels, result.axes)):
        panel.plot(result.time, result.measured[:, j], "k", lw=1, label="recording")
        if result.reference is not None:
            panel.plot(result.time, result.reference.outputs[axis], "--", color="tab:orange",
                       label=f"{result.reference.name} (FMU)")
        panel.plot(result.time, result.gp.outputs[axis], color="tab:blue", label=f"{result.gp.name} (FMU)")
        panel.fill_between(result.time, result.gp.outputs[f"{axis}_lower"], result.gp.outputs[f"{axis}_upper"],
                           color="tab:blue", alpha=0.25, label=f"GP {result.band_words}")
        panel.set_ylabel(f"{axis} [rad/s]")
        panel.grid(True, alpha=0.3)
    panels[0].legend(fontsize="small", ncol=2)
    panels[-1].set_xlabel("time [s]")
    figure.suptitle("fmpy co-simulation: GP FMU (free run) and reference FMU vs recording")
    return figure
