"""The robustness benchmark's summaries (hec.bench.robustness): per case and method the median and
95th-percentile errors, mean NEES, warnings and failures; the default method's acceptance lines
against the best OpenCV method and the Cramer-Rao bound; the printed table of a case."""

from __future__ import annotations

from collections import Counter

import numpy as np

from hec.estimator.solve.baselines import OPENCV_METHODS
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import METHODS

TARGET_RATIO = 0.8  # the default's median error must be at most this times the best OpenCV's
NEES_RANGE = (4.0, 9.0)
BOUND_SAMPLES = 2000


def summarise(trials: list[dict]) -> dict:
    """Per method over the trials: median / p95 errors, mean NEES, warned and rejected fractions,
    failures (with one message), warning kinds; the bound's median; the acceptance lines."""
    crb = np.array([t["crb"] for t in trials], dtype=float)
    finite = crb[np.all(np.isfinite(crb), axis=1)]
    summary = {
        "trials": len(trials),
        "redrawn": sum(1 for t in trials if t.get("redrawn")),
        "crb_median_mm": float(np.median(finite[:, 0])) if len(finite) else None,
        "crb_median_deg": float(np.median(finite[:, 1])) if len(finite) else None,
        **_bound_error_medians([t["crb_cov"] for t in trials if t["crb_cov"] is not None]),
        "methods": {},
    }
    for method in METHODS:
        runs = [t["methods"][method] for t in trials]
        ok = [r for r in runs if "failed" not in r]
        failed = [r["failed"] for r in runs if "failed" in r]
        row: dict = {"runs": len(runs), "failures": len(failed), "failure": failed[0] if failed else None}
        if ok:
            mm, deg = np.array([r["error_mm"] for r in ok]), np.array([r["error_deg"] for r in ok])
            nees = [r["nees"] for r in ok if r["nees"] is not None]
            kinds = Counter(k for r in ok for k in r["warnings"])
            row |= {
                "median_mm": float(np.median(mm)),
                "p95_mm": float(np.percentile(mm, 95)),
                "median_deg": float(np.median(deg)),
                "p95_deg": float(np.percentile(deg, 95)),
                "mean_nees": float(np.mean(nees)) if nees else None,
                "warned": sum(bool(r["warnings"]) for r in ok) / len(ok),
                "rejected": float(np.mean([r["rejected"] for r in ok])),
                "warning_kinds": dict(kinds.most_common()),
            }
        summary["methods"][method] = row
    summary["acceptance"] = acceptance(summary)
    return summary


def _bound_error_medians(covariances: list) -> dict:
    """The median error an efficient unbiased estimator would have, comparable to a method's median:
    the median norm of e ~ N(0, CRB) pooled over the trials (BOUND_SAMPLES fixed draws per trial),
    translation (mm) and rotation (deg). covariances: per trial [(3, 3) mm^2, (3, 3) deg^2]."""
    if not covariances:
        return {"crb_error_median_mm": None, "crb_error_median_deg": None}
    rng, medians = np.random.default_rng(0), []
    for part in (0, 1):
        norms = []
        for trial in covariances:
            w, V = np.linalg.eigh(np.array(trial[part]))
            e = rng.standard_normal((BOUND_SAMPLES, 3)) @ (V * np.sqrt(np.maximum(w, 0.0))).T
            norms.append(np.linalg.norm(e, axis=1))
        medians.append(float(np.median(np.concatenate(norms))))
    return {"crb_error_median_mm": medians[0], "crb_error_median_deg": medians[1]}


def best_opencv(rows: dict, key: str) -> str | None:
    usable = [m for m in OPENCV_METHODS if key in rows[m] and rows[m]["failures"] <= rows[m]["runs"] / 2]
    return min(usable, key=lambda m: rows[m][key]) if usable else None


