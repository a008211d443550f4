"""The short report of one calibration (`hec calibrate` without --verbose): the transform, the pick
error, one verdict line (good / usable / redo, with why) and at most MAX_FINDINGS findings, each a
cause and a fix. The full report is hec.calibration.report.format_calibration.

The verdict reads three things the calibration already computed:

- the fit: a residual no model explains (MISFIT_RESIDUAL_PX, or far above the data's noise:
  hec.estimator.solve.misfit), or a method that says its result does not fit, is "redo";
- the observability: a direction of the mount the views do not determine is "redo";
- the leave-one-frame-out prediction against its floor (what the held-out views' own noise alone
  gives): above REDO_RATIO x the floor "redo", above hec.calibration.loo.MISFIT_RATIO x "usable".

Any warning (a finding) makes a "good" result "usable".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hec.calibration.loo import LOO_KEY, MISFIT_RATIO
from hec.calibration.report import format_matrix, format_vector, ground_truth_errors, pick_dict, pose_numbers
from hec.estimator.common.setups import HAND_EYE_MEANINGS
from hec.estimator.solve.baselines import MISFIT_RESIDUAL_PX
from hec.estimator.solve.calibration import Calibration
from hec.estimator.solve.cross_validation import CrossValidation
from hec.estimator.solve.fit_check import SELF_CALIBRATED

# Held-out views predicted this many times worse than their own noise explains: redo the calibration.
REDO_RATIO = 3.0
MAX_FINDINGS = 3
GRADES = ("good", "usable", "redo")


@dataclass(frozen=True)
class Verdict:
    """grade: one of GRADES; reasons: why, in plain words, the deciding one first."""

    grade: str
    reasons: list[str]

    @property
    def line(self) -> str:
        return f"verdict: {self.grade}: " + "; ".join(self.reasons)


def verdict(cal: Calibration) -> Verdict:
    """The verdict of one calibration (module doc)."""
    redo, usable, good = [], [], []
    if "misfit" in cal.diagnostics:
        redo.append("the result does not fit its data (see the findings)")
    elif cal.residual_rms_px > MISFIT_RESIDUAL_PX:
        redo.append(f"the result does not fit the images ({cal.residual_rms_px:.0f} px RMS residual)")
    report = cal.diagnostics.get("observability")
    if report is not None and not report.observable:
        redo.append("these views do not determine every direction of the mount (see the findings)")
    elif report is not None:
        good.append("the views determine every direction of the mount")
    cv = cal.diagnostics.get(LOO_KEY)
    if isinstance(cv, CrossValidation) and cv.folds and cv.floor_mm > 0:
        ratio = cv.rms_mm / cv.floor_mm
        words = (
            f"new views are predicted to {cv.rms_mm:.2f} mm, {ratio:.1f}x what their own noise explains "
            f"({cv.floor_mm:.2f} mm)"
        )
        if ratio > REDO_RATIO:
            redo.append(words + ": a model error or frames that disagree")
        elif ratio > MISFIT_RATIO:
            usable.append(words)
        else:
            good.append(
                f"new views are predicted to {cv.rms_mm:.2f} mm, as well as their own noise allows "
                f"({cv.floor_mm:.2f} mm)"
            )
    else:
        usable.append("not cross-validated (no leave-one-frame-out figures)")
    if not redo and not usable and cal.warnings:
        usable.append("the findings below change what to trust")
    grade = "redo" if redo else "usable" if usable else "good"
    return Verdict(grade, redo or usable + good or good)


def findings(cal: Calibration) -> list[str]:
    """The calibration's warnings as findings: the self-calibration's split into one per cause."""
    out = []
    for warning in cal.warnings:
        if SELF_CALIBRATED in warning:
            out += warning.split(SELF_CALIBRATED, 1)[1].split("; ")
        else:
            out.append(warning)
    return out


def format_summary(cal: Calibration, T_true: np.ndarray | None = None) -> str:
    """The short report (module doc); with T_true (4, 4) the errors against it."""
    n = pose_numbers(cal.T_flange_cam)
    sigma_t = "" if cal.covariance is None else f" (1 sigma {format_vector(cal.sigma_translation_mm, '.3f')})"
    sigma_r = (
        "" if cal.covariance is None else f"; 1 sigma deg {format_vector(cal.sigma_rotation_deg, '.4f')}"
    )
    lines = [
        f"{cal.hand_eye_name} by {cal.method} ({HAND_EYE_MEANINGS[cal.setup]}):",
        f"  translation [mm] {format_vector(n['translation_mm'], '+.3f')}{sigma_t}",
        f"  rotation vector [rad] {format_vector(n['rotation_vector_rad'], '+.6f')} "
        f"(angle {n['rotation_angle_deg']:.4f} deg{sigma_r})",
    ]
    pick = pick_dict(cal, T_true)
    if pick is not None:
        lines.append(
            f"pick error at the working distance ({1e3 * pick['distance_m']:.0f} mm): "
            f"{pick['rms_mm']:.3f} mm RMS, 95 % within {pick['p95_mm']:.3f} mm"
        )
    lines.append(verdict(cal).line)
    found = findings(cal)
    lines += [f"  - {f}" for f in found[:MAX_FINDINGS]]
    if len(found) > MAX_FINDINGS:
        lines.append(f"  ({len(found) - MAX_FINDINGS} more findings with --verbose)")
    lines.append(format_matrix(cal.T_flange_cam))
    if T_true is not None:
        e = ground_truth_errors(cal, T_true)
        truth = "" if pick is None or pick["true_mm"] is None else f", at the pick {pick['true_mm']:.3f} mm"
        lines.append(
            f"vs ground truth: translation error {e['error_translation_mm']:.3f} mm, rotation error "
            f"{e['error_rotation_deg']:.4f} deg{truth}"
        )
    lines.append("the full report (residuals, noise, fit, folds): --verbose; every figure: --json")
    return "\n".join(lines)
