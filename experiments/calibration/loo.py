"""Leave-one-frame-out cross-validation in `hec calibrate` (hec.estimator.solve.cross_validation): run it for
a method's result, and its text, table and JSON forms.

One protocol for every method: the folds of every method calibrate with, and predict the held-out
frame in, the same model (LooModel), and the held-out frame is predicted on all its corners:

- the declared model (declared_model): the camera, board, depth and arm as the dataset declares
  them, at the declared noise levels; nothing is learned from the data.
- the self-calibrated model (self_calibrated_model): the noise levels, and the camera, board, depth
  and arm as the noise learning self-calibrated them, learned once on all frames, the held-out
  frame included (the figures say so); every method's folds use it, the OpenCV baselines' too.

A single method is cross-validated in the model it ran with (hec's methods the self-calibrated one,
the OpenCV baselines the declared one); `--method all` cross-validates every method in both, side by
side.

LOO costs one calibration per frame. It runs for a method unless --no-loo, or its estimated cost
(frames x the time of the full run) exceeds the budget (BUDGET_S, --loo-all lifts it).

The figures live in Calibration.diagnostics[LOO_KEY] (and [LOO_DECLARED_KEY] with --method all): a
CrossValidation, or a string saying why it was not run; without the key the report says nothing
about it.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace

import numpy as np
from tqdm import tqdm

from hec.estimator.observe.observations import FrameObservations
from hec.estimator.solve.calibration import Calibration, MethodOptions
from hec.estimator.solve.cross_validation import CrossValidation, leave_one_frame_out
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import METHODS
from hec.estimator.solve.noise_learning import LearnedNoise
from hec.estimator.solve.noise_levels import scaled_problem
from hec.estimator.solve.problem import CalibrationProblem

LOO_KEY = "cross_validation"
LOO_DECLARED_KEY = "cross_validation_declared"
DECLARED = "declared"
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


@dataclass(frozen=True)
class LooModel:
    """What every method's folds calibrate with and predict in. key: the diagnostics key its figures
    go to; problem: the model's problem (all frames, all corners); options: the methods' options in
    it (noise levels as the problem has them, nothing learned per fold); description: in words, what
    of it was learned on all frames ("declared" when nothing was)."""

    key: str
    problem: CalibrationProblem
    options: MethodOptions
    description: str


def declared_model(problem: CalibrationProblem, options: MethodOptions, key: str = LOO_KEY) -> LooModel:
    """The declared camera, board, depth, arm and noise levels (module doc)."""
    return LooModel(key, problem, replace(options, learn_noise=False), DECLARED)


def self_calibrated_model(
    problem: CalibrationProblem, options: MethodOptions, learned: LearnedNoise
) -> LooModel:
    """The noise levels and the self-calibrated camera, board, depth and arm learned on all frames
    (module doc); the held-out frames' outliers stay in, gated by each method's robust option."""
    parts = ["noise levels", *(g.replace("_", " ") for g in learned.groups_kept)]
    if learned.measured(problem) is not problem:
        parts.append("depths left out (they disagree with the pixels)")
    return LooModel(
        LOO_KEY,
        scaled_problem(learned.adjusted(problem), learned.learned),
        replace(options, learn_noise=False, robust=True),
        "self-calibrated on all frames, the held-out one included: " + ", ".join(parts),
    )


def cross_validate(
    cal: Calibration,
    name: str,
    model: LooModel,
    observations: list[FrameObservations],
    quiet: bool = True,
) -> CrossValidation:
    """Leave-one-frame-out for method ``name`` (a METHODS key) in ``model``; stored in
    cal.diagnostics[model.key] and returned. A progress bar per fold unless quiet."""
    desc = f"leave-one-frame-out {name}" + ("" if model.key == LOO_KEY else " (declared model)")
    with tqdm(total=len(model.problem.frames), desc=desc, unit="fold", disable=quiet, file=sys.stderr) as bar:
        cv = leave_one_frame_out(
            model.problem,
            lambda fold: METHODS[name](fold, model.options, observations),
            progress=lambda done, total: bar.update(done - bar.n),
        )
    cv.model = model.description
    cal.diagnostics[model.key] = cv
    return cv


def add_cross_validation(
    cal: Calibration,
    name: str,
    model: LooModel,
    observations: list[FrameObservations],
    enabled: bool,
    budget_s: float | None,
    quiet: bool = True,
) -> None:
    """cross_validate when enabled and the folds' estimated cost (frames x the full run's time) fits
    in budget_s seconds (None: any), else cal.diagnostics[model.key] says why not."""
    time_s = float(cal.diagnostics.get("time_s", 0.0))
    frames = len(model.problem.frames)
    estimate = frames * time_s
    if not enabled:
        cal.diagnostics[model.key] = NOT_RUN
    elif budget_s is None or estimate <= budget_s:
        cross_validate(cal, name, model, observations, quiet)
    else:
        cal.diagnostics[model.key] = (
            f"not run: about {estimate:.0f} s ({frames} folds x {time_s:.1f} s), over the "
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
        f"  the folds' model: {cv.model}",
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


def loo_cells(cal: Calibration, key: str = LOO_KEY) -> str:
    """The table's two columns of one model, loo px and loo mm ('-' without figures)."""
    cv = cal.diagnostics.get(key)
    if not isinstance(cv, CrossValidation) or not cv.folds:
        return f" {'-':>8} {'-':>8}"
    return f" {cv.rms_px:>8.3f} {cv.rms_mm:>8.3f}"


