"""`hec report DIR`: the summary tables and plots of a Monte-Carlo sweep, as one self-contained HTML page.

Input: the sweep's result rows (one per trial x method: the ROW_COLUMNS, plus one column per trial
parameter, swept when it takes more than one value) read by load_report_rows, and, when present,
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

import base64
import html
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hec.estimator.common.files import write_atomic
from hec.estimator.common.jsonfile import read_json_object
from hec.estimator.solve.calibration import MethodOptions
from hec.support.plotting import png_bytes
from hec.sweep.budget import TEXT_FILE, budget_table_html, budget_text, has_budget, plot_budget
from hec.sweep.plots import plot_boxes, plot_convergence, plot_error_vs_parameter
from hec.sweep.rows import EXAMPLE_DIR, META_FILE, ROWS_FILE, trial_id
from hec.sweep.summary import (
    CellSummary,
    ReportError,
    _unique,
    check_rows,
    convergence,
    fixed_parameters,
    load_report_rows,
    representative_trial,
    summarise,
    swept_parameters,
)

REPORT_FILE = "report.html"
PLOTS_DIR = "plots"
EXAMPLE_OVERLAYS = f"{EXAMPLE_DIR}/overlay/*.png"
EXAMPLE_OVERVIEW = f"{EXAMPLE_DIR}/preview/overview.png"


CSS = """
body { font-family: system-ui, sans-serif; margin: 2em; color: #222; max-width: 1400px; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }
th { background: #f0f0f0; }
td.name, th.name { text-align: left; }
tr.cell td { background: #e8eef8; text-align: left; font-weight: 600; }
td.bad, p.bad { background: #fde2e2; }
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


def missing_trials(sweep: dict | None, rows: list[dict]) -> str | None:
    """What an unfinished sweep lacks, in words (the grid cells without any trial, the number of
    trials and method rows missing), from sweep.json's grid; None when complete or unknown."""
    config = (sweep or {}).get("config") or {}
    cells, trials, methods = config.get("cells"), config.get("trials"), config.get("methods")
    if not isinstance(cells, list) or not isinstance(trials, int) or not isinstance(methods, list):
        return None
    present = {(r["trial_id"], r["method"]) for r in rows}
    try:
        expected = [trial_id(c["index"], t) for c in cells for t in range(trials)]
        names = [c["cell"] for c in cells]
    except (KeyError, TypeError, ValueError):  # a sweep.json not written by `hec sweep`
        return None
    absent = [t for t in expected if not any((t, m) in present for m in methods)]
    short = sum((t, m) not in present for t in expected for m in methods) - len(absent) * len(methods)
    if not absent and not short:
        return None
    seen = {r["cell"] for r in rows}
    empty = [name for name in names if name not in seen]
    words = f"unfinished sweep: {len(absent)} of {len(expected)} trials missing"
    if empty:
        words += f" (no trial at all of cells {', '.join(empty)})"
    if short:
        words += f"; {short} method rows missing from trials present"
    return words + "; finish it with `hec sweep CONFIG --out DIR --resume`"


@dataclass
class Report:
    """What build_report wrote: the HTML page, the plot files, the number of embedded images, and
    what an unfinished sweep lacks (None when complete)."""

    html: Path
    plots: list[Path]
    images: int
    summaries: list[CellSummary]
    missing: str | None = None


def _convergence_seed(sweep: dict | None) -> int:
    sweep = sweep or {}
    seed = sweep.get("seed", (sweep.get("config") or {}).get("seed"))
    return seed if isinstance(seed, int) and not isinstance(seed, bool) and seed >= 0 else 0


def _budget_section(summaries: list[CellSummary]) -> str:
    return (
        "<h2>Error budget</h2><p class=note>Per error source (its cell's error_sources: that source "
        "alone at the scenario's magnitude; none = the ideal cell; all = every source together) and "
        "method: the median / p95 translation error (mm), the median / p95 rotation error (degrees) "
        "and the mean NEES (6 when the reported uncertainty is honest). The largest figures say "
        f"which source to fix first; the same table as text is in {TEXT_FILE}.</p>"
        + budget_table_html(summaries)
    )


def build_report(out_dir: Path, rows: list[dict] | None = None) -> Report:
    """Rebuild DIR/report.html and DIR/plots/*.png from the rows (default: load_report_rows(out_dir))."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise ReportError(f"{out_dir}: folder does not exist; expected the --out folder of `hec sweep`")
    rows = load_report_rows(out_dir) if rows is None else rows
    check_rows(rows, str(out_dir / ROWS_FILE))
    sweep_path = out_dir / META_FILE
    sweep = read_json_object(sweep_path, ReportError) if sweep_path.exists() else None
    summaries = summarise(rows)
    parameters = swept_parameters(rows)
    fixed = fixed_parameters(rows)

    figures: list[tuple[str, str, object]] = []  # (file name, heading, figure)
    budget = has_budget(summaries)
    if budget:
        figures.append(("error_budget.png", "Error budget per source and method", plot_budget(summaries)))
        write_atomic(out_dir / TEXT_FILE, budget_text(summaries) + "\n")
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

    missing = missing_trials(sweep, rows)
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
{f"<p class=bad><strong>{_e(missing)}.</strong></p>" if missing else ""}
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
{_budget_section(summaries) if budget else ""}
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
    return Report(report_path, written, images, summaries, missing)
