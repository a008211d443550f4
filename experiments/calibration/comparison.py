"""The comparison table of several methods' results (format_comparison), for `hec calibrate --method all`."""

from __future__ import annotations

import numpy as np

from hec.calibration.loo import LOO_DECLARED_KEY, loo_cells, loo_table_note
from hec.calibration.report import MethodFailure, Result, chi2_dof, format_vector, ground_truth_errors, rss
from hec.estimator.solve.calibration import Calibration
from hec.estimator.solve.method_names import DEFAULT_METHOD


def _cell(value: float | None, fmt: str, width: int) -> str:
    return f"{'-':>{width}}" if value is None else f"{value:>{width}{fmt}}"


def _comparison_row(r: Result, T_true: np.ndarray | None, earlier: dict[str, str], declared: bool) -> str:
    """One table row. earlier: failure reason -> first method that gave it (updated here); declared:
    with the declared model's loo columns."""
    if isinstance(r, MethodFailure):
        reason = r.error.removeprefix(f"{r.method}: ")
        first = earlier.setdefault(reason, r.method)
        return f"{r.method:<18} failed: " + (reason if first == r.method else f"as {first}")
    x, y, z = 1e3 * r.T_flange_cam[:3, 3]
    row = f"{r.method:<18} {x:>+9.3f} {y:>+9.3f} {z:>+9.3f}"
    row += f" {_cell(rss(r.sigma_translation_mm), '.4f', 10)} {_cell(rss(r.sigma_rotation_deg), '.5f', 11)}"
    row += f" {r.residual_rms_px:>9.3f} {_cell(chi2_dof(r), '.2f', 8)}"
    row += f" {r.observations_used:>4}/{r.observations_rejected:<4}"
    row += loo_cells(r) + (loo_cells(r, LOO_DECLARED_KEY) if declared else "")
    row += f" {1e3 * r.diagnostics.get('time_s', float('nan')):>9.1f}"
    if T_true is not None:
        e = ground_truth_errors(r, T_true)
        row += f" {e['error_translation_mm']:>9.3f} {e['error_rotation_deg']:>9.4f}"
    assumptions = r.diagnostics.get("assumptions")
    if assumptions is not None and not assumptions.holds:
        row += "  its assumptions fail here: biased, do not use (warning below)"
    return row


def format_comparison(results: list[Result], T_true: np.ndarray | None = None) -> str:
    """One row per method: translation, root-sum-square sigmas, residual, leave-one-frame-out figures,
    time, and errors with T_true."""
    declared = any(LOO_DECLARED_KEY in r.diagnostics for r in results if isinstance(r, Calibration))
    header = (
        f"{'method':<18} {'x [mm]':>9} {'y [mm]':>9} {'z [mm]':>9} {'sigma_t mm':>10} {'sigma_r deg':>11}"
    )
    header += (
        f" {'resid px':>9} {'chi2/dof':>8} {'used/rej':>9} {'loo px':>8} {'loo mm':>8}"
        + (f" {'dec px':>8} {'dec mm':>8}" if declared else "")
        + f" {'time ms':>9}"
        + (f" {'err mm':>9} {'err deg':>9}" if T_true is not None else "")
    )
    lines = [header]
    failures: dict[str, str] = {}
    lines += [_comparison_row(r, T_true, failures, declared) for r in results]
    lines.append(
        "sigma_t, sigma_r: root-sum-square of the 1-sigma values (translation along the flange axes, "
        "rotation about the camera axes), '-' = no uncertainty; resid: pixel RMS at the reported flange "
        "poses; chi2/dof: the measurements' chi-square per degree of freedom at the declared noise (1 = the "
        "model fits, '-' = not computed); used/rej: observations used and left out; time: the method's own "
        "(the noise learning the model-based methods share is not in it)"
    )
    return "\n".join(lines + _comparison_notes(results))


def _comparison_notes(results: list[Result]) -> list[str]:
    """The Cramer-Rao bound once, and each warning once with the methods that raised it."""
    done = [r for r in results if isinstance(r, Calibration)]
    lines = []
    # The bound at the default method's estimate (any good estimate gives nearly the same).
    shown = next((r for r in done if r.method == DEFAULT_METHOD), done[0] if done else None)
    report = None if shown is None else shown.diagnostics.get("observability")
    if report is not None and report.observable:
        lines.append(
            f"Cramer-Rao bound (1 sigma, at the {shown.method} estimate): translation [mm] "
            f"{format_vector(report.crb_sigma_translation_mm, '.4f')}; rotation [deg] "
            f"{format_vector(report.crb_sigma_rotation_deg, '.5f')}"
        )
    warnings: dict[str, list[str]] = {}
    for r in done:
        for w in r.warnings:
            warnings.setdefault(w, []).append(r.method)
    lines += [f"warning ({', '.join(methods)}): {w}" for w, methods in warnings.items()]
    note = loo_table_note(done)
    return ([note] if note else []) + lines
