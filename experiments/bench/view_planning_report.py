"""The view-planning benchmark's summaries, acceptance lines, table and plot
(hec.bench.view_planning runs it)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from hec.estimator.solve.method_names import DEFAULT_METHOD

STRATEGIES = ("d-optimal", "worst-direction", "default", "random", "easy_handeye")
PLANNERS = ("d-optimal", "worst-direction")
TARGET = (0.15, 0.015)  # RSS 1-sigma of T_flange_cam, mm and degrees
WITHIN = 12  # views: 95 % of placements should reach TARGET with at most this many planned views
TARGET_FRACTION = 0.95
MAX_VIEWS = 40  # planned and random views considered
ACHIEVED_COUNTS = (4, 6, 8, 12, 17)  # views calibrated for the achieved accuracy
RENDER_SCENARIOS = ("default", "realistic")


def nees_band(count: int, dof: int = 6) -> tuple[float, float]:
    """The 95 % band of the mean of count chi-square(dof) NEES values."""
    lo, hi = chi2.ppf([0.025, 0.975], dof * count)
    return float(lo / count), float(hi / count)


def _rms(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values else math.nan


def _accuracy(runs: list[dict]) -> dict:
    """RMS error and RMS predicted RSS 1-sigma (mm, deg) and the mean NEES of calibrations."""
    ok = [r for r in runs if "failed" not in r]
    nees = [r["nees"] for r in ok if r.get("nees") is not None]
    row = {
        "runs": len(runs),
        "failures": len(runs) - len(ok),
        "rms_error_mm": _rms([r["error_mm"] for r in ok]),
        "rms_error_deg": _rms([r["error_deg"] for r in ok]),
        "median_error_mm": float(np.median([r["error_mm"] for r in ok])) if ok else math.nan,
        "rms_sigma_mm": _rms([r["sigma_mm"] for r in ok if "sigma_mm" in r]),
        "rms_sigma_deg": _rms([r["sigma_deg"] for r in ok if "sigma_deg" in r]),
        "mean_nees": float(np.mean(nees)) if nees else math.nan,
        "nees_band": nees_band(len(nees)) if nees else None,
    }
    if ok and "predicted" in ok[0]:
        row["rms_predicted_mm"] = _rms([r["predicted"][0] for r in ok])
        row["rms_predicted_deg"] = _rms([r["predicted"][1] for r in ok])
    if ok and "frames" in ok[0]:
        row["median_frames"] = float(np.median([r["frames"] for r in ok]))
    return row


def summarise(placements: list[dict]) -> dict:
    """Per strategy the views to the target and the bounds; the planners' views to the default's
    final bound; the achieved and rendered accuracy."""
    summary: dict = {"placements": len(placements), "strategies": {}, "achieved": {}, "rendered": {}}
    default_views = np.array([p["strategies"]["default"]["views"] for p in placements], float)
    for name in STRATEGIES:
        rows = [p["strategies"][name] for p in placements]
        to_target = np.array([r["to_target"] for r in rows])
        finals = np.array([r["curve"][-1] if r["curve"] else (math.inf, math.inf) for r in rows])
        row = {
            "median_views": float(np.median([r["views"] for r in rows])),
            "median_to_target": float(np.median(to_target)),
            "p90_to_target": float(np.quantile(to_target, 0.9, method="higher")),
            "within": float(np.mean(to_target <= WITHIN)),
            "reached": float(np.mean(np.isfinite(to_target))),
            "median_final_mm": float(np.median(finals[:, 0])),
            "median_final_deg": float(np.median(finals[:, 1])),
        }
        if name in PLANNERS:
            to_default = np.array([r["to_default_final"] for r in rows])
            row["median_to_default_final"] = float(np.median(to_default))
            row["max_to_default_final"] = float(np.max(to_default))
            row["half_of_default"] = float(np.mean(to_default <= default_views / 2))
        summary["strategies"][name] = row
    for name in ("d-optimal", "default"):
        for k in ACHIEVED_COUNTS:
            runs = [p["achieved"][name][str(k)] for p in placements if str(k) in p["achieved"].get(name, {})]
            if runs:
                summary["achieved"].setdefault(name, {})[str(k)] = _accuracy(runs)
    for scenario_name in RENDER_SCENARIOS:
        for name in ("d-optimal", "default"):
            runs = [p["rendered"][scenario_name][name] for p in placements if p["rendered"]]
            if runs:
                summary["rendered"].setdefault(scenario_name, {})[name] = _accuracy(runs)
    return summary


def acceptance(summary: dict, timing: dict) -> list[tuple[str, bool]]:
    """The issue's acceptance lines, each (text, passed)."""
    planned, default = summary["strategies"]["d-optimal"], summary["strategies"]["default"]
    lines = [
        (
            f"d-optimal plans reach the default list's final bound with "
            f"{planned['median_to_default_final']:g} views (median; {100 * planned['half_of_default']:.0f} % "
            f"of placements within half the default's views) against its {default['median_views']:g}: "
            "goal at most half",
            planned["median_to_default_final"] <= default["median_views"] / 2,
        ),
        (
            f"{100 * planned['within']:.0f} % of placements reach {TARGET[0]:g} mm / {TARGET[1]:g} deg "
            f"within {WITHIN} planned views: goal {100 * TARGET_FRACTION:.0f} %",
            planned["within"] >= TARGET_FRACTION,
        ),
    ]
    measured = summary["achieved"].get("d-optimal", {}).get(str(WITHIN))
    rendered = [("measurements", measured)] + [
        (f"rendered {s}", summary["rendered"].get(s, {}).get("d-optimal")) for s in RENDER_SCENARIOS
    ]
    for where, row in rendered:
        if row is None or row["nees_band"] is None:
            continue
        lo, hi = row["nees_band"]
        lines.append(
            (
                f"{where}: {WITHIN} planned views, mean NEES {row['mean_nees']:.2f} (95 % band "
                f"{lo:.2f}-{hi:.2f} over {row['runs'] - row['failures']})",
                lo <= row["mean_nees"] <= hi,
            )
        )
    lines.append(
        (
            f"planning with {timing['candidates']} candidates {timing['plan_s']:.2f} s, "
            f"{timing['plan_s'] / timing['calibration_s']:.2f}x one {DEFAULT_METHOD} calibration of the "
            f"default 17 views ({timing['calibration_s']:.2f} s): goal under 2 s",
            timing["plan_s"] < 2.0,
        )
    )
    return lines


