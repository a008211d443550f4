"""Leave-one-frame-out (LOO) cross-validation: how well a calibration predicts a view it has not seen.

For each frame i the method calibrates the problem without frame i (a fold) and the fold predicts
frame i, at frame i's REPORTED flange pose F_i (the robot's own error is part of the prediction):

- pixels: the board corners c of frame i's markers, p_base = T_base_board c (board model) or the
  fold's landmarks (landmark model), projected through inv(F_i X) and problem.intrinsics
  (distortion included; hec.estimator.solve.measurement_model.predict_frame), against the measured
  corners. RMS of the pixel distance over the frame's corners.
- base frame, mm: frame i's own view of the board, its PnP pose C_i = T_cam_board_i
  (hec.estimator.solve.initialise.board_pose_pnp), mapped into the base frame, F_i X C_i c, against the
  fold's board (or landmarks) in the base frame. RMS of the 3D distance over the frame's corners:
  roughly the error of picking a point at the board's distance with this calibration.

X is the fold's T_flange_cam. Both figures include frame i's own noise (its corner noise, its
flange pose error, its PnP pose error): floor_px and floor_mm are what that noise alone gives
(hec.estimator.solve.prediction_floor), so a figure near its floor says the calibration predicts new
views as well as the measurements allow, and one well above it a model error or frames that
disagree. With the landmark model, markers the fold never saw are not predicted (corners counts
what was). The overall figures are RMS over every predicted corner of every
fold. Every method returns a board pose or landmarks (the OpenCV AX = XB baselines the chordal
mean of F_j X C_j over the fold's frames, i.e. j != i; shah and li OpenCV's own world pose); a
Calibration with neither gets that same mean here (board_source 'mean of the other frames').

A fold is skipped, with its reason, when it leaves fewer than MIN_FRAMES frames or the method
raises a ValueError (CalibrationInputError included) or LinAlgError. Cost: one calibration per
frame, N calibrations in all (time_s says how long).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from hec.estimator.geometry.transforms import transform_points
from hec.estimator.solve.calibration import Calibration
from hec.estimator.solve.initialise import board_pose_pnp, mean_pose
from hec.estimator.solve.measurement_model import HandEyeState, predict_frame
from hec.estimator.solve.prediction_floor import view_noise_floor
from hec.estimator.solve.problem import (
    MIN_FRAMES,
    CalibrationInputError,
    CalibrationProblem,
    FrameMeasurements,
)

Calibrate = Callable[[CalibrationProblem], Calibration]


@dataclass(frozen=True)
class FoldPrediction:
    """Frame ``frame`` predicted by the calibration without it. rms_px: corner pixel distance RMS;
    rms_mm: base-frame corner distance RMS, mm; floor_px, floor_mm: the RMS the frame's own noise
    alone would give (hec.estimator.solve.prediction_floor); the mm and floor figures are None when PnP
    fails on the frame. corners: the corners compared; time_s: the fold's calibration and prediction."""

    frame: int
    rms_px: float
    rms_mm: float | None
    floor_px: float | None
    floor_mm: float | None
    corners: int
    time_s: float


@dataclass(frozen=True)
class SkippedFold:
    """A frame whose fold did not run, and why."""

    frame: int
    reason: str


@dataclass
class CrossValidation:
    """The LOO figures of one method. folds: per predicted frame, in problem order. rms_px, rms_mm:
    RMS over all predicted corners (NaN without folds); floor_px, floor_mm: the same RMS that the
    held-out views' own noise alone would give. board_source: where the folds' board came from.
    time_s: all folds together. model: what the folds calibrated with, in words ("declared", or
    what was learned on all frames)."""

    folds: list[FoldPrediction]
    skipped: list[SkippedFold]
    rms_px: float
    rms_mm: float
    floor_px: float
    floor_mm: float
    board_source: str
    time_s: float
    model: str = "declared"

    @property
    def folds_run(self) -> int:
        return len(self.folds)

    def worst(self, count: int) -> list[FoldPrediction]:
        """The ``count`` folds with the largest rms_mm (rms_px where it is None), worst first."""
        return sorted(self.folds, key=lambda f: -(f.rms_px if f.rms_mm is None else f.rms_mm))[:count]

    def to_dict(self) -> dict:
        fields = ("frame", "rms_px", "rms_mm", "floor_px", "floor_mm", "corners", "time_s")
        return {
            "rms_px": self.rms_px,
            "rms_mm": self.rms_mm,
            "floor_px": self.floor_px,
            "floor_mm": self.floor_mm,
            "folds_run": self.folds_run,
            "folds_skipped": len(self.skipped),
            "skipped": [{"frame": s.frame, "reason": s.reason} for s in self.skipped],
            "frames": [{k: getattr(f, k) for k in fields} for f in self.folds],
            "board_source": self.board_source,
            "time_s": self.time_s,
            "model": self.model,
        }


def without_frame(problem: CalibrationProblem, index: int) -> CalibrationProblem:
    """A copy of the problem without problem.frames[index]; the other frames are the same objects,
    marker_ids those the remaining frames observe, everything else unchanged."""
    frames = problem.frames[:index] + problem.frames[index + 1 :]
    marker_ids = sorted({m.marker_id for f in frames for m in f.markers})
    return replace(problem, frames=frames, marker_ids=marker_ids)


