"""Matplotlib helpers shared by the reports: figures of a fixed DPI, plain-number log axes,
legends below the plot, PNG bytes."""

from __future__ import annotations

import io
import math

DPI = 110


def figure(width: float, height: float, rows: int = 1, cols: int = 1, **kwargs: object) -> tuple:
    """A matplotlib Figure (Agg, no pyplot state) and its axes."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    return fig, fig.subplots(rows, cols, squeeze=False, **kwargs)


def plain_log_axis(ax: object, which: str = "y") -> None:
    """Log axis labelled with plain numbers (0.2, 0.3, 0.5, 1, 2) rather than powers of ten; over
    more than a decade and a half only 2 and 5 between the decades."""
    from matplotlib.ticker import FuncFormatter

    axis = ax.yaxis if which == "y" else ax.xaxis

    def minor(v: float, _: object) -> str:
        lo, hi = sorted(axis.get_view_interval())
        wide = lo > 0 and math.log10(hi / lo) > 1.5
        digit = round(v / 10 ** math.floor(math.log10(v))) if v > 0 else 0
        return f"{v:g}" if digit in ((2, 5) if wide else (2, 3, 5)) else ""

    (ax.set_yscale if which == "y" else ax.set_xscale)("log")
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(FuncFormatter(minor))


def legend_below(fig: object, ax: object) -> None:
    """One legend for the figure (the entries of ax) below the panels, out of the data's way."""
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 3), fontsize=8)


def png_bytes(fig: object) -> bytes:
    """The figure as PNG bytes."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    return buffer.getvalue()
