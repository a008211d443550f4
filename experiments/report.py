"""`hec report DIR`: the summary tables and plots of a Monte-Carlo sweep, as one self-contained HTML page.

Input: the sweep's result rows (one per trial x method: the ROW_COLUMNS, plus one column per trial
parameter, swept when it takes more than one value) read by load_rows, and, when present,
DIR/sweep.json (resolved config, seed, versions) and DIR/example/ (one rendered dataset).
Output, rebuilt from the saved rows every time:

    DIR/report.html   tables and plots (PNGs embedded as base64 data URIs): opens anywhere, no files beside it
    DIR/plots/*.png   the same plots as files

Per grid cell and method: median, p95 and RMS of the translation (mm) and rotation (degrees)
errors of the ok trials, the success rate (failed rows count as trials), and the RMS error divided
by the RMS Cramer-Rao bound over the same trials (the bound differs per trial with the random
mount). Plots: the RMS error against each swept parameter per method with the bound, box plots
per method, and one filter's convergence over the waypoints with its +-3 sigma band.
"""

from __future__ import annotations

import argparse
import base64
import csv
import html
import io
import json
import math
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator.calibration import MethodOptions
from estimator.files import write_atomic
from estimator.jsonfile import read_json_object
from estimator.lie import pose_minus
from estimator.problem import CalibrationProblem
from experiments.sweep import EXAMPLE_DIR, FLOAT_COLUMNS, ID_COLUMNS, META_FILE, RESULT_COLUMNS, ROWS_FILE

REPORT_FILE = "report.html"
PLOTS_DIR = "plots"
EXAMPLE_OVERLAYS = f"{EXAMPLE_DIR}/overlay/*.png"
EXAMPLE_OVERVIEW = f"{EXAMPLE_DIR}/preview/overview.png"

# Columns every row has (experiments.sweep's row contract; seed is text, e.g. "seed/cell/trial"). Every
# other column is a parameter of the trial (pixel_sigma_px, waypoints, trajectory, mount, ...): swept
# when it takes more than one value over the rows, fixed otherwise.
STRING_COLUMNS = (*ID_COLUMNS, *RESULT_COLUMNS[:3])
ROW_COLUMNS = (*STRING_COLUMNS, *FLOAT_COLUMNS)
STATUSES = ("ok", "failed")
FIDELITIES = ("measurements", "render")
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
DPI = 110


class ReportError(ValueError):
    """The sweep folder has no rows, or a row is not what the row contract says."""


# ---------------------------------------------------------------- rows


def load_rows(out_dir: Path) -> list[dict]:
    """The sweep's result rows of out_dir, one dict per trial x method, typed by column name.

    The one place rows are read (to be replaced by experiments.sweep.load_rows): DIR/rows.csv."""
    return read_rows_csv(Path(out_dir) / ROWS_FILE)


def read_rows_csv(path: Path) -> list[dict]:
    """Rows of a CSV file with a header: contract columns typed (FLOAT_COLUMNS float, empty = NaN;
    the others text), parameter columns int, float or text as they read (empty = None).
    Raises ReportError naming the file, line and column."""
    try:
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            header = reader.fieldnames
            raw = list(reader)
    except FileNotFoundError:
        raise ReportError(
            f"{path}: file missing; expected the result rows of `hec sweep CONFIG.toml --out {path.parent}`"
        ) from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ReportError(f"{path}: not a readable CSV file ({exc})") from None
    if not header:
        raise ReportError(f"{path}: empty file; expected a header line and one row per trial x method")
    rows = []
    for line, values in enumerate(raw, start=2):
        if None in values:
            raise ReportError(f"{path}, line {line}: more values than the {len(header)} header columns")
        rows.append({name: _typed(value, name, f"{path}, line {line}") for name, value in values.items()})
    return rows


def _typed(text: str | None, column: str, where: str) -> object:
    text = "" if text is None else text.strip()
    if column in FLOAT_COLUMNS:
        try:
            return float(text) if text else math.nan
        except ValueError:
            raise ReportError(f"{where}, column {column!r}: expected a number, got {text!r}") from None
    if column in STRING_COLUMNS:
        return text
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text or None


