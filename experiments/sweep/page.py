"""A sweep's results as a documentation page (`hec report DIR --page PATH.md`): per cell and method
the median, p95 and RMS error and the mean NEES; per cell hec's default method beside OpenCV's
best and how often seed-ekf warned when it was off; for an error-budget sweep also the budget,
hec's default method beside OpenCV's best per source. Written from the saved rows, never typed."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.support.results_page import markdown_table, write_results_page
from hec.sweep.budget import PARAMETER, has_budget
from hec.sweep.rows import load_rows
from hec.sweep.summary import CellSummary

OPENCV_PREFIX = "opencv-"
SEED_EKF = "seed-ekf"
# seed-ekf's NEES beyond which its result must carry a warning (6 degrees of freedom: p < 0.003).
SEED_EKF_NEES_LIMIT = 20.0


def _mm_deg(s: CellSummary | None) -> str:
    if s is None or s.ok == 0:
        return "-"
    return f"{s.translation_mm.median:.3f} / {s.rotation_deg.median:.4f}"


def cell_rows(summaries: Sequence[CellSummary]) -> list[list[str]]:
    """A row per cell and method: ok/trials, median / p95 / RMS mm, median deg, RMS / CRB, NEES."""
    return [
        [
            " ".join([s.cell, *(f"{k}={v}" for k, v in s.parameters.items())]),
            s.method,
            f"{s.ok}/{s.trials}",
            f"{s.translation_mm.median:.3f}",
            f"{s.translation_mm.p95:.3f}",
            f"{s.translation_mm.rms:.3f}",
            f"{s.rotation_deg.median:.4f}",
            f"{s.translation_mm.ratio:.2f}" if np.isfinite(s.translation_mm.ratio) else "-",
            f"{s.mean_nees:.1f}" if np.isfinite(s.mean_nees) else "-",
        ]
        for s in summaries
    ]


def paired_cost(rows: Sequence[dict], method: str) -> dict[str, str]:
    """Per error source, method's mean extra error (mm) over the ideal cell ("none") on the same
    trial, with its standard error: a paired sweep draws trial t's mount and views alike in every
    cell. Sources without two common ok trials are left out."""
    error = {
        (str(r[PARAMETER]), r["trial_id"].split("-")[-1]): float(r["error_translation_mm"])
        for r in rows
        if r["method"] == method and r["status"] == "ok"
    }
    ideal = {trial: e for (source, trial), e in error.items() if source == "none"}
    cost = {}
    for source in dict.fromkeys(source for source, _ in error):
        differences = [e - ideal[t] for (src, t), e in error.items() if src == source and t in ideal]
        if source != "none" and len(differences) >= 2:
            d = np.array(differences)
            cost[source] = f"{d.mean():+.3f} +- {d.std(ddof=1) / np.sqrt(len(d)):.3f}"
    return cost


def budget_rows(summaries: Sequence[CellSummary], cost: dict[str, str]) -> list[list[str]]:
    """A row per error source: the default method's median mm / deg and NEES, OpenCV Park's, the
    best OpenCV method by median mm, the default method's median over that best one's, and its
    paired cost over the ideal cell (paired_cost, "-" without)."""
    by = {(str(s.parameters[PARAMETER]), s.method): s for s in summaries if PARAMETER in s.parameters}
    rows = []
    for source in dict.fromkeys(source for source, _ in by):
        ours = by.get((source, DEFAULT_METHOD))
        opencv = [s for (src, m), s in by.items() if src == source and m.startswith(OPENCV_PREFIX) and s.ok]
        best = min(opencv, key=lambda s: s.translation_mm.median, default=None)
        ratio = "-"
        if ours is not None and ours.ok and best is not None:
            ratio = f"{ours.translation_mm.median / best.translation_mm.median:.2f}x"
        rows.append(
            [
                source,
                _mm_deg(ours),
                f"{ours.mean_nees:.1f}" if ours is not None and np.isfinite(ours.mean_nees) else "-",
                _mm_deg(by.get((source, "opencv-park"))),
                "-" if best is None else f"{best.method.removeprefix(OPENCV_PREFIX)} {_mm_deg(best)}",
                ratio,
                cost.get(source, "-"),
            ]
        )
    return rows


def versus_rows(summaries: Sequence[CellSummary]) -> list[list[str]]:
    """A row per cell: the default method's median mm and mean NEES, the best OpenCV method by
    median mm, and the default method's median over that best one's."""
    rows = []
    for cell in dict.fromkeys(s.cell for s in summaries):
        mine = [s for s in summaries if s.cell == cell]
        ours = next((s for s in mine if s.method == DEFAULT_METHOD and s.ok), None)
        opencv = [s for s in mine if s.method.startswith(OPENCV_PREFIX) and s.ok]
        best = min(opencv, key=lambda s: s.translation_mm.median, default=None)
        if ours is None or best is None:
            continue
        rows.append(
            [
                " ".join([cell, *(f"{k}={v}" for k, v in ours.parameters.items())]),
                f"{ours.translation_mm.median:.3f}",
                f"{ours.mean_nees:.1f}" if np.isfinite(ours.mean_nees) else "-",
                f"{best.method.removeprefix(OPENCV_PREFIX)} {best.translation_mm.median:.3f}",
                f"{ours.translation_mm.median / best.translation_mm.median:.2f}x",
            ]
        )
    return rows


def warning_rows(rows: Sequence[dict], method: str, nees_limit: float) -> list[list[str]]:
    """A row per cell: method's ok trials, those with NEES above nees_limit, and how many of those
    carried a warning (rows with a warnings column; none without)."""
    out = []
    for cell in dict.fromkeys(r["cell"] for r in rows):
        ok = [r for r in rows if r["cell"] == cell and r["method"] == method and r["status"] == "ok"]
        if not ok or "warnings" not in ok[0]:
            continue
        high = [r for r in ok if float(r["nees"]) > nees_limit]
        warned = sum(float(r["warnings"]) > 0 for r in high)
        out.append([cell, str(len(ok)), str(len(high)), str(warned)])
    return out


def write_sweep_page(
    out_dir: Path, summaries: Sequence[CellSummary], page: Path, missing: str | None = None
) -> Path:
    """Write the sweep in out_dir (its sweep.json names the configuration) as a results page;
    missing: what an unfinished sweep lacks (hec.sweep.report.missing_trials), said at the top."""
    record = json.loads((Path(out_dir) / "sweep.json").read_text())
    name = Path(str(record.get("config_file", "the sweep file"))).name
    paired = bool(record.get("config", {}).get("paired"))
    body = [
        f"`hec sweep` of `{name}`, then `hec report`. Errors of `T_flange_cam` against the truth over"
        " the successful trials; RMS / CRB is the RMS error over the Cramer-Rao bound's RMS on the same"
        " trials; the mean NEES is about 6 when the reported uncertainty is honest."
    ]
    if missing is not None:
        body.append(f"**Not every trial is in these tables**: {missing}.")
    if has_budget(list(summaries)):
        header = [
            "error source",
            f"{DEFAULT_METHOD} mm / deg",
            "NEES",
            "OpenCV Park mm / deg",
            "best OpenCV mm / deg",
            f"{DEFAULT_METHOD} / best",
            f"{DEFAULT_METHOD} - none, mm (paired)",
        ]
        cost = paired_cost(load_rows(out_dir), DEFAULT_METHOD) if paired else {}
        body += [
            "## Error budget (medians)",
            f"Per error source alone, then all, then none (the ideal cell). The last column is"
            f" {DEFAULT_METHOD}'s mean extra error over the ideal cell on the same trial, with its"
            " standard error (paired sweeps only).",
            markdown_table(header, budget_rows(summaries, cost)),
        ]
    versus = versus_rows(summaries)
    if versus:
        header = [
            "cell",
            f"{DEFAULT_METHOD} median mm",
            "NEES",
            "best OpenCV median mm",
            f"{DEFAULT_METHOD} / best",
        ]
        body += ["## The default method against OpenCV's best", markdown_table(header, versus)]
    warned = warning_rows(load_rows(out_dir), SEED_EKF, SEED_EKF_NEES_LIMIT)
    if warned:
        header = [
            "cell",
            f"{SEED_EKF} ok trials",
            f"NEES > {SEED_EKF_NEES_LIMIT:g}",
            "of those with a warning",
        ]
        body += [
            f"## Does {SEED_EKF} say when it is off?",
            f"The paper's method takes the camera, depth and arm as declared; its result should warn"
            f" whenever its error is beyond its uncertainty (NEES > {SEED_EKF_NEES_LIMIT:g}).",
            markdown_table(header, warned),
        ]
    header = ["cell", "method", "ok", "median mm", "p95 mm", "RMS mm", "median deg", "RMS / CRB", "NEES"]
    body += ["## Every cell and method", markdown_table(header, cell_rows(summaries))]
    title = f"Sweep results: {Path(name).stem.replace('_', ' ')}"
    return write_results_page(page, title, f"hec report DIR --page {page}", body)
