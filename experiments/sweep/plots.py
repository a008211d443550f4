"""The plots of a sweep report: error against each swept parameter with the Cramer-Rao bound,
box plots per method, and a filter's convergence with its 3-sigma band."""

from __future__ import annotations

import numpy as np

from hec.support.plotting import figure, legend_below, plain_log_axis
from hec.sweep.summary import Convergence, _num, _ok_values, _rms, _same, _unique, swept_parameters

PARAMETER_LABELS = {
    "pixel_sigma_px": "corner pixel noise sigma [px]",
    "rgb_sigma_grey": "image noise sigma [grey levels]",
    "depth_bias_offset_mm": "depth bias offset [mm]",
    "depth_subpixel": "stereo depth subpixel [px]",
    "depth_bias_scale": "depth bias scale",
    "robot_translation_sigma_mm": "robot translation sigma [mm]",
    "robot_rotation_sigma_deg": "robot rotation sigma [deg]",
    "waypoints": "waypoints",
    "trajectory": "trajectory",
    "mount": "mount",
}
COMPONENTS = ("x [mm]", "y [mm]", "z [mm]", "rx [deg]", "ry [deg]", "rz [deg]")


MAX_GROUPED_CELLS = 6  # box plots group boxes by cell up to this many cells, then pool them


def plot_convergence(conv: Convergence, title: str) -> object:
    """Six panels (x, y, z in mm; rx, ry, rz in degrees): error against waypoints with +-3 sigma."""
    fig, axes = figure(13.0, 6.0, 2, 3, sharex=True)
    scale = np.array([1e3] * 3 + [np.degrees(1.0)] * 3)
    for k, ax in enumerate(axes.flat):
        error, band = conv.error[:, k] * scale[k], 3.0 * conv.sigma[:, k] * scale[k]
        ax.fill_between(conv.waypoints, -band, band, color="C0", alpha=0.2, lw=0, label="+-3 sigma (filter)")
        ax.plot(conv.waypoints, error, "C3.-", label="error (estimate - truth)")
        ax.axhline(0.0, color="k", lw=0.6)
        # The first update's band is wide; keep the later ones readable.
        later = slice(min(1, len(error) - 1), None)
        limit = 1.3 * max(np.max(band[later]), np.max(np.abs(error[later])), 1e-12)
        ax.set_ylim(-limit, limit)
        ax.set_ylabel(COMPONENTS[k])
        ax.grid(alpha=0.3)
        if k >= 3:
            ax.set_xlabel("waypoints taken in")
    legend_below(fig, axes[0, 0])
    fig.suptitle(title)
    return fig


def _parameter_axis(values: list) -> tuple[np.ndarray, list[str] | None]:
    """x positions of parameter values: the numbers themselves, or 0..n-1 with labels for text."""
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        return np.array(values, dtype=float), None
    return np.arange(len(values), dtype=float), [str(v) for v in values]


