"""Observations graded against simulated ground truth: detection rate, errors and normalised errors.

The true camera pose of frame i is T_base_cam = T_base_flange_true[i] @ T_flange_cam,
so the true board in the camera is T_cam_board = T_base_cam^-1 @ T_base_board. The true
marker corners are the printed ones seen through the true camera (lens included) when the
truth records model errors (hec.sim.model_errors), else the definition's through the dataset's.
Normalised errors are e^T C^-1 e / dim, whose mean is 1 when the covariances C are
honest.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hec.estimator.geometry.camera import CameraIntrinsics, project
from hec.estimator.geometry.transforms import invert, transform_points
from hec.estimator.observe.frames import GroundTruth
from hec.estimator.observe.observations import FrameObservations
from hec.estimator.targets.target import Target

# A detection this far (pixels, any corner) from its marker's true corners has the wrong ID.
WRONG_ID_PX = 5.0


@dataclass
class MeasurementErrors:
    """Pooled over frames. Arrays have one row per graded marker (points: centre, points 0..P-1)."""

    visible: int = 0
    found_visible: int = 0
    wrong_id: int = 0
    corner_errors_px: list[np.ndarray] = field(default_factory=list)  # (P, 2) each
    raw_corner_errors_px: list[np.ndarray] = field(default_factory=list)  # (P, 2) each
    corner_nees: list[float] = field(default_factory=list)  # per corner, dim 2
    center_errors_px: list[np.ndarray] = field(default_factory=list)  # (2,) each
    center_px_nees: list[float] = field(default_factory=list)
    point_errors_m: list[np.ndarray] = field(default_factory=list)  # (5, 3) each
    point_nees: list[np.ndarray] = field(default_factory=list)  # (5,) each, dim 3

    @property
    def detection_rate(self) -> float:
        return self.found_visible / self.visible if self.visible else float("nan")

    @staticmethod
    def _rms(errors: list[np.ndarray]) -> float:
        if not errors:
            return float("nan")
        e = np.concatenate([np.reshape(x, (-1, 2)) for x in errors])
        return float(np.sqrt(np.mean(np.sum(e * e, axis=1))))

    @property
    def corner_rms_px(self) -> float:
        """RMS of the corners' 2D pixel error."""
        return self._rms(self.corner_errors_px)

    @property
    def raw_corner_rms_px(self) -> float:
        """The same for the decoders' corners before refinement."""
        return self._rms(self.raw_corner_errors_px)

    def summary(self) -> dict:
        points = np.array(self.point_errors_m) if self.point_errors_m else np.zeros((0, 5, 3))
        nees = np.array(self.point_nees) if self.point_nees else np.zeros((0, 5))
        return {
            "visible_markers": self.visible,
            "detected_visible": self.found_visible,
            "detection_rate": self.detection_rate,
            "wrong_id": self.wrong_id,
            "corner_rms_px": self.corner_rms_px,
            "raw_corner_rms_px": self.raw_corner_rms_px,
            "corner_nees": float(np.mean(self.corner_nees)) if self.corner_nees else float("nan"),
            "center_px_nees": float(np.mean(self.center_px_nees)) if self.center_px_nees else float("nan"),
            "center_rms_mm": 1000.0 * float(np.sqrt(np.mean(np.sum(points[:, 0] ** 2, axis=1))))
            if len(points)
            else float("nan"),
            "center_point_nees": float(np.mean(nees[:, 0])) if len(nees) else float("nan"),
            "point_nees": float(np.mean(nees)) if len(nees) else float("nan"),
        }


def true_T_cam_board(truth: GroundTruth, frame: int) -> np.ndarray:
    """(4, 4) the board in the true camera frame of one frame."""
    return truth.T_cam_board(frame)


def true_cell(
    truth: GroundTruth, board: Target, intrinsics: CameraIntrinsics
) -> tuple[CameraIntrinsics, np.ndarray]:
    """The camera that formed the images and the (M, P, 3) points of the board's markers as
    printed (board frame, metres, ordered by board.marker_ids): the truth's model errors where
    it records them, else the dataset's intrinsics and the board definition."""
    errors = truth.model_errors or {}
    camera = CameraIntrinsics.from_dict(errors["intrinsics"]) if "intrinsics" in errors else intrinsics
    corners = np.array(errors["board"]["true_corners_m"]) if "board" in errors else board.all_corners()
    return camera, corners


def _in_image(
    T_cam_board: np.ndarray, points_board: np.ndarray, margin_m: float, camera: CameraIntrinsics
) -> bool:
    """Whether the squares of half-side margin_m (board frame) about the points (P, 3) lie
    inside the image, in front of the camera: the marker and its margin are fully visible."""
    offsets = margin_m * np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    grown = (points_board[:, None, :] + offsets[None]).reshape(-1, 3)
    if np.any(transform_points(T_cam_board, grown)[:, 2] <= 0.0):
        return False
    uv = project(T_cam_board, grown, camera)
    return bool(
        np.all(uv >= 0.0) and np.all(uv[:, 0] <= camera.width - 1) and np.all(uv[:, 1] <= camera.height - 1)
    )


def grade_observations(
    observations: list[FrameObservations],
    truth: GroundTruth,
    board: Target,
    intrinsics: CameraIntrinsics,
) -> MeasurementErrors:
    """Compare every frame's observations with the truth (true_cell). A marker's true centre
    is the mean of its true corners (off its bent sheet by a few hundredths of a millimetre)."""
    errors = MeasurementErrors()
    camera, corners_board = true_cell(truth, board, intrinsics)
    for obs in observations:
        T_cam_board = true_T_cam_board(truth, obs.frame)
        for marker_id, corners in zip(board.marker_ids, corners_board, strict=True):
            points_board = np.vstack([corners.mean(axis=0), corners])
            true_points = transform_points(T_cam_board, points_board)
            true_center, true_corners = np.split(project(T_cam_board, points_board, camera), [1])
            facing = (invert(T_cam_board) @ np.array([0.0, 0.0, 0.0, 1.0]))[2] > 0.0
            visible = facing and _in_image(T_cam_board, corners, board.visible_margin_m, camera)
            errors.visible += int(visible)
            marker = obs.marker(marker_id)
            if marker is None:
                continue
            corner_error = marker.corners_px - true_corners
            if np.abs(corner_error).max() > WRONG_ID_PX:
                errors.wrong_id += 1
                continue
            errors.found_visible += int(visible)
            errors.corner_errors_px.append(corner_error)
            errors.raw_corner_errors_px.append(marker.raw_corners_px - true_corners)
            for k in range(len(corner_error)):
                cov = marker.corners_cov[2 * k : 2 * k + 2, 2 * k : 2 * k + 2]
                errors.corner_nees.append(
                    float(corner_error[k] @ np.linalg.solve(cov, corner_error[k])) / 2.0
                )
            e = marker.center_px - true_center[0]
            errors.center_errors_px.append(e)
            errors.center_px_nees.append(float(e @ np.linalg.solve(marker.center_cov, e)) / 2.0)
            if marker.points_cam is None:
                continue
            d = marker.points_cam - true_points
            errors.point_errors_m.append(d)
            errors.point_nees.append(
                np.einsum("ki,ki->k", d, np.linalg.solve(marker.points_cov, d[:, :, None])[:, :, 0]) / 3.0
            )
    return errors
