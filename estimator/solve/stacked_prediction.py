"""Every frame of a problem predicted in one call: measurement_model.predict_frame's model and its
state and flange Jacobians, batched over the frames (the per-frame calls' overhead was most of the
batch objective's time)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse

from estimator.geometry.lie import SMALL_ANGLE, skew_rows
from estimator.solve.measurement_model import HandEyeState, predict_points
from estimator.solve.problem import CalibrationProblem


@dataclass(frozen=True)
class StackedFrames:
    """A problem's N frames stacked (K markers, P = 4 K points, R whitened rows, frames in order):
    points (P, 3) board corners or (P,) landmark rows (predict_points); frame_of_point (P,);
    T_base_flange (N, 4, 4) as reported; selected (r,) the measured entries of the per-marker
    layout (predict_points' predicted), measured (r,) their values; whitening (R, r) sparse, every
    frame's block-diagonally; frame_of_row (R,); pixel_row (R,) whether a row whitens pixels
    (else depths)."""

    points: np.ndarray
    frame_of_point: np.ndarray
    T_base_flange: np.ndarray
    selected: np.ndarray
    measured: np.ndarray
    whitening: sparse.csr_array
    frame_of_row: np.ndarray
    pixel_row: np.ndarray

    def scaled(self, pixel_scale: float, depth_scale: float) -> StackedFrames:
        """The stack with its pixel and depth rows' whitening divided by these scales (the same
        numbers noise_levels.scaled_problem's whitening holds)."""
        if pixel_scale == 1.0 and depth_scale == 1.0:
            return self
        row_scale = np.where(self.pixel_row, 1.0 / pixel_scale, 1.0 / depth_scale)
        return replace(self, whitening=sparse.diags_array(row_scale, format="csr") @ self.whitening)

    @property
    def frame_row_counts(self) -> np.ndarray:
        """(N,) whitened rows per frame."""
        return np.bincount(self.frame_of_row, minlength=len(self.T_base_flange))


def stacked_frames(problem: CalibrationProblem, board: bool) -> StackedFrames:
    """The problem's frames stacked; board: the points are board corners (else landmark rows)."""
    markers = [(i, m) for i, f in enumerate(problem.frames) for m in f.markers]
    if board:
        points = np.concatenate([m.corners_board for _, m in markers])
    else:
        points = np.concatenate([4 * problem.marker_index(m.marker_id) + np.arange(4) for _, m in markers])
    columns = [12 * k + np.arange(m.whitening.shape[1]) for k, (_, m) in enumerate(markers)]
    heights = [len(m.whitening) for _, m in markers]
    return StackedFrames(
        points,
        np.repeat([i for i, _ in markers], 4),
        np.array([f.T_base_flange for f in problem.frames]),
        np.concatenate(columns),
        np.concatenate([m.measured for _, m in markers]),
        sparse.csr_array(sparse.block_diag([m.whitening for _, m in markers])),
        np.repeat([i for i, _ in markers], heights),
        np.concatenate([np.arange(len(m.whitening)) < m.pixel_rows for _, m in markers]),
    )


@dataclass
class StackedPrediction:
    """Whitened residual W (measured - predicted) (R,) over all frames, and with jacobians the
    whitened prediction's derivatives with respect to the state perturbation J_state (R, n) and
    each row's own frame's flange pose perturbation J_flange (R, 6)."""

    residual: np.ndarray
    J_state: np.ndarray | None = None
    J_flange: np.ndarray | None = None


def predict_frames(
    problem: CalibrationProblem,
    stacked: StackedFrames,
    state: HandEyeState,
    deltas: np.ndarray | None,
    jacobians: bool,
) -> StackedPrediction:
    """predict_frame over every frame at once; deltas (N, 6): each frame's flange pose perturbation
    (None: the poses as reported)."""
    R_F, t_F = stacked.T_base_flange[:, :3, :3], stacked.T_base_flange[:, :3, 3]
    if deltas is not None:
        R_F, t_F = R_F @ exp_rows(deltas[:, 3:]), t_F + deltas[:, :3]
    frame = stacked.frame_of_point
    pred = predict_points(problem, state, stacked.points, R_F[frame], t_F[frame], jacobians)
    residual = stacked.whitening @ (stacked.measured - pred.predicted[stacked.selected])
    if not jacobians:
        return StackedPrediction(residual)
    return StackedPrediction(residual, _whitened(stacked, pred.J_state), _whitened(stacked, pred.J_flange))


def _whitened(stacked: StackedFrames, J_points: np.ndarray) -> np.ndarray:
    """(R, n) whitened rows of derivatives per point (P, 3, n) (measurement_model._whitened_rows
    over all frames)."""
    K, n = len(J_points) // 4, J_points.shape[-1]
    per_marker = np.concatenate([J_points[:, :2].reshape(K, 8, n), J_points[:, 2].reshape(K, 4, n)], axis=1)
    return stacked.whitening @ per_marker.reshape(12 * K, n)[stacked.selected]


def _rodrigues(w: np.ndarray, sine: np.ndarray, cosine: np.ndarray) -> np.ndarray:
    """(N, 3, 3) I + sine W + cosine W^2 for rotation vectors w (N, 3), coefficients (N,)."""
    W = skew_rows(w)
    return np.eye(3) + sine[:, None, None] * W + cosine[:, None, None] * (W @ W)


def exp_rows(w: np.ndarray) -> np.ndarray:
    """(N, 3, 3) lie.so3_exp of each rotation vector (N, 3)."""
    angle = np.linalg.norm(w, axis=1)
    small = angle < SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    sine = np.where(small, 1.0, np.sin(safe) / safe)
    cosine = np.where(small, 0.5, (1.0 - np.cos(safe)) / safe**2)
    return _rodrigues(w, sine, cosine)


def plus_jacobian_rows(delta: np.ndarray) -> np.ndarray:
    """(N, 6, 6) lie.pose_plus_jacobian of each perturbation (N, 6)."""
    w = delta[:, 3:]
    angle = np.linalg.norm(w, axis=1)
    small = angle < SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    sine = np.where(small, -0.5, -(1.0 - np.cos(safe)) / safe**2)
    cosine = np.where(small, 1.0 / 6.0, (safe - np.sin(safe)) / safe**3)
    J = np.broadcast_to(np.eye(6), (len(delta), 6, 6)).copy()
    J[:, 3:, 3:] = _rodrigues(w, sine, cosine)
    return J