def _fold_map(
    fold: CalibrationProblem, cal: Calibration
) -> tuple[dict[int, np.ndarray] | None, np.ndarray | None, str]:
    """(landmarks {marker_id: (C, 3)} or None, T_base_board (4, 4) or None, where it came from)."""
    if cal.landmarks_base is not None:
        return cal.landmarks_base, None, "landmarks"
    if cal.T_base_board is not None:
        return None, cal.T_base_board, "board pose"
    X = cal.T_flange_cam
    boards = [f.T_base_flange @ X @ board_pose_pnp(fold, f) for f in fold.frames]
    return None, mean_pose(boards), "mean of the other frames"


@dataclass(frozen=True)
class HeldOut:
    """One held-out frame's prediction, per corner of its markers (those the fold's map holds):
    d_px (P,) pixel distances, d_m (P,) base-frame distances in metres, and the expected squares
    of both from the frame's own noise alone, floor_px2 (P,) and floor_m2 (P,)
    (hec.estimator.solve.prediction_floor). The last three are None when PnP fails on the frame."""

    d_px: np.ndarray
    d_m: np.ndarray | None
    floor_px2: np.ndarray | None
    floor_m2: np.ndarray | None


def predict_held_out(
    problem: CalibrationProblem,
    frame: FrameMeasurements,
    T_flange_cam: np.ndarray,
    T_base_board: np.ndarray | None,
    landmarks: dict[int, np.ndarray] | None,
) -> HeldOut:
    """Predict a frame at its reported flange pose from a calibration: T_flange_cam (4, 4) and
    either T_base_board (4, 4) or landmarks {marker_id: (C, 3)}, base frame (module doc)."""
    if landmarks is not None:
        frame = replace(frame, markers=[m for m in frame.markers if m.marker_id in landmarks])
        if not frame.markers:
            raise CalibrationInputError("none of its markers is in the other frames")
        C = problem.points_per_marker
        rows = np.full((C * len(problem.marker_ids), 3), np.nan)
        for k, i in enumerate(problem.marker_ids):
            if i in landmarks:
                rows[C * k : C * k + C] = landmarks[i]
        state = HandEyeState(T_flange_cam, landmarks_base=rows)
        p_base = np.concatenate([landmarks[m.marker_id] for m in frame.markers])
    else:
        state = HandEyeState(T_flange_cam, T_base_board=T_base_board)
        p_base = transform_points(T_base_board, np.concatenate([m.corners_board for m in frame.markers]))
    pred = predict_frame(problem, state, frame, jacobians=False)
    d_px = np.linalg.norm(pred.pixels - np.concatenate([m.corners_px for m in frame.markers]), axis=1)
    try:
        T_cam_board = board_pose_pnp(problem, frame)
    except CalibrationInputError:
        return HeldOut(d_px, None, None, None)
    corners_board = np.concatenate([m.corners_board for m in frame.markers])
    seen_base = transform_points(frame.T_base_flange @ T_flange_cam @ T_cam_board, corners_board)
    floor_px2, floor_m2 = view_noise_floor(problem, frame, T_flange_cam, T_cam_board)
    return HeldOut(d_px, np.linalg.norm(seen_base - p_base, axis=1), floor_px2, floor_m2)


def _rms(values: list[np.ndarray], squared: bool = False) -> float:
    """RMS over the concatenated values (already squared when ``squared``); NaN when empty."""
    v = np.concatenate(values) if values else np.empty(0)
    return float(np.sqrt(np.mean(v if squared else np.square(v)))) if len(v) else float("nan")


def _fold_figures(frame: int, h: HeldOut, time_s: float) -> FoldPrediction:
    if h.d_m is None:
        return FoldPrediction(frame, _rms([h.d_px]), None, None, None, len(h.d_px), time_s)
    return FoldPrediction(
        frame,
        _rms([h.d_px]),
        1e3 * _rms([h.d_m]),
        _rms([h.floor_px2], squared=True),
        1e3 * _rms([h.floor_m2], squared=True),
        len(h.d_px),
        time_s,
    )


def leave_one_frame_out(
    problem: CalibrationProblem,
    calibrate: Calibrate,
    progress: Callable[[int, int], None] | None = None,
) -> CrossValidation:
    """Calibrate without each frame in turn and predict it (module doc). calibrate: one method on a
    problem. progress(done, total) is called after each fold."""
    start = time.perf_counter()
    folds: list[FoldPrediction] = []
    skipped: list[SkippedFold] = []
    held: list[HeldOut] = []
    sources: set[str] = set()
    for index, frame in enumerate(problem.frames):
        fold_start = time.perf_counter()
        fold = without_frame(problem, index)
        if len(fold.frames) < MIN_FRAMES:
            skipped.append(SkippedFold(frame.frame, f"{len(fold.frames)} frames left, need {MIN_FRAMES}"))
        else:
            try:
                cal = calibrate(fold)
                landmarks, board, source = _fold_map(fold, cal)
                h = predict_held_out(problem, frame, cal.T_flange_cam, board, landmarks)
            except (ValueError, np.linalg.LinAlgError) as exc:
                reason = (
                    str(exc) if isinstance(exc, CalibrationInputError) else f"{type(exc).__name__}: {exc}"
                )
                skipped.append(SkippedFold(frame.frame, reason))
            else:
                sources.add(source)
                held.append(h)
                folds.append(_fold_figures(frame.frame, h, time.perf_counter() - fold_start))
        if progress is not None:
            progress(index + 1, len(problem.frames))
    done = [h for h in held if h.d_m is not None]
    return CrossValidation(
        folds,
        skipped,
        _rms([h.d_px for h in held]),
        1e3 * _rms([h.d_m for h in done]),
        _rms([h.floor_px2 for h in done], squared=True),
        1e3 * _rms([h.floor_m2 for h in done], squared=True),
        ", ".join(sorted(sources)) or "-",
        time.perf_counter() - start,
    )