def check_rows(rows: list[dict], source: str) -> None:
    """Raise ReportError naming source unless there are rows with every ROW_COLUMNS column,
    known statuses and fidelities, and each cell has one value of each parameter."""
    if not rows:
        raise ReportError(f"{source}: no result rows; run `hec sweep` into this folder first")
    missing = [c for c in ROW_COLUMNS if c not in rows[0]]
    if missing:
        raise ReportError(
            f"{source}: missing column(s) {', '.join(missing)}; expected {', '.join(ROW_COLUMNS)}"
        )
    parameters = parameter_columns(rows)
    first_of_cell: dict[str, dict] = {}
    for i, row in enumerate(rows):
        for column, allowed in (("status", STATUSES), ("fidelity", FIDELITIES)):
            if row[column] not in allowed:
                raise ReportError(
                    f"{source}, data row {i + 1}: column {column!r} must be one of {', '.join(allowed)}, "
                    f"got {row[column]!r}"
                )
        first = first_of_cell.setdefault(row["cell"], row)
        for p in parameters:
            if not _same(row.get(p), first.get(p)):
                raise ReportError(
                    f"{source}, data row {i + 1}: cell {row['cell']!r} has two values of {p!r}: "
                    f"{first.get(p)!r} and {row.get(p)!r}"
                )


def _same(a: object, b: object) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def _num(value: object) -> float:
    """A row value as a float; None and empty text are NaN."""
    if value is None or value == "":
        return math.nan
    return float(value)


def _ok_values(rows: list[dict], column: str, **match: object) -> np.ndarray:
    """The finite values of column in the ok rows whose fields equal match."""
    values = np.array(
        [
            _num(r[column])
            for r in rows
            if r["status"] == "ok" and all(_same(r.get(k), v) for k, v in match.items())
        ],
        dtype=float,
    )
    return values[np.isfinite(values)]


def parameter_columns(rows: list[dict]) -> list[str]:
    """The columns beyond the row contract (the trials' parameters), in column order."""
    return [c for c in _unique(c for r in rows for c in r) if c not in ROW_COLUMNS]


def swept_parameters(rows: list[dict]) -> list[str]:
    """The parameter columns taking more than one value over the rows, in column order."""
    return [p for p in parameter_columns(rows) if len(_unique(repr(r.get(p)) for r in rows)) > 1]


def fixed_parameters(rows: list[dict]) -> dict:
    """The parameter columns taking one value over the rows, with that value."""
    swept = swept_parameters(rows)
    return {p: rows[0].get(p) for p in parameter_columns(rows) if p not in swept}


def _unique(values: Iterable) -> list:
    return list(dict.fromkeys(values))


# ---------------------------------------------------------------- numbers


@dataclass
class Stats:
    """Median, 95th percentile (linear interpolation) and RMS of errors; the RMS Cramer-Rao bound
    over the same trials (those with a finite bound) and the ratio RMS / bound. NaN when empty."""

    median: float
    p95: float
    rms: float
    crb_rms: float
    ratio: float

    @classmethod
    def of(cls, errors: np.ndarray, crb: np.ndarray) -> Stats:
        """errors, crb: (N,) per ok trial; crb NaN where the mount was not observable."""
        if len(errors) == 0:
            return cls(*[math.nan] * 5)
        finite = np.isfinite(crb)
        rms_bounded = _rms(errors[finite])
        crb_rms = _rms(crb[finite])
        ratio = rms_bounded / crb_rms if finite.any() and crb_rms > 0 else math.nan
        return cls(float(np.median(errors)), float(np.percentile(errors, 95)), _rms(errors), crb_rms, ratio)


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else math.nan


@dataclass
class CellSummary:
    """One grid cell x method. trials: rows (ok and failed); ok: rows with status ok.
    crb_trials: ok trials with a finite bound (the ratio's trials). mean_nees: over ok trials with
    a covariance (6 on average when honest), NaN without. failures: distinct messages, counted."""

    cell: str
    method: str
    fidelity: str
    parameters: dict
    trials: int
    ok: int
    translation_mm: Stats
    rotation_deg: Stats
    crb_trials: int
    mean_nees: float
    median_time_s: float
    failures: dict[str, int] = field(default_factory=dict)

    @property
    def success_rate(self) -> float:
        return self.ok / self.trials


