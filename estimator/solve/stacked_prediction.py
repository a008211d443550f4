"""Every frame of a problem predicted in one call: measurement_model.predict_frame's model and its
state and flange Jacobians, batched over the frames (the per-frame calls' overhead was most of the
batch objective's time)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse

from hec.estimator.solve.measurement_model import (
    HandEyeState,
    PointPrediction,
    marker_points,
    predict_points,
    whitened_point_rows,
)
from hec.estimator.solve.problem import CalibrationProblem
from hec.estimator.solve.setup_roles import flange_plus_rows


@dataclass(frozen=True)
class StackedFrames:
    """A problem's N frames stacked (K markers of C points, P = C K points, R whitened rows, frames in order):
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
        W = self.whitening
        entries_per_row = np.diff(W.indptr)
        data = W.data * np.repeat(row_scale, entries_per_row)  # each entry times its row's scale
        return replace(self, whitening=sparse.csr_array((data, W.indices, W.indptr), shape=W.shape))

    @property
    def frame_row_counts(self) -> np.ndarray:
        """(N,) whitened rows per frame."""
        return np.bincount(self.frame_of_row, minlength=len(self.T_base_flange))


def stacked_frames(problem: CalibrationProblem, board: bool) -> StackedFrames:
    """The problem's frames stacked; board: the points are board corners (else landmark rows)."""
    markers = [(i, m) for i, f in enumerate(problem.frames) for m in f.markers]
    points = marker_points(problem, [m for _, m in markers], board)
    C = problem.points_per_marker
    columns = [3 * C * k + np.arange(m.whitening.shape[1]) for k, (_, m) in enumerate(markers)]
    heights = [len(m.whitening) for _, m in markers]
    return StackedFrames(
        points,
        np.repeat([i for i, _ in markers], C),
        np.array([f.T_base_flange for f in problem.frames]),
        np.concatenate(columns),
        np.concatenate([m.measured for _, m in markers]),
        _block_diagonal([m.whitening for _, m in markers]),
        np.repeat([i for i, _ in markers], heights),
        np.concatenate([np.arange(len(m.whitening)) < m.pixel_rows for _, m in markers]),
    )


# The last block-diagonal whitening built and the blocks it was built from (held, so that identity
# means the same arrays): a problem's self-calibrated variants share their markers' whitening.
_last_whitening: tuple[list[np.ndarray], sparse.csr_array] | None = None


def _block_diagonal(blocks: list[np.ndarray]) -> sparse.csr_array:
    """sparse.block_diag of the blocks as a CSR array, reused when the blocks are the very arrays of
    the last call (the noise learning stacks each adjusted problem's frames, some 250 times)."""
    global _last_whitening
    if _last_whitening is not None:
        last_blocks, last = _last_whitening
        if len(last_blocks) == len(blocks) and all(a is b for a, b in zip(last_blocks, blocks, strict=True)):
            return last
    whitening = sparse.csr_array(sparse.block_diag(blocks))
    _last_whitening = (list(blocks), whitening)
    return whitening


@dataclass
class StackedPrediction:
    """Whitened residual W (measured - predicted) (R,) over all frames, and with jacobians the
    whitened prediction's derivatives with respect to the state perturbation J_state (R, n) and
    each row's own frame's flange pose perturbation J_flange (R, 6), and the points' prediction."""

    residual: np.ndarray
    J_state: np.ndarray | None = None
    J_flange: np.ndarray | None = None
    points: PointPrediction | None = None


def predict_frames(
    problem: CalibrationProblem,
    stacked: StackedFrames,
    state: HandEyeState,
    deltas: np.ndarray | None,
    jacobians: bool,
    camera: bool = False,
) -> StackedPrediction:
    """predict_frame over every frame at once; deltas (N, 6): each frame's flange pose perturbation
    (None: the poses as reported). With jacobians, points holds the per-point prediction (with what
    measurement_model.camera_jacobian_rows needs when camera)."""
    R_F, t_F = stacked.T_base_flange[:, :3, :3], stacked.T_base_flange[:, :3, 3]
    if deltas is not None:
        R_F, t_F = flange_plus_rows(problem.setup, R_F, t_F, deltas)
    frame = stacked.frame_of_point
    pred = predict_points(problem, state, stacked.points, R_F[frame], t_F[frame], jacobians, camera)
    residual = stacked.whitening @ (stacked.measured - pred.predicted[stacked.selected])
    if not jacobians:
        return StackedPrediction(residual)
    return StackedPrediction(
        residual,
        whitened_point_rows(stacked.whitening, stacked.selected, pred.J_state, problem.points_per_marker),
        whitened_point_rows(stacked.whitening, stacked.selected, pred.J_flange, problem.points_per_marker),
        pred,
    )