def loo_table_note(results: list[Calibration]) -> str | None:
    """The table's note on its loo columns (None when no result says anything about LOO)."""
    keys = [k for k in (LOO_KEY, LOO_DECLARED_KEY) if any(k in r.diagnostics for r in results)]
    if not keys:
        return None
    found = [r.diagnostics.get(k) for r in results for k in keys]
    cvs = [cv for cv in found if isinstance(cv, CrossValidation) and cv.folds]
    reasons = {why for why in found if isinstance(why, str)}
    if not cvs and len(reasons) == 1:
        return f"loo px, loo mm: {reasons.pop()}"
    parts = [_model_note(results, k) for k in keys]
    # The floor at the default method's folds (any good estimate gives nearly the same).
    default = next((r for r in results if r.method == DEFAULT_METHOD), None)
    shown = default.diagnostics.get(LOO_KEY) if default is not None else None
    shown = shown if isinstance(shown, CrossValidation) and shown.folds else (cvs[0] if cvs else None)
    floor = (
        ""
        if shown is None
        else f"; a new view's own noise alone: {shown.floor_px:.2f} px, {shown.floor_mm:.2f} mm"
    )
    time_s = sum(cv.time_s for cv in cvs)
    return (
        "loo, dec px and mm: leave-one-frame-out prediction RMS, pixels at the reported flange pose and mm "
        f"in the base frame, every method's folds in the same model{floor}; {time_s:.1f} s for all folds; "
        + "; ".join(parts)
    )


def _model_note(results: list[Calibration], key: str) -> str:
    """What one model's columns are, and which methods were not cross-validated in it and why."""
    cvs = {r.method: cv for r in results if isinstance(cv := r.diagnostics.get(key), CrossValidation)}
    reasons: dict[str, list[str]] = {}
    for r in results:
        if isinstance(r.diagnostics.get(key), str):
            reasons.setdefault(r.diagnostics[key], []).append(r.method)
    columns = "loo" if key == LOO_KEY else "dec"
    model = next(iter(cvs.values())).model if cvs else "not run"
    skipped = [f"{m} {len(cv.skipped)}" for m, cv in cvs.items() if cv.skipped]
    not_run = "; ".join(f"{', '.join(m)}: {why}" for why, m in reasons.items())
    return (
        f"{columns}: {model}"
        + (f" (folds skipped: {', '.join(skipped)})" if skipped else "")
        + (f" (not run for {not_run})" if not_run else "")
    )


def loo_to_dict(cal: Calibration) -> dict:
    """The JSON keys: leave_one_frame_out (CrossValidation.to_dict, or None) and
    leave_one_frame_out_not_run (why not, or None); with the declared model's figures too,
    leave_one_frame_out_declared (its to_dict, or why not)."""
    cv = cal.diagnostics.get(LOO_KEY)
    out = (
        {"leave_one_frame_out": cv.to_dict(), "leave_one_frame_out_not_run": None}
        if isinstance(cv, CrossValidation)
        else {"leave_one_frame_out": None, "leave_one_frame_out_not_run": cv}
    )
    if LOO_DECLARED_KEY in cal.diagnostics:
        declared = cal.diagnostics[LOO_DECLARED_KEY]
        out["leave_one_frame_out_declared"] = (
            declared.to_dict() if isinstance(declared, CrossValidation) else declared
        )
    return out
