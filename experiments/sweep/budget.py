"""The error budget of a sweep over error_sources (models/sweeps/error_budget.toml): per error
source and method, the median and p95 error in mm and degrees and the mean NEES, as a table and
a plot, so a user sees which error source to fix first."""

from __future__ import annotations

import html

import numpy as np

from hec.support.plotting import figure
from hec.sweep.summary import CellSummary

PARAMETER = "error_sources"
TEXT_FILE = "error_budget.txt"


def has_budget(summaries: list[CellSummary]) -> bool:
    """True when the sweep varied error_sources, one cell per value (a sweep that also scales the
    errors has several cells of one source: no budget)."""
    source = {s.cell: s.parameters[PARAMETER] for s in summaries if PARAMETER in s.parameters}
    values = set(source.values())
    return len(values) > 1 and len(values) == len(source)


def _by_source(summaries: list[CellSummary]) -> tuple[list[str], list[str], dict]:
    sources = list(dict.fromkeys(str(s.parameters[PARAMETER]) for s in summaries))
    methods = list(dict.fromkeys(s.method for s in summaries))
    table = {(str(s.parameters[PARAMETER]), s.method): s for s in summaries}
    return sources, methods, table


def _numbers(s: CellSummary | None) -> tuple[float, float, float, float, float]:
    if s is None or s.ok == 0:
        return (np.nan,) * 5
    t, r = s.translation_mm, s.rotation_deg
    return t.median, t.p95, r.median, r.p95, s.mean_nees


def budget_text(summaries: list[CellSummary]) -> str:
    """The budget as a fixed-width text table: a row per source and method."""
    sources, methods, table = _by_source(summaries)
    lines = [
        f"{'source':<12} {'method':<18} {'median mm':>10} {'p95 mm':>9} {'median deg':>11} "
        f"{'p95 deg':>9} {'NEES':>8} {'ok':>7}"
    ]
    for source in sources:
        for method in methods:
            s = table.get((source, method))
            tm, tp, rm, rp, nees = _numbers(s)
            ok = f"{s.ok}/{s.trials}" if s is not None else "-"
            numbers = f"{tm:>10.3f} {tp:>9.3f} {rm:>11.4f} {rp:>9.4f} {nees:>8.2f}"
            lines.append(f"{source:<12} {method:<18} {numbers} {ok:>7}")
    return "\n".join(lines)


def budget_table_html(summaries: list[CellSummary]) -> str:
    """The budget as HTML: a row per source, per method the median / p95 translation error (mm),
    median / p95 rotation error (degrees) and the mean NEES."""
    sources, methods, table = _by_source(summaries)
    head = "<tr><th class=name>error source</th>" + "".join(
        f"<th>{html.escape(m)}<br>mm: median / p95<br>deg: median / p95<br>NEES</th>" for m in methods
    )
    rows = []
    for source in sources:
        cells = [f"<td class=name>{html.escape(source)}</td>"]
        for method in methods:
            tm, tp, rm, rp, nees = _numbers(table.get((source, method)))
            cells.append(f"<td>{tm:.3g} / {tp:.3g}<br>{rm:.3g} / {rp:.3g}<br>{nees:.3g}</td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table>{head}</tr>{''.join(rows)}</table>"


def plot_budget(summaries: list[CellSummary]) -> object:
    """Two heat maps (translation mm, rotation degrees): a row per error source, a column per
    method, coloured by the median error on a log scale and labelled "median (p95)"."""
    from matplotlib.colors import LogNorm

    sources, methods, table = _by_source(summaries)
    values = np.array([[_numbers(table.get((s, m))) for m in methods] for s in sources])
    fig, axes = figure(max(8.0, 1.0 + 0.95 * len(methods)), max(3.5, 1.2 + 0.75 * len(sources)), cols=2)
    for ax, (median_i, p95_i, unit, spec) in zip(
        axes[0], ((0, 1, "mm", ".2g"), (2, 3, "deg", ".2g")), strict=True
    ):
        median, p95 = values[:, :, median_i], values[:, :, p95_i]
        finite = median[np.isfinite(median) & (median > 0)]
        norm = LogNorm(finite.min(), finite.max()) if finite.size else None
        image = ax.imshow(np.where(median > 0, median, np.nan), cmap="viridis", norm=norm, aspect="auto")
        for r in range(len(sources)):
            for c in range(len(methods)):
                text = (
                    "-" if not np.isfinite(median[r, c]) else f"{median[r, c]:{spec}}\n({p95[r, c]:{spec}})"
                )
                light = norm is not None and np.isfinite(median[r, c]) and norm(median[r, c]) > 0.6
                ax.text(c, r, text, ha="center", va="center", fontsize=6.5, color="k" if light else "w")
        ax.set_xticks(range(len(methods)), methods, rotation=60, ha="right", fontsize=8)
        ax.set_yticks(range(len(sources)), sources, fontsize=8)
        ax.set_title(f"error [{unit}]: median (p95) per source and method", fontsize=9)
        fig.colorbar(image, ax=ax, label=f"median error [{unit}]")
    return fig
