"""Plotting helpers: figures of recordings, rendered with matplotlib's Agg (PNG) canvas.

Figures are built with :class:`matplotlib.figure.Figure` directly, never through ``pyplot``, so
nothing depends on a display or on pyplot's global state and nothing is shown on screen.
"""
from __future__ import annotations

import io

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from validation.core.recordings import Recording, column_unit


def recording_figure(recording: Recording, *, reference: Recording | None = None,
                     title: str = "") -> Figure:
    """Inputs and outputs of ``recording`` against time, one panel each.

    Parameters
    ----------
    recording : Recording
        Drawn as solid lines: the inputs in the first panel, then one panel per output.
    reference : Recording, optional
        Another recording on the same inputs (e.g. the physics reference of a flight-test
        stand-in); its outputs that share a name with ``recording``'s are drawn dashed on
        the same panels.
    title : str
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        With an Agg canvas attached (see :func:`png_bytes`).
    """
    n_panels = 1 + len(recording.output_names)
    n_columns = 1 if n_panels <= 5 else 2
    n_rows = -(-n_panels // n_columns)
    figure = Figure(figsize=(7 * n_columns, 1.8 * n_rows + 0.8), layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.subplots(n_rows, n_columns, sharex=True, squeeze=False).ravel(order="F")
    for name in recording.input_names:
        axes[0].plot(recording.time, recording.input(name), label=f"{name} [{column_unit(name)}]")
    axes[0].set_ylabel("inputs")
    axes[0].legend(loc="upper right", fontsize="small")
    for axis, name in zip(axes[1:], recording.output_names):
        axis.plot(recording.time, recording.output(name), label=recording.metadata.get("vehicle", "recording"))
        if reference is not None and name in reference.output_names:
            axis.plot(reference.time, reference.output(name), "--",
                      label=reference.metadata.get("vehicle", "reference"))
        axis.set_ylabel(f"{name} [{column_unit(name)}]")
    if reference is not None:
        axes[1].legend(loc="upper right", fontsize="small")
    for axis in axes[n_panels:]:
        axis.set_visible(False)
    for axis in axes:
        axis.grid(True, alpha=0.3)
    for index in range(n_columns):  # the lowest visible panel of each column carries the time axis
        bottom = axes[min((index + 1) * n_rows, n_panels) - 1]
        bottom.set_xlabel("time [s]")
        bottom.xaxis.set_tick_params(labelbottom=True)
    figure.suptitle(title)
    return figure


def png_bytes(figure: Figure, *, dpi: int = 100) -> bytes:
    """``figure`` rendered as a PNG file's bytes (write them with ``write_atomically``)."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()