def _views_text(value: float) -> str:
    return "never" if not math.isfinite(value) else f"{value:g}"


def print_summary(summary: dict, timing: dict, corner_sigma_px: float) -> None:
    print(
        f"\n{summary['placements']} placements, corners at {corner_sigma_px:g} px; views to "
        f"{TARGET[0]:g} mm / {TARGET[1]:g} deg (RSS 1-sigma, predicted):"
    )
    print(
        f"{'strategy':16s} {'views':>6s} {'median':>7s} {'p90':>6s} {'within ' + str(WITHIN):>10s} "
        f"{'reached':>8s} {'final mm':>9s} {'final deg':>10s} {'to default':>11s}"
    )
    for name, row in summary["strategies"].items():
        to_default = f"{_views_text(row['median_to_default_final'])}" if name in PLANNERS else ""
        print(
            f"{name:16s} {row['median_views']:6g} {_views_text(row['median_to_target']):>7s} "
            f"{_views_text(row['p90_to_target']):>6s} {100 * row['within']:9.0f}% "
            f"{100 * row['reached']:7.0f}% {row['median_final_mm']:9.3f} {row['median_final_deg']:10.4f} "
            f"{to_default:>11s}"
        )
    print(
        f"\nachieved ({DEFAULT_METHOD}, synthetic measurements): views, RMS error / RMS predicted, mean NEES"
    )
    for name, counts in summary["achieved"].items():
        for k, row in counts.items():
            print(
                f"  {name:10s} {k:>3s}  {row['rms_error_mm']:.3f} / {row['rms_predicted_mm']:.3f} mm  "
                f"{row['rms_error_deg']:.4f} / {row['rms_predicted_deg']:.4f} deg  "
                f"NEES {row['mean_nees']:.2f}" + (f"  ({row['failures']} failed)" if row["failures"] else "")
            )
    for scenario_name, strategies in summary["rendered"].items():
        print(f"\nrendered, {scenario_name} scenario: frames, median / RMS error, RMS 1-sigma, mean NEES")
        for name, row in strategies.items():
            print(
                f"  {name:10s} {row.get('median_frames', math.nan):4g}  "
                f"{row['median_error_mm']:.3f} / "
                f"{row['rms_error_mm']:.3f} mm  {row['rms_error_deg']:.4f} deg  "
                f"sigma {row['rms_sigma_mm']:.3f} mm {row['rms_sigma_deg']:.4f} deg  "
                f"NEES {row['mean_nees']:.2f}" + (f"  ({row['failures']} failed)" if row["failures"] else "")
            )
    print()
    for text, passed in acceptance(summary, timing):
        print(f"{'PASS' if passed else 'FAIL'}  {text}")


def plot(placements: list[dict], summary: dict, path: Path) -> None:
    """Predicted RSS 1-sigma (median over the placements) against the views per strategy, the
    achieved RMS errors of the d-optimal plan and the default list, and the target."""
    from hec.estimator.common.files import write_atomic
    from hec.support.plotting import figure, legend_below, plain_log_axis, png_bytes

    fig, axes = figure(10.0, 4.2, 1, 2)
    colours = {
        "d-optimal": "C0",
        "worst-direction": "C2",
        "default": "C3",
        "random": "C7",
        "easy_handeye": "C1",
    }
    for column, (unit, scale) in enumerate((("mm", 1.0), ("deg", 1.0))):
        ax = axes[0][column]
        for name in STRATEGIES:
            curves = [p["strategies"][name]["curve"] for p in placements]
            length = max(len(c) for c in curves)
            padded = np.full((len(curves), length), np.nan)
            for i, c in enumerate(curves):
                padded[i, : len(c)] = [v[column] * scale for v in c]
                padded[i, len(c) :] = np.inf  # views a strategy did not have: not reached
            median = np.nanmedian(padded, axis=0)
            k = np.arange(1, length + 1)
            finite = np.isfinite(median)
            ax.plot(k[finite], median[finite], color=colours[name], label=f"{name}, predicted (median)")
        for name in ("d-optimal", "default"):
            rows = summary["achieved"].get(name, {})
            ks = [int(k) for k in rows]
            key = "rms_error_mm" if unit == "mm" else "rms_error_deg"
            ax.plot(
                ks, [rows[str(k)][key] for k in ks], "o", color=colours[name], label=f"{name}, achieved (RMS)"
            )
        ax.axhline(TARGET[column], color="k", linestyle=":", label="target")
        ax.axvline(WITHIN, color="0.6", linestyle="--", linewidth=0.8)
        plain_log_axis(ax)
        ax.set_xlabel("views")
        ax.set_ylabel(f"RSS 1-sigma of T_flange_cam ({unit})")
        ax.set_xlim(1, MAX_VIEWS)
    legend_below(fig, axes[0][0])
    write_atomic(path, png_bytes(fig))