def summarise(rows: list[dict]) -> list[CellSummary]:
    """Per grid cell and method (in order of first appearance), the statistics of CellSummary."""
    parameters = swept_parameters(rows)
    out = []
    for cell in _unique(r["cell"] for r in rows):
        cell_rows = [r for r in rows if r["cell"] == cell]
        for method in _unique(r["method"] for r in cell_rows):
            mine = [r for r in cell_rows if r["method"] == method]
            ok = [r for r in mine if r["status"] == "ok"]

            def column(name: str, ok: list[dict] = ok) -> np.ndarray:
                return np.array([_num(r[name]) for r in ok], dtype=float)

            nees = column("nees")
            nees = nees[np.isfinite(nees)]
            failures: dict[str, int] = {}
            for r in mine:
                if r["status"] == "failed":
                    message = r["failure"] or "(no message)"
                    failures[message] = failures.get(message, 0) + 1
            out.append(
                CellSummary(
                    cell=cell,
                    method=method,
                    fidelity=mine[0]["fidelity"],
                    parameters={p: mine[0].get(p) for p in parameters},
                    trials=len(mine),
                    ok=len(ok),
                    translation_mm=Stats.of(column("error_translation_mm"), column("crb_translation_mm")),
                    rotation_deg=Stats.of(column("error_rotation_deg"), column("crb_rotation_deg")),
                    crb_trials=int(np.sum(np.isfinite(column("crb_translation_mm")))),
                    mean_nees=float(np.mean(nees)) if len(nees) else math.nan,
                    median_time_s=float(np.median(column("time_s"))) if ok else math.nan,
                    failures=failures,
                )
            )
    return out


# ---------------------------------------------------------------- convergence of one trial


@dataclass
class Convergence:
    """A filter over one trial. waypoints: (S,) waypoints taken in after each update (the last
    one + 1 for a prior fused after the frames). error: (S, 6) estimate minus truth in the
    estimator.lie convention (m along the flange axes, rad about the camera axes). sigma: (S, 6)
    the filter's 1-sigma of the same components."""

    method: str
    waypoints: np.ndarray
    error: np.ndarray
    sigma: np.ndarray


def convergence(
    problem: CalibrationProblem, T_flange_cam_true: np.ndarray, options: MethodOptions, iterated: bool = False
) -> Convergence:
    """Run ekf (or iekf) over the problem's frames and keep each update's error and 1-sigma."""
    from estimator.filters import filter_steps

    position = {f.frame: i + 1 for i, f in enumerate(problem.frames)}
    waypoints, errors, sigmas = [], [], []
    for step in filter_steps(problem, options, iterated):
        waypoints.append(position[step.frame] if step.frame >= 0 else len(problem.frames) + 1)
        errors.append(pose_minus(step.state.T_flange_cam, T_flange_cam_true))
        sigmas.append(np.sqrt(np.diag(step.covariance)[:6]))
    return Convergence("iekf" if iterated else "ekf", np.array(waypoints), np.array(errors), np.array(sigmas))


def representative_trial(seed: int) -> tuple[CalibrationProblem, np.ndarray]:
    """A measurement-level trial like the sweep's: a random mount, the default views, board and
    noise (experiments.synthetic_scenes). Returns the problem and the true T_flange_cam (4, 4)."""
    from estimator.problem import build_problem
    from estimator.synthetic import SyntheticNoise
    from experiments.synthetic_scenes import BOARD, INTRINSICS, random_mount, scene

    rng = np.random.default_rng(seed)
    noise = SyntheticNoise()
    T_flange_cam = random_mount(rng)
    observations = scene(T_flange_cam, rng, noise)
    return build_problem(observations, BOARD, INTRINSICS, noise.robot), T_flange_cam


# ---------------------------------------------------------------- plots


def _figure(width: float, height: float, rows: int = 1, cols: int = 1, **kwargs: object) -> tuple:
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


def _legend_below(fig: object, ax: object) -> None:
    """One legend for the figure (the entries of ax) below the panels, out of the data's way."""
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 3), fontsize=8)


