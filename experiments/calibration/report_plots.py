"""The figures of one calibration's report (hec.calibration.html_report): residuals per frame and per
marker, leave-one-frame-out per frame, the camera's poses around the board, and each frame's image
with its detected and reprojected corners. Figures come back as PNG or JPEG bytes."""

from __future__ import annotations

import cv2
import numpy as np

from hec.calibration.loo import LOO_KEY
from hec.estimator.observe.frames import Dataset
from hec.estimator.solve.calibration import Calibration, calibration_state
from hec.estimator.solve.cross_validation import CrossValidation
from hec.estimator.solve.measurement_model import predict_frame
from hec.estimator.solve.methods import camera_problem
from hec.estimator.solve.problem import CalibrationProblem
from hec.support.plotting import figure, legend_below, png_bytes

OVERLAY_WIDTH_PX = 540  # the frames' pictures are shrunk to this width
RESIDUAL_SCALE = 20.0  # residuals are drawn this many times their length
MAX_LINE_PX = 200.0  # ... and at most this long, in the image's pixels
DETECTED_BGR = (40, 190, 40)
RESIDUAL_BGR = (30, 30, 230)
LEFT_OUT_BGR = (0, 140, 255)


def frame_residual_plot(cal: Calibration) -> bytes:
    """Per frame: the fit's RMS corner residual (px) of the markers used, the leave-one-frame-out
    prediction (px) and its floor when run, and, with depth, the depth residual (mm)."""
    frames = sorted({r.frame for r in cal.residuals})
    has_depth = any(r.depth_rms_mm is not None for r in cal.residuals)
    fig, axes = figure(7.5, 4.6 if has_depth else 2.8, rows=2 if has_depth else 1, sharex=True)
    ax = axes[0][0]
    x = np.arange(len(frames))
    fit = [_rms([r.rms_px for r in cal.residuals if r.frame == f and r.used]) for f in frames]
    ax.bar(x - 0.2, fit, 0.4, label="fit residual", color="#4a7ebb")
    cv = cal.diagnostics.get(LOO_KEY)
    if isinstance(cv, CrossValidation) and cv.folds:
        fold = {p.frame: p for p in cv.folds}
        ax.bar(x + 0.2, [fold[f].rms_px if f in fold else np.nan for f in frames], 0.4,
               label="predicted without the frame", color="#d9822b")  # fmt: skip
        floor = [fold[f].floor_px if f in fold and fold[f].floor_px is not None else np.nan for f in frames]
        ax.plot(x + 0.2, floor, "k_", markersize=12, label="what the frame's own noise gives")
    ax.set_ylabel("corner RMS [px]")
    legend_below(fig, ax)
    if has_depth:
        depth = [
            _rms(
                [
                    r.depth_rms_mm
                    for r in cal.residuals
                    if r.frame == f and r.used and r.depth_rms_mm is not None
                ]
            )
            for f in frames
        ]
        axes[1][0].bar(x, depth, 0.5, color="#6a9f58")
        axes[1][0].set_ylabel("depth RMS [mm]")
    left_out = [sum(1 for r in cal.residuals if r.frame == f and not r.used) for f in frames]
    labels = [f"{f}\n-{n}" if n else str(f) for f, n in zip(frames, left_out, strict=True)]
    axes[-1][0].set_xticks(x, labels, fontsize=7)
    axes[-1][0].set_xlabel("frame (under it: markers the method left out)")
    return png_bytes(fig)


