"""Leave-one-frame-out cross-validation in `hec calibrate` (hec.estimator.solve.cross_validation): run it for
a method's result, and its text, table and JSON forms.

LOO costs one calibration per frame. It runs for a method unless --no-loo, or its estimated cost
(frames x the time of the full run) exceeds the budget (BUDGET_S, --loo-all lifts it): batch on a
realistic dataset takes about 3 s a calibration, 50 s for 17 folds.

The figures live in Calibration.diagnostics[LOO_KEY]: a CrossValidation, or a string saying why it
was not run; without the key the report says nothing about it.
"""

from __future__ import annotations

import sys

import numpy as np
from tqdm import tqdm

from hec.estimator.observe.observations import FrameObservations
from hec.estimator.solve.calibration import Calibration, MethodOptions
from hec.estimator.solve.cross_validation import CrossValidation, leave_one_frame_out
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import METHODS, learned_setup
from hec.estimator.solve.problem import CalibrationProblem

LOO_KEY = "cross_validation"
NOT_RUN = "not run (--no-loo)"
# A method whose folds would take longer than this, seconds, is not cross-validated without --loo-all.
BUDGET_S = 30.0
WORST_SHOWN = 3
# Figures this many times their floor are more than the held-out views' own noise explains.
MISFIT_RATIO = 2.0
# A frame predicted this many times worse than the median frame (and above MISFIT_RATIO x its floor).
ODD_FRAME_RATIO = 3.0
# The table's note names the methods whose folds took at least this long, seconds.
SLOW_S = 1.0


def cross_validate(
    cal: Calibration,
    name: str,
    problem: CalibrationProblem,
    options: MethodOptions,
    observations: list[FrameObservations],
    quiet: bool = True,
) -> CrossValidation:
    """Leave-one-frame-out for method ``name`` (a METHODS key) with the options of the full run and,
    when it learned the noise, its learned levels, camera and outliers (the folds do not learn
    again); stored in cal.diagnostics[LOO_KEY] and returned. A progress bar per fold unless quiet."""
    learned = cal.diagnostics.get("noise")
    if learned is not None:
        _, problem, options = learned_setup(name, problem, options, learned)
    desc = f"leave-one-frame-out {name}"
    with tqdm(total=len(problem.frames), desc=desc, unit="fold", disable=quiet, file=sys.stderr) as bar:
        cv = leave_one_frame_out(
            problem,
            lambda fold: METHODS[name](fold, options, observations),
            progress=lambda done, total: bar.update(done - bar.n),
        )
    cal.diagnostics[LOO_KEY] = cv
    return cv


def add_cross_validation(
    cal: Calibration,
    name: str,
    problem: CalibrationProblem,
    options: MethodOptions,
    observations: list[FrameObservations],
    enabled: bool,
    budget_s: float | None,
    quiet: bool = True,
) -> None:
    """cross_validate when enabled and the folds' estimated cost (frames x the full run's time) fits
    in budget_s seconds (None: any), else cal.diagnostics[LOO_KEY] says why not."""
    time_s = float(cal.diagnostics.get("time_s", 0.0))
    estimate = len(problem.frames) * time_s
    if not enabled:
        cal.diagnostics[LOO_KEY] = NOT_RUN
    elif budget_s is None or estimate <= budget_s:
        cross_validate(cal, name, problem, options, observations, quiet)
    else:
        cal.diagnostics[LOO_KEY] = (
            f"not run: about {estimate:.0f} s ({len(problem.frames)} folds x {time_s:.1f} s), over the "
            f"{budget_s:.0f} s budget; --loo-all runs it"
        )


def _frame_text(f) -> str:
    mm = "" if f.rms_mm is None else f", {f.rms_mm:.2f} mm"
    return f"{f.frame} ({f.rms_px:.2f} px{mm})"


def format_loo(cal: Calibration) -> list[str]:
    """The report's lines on the LOO figures of a Calibration ([] when it has none)."""
    if LOO_KEY not in cal.diagnostics:
        return []
    cv: CrossValidation | str = cal.diagnostics[LOO_KEY]
    if isinstance(cv, str):
        return [f"leave-one-frame-out prediction: {cv}"]
    skipped = "; ".join(f"frame {s.frame}: {s.reason}" for s in cv.skipped)
    if not cv.folds:
        return [f"leave-one-frame-out prediction: no fold could calibrate ({skipped})"]
    lines = [
        f"leave-one-frame-out prediction: {cv.rms_px:.2f} px RMS, {cv.rms_mm:.2f} mm RMS in the base frame "
        f"({cv.folds_run} folds, {cv.time_s:.1f} s)",
        f"  a new view's own noise alone (corners, robot pose, its PnP pose) gives {cv.floor_px:.2f} px, "
        f"{cv.floor_mm:.2f} mm; worst frames: " + ", ".join(_frame_text(f) for f in cv.worst(WORST_SHOWN)),
    ]
    if cv.skipped:
        lines.append(f"  skipped folds ({len(cv.skipped)}): {skipped}")
    lines += [f"  note: {n}" for n in loo_notes(cv)]
    return lines