def png_bytes(fig: object) -> bytes:
    """The figure as PNG bytes."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    return buffer.getvalue()


def plot_convergence(conv: Convergence, title: str) -> object:
    """Six panels (x, y, z in mm; rx, ry, rz in degrees): error against waypoints with +-3 sigma."""
    fig, axes = _figure(13.0, 6.0, 2, 3, sharex=True)
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
    _legend_below(fig, axes[0, 0])
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
    fig, axes = _figure(12.0, 4.6, 1, 2)
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
    _legend_below(fig, axes[0, 0])
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
    fig, axes = _figure(max(10.0, 1.2 * len(methods) * max(1, len(groups) / 2)), 4.8, 1, 2)
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
    _legend_below(fig, axes[0, 0])
    fig.suptitle("errors of the ok trials per method" + (" and cell" if groups != [None] else ", all cells"))
    return fig


# ---------------------------------------------------------------- HTML

CSS = """
body { font-family: system-ui, sans-serif; margin: 2em; color: #222; max-width: 1400px; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }
th { background: #f0f0f0; }
td.name, th.name { text-align: left; }
tr.cell td { background: #e8eef8; text-align: left; font-weight: 600; }
td.bad { background: #fde2e2; }
img { max-width: 100%; border: 1px solid #ddd; margin: 0.5em 0; }
.note { color: #555; font-size: 0.9em; }
pre { background: #f6f6f6; padding: 0.8em; overflow-x: auto; font-size: 0.85em; }
"""
BAD_RATIO = 1.5  # RMS / bound above this is highlighted


def fmt(value: float, spec: str = ".3g") -> str:
    """A number for the tables; an em dash for NaN."""
    return "\u2014" if value is None or not np.isfinite(value) else format(value, spec)


def _e(value: object) -> str:
    return html.escape(str(value))


def _image(png: bytes, alt: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{_e(alt)}">'


def summary_table(summaries: list[CellSummary]) -> str:
    """The HTML summary table: a header row per cell (its swept parameters), a row per method."""
    head = (
        "<tr><th class=name rowspan=2>method</th><th rowspan=2>success</th>"
        "<th colspan=5>translation error [mm]</th><th colspan=5>rotation error [deg]</th>"
        "<th rowspan=2>mean NEES<br>(6 = honest)</th><th rowspan=2>median time [ms]</th></tr>"
        "<tr>" + "<th>median</th><th>p95</th><th>RMS</th><th>CRB</th><th>RMS / CRB</th>" * 2 + "</tr>"
    )
    body = []
    for i, s in enumerate(summaries):
        if i == 0 or s.cell != summaries[i - 1].cell:
            params = ", ".join(f"{p} = {_e(v)}" for p, v in s.parameters.items())
            n = max(x.trials for x in summaries if x.cell == s.cell)
            body.append(
                f"<tr class=cell><td colspan=14>cell {_e(s.cell)} \u2014 {_e(s.fidelity)}"
                f"{'; ' + params if params else ''}; {n} trials</td></tr>"
            )
        cells = [f"<td class=name>{_e(s.method)}</td>"]
        rate = f"{s.ok}/{s.trials} ({100 * s.success_rate:.0f} %)"
        cells.append(f"<td{' class=bad' if s.ok < s.trials else ''}>{rate}</td>")
        for stats in (s.translation_mm, s.rotation_deg):
            cells += [f"<td>{fmt(v)}</td>" for v in (stats.median, stats.p95, stats.rms, stats.crb_rms)]
            bad = np.isfinite(stats.ratio) and stats.ratio > BAD_RATIO
            ratio = fmt(stats.ratio, ".2f")
            if 0 < s.crb_trials < s.ok:  # some mounts had no bound: say over how many trials
                ratio += f" ({s.crb_trials} of {s.ok})"
            cells.append(f"<td{' class=bad' if bad else ''}>{ratio}</td>")
        cells += [f"<td>{fmt(s.mean_nees, '.2f')}</td>", f"<td>{fmt(1e3 * s.median_time_s, '.1f')}</td>"]
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table>{head}{''.join(body)}</table>"


def failures_table(summaries: list[CellSummary]) -> str:
    """Failure messages per cell and method with their counts, or a sentence when none failed."""
    rows = [
        f"<tr><td class=name>{_e(s.cell)}</td><td class=name>{_e(s.method)}</td><td>{count}</td>"
        f"<td class=name>{_e(message)}</td></tr>"
        for s in summaries
        for message, count in s.failures.items()
    ]
    if not rows:
        return "<p>No method failed in any trial.</p>"
    head = (
        "<tr><th class=name>cell</th><th class=name>method</th><th>rows</th><th class=name>failure</th></tr>"
    )
    return f"<table>{head}{''.join(rows)}</table>"


def _sweep_section(sweep: dict | None, out_dir: Path) -> str:
    if sweep is None:
        return f"<p class=note>No {_e(out_dir / META_FILE)}: config, seed and versions unknown.</p>"
    scalars = {k: v for k, v in sweep.items() if not isinstance(v, dict | list)}
    for key in ("software", "versions"):  # versions of the software the rows came from, one per line
        if isinstance(sweep.get(key), dict):
            scalars |= {f"{key}: {k}": v for k, v in sweep[key].items()}
    table = "".join(
        f"<tr><td class=name>{_e(k)}</td><td class=name>{_e(v)}</td></tr>" for k, v in scalars.items()
    )
    full = html.escape(json.dumps(sweep, indent=1, sort_keys=True))
    return (
        (f"<table>{table}</table>" if table else "")
        + f"<details><summary>{_e(META_FILE)} (resolved config, grid, versions)</summary>"
        + f"<pre>{full}</pre></details>"
    )


def _example_section(out_dir: Path) -> tuple[str, int]:
    """The rendered example's detection overlay and cell overview, or a sentence when absent;
    and the number of images embedded."""
    overlays = sorted(out_dir.glob(EXAMPLE_OVERLAYS))
    overview = out_dir / EXAMPLE_OVERVIEW
    parts, images = [], 0
    if overlays:
        parts.append(f"<h3>Detection overlay ({_e(overlays[0].relative_to(out_dir))})</h3>")
        parts.append(_image(overlays[0].read_bytes(), "detection overlay"))
        images += 1
    else:
        parts.append(
            f"<p class=note>No detection overlay: nothing matches {_e(out_dir / EXAMPLE_OVERLAYS)}.</p>"
        )
    if overview.is_file():
        parts.append(f"<h3>Overview of the cell ({_e(EXAMPLE_OVERVIEW)})</h3>")
        parts.append(_image(overview.read_bytes(), "overview of the cell"))
        images += 1
    else:
        parts.append(f"<p class=note>No overview picture: {_e(overview)} is missing.</p>")
    return "".join(parts), images


@dataclass
class Report:
    """What build_report wrote: the HTML page, the plot files, the number of embedded images."""

    html: Path
    plots: list[Path]
    images: int
    summaries: list[CellSummary]


def _convergence_seed(sweep: dict | None) -> int:
    sweep = sweep or {}
    seed = sweep.get("seed", (sweep.get("config") or {}).get("seed"))
    return seed if isinstance(seed, int) and not isinstance(seed, bool) and seed >= 0 else 0


def build_report(out_dir: Path, rows: list[dict] | None = None) -> Report:
    """Rebuild DIR/report.html and DIR/plots/*.png from the rows (default: load_rows(out_dir))."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise ReportError(f"{out_dir}: folder does not exist; expected the --out folder of `hec sweep`")
    rows = load_rows(out_dir) if rows is None else rows
    check_rows(rows, str(out_dir / ROWS_FILE))
    sweep_path = out_dir / META_FILE
    sweep = read_json_object(sweep_path, ReportError) if sweep_path.exists() else None
    summaries = summarise(rows)
    parameters = swept_parameters(rows)
    fixed = fixed_parameters(rows)

    figures: list[tuple[str, str, object]] = []  # (file name, heading, figure)
    for p in parameters:
        figures.append((f"error_vs_{p}.png", f"Error against {p}", plot_error_vs_parameter(rows, p)))
    figures.append(("boxes.png", "Errors per method", plot_boxes(rows)))
    seed = _convergence_seed(sweep)
    conv = convergence(*representative_trial(seed), MethodOptions())
    title = (
        f"{conv.method} on a representative measurement-level trial (random mount, default noise, "
        f"seed {seed}): error and +-3 sigma per component"
    )
    heading = f"Filter convergence over the waypoints ({conv.method}, representative trial, seed {seed})"
    figures.append(("convergence.png", heading, plot_convergence(conv, title)))

    plots_dir = out_dir / PLOTS_DIR
    plots_dir.mkdir(exist_ok=True)
    written, sections = [], []
    for name, heading, fig in figures:
        png = png_bytes(fig)
        write_atomic(plots_dir / name, png)
        written.append(plots_dir / name)
        sections.append(f"<h3>{_e(heading)}</h3>{_image(png, heading)}")
    images = len(figures)
    for stale in set(plots_dir.glob("error_vs_*.png")) - set(written):  # an earlier report's parameter
        stale.unlink()

    notes = []
    if not parameters:
        notes.append("No parameter takes more than one value: no plot of error against a parameter.")
    fidelities = _unique(r["fidelity"] for r in rows)
    render = "render" in fidelities or (out_dir / "example").is_dir()
    example_html, example_images = _example_section(out_dir) if render else ("", 0)
    images += example_images

    fixed_text = _e(", ".join(f"{p} = {v}" for p, v in fixed.items()) or "nothing")
    trials = len(_unique(r["trial_id"] for r in rows))
    methods = _unique(r["method"] for r in rows)
    cells = _unique(r["cell"] for r in rows)
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>hec sweep report: {_e(out_dir.name)}</title>
<style>{CSS}</style></head><body>
<h1>Hand-eye calibration sweep: {_e(out_dir.name)}</h1>
<p>{len(rows)} rows: {trials} trials x {len(methods)} methods ({_e(", ".join(methods))})
over {len(cells)} grid cells; fidelity {_e(", ".join(fidelities))};
swept: {_e(", ".join(parameters) or "nothing")}; fixed: {fixed_text}.
Built from {_e(out_dir / ROWS_FILE)} by <code>hec report</code>.</p>
<p class=note>Errors of the estimated T_flange_cam (camera optical frame in the flange frame; OpenCV's
cam2gripper) against the simulated truth: translation = norm of the difference of the translations,
rotation = geodesic angle of R_est^T R_true. Median, p95 and RMS are over the ok trials; success counts
failed trials too. CRB = RMS over the same trials of the root-sum-square Cramer-Rao sigmas at the truth;
RMS / CRB near 1 means the method reaches the bound (highlighted above {BAD_RATIO}; trials whose mount was
not observable have no bound and are left out of the ratio).</p>
<h2>Sweep</h2>{_sweep_section(sweep, out_dir)}
<h2>Summary per grid cell and method</h2>{summary_table(summaries)}
<h2>Failures</h2>{failures_table(summaries)}
<h2>Plots</h2>{"".join(f"<p class=note>{_e(n)}</p>" for n in notes)}
<p class=note>Files in {_e(plots_dir)}. The convergence plot regenerates one measurement-level trial
(default noise, random mount; ekf from MethodOptions()), the error being estimate minus truth per
component (translation along the flange axes, rotation about the camera axes).</p>
{"".join(sections)}
{"<h2>Rendered example</h2>" + example_html if render else ""}
</body></html>
"""
    report_path = out_dir / REPORT_FILE
    write_atomic(report_path, page.encode("utf-8"))
    return Report(report_path, written, images, summaries)


# ---------------------------------------------------------------- the command


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add `hec report DIR`."""
    p = sub.add_parser(
        "report",
        help="rebuild DIR/report.html (tables and plots) and DIR/plots/ from a sweep's saved rows",
    )
    p.add_argument("dir", type=Path, metavar="DIR", help="the --out folder of `hec sweep`")


def run(args: argparse.Namespace) -> int:
    """`hec report DIR`: 0 when written, 2 with a message on stderr when DIR has no usable rows."""
    try:
        report = build_report(args.dir)
    except ReportError as exc:
        print(f"hec: error: {exc}", file=sys.stderr)
        return 2
    _print_summary(report.summaries)
    print(
        f"report: {report.html} ({report.images} images embedded; plots in {report.html.parent / PLOTS_DIR})"
    )
    return 0


def _print_summary(summaries: Sequence[CellSummary]) -> None:
    """A short terminal table: per cell and method the success and RMS errors with their ratio."""
    print(
        f"{'cell':12s} {'method':18s} {'ok':>7s} {'RMS mm':>9s} {'x CRB':>8s} {'RMS deg':>9s} {'x CRB':>8s}"
    )
    for s in summaries:
        t, r = s.translation_mm, s.rotation_deg
        print(
            f"{s.cell[:12]:12s} {s.method[:18]:18s} {f'{s.ok}/{s.trials}':>7s} {fmt(t.rms):>9s} "
            f"{fmt(t.ratio, '.3g'):>8s} {fmt(r.rms):>9s} {fmt(r.ratio, '.3g'):>8s}"
        )