def marker_residual_plot(cal: Calibration) -> bytes:
    """Frames x markers: each marker's RMS corner residual (px) in each frame; left out ones crossed."""
    frames = sorted({r.frame for r in cal.residuals})
    markers = sorted({r.marker_id for r in cal.residuals})
    grid = np.full((len(frames), len(markers)), np.nan)
    fig, axes = figure(7.5, 1.2 + 0.22 * len(frames))
    ax = axes[0][0]
    for r in cal.residuals:
        grid[frames.index(r.frame), markers.index(r.marker_id)] = r.rms_px
    shown = ax.imshow(grid, aspect="auto", cmap="viridis", interpolation="nearest")
    fig.colorbar(shown, ax=ax, label="corner RMS [px]")
    for r in cal.residuals:
        if not r.used:
            ax.plot(markers.index(r.marker_id), frames.index(r.frame), "rx", markersize=6)
    step = max(1, len(markers) // 24)
    ax.set_xticks(range(0, len(markers), step), [str(m) for m in markers[::step]], fontsize=7)
    ax.set_yticks(range(len(frames)), [str(f) for f in frames], fontsize=7)
    ax.set_xlabel("marker (x: left out by the method)")
    ax.set_ylabel("frame")
    return png_bytes(fig)


def poses_plot(problem: CalibrationProblem, cal: Calibration) -> bytes:
    """The board and, per frame, the camera (its centre and viewing direction) in the robot's base
    frame, from the reported flange poses and the calibrated mount; two views."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, 4.0), layout="constrained")
    cameras = [f.T_base_flange @ cal.T_flange_cam for f in problem.frames]
    centres = np.array([T[:3, 3] for T in cameras])
    board = _board_outline_base(problem, cal)
    reach = np.ptp(np.vstack([centres, board]), axis=0).max()
    for k, (elev, azim) in enumerate(((25, -60), (70, 20))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        ax.plot(*board.T, color="k")
        for T, f in zip(cameras, problem.frames, strict=True):
            tip = T[:3, 3] + 0.15 * reach * T[:3, 2]
            ax.plot(*np.column_stack([T[:3, 3], tip]), color="#d9822b")
            ax.text(*T[:3, 3], str(f.frame), fontsize=6)
        ax.scatter(*centres.T, s=8, color="#4a7ebb")
        ax.view_init(elev=elev, azim=azim)
        ax.set_xlabel("x [m]", fontsize=7)
        ax.set_ylabel("y [m]", fontsize=7)
        ax.set_zlabel("z [m]", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.set_box_aspect((1, 1, 1))
        _equal_limits(ax, np.vstack([centres, board]))
    return png_bytes(fig)


def frame_overlays(
    dataset: Dataset, problem: CalibrationProblem, cal: Calibration
) -> list[tuple[int, bytes]]:
    """(frame, JPEG bytes) per frame the method saw: its image with each detected corner (a green dot,
    orange for markers the method left out) and its residual to where the calibration predicts it,
    drawn RESIDUAL_SCALE times its length (a red line)."""
    adjusted = camera_problem(cal.method, problem, cal.diagnostics.get("noise"))
    state = calibration_state(adjusted, cal)
    left_out = {(r.frame, r.marker_id) for r in cal.residuals if not r.used}
    P = adjusted.points_per_marker
    out = []
    for frame in adjusted.frames:
        image = cv2.cvtColor(dataset.frame(frame.frame).rgb, cv2.COLOR_RGB2BGR)
        scale = OVERLAY_WIDTH_PX / image.shape[1]
        image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        predicted = predict_frame(adjusted, state, frame, jacobians=False).pixels
        for k, marker in enumerate(frame.markers):
            colour = LEFT_OUT_BGR if (frame.frame, marker.marker_id) in left_out else DETECTED_BGR
            for detected, there in zip(marker.corners_px, predicted[P * k : P * k + P], strict=True):
                tip = detected + np.clip(RESIDUAL_SCALE * (there - detected), -MAX_LINE_PX, MAX_LINE_PX)
                start, end = (tuple(int(round(c)) for c in scale * p) for p in (detected, tip))
                cv2.line(image, start, end, RESIDUAL_BGR, 1, cv2.LINE_AA)
                cv2.circle(image, start, 2, colour, -1, cv2.LINE_AA)
        _, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
        out.append((frame.frame, jpeg.tobytes()))
    return out


def _board_outline_base(problem: CalibrationProblem, cal: Calibration) -> np.ndarray:
    """(5, 3) the sheet's outline in the base frame (closed), or the landmarks' box seen from above."""
    if cal.T_base_board is None:
        points = np.concatenate(list(cal.landmarks_base.values()))
        (x0, y0, _), (x1, y1, _), z = points.min(axis=0), points.max(axis=0), points[:, 2].mean()
        return np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z], [x0, y0, z]])
    w, h = (s / 2 for s in problem.board.size_m)
    corners = np.array([[-w, -h, 0], [w, -h, 0], [w, h, 0], [-w, h, 0], [-w, -h, 0]])
    return corners @ cal.T_base_board[:3, :3].T + cal.T_base_board[:3, 3]


def _equal_limits(ax: object, points: np.ndarray) -> None:
    centre = (points.max(axis=0) + points.min(axis=0)) / 2
    half = np.ptp(points, axis=0).max() / 2 * 1.1
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)


def _rms(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values else np.nan
