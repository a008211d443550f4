"""One calibration as a page to look at (`hec calibrate ... --report DIR`, and `hec run`):
DIR/report.html, self-contained (figures embedded), with

- the verdict and the short report (hec.calibration.summary);
- the uncertainty of each axis beside its Cramer-Rao bound (what these views allow at best);
- what the self-calibration found against the declared camera, board, depth and arm;
- residuals per frame (pixels, depth) with the leave-one-frame-out prediction, and per marker;
- the camera's poses around the board in the robot's base frame;
- every frame with its detected corners and the corners the calibration predicts there;
- the full text report.

The page checks its own figures once loaded: the body's data-figures attribute says how many of
its images decoded ("12/12"), which the tests read in a headless browser.
"""

from __future__ import annotations

import base64
import html
import os
import shutil
from pathlib import Path

import numpy as np

from hec.calibration import report_plots
from hec.calibration.report import format_calibration
from hec.calibration.summary import findings, format_summary, verdict
from hec.estimator.common.files import write_atomic
from hec.estimator.observe.frames import Dataset
from hec.estimator.solve.calibration import Calibration
from hec.estimator.solve.problem import CalibrationProblem

REPORT_FILE = "report.html"
SHOWN_CORRECTIONS = 12  # a longer table of self-calibrated corrections opens on a click
AXES = (
    ("x", "mm"),
    ("y", "mm"),
    ("z", "mm"),
    ("rotation about x", "deg"),
    ("about y", "deg"),
    ("about z", "deg"),
)

CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; color: #222; max-width: 1100px; padding: 0 1em; }
h1 { font-size: 1.5em; } h2 { font-size: 1.15em; margin-top: 2em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }
th { background: #f0f0f0; } td.name, th.name { text-align: left; }
.verdict { font-size: 1.1em; padding: 0.6em 0.9em; border-radius: 4px; margin: 1em 0; }
.good { background: #e2f4e2; } .usable { background: #fdf3d8; } .redo { background: #fde2e2; }
img { max-width: 100%; border: 1px solid #ddd; }
.frames { display: flex; flex-wrap: wrap; gap: 0.6em; }
.frames figure { margin: 0; width: 540px; max-width: 100%; } figcaption { font-size: 0.8em; color: #555; }
.note { color: #555; font-size: 0.9em; }
pre { background: #f6f6f6; padding: 0.8em; white-space: pre-wrap; font-size: 0.8em; }
"""
# Counts the images that decoded once the page has loaded (module doc).
CHECK_SCRIPT = """
window.addEventListener("load", () => {
  const images = Array.from(document.images);
  const drawn = images.filter((i) => i.complete && i.naturalWidth > 0).length;
  document.body.dataset.figures = drawn + "/" + images.length;
});
"""


def check_report_dir(out_dir: Path) -> None:
    """Raise now, before any work, when out_dir/report.html cannot be written: out_dir is a file, or
    the folder it is (or would be made in) cannot be written."""
    if out_dir.exists() and not out_dir.is_dir():
        raise NotADirectoryError(f"{out_dir}: is a file; --report takes a folder (report.html goes in it)")
    existing = next(p for p in (out_dir, *out_dir.parents) if p.exists())
    if not os.access(existing, os.W_OK):
        raise PermissionError(f"{out_dir}: cannot write in {existing}")


def write_calibration_report(
    out_dir: Path,
    dataset: Dataset,
    problem: CalibrationProblem,
    cal: Calibration,
    T_true: np.ndarray | None = None,
    comparison: str | None = None,
) -> Path:
    """Write out_dir/report.html (module doc) for cal, the calibration of dataset's problem; with
    T_true (4, 4) the errors against it, with comparison the --method all table. Returns the path."""
    made = next((p for p in (*reversed(out_dir.parents), out_dir) if not p.exists()), None)
    out_dir.mkdir(parents=True, exist_ok=True)
    graded = verdict(cal)
    found = findings(cal)
    parts = [
        f"<h1>Hand-eye calibration of {_e(dataset.root.name)} by {_e(cal.method)}</h1>",
        f"<p class='verdict {graded.grade}'><b>{_e(graded.grade)}</b>: {_e('; '.join(graded.reasons))}</p>",
        f"<pre>{_e(format_summary(cal, T_true))}</pre>",
    ]
    if comparison is not None:
        parts += ["<h2>Every method on these frames</h2>", f"<pre>{_e(comparison)}</pre>"]
    parts += [
        "<h2>Findings</h2>",
        "<ul>" + "".join(f"<li>{_e(f)}</li>" for f in found) + "</ul>" if found else "<p>None.</p>",
        "<h2>Uncertainty and the best these views allow</h2>",
        _uncertainty_table(cal),
        *_self_calibration(cal),
        "<h2>Residuals per frame</h2>",
        "<p class=note>Blue: how far the detected corners lie from where the calibration puts them. Orange: "
        "the same for the frame predicted by a calibration without it (leave one frame out); the black "
        "mark is what the frame's own noise alone would give.</p>",
        _image(report_plots.frame_residual_plot(cal), "png", "residuals per frame"),
        "<h2>Residuals per marker</h2>",
        "<p class=note>Each marker's corner RMS in each frame; white: not seen in that frame.</p>",
        _image(report_plots.marker_residual_plot(cal), "png", "residuals per marker and frame"),
        "<h2>The camera around the board</h2>",
        "<p class=note>The board (black) and the camera in every frame (its centre, the orange line its "
        "viewing direction, the frame's number), in the robot's base frame, metres.</p>",
        _image(report_plots.poses_plot(problem, cal), "png", "camera poses around the board"),
        "<h2>The frames</h2>",
        f"<p class=note>Green dots: detected corners (orange: markers the method left out); red lines: "
        f"from each to where the calibration predicts it, drawn {report_plots.RESIDUAL_SCALE:.0f} times its "
        "length, so a pattern in them shows what the model misses.</p>",
        _frames(dataset, problem, cal),
        "<h2>The full report</h2>",
        f"<pre>{_e(format_calibration(cal, T_true))}</pre>",
    ]
    page = (
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>"
        f"<title>hec calibration: {_e(dataset.root.name)}</title><style>{CSS}</style>"
        f"<script>{CHECK_SCRIPT}</script></head><body>{''.join(parts)}</body></html>"
    )
    try:
        return write_atomic(out_dir / REPORT_FILE, page)
    except BaseException:
        if made:  # no empty folder left by a report that could not be written
            shutil.rmtree(made, ignore_errors=True)
        raise


def _uncertainty_table(cal: Calibration) -> str:
    report = cal.diagnostics.get("observability")
    if cal.covariance is None:
        return "<p>None: this method gives no uncertainty.</p>"
    sigma = np.concatenate([cal.sigma_translation_mm, cal.sigma_rotation_deg])
    bound = (
        np.concatenate([report.crb_sigma_translation_mm, report.crb_sigma_rotation_deg])
        if report is not None
        else np.full(6, np.nan)
    )
    rows = "".join(
        f"<tr><td class=name>{name} [{unit}]</td><td>{s:.4g}</td><td>{b:.4g}</td><td>{s / b:.2f}</td></tr>"
        for (name, unit), s, b in zip(AXES, sigma, bound, strict=True)
    )
    return (
        "<table><tr><th class=name>axis</th><th>1 sigma</th><th>Cramer-Rao bound</th><th>ratio</th></tr>"
        f"{rows}</table><p class=note>The bound is the least 1 sigma any unbiased method reaches from "
        "these views at the declared noise, with the declared camera, board and arm. The 1 sigma holds "
        "the noise learned from the data and the uncertainty of what the self-calibration corrected: a "
        "ratio well above 1 says those, not the views, limit the result.</p>"
    )


def _self_calibration(cal: Calibration) -> list[str]:
    learned = cal.diagnostics.get("noise")
    if learned is None or learned.theta is None or not len(learned.theta_names):
        return []
    rows = "".join(
        f"<tr><td class=name>{_e(name)}</td><td>{_value(name, v)}</td><td>{_value(name, s)[1:]}</td></tr>"
        for name, v, s in zip(learned.theta_names, learned.theta, learned.theta_sigma, strict=True)
    )
    table = f"<table><tr><th class=name>parameter</th><th>correction</th><th>1 sigma</th></tr>{rows}</table>"
    count = len(learned.theta_names)
    return [
        "<h2>What the self-calibration found</h2>",
        "<p class=note>Each correction to the declared camera, board, depth and arm the data "
        "determine, with its 1 sigma (the findings above name those that matter).</p>",
        table
        if count <= SHOWN_CORRECTIONS
        else f"<details><summary>{count} corrections</summary>{table}</details>",
    ]


def _value(name: str, value: float) -> str:
    """A correction in the units people read it in: mm, degrees, percent, else as it is."""
    if name.endswith("_m"):
        return f"{1e3 * value:+.3f} mm"
    if name.endswith("_rad"):
        return f"{np.degrees(value):+.4f} deg"
    if "scale" in name:
        return f"{100 * value:+.3f} %"
    return f"{value:+.4g}"


def _frames(dataset: Dataset, problem: CalibrationProblem, cal: Calibration) -> str:
    residual = cal.frame_residuals()
    figures = [
        f"<figure>{_image(jpeg, 'jpeg', f'frame {frame}')}<figcaption>frame {frame}: "
        f"{residual.get(frame, float('nan')):.2f} px RMS</figcaption></figure>"
        for frame, jpeg in report_plots.frame_overlays(dataset, problem, cal)
    ]
    return f"<div class=frames>{''.join(figures)}</div>"


def _image(data: bytes, kind: str, alt: str) -> str:
    return f'<img src="data:image/{kind};base64,{base64.b64encode(data).decode("ascii")}" alt="{_e(alt)}">'


def _e(value: object) -> str:
    return html.escape(str(value))