def plot_error_vs_parameter(rows: list[dict], parameter: str) -> object:
    """Two panels (translation mm, rotation deg): RMS error of the ok trials against one swept
    parameter, a line per method, and the RMS Cramer-Rao bound over the trials (black, dashed).
    Trials of every cell with that parameter value are pooled (other swept parameters mixed)."""
    values = _unique(r.get(parameter) for r in rows)
    try:
        values = sorted(values)
    except TypeError:
        pass
    from matplotlib import colormaps

    x, labels = _parameter_axis(values)
    fig, axes = figure(12.0, 4.6, 1, 2)
    for ax, (error_col, crb_col, unit) in zip(
        axes[0],
        (
            ("error_translation_mm", "crb_translation_mm", "mm"),
            ("error_rotation_deg", "crb_rotation_deg", "deg"),
        ),
        strict=True,
    ):
        for i, method in enumerate(_unique(r["method"] for r in rows)):
            rms = [_rms(_ok_values(rows, error_col, method=method, **{parameter: v})) for v in values]
            label = method if np.isfinite(rms).any() else f"{method} (no ok trial)"
            # 12 methods: tab20 colours and three markers keep every line distinguishable.
            ax.plot(x, rms, "os^"[i % 3] + "-", color=colormaps["tab20"](i % 20), label=label)
        crb = []
        for v in values:
            # The bound is the trial's, repeated on each of its method rows (failed ones may lack it).
            per_trial = {
                r["trial_id"]: _num(r[crb_col])
                for r in rows
                if _same(r.get(parameter), v) and np.isfinite(_num(r[crb_col]))
            }
            crb.append(_rms(np.array(list(per_trial.values()))))
        ax.plot(x, crb, "k--", lw=2, label="Cramer-Rao bound")
        plain_log_axis(ax)
        ax.set_xlabel(PARAMETER_LABELS.get(parameter, parameter))
        ax.set_ylabel(f"RMS {'translation' if unit == 'mm' else 'rotation'} error [{unit}]")
        if labels is not None:
            ax.set_xticks(x, labels)
        elif np.all(x > 0) and x.max() >= 8 * x.min():  # levels growing by factors: log x
            plain_log_axis(ax, "x")
        ax.grid(alpha=0.3, which="both")
    legend_below(fig, axes[0, 0])
    others = [p for p in swept_parameters(rows) if p != parameter]
    pooled = f"; pooled over {', '.join(others)}" if others else ""
    fig.suptitle(f"error against {parameter} (ok trials{pooled})")
    return fig


def _cell_label(rows: list[dict], cell: str | None) -> str:
    """'c03: pixel_sigma_px 0.6, trajectory random' (the cell's swept parameters), or 'all cells'."""
    if cell is None:
        return "all cells"
    row = next(r for r in rows if r["cell"] == cell)
    swept = ", ".join(f"{p} {row.get(p)}" for p in swept_parameters(rows))
    return f"{cell}: {swept}" if swept else cell


def plot_boxes(rows: list[dict]) -> object:
    """Two panels (translation mm, rotation deg): box plots of the ok trials' errors per method,
    one box per cell side by side (pooled over cells when there are more than MAX_GROUPED_CELLS)."""
    methods = _unique(r["method"] for r in rows)
    cells = _unique(r["cell"] for r in rows)
    groups = cells if len(cells) <= MAX_GROUPED_CELLS else [None]
    width = 0.8 / len(groups)
    fig, axes = figure(max(10.0, 1.2 * len(methods) * max(1, len(groups) / 2)), 4.8, 1, 2)
    for ax, (error_col, label) in zip(
        axes[0],
        (("error_translation_mm", "translation error [mm]"), ("error_rotation_deg", "rotation error [deg]")),
        strict=True,
    ):
        for g, cell in enumerate(groups):
            data, positions = [], []
            for m, method in enumerate(methods):
                match = {"method": method} if cell is None else {"method": method, "cell": cell}
                values = _ok_values(rows, error_col, **match)
                if len(values):
                    data.append(values)
                    positions.append(m - 0.4 + width * (g + 0.5))
            if not data:
                continue
            color = f"C{g % 10}"
            ax.boxplot(
                data,
                positions=positions,
                widths=0.9 * width,
                patch_artist=True,
                boxprops={"facecolor": color, "alpha": 0.5},
                medianprops={"color": "k"},
                flierprops={"markersize": 3},
                manage_ticks=False,
            )
            ax.plot([], [], "s", color=color, alpha=0.5, label=_cell_label(rows, cell))
        for m, method in enumerate(methods):
            if not len(_ok_values(rows, error_col, method=method)):
                ax.text(m, 0.5, "no ok trial", transform=ax.get_xaxis_transform(), ha="center", color="0.4")
        ax.set_xticks(range(len(methods)), methods, rotation=30, ha="right")
        ax.set_xlim(-0.6, len(methods) - 0.4)
        plain_log_axis(ax)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, axis="y", which="both")
    legend_below(fig, axes[0, 0])
    fig.suptitle("errors of the ok trials per method" + (" and cell" if groups != [None] else ", all cells"))
    return fig