def acceptance(summary: dict) -> list[dict]:
    """The default method's lines: median error <= TARGET_RATIO x the best OpenCV's (translation and
    rotation) and mean NEES in NEES_RANGE, each {'text', 'ok'}; then the bound beside the target
    ({'text', 'ok': None}, not a check)."""
    rows, default = summary["methods"], summary["methods"][DEFAULT_METHOD]
    lines, targets = [], {}
    for key, unit, what in (("median_mm", "mm", "translation"), ("median_deg", "deg", "rotation")):
        best = best_opencv(rows, key)
        head = f"default median {what} <= {TARGET_RATIO}x best OpenCV"
        if best is None or key not in default:
            why = "no OpenCV method succeeded" if best is None else f"{DEFAULT_METHOD} never succeeded"
            lines.append({"text": f"{head}: FAIL ({why})", "ok": False})
            continue
        ratio = default[key] / rows[best][key]
        targets[what] = (TARGET_RATIO * rows[best][key], unit)
        ok = bool(ratio <= TARGET_RATIO)
        detail = f"{DEFAULT_METHOD} {default[key]:.4g} {unit}, {best} {rows[best][key]:.4g} {unit}"
        lines.append({"text": f"{head}: {'PASS' if ok else 'FAIL'} ({ratio:.2f}; {detail})", "ok": ok})
    lo, hi = NEES_RANGE
    nees = default.get("mean_nees")
    ok = nees is not None and lo <= nees <= hi
    shown = "no covariance" if nees is None else f"{DEFAULT_METHOD} {nees:.2f}"
    lines.append({"text": f"mean NEES in [{lo:g}, {hi:g}]: {'PASS' if ok else 'FAIL'} ({shown})", "ok": ok})
    if summary["crb_median_mm"] is None:
        lines.append({"text": "Cramer-Rao bound: not observable", "ok": None})
        return lines
    rss = f"median RSS 1-sigma {summary['crb_median_mm']:.4g} mm, {summary['crb_median_deg']:.4g} deg"
    parts = []
    for what, key, unit in (("translation", "mm", "mm"), ("rotation", "deg", "deg")):
        value = summary[f"crb_error_median_{key}"]
        text = f"{value:.4g} {unit}"
        if what in targets:
            target = targets[what][0]
            text += f" (target {target:.4g}{': out of reach' if value > target else ''})"
        parts.append(text)
    text = f"Cramer-Rao bound at the truth: {rss}; an efficient estimator's median error {', '.join(parts)}"
    lines.append({"text": text, "ok": None})
    return lines


def format_case(key: str, summary: dict) -> list[str]:
    """The printed table of one case, its default method's warnings and its acceptance lines."""
    lines = [
        f"\n## {key} ({summary['trials']} trials"
        + (f", {summary['redrawn']} drawn again: the mount hid the board)" if summary["redrawn"] else ")"),
        f"{'method':18s} {'med mm':>8s} {'p95 mm':>8s} {'med deg':>8s} {'p95 deg':>8s} {'NEES':>8s} "
        f"{'warned':>6s} {'reject':>6s} {'failed':>6s}",
    ]
    for method, r in summary["methods"].items():
        if "median_mm" not in r:
            lines.append(f"{method:18s} all {r['failures']} runs failed: {r['failure'][:70]}")
            continue
        nees = "-" if r["mean_nees"] is None else f"{r['mean_nees']:8.2f}"
        lines.append(
            f"{method:18s} {r['median_mm']:8.3f} {r['p95_mm']:8.3f} {r['median_deg']:8.4f} "
            f"{r['p95_deg']:8.4f} {nees:>8s} {r['warned']:6.0%} {r['rejected']:6.1%} {r['failures']:6d}"
        )
    default = summary["methods"][DEFAULT_METHOD]
    ok_runs = default["runs"] - default["failures"]
    if default.get("warning_kinds"):
        kinds = ", ".join(f"{k} {n}/{ok_runs}" for k, n in default["warning_kinds"].items())
        lines.append(f"{DEFAULT_METHOD} warnings: {kinds}")
    for line in summary["acceptance"]:
        lines.append(("" if line["ok"] is None else "acceptance: ") + line["text"])
    return lines