def loo_notes(cv: CrossValidation) -> list[str]:
    """Plain words when the figures are more than the views' noise explains."""
    mm = [f.rms_mm for f in cv.folds if f.rms_mm is not None]
    median = float(np.median(mm)) if mm else float("nan")
    odd = [
        f
        for f in cv.folds
        if f.rms_mm is not None
        and f.rms_mm > ODD_FRAME_RATIO * median
        and f.rms_mm > MISFIT_RATIO * (f.floor_mm or 0.0)
    ]
    notes = []
    if odd:
        notes.append(
            "frame(s) "
            + ", ".join(str(f.frame) for f in odd)
            + f" predicted more than {ODD_FRAME_RATIO:g}x worse than the median frame ({median:.2f} mm): "
            "their flange pose or detection disagrees with the other frames"
        )
    if cv.rms_mm > MISFIT_RATIO * cv.floor_mm or cv.rms_px > MISFIT_RATIO * cv.floor_px:
        notes.append(
            "new views are predicted worse than their noise explains: a model error (intrinsics, depth, "
            "board, arm kinematics), a robot less exact than its pose noise says, or frames that disagree"
        )
    return notes


def loo_cells(cal: Calibration) -> str:
    """The table's two columns, loo px and loo mm ('-' without figures)."""
    cv = cal.diagnostics.get(LOO_KEY)
    if not isinstance(cv, CrossValidation) or not cv.folds:
        return f" {'-':>8} {'-':>8}"
    return f" {cv.rms_px:>8.3f} {cv.rms_mm:>8.3f}"


def loo_table_note(results: list[Calibration]) -> str | None:
    """The table's note on its loo columns (None when no result says anything about LOO)."""
    if not any(LOO_KEY in r.diagnostics for r in results):
        return None
    figures = [r for r in results if isinstance(r.diagnostics.get(LOO_KEY), CrossValidation)]
    cvs = {r.method: r.diagnostics[LOO_KEY] for r in figures}
    reasons: dict[str, list[str]] = {}
    for r in results:
        if isinstance(r.diagnostics.get(LOO_KEY), str):
            reasons.setdefault(r.diagnostics[LOO_KEY], []).append(r.method)
    alone = len(reasons) == 1 and not cvs
    not_run = "; ".join(why if alone else f"{', '.join(m)}: {why}" for why, m in reasons.items())
    if not cvs:
        return f"loo px, loo mm: {not_run}"
    # The floor at the default method's folds (any good estimate gives nearly the same).
    shown = cvs.get(DEFAULT_METHOD) or next((cv for cv in cvs.values() if cv.folds), None)
    floor = (
        ""
        if shown is None or not shown.folds
        else f"; a new view's own noise alone: {shown.floor_px:.2f} px, {shown.floor_mm:.2f} mm"
    )
    slow = sorted(((cv.time_s, m) for m, cv in cvs.items() if cv.time_s >= SLOW_S), reverse=True)
    slow_text = f" ({', '.join(f'{m} {t:.1f} s' for t, m in slow)})" if slow else ""
    skipped = [f"{m} {len(cv.skipped)}" for m, cv in cvs.items() if cv.skipped]
    return (
        "loo px, loo mm: leave-one-frame-out prediction RMS, pixels at the reported flange pose and mm in "
        f"the base frame{floor}; {sum(cv.time_s for cv in cvs.values()):.1f} s for all folds{slow_text}"
        + (f"; folds skipped: {', '.join(skipped)}" if skipped else "")
        + (f"; {not_run}" if not_run else "")
    )


def loo_to_dict(cal: Calibration) -> dict:
    """The JSON keys: leave_one_frame_out (CrossValidation.to_dict, or None) and
    leave_one_frame_out_not_run (why not, or None)."""
    cv = cal.diagnostics.get(LOO_KEY)
    if isinstance(cv, CrossValidation):
        return {"leave_one_frame_out": cv.to_dict(), "leave_one_frame_out_not_run": None}
    return {"leave_one_frame_out": None, "leave_one_frame_out_not_run": cv}
