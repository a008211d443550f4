"""The hand-eye measurement model shared by ekf, iekf, ukf, batch and the Cramer-Rao bound.

A board corner c (board frame) seen in frame i:

    p_base = T_base_board @ c                 (board mode), or a landmark (landmark mode)
    p_cam  = inv(T_flange_cam) @ inv(pose_plus(T_base_flange_i, delta_i)) @ p_base
             (eye-to-hand the same with the roles swapped, hec.estimator.solve.setup_roles: the
             frame's pose is inv(pose_plus(reported, delta_i)), T_flange_cam is T_base_cam,
             T_base_board is T_flange_board)
    pixel  = project(p_cam) + b               (K and OpenCV distortion; b: where the detector's
                                               homography fit over the marker's distorted image
                                               puts its corners, hec.estimator.geometry.marker_fit_bias;
                                               QR boards only, whose corners come from that fit)
    depth  = exp(s) (depth_scale * p_cam.z + o + tx p_cam.x + ty p_cam.y)
             (s, o: problem.depth_bias, tx, ty: problem.depth_tilt, 0 unless self-calibrated)

State perturbations follow hec.estimator.geometry.lie: (dt, dtheta) for T_flange_cam and
T_base_board, (dx, dy, dz) for a landmark, d(scale) for the depth scale, in this
order in the state vector.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hec.estimator.common.setups import EYE_TO_HAND
from hec.estimator.geometry.camera import distort_normalized
from hec.estimator.geometry.lie import pose_minus, pose_plus, pose_plus_jacobian, skew_rows
from hec.estimator.geometry.marker_fit_bias import (
    MarkerFitBiasJacobians,
    marker_fit_bias,
    marker_fit_bias_jacobians,
)
from hec.estimator.solve.problem import CalibrationProblem, FrameMeasurements
from hec.estimator.solve.setup_roles import flange_plus, model_pose_jacobian


@dataclass(frozen=True)
class HandEyeState:
    """T_flange_cam (4, 4), and either T_base_board (4, 4) or landmarks_base (L, 3) (corner
    4k + c of problem.marker_ids[k], metres, base frame); depth_scale None = fixed at 1."""

    T_flange_cam: np.ndarray
    T_base_board: np.ndarray | None = None
    landmarks_base: np.ndarray | None = None
    depth_scale: float | None = None

    def __post_init__(self) -> None:
        if (self.T_base_board is None) == (self.landmarks_base is None):
            raise ValueError("a state holds exactly one of T_base_board and landmarks_base")

    @property
    def map_dim(self) -> int:
        return 6 if self.T_base_board is not None else self.landmarks_base.size

    @property
    def dim(self) -> int:
        return 6 + self.map_dim + (self.depth_scale is not None)

    def plus(self, delta: np.ndarray) -> HandEyeState:
        """The state moved by a perturbation (dim,)."""
        m = 6 + self.map_dim
        return HandEyeState(
            pose_plus(self.T_flange_cam, delta[:6]),
            None if self.T_base_board is None else pose_plus(self.T_base_board, delta[6:12]),
            None if self.landmarks_base is None else self.landmarks_base + delta[6:m].reshape(-1, 3),
            None if self.depth_scale is None else self.depth_scale + float(delta[m]),
        )

    def minus(self, reference: HandEyeState) -> np.ndarray:
        """The perturbation (dim,) with reference.plus(delta) == self."""
        parts = [pose_minus(self.T_flange_cam, reference.T_flange_cam)]
        if self.T_base_board is not None:
            parts.append(pose_minus(self.T_base_board, reference.T_base_board))
        else:
            parts.append((self.landmarks_base - reference.landmarks_base).reshape(-1))
        if self.depth_scale is not None:
            parts.append([self.depth_scale - reference.depth_scale])
        return np.concatenate(parts)

    def plus_jacobian(self, delta: np.ndarray) -> np.ndarray:
        """(dim, dim) d(local perturbation at self.plus(delta)) / d(delta)."""
        J = np.eye(self.dim)
        J[:6, :6] = pose_plus_jacobian(delta[:6])
        if self.T_base_board is not None:
            J[6:12, 6:12] = pose_plus_jacobian(delta[6:12])
        return J


@dataclass
class FramePrediction:
    """Whitened residual W (measured - predicted), (m,), and the Jacobians of the whitened
    prediction W h with respect to the state perturbation (m, dim) and the flange pose
    perturbation delta (m, 6). pixels: (P, 2) predicted corners; depth_m: (P,) predicted
    depth; points_cam: (P, 3), all in marker order. J_camera (m, 14), with camera_jacobian: with
    respect to fx, fy, cx, cy, k1, k2 (added to the distortion), the board's scale along its x
    and y, the depth bias's log scale and offset, the board's bend along x and y and the depth's
    tilt along x and y; J_marker_shift (m, 2), with it: with respect to a shift of each row's own
    marker along the board's x and y (board mode; zero with landmarks)
    (hec.estimator.solve.self_calibration.CAMERA_NUISANCE)."""

    residual: np.ndarray
    J_state: np.ndarray
    J_flange: np.ndarray
    pixels: np.ndarray
    depth_m: np.ndarray
    points_cam: np.ndarray
    J_camera: np.ndarray | None = None
    J_marker_shift: np.ndarray | None = None


def _projection(
    p_cam: np.ndarray, problem: CalibrationProblem
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(P, 3) camera points -> (P, 2) pixels, (P, 2, 3) d(pixel)/d(p_cam), and the undistorted and
    distorted normalised coordinates (P, 2) each."""
    k = problem.intrinsics
    z = p_cam[:, 2]
    xy = p_cam[:, :2] / z[:, None]
    d_xy = np.zeros((len(z), 2, 3))
    d_xy[:, 0, 0] = d_xy[:, 1, 1] = 1.0 / z
    d_xy[:, :, 2] = -xy / z[:, None]
    xy_d = xy
    if any(k.dist):
        xy_d, d_dist = distort_normalized(xy, k.dist)
        d_xy = d_dist @ d_xy
    f = np.array([k.fx, k.fy])
    return xy_d * f + np.array([k.cx, k.cy]), d_xy * f[None, :, None], xy, xy_d


def predict_frame(
    problem: CalibrationProblem,
    state: HandEyeState,
    frame: FrameMeasurements,
    delta_flange: np.ndarray | None = None,
    jacobians: bool = True,
    camera_jacobian: bool = False,
) -> FramePrediction:
    """Predict one frame's markers and compare with the measurements (see the module doc)."""
    T_base_flange = (
        frame.T_base_flange
        if delta_flange is None
        else flange_plus(problem.setup, frame.T_base_flange, delta_flange)
    )
    points = marker_points(problem, frame.markers, state.T_base_board is not None)
    R_F, t_F = T_base_flange[:3, :3], T_base_flange[:3, 3]
    pred = predict_points(problem, state, points, R_F, t_F, jacobians, camera_jacobian)
    stacked = frame.stacked
    residual = stacked.whitening @ (stacked.measured - pred.predicted[stacked.rows])
    if not jacobians:
        return FramePrediction(
            residual, np.empty((0, 0)), np.empty((0, 0)), pred.pixels, pred.depth, pred.p_cam
        )
    J_camera = J_shift = None
    if camera_jacobian:
        corners_board = np.concatenate([m.corners_board for m in frame.markers])
        J_camera, J_shift = camera_jacobian_rows(
            problem, state, corners_board, stacked.whitening, stacked.rows, pred
        )
    return FramePrediction(
        residual,
        whitened_point_rows(stacked.whitening, stacked.rows, pred.J_state, problem.points_per_marker),
        whitened_point_rows(stacked.whitening, stacked.rows, pred.J_flange, problem.points_per_marker),
        pred.pixels,
        pred.depth,
        pred.p_cam,
        J_camera,
        J_shift,
    )


@dataclass
class PointPrediction:
    """The prediction of P points (C per marker, problem.points_per_marker, the markers in order):
    predicted (3 C K,) per marker its 2C point pixels then its C depths; pixels (P, 2); depth (P,);
    p_cam (P, 3).
    With jacobians, d(u, v, depth)/d(the state's perturbation) J_state (P, 3, n) and /d(the flange
    pose's) J_flange (P, 3, 6), and what camera_jacobian_rows needs: the undistorted and distorted
    normalised coordinates xy, xy_d (P, 2), the corner bias's derivatives fit (with distortion or
    camera), d(u, v, depth)/d(p_cam) d_meas_d_cam (P, 3, 3) and d(p_cam)/d(p_base)
    d_cam_d_base ((3, 3) or (P, 3, 3))."""

    predicted: np.ndarray
    pixels: np.ndarray
    depth: np.ndarray
    p_cam: np.ndarray
    J_state: np.ndarray | None = None
    J_flange: np.ndarray | None = None
    xy: np.ndarray | None = None
    xy_d: np.ndarray | None = None
    fit: MarkerFitBiasJacobians | None = None
    d_meas_d_cam: np.ndarray | None = None
    d_cam_d_base: np.ndarray | None = None


def marker_points(problem: CalibrationProblem, markers: list, board: bool) -> np.ndarray:
    """predict_points' points of these markers (C each, in order): their points in the board frame
    (C K, 3) with board, else their landmark rows (C K,)."""
    if board:
        return np.concatenate([m.corners_board for m in markers])
    C = problem.points_per_marker
    return np.concatenate([C * problem.marker_index(m.marker_id) + np.arange(C) for m in markers])


def homography_fitted(problem: CalibrationProblem) -> bool:
    """Whether the corners come from one homography fit over each whole marker (the QR detector's),
    so that lens distortion biases them (hec.estimator.geometry.marker_fit_bias)."""
    return problem.board.corners_homography_fitted


def _rotated(v: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(P, 3) rows v times R: one (3, 3) for all, or (P, 3, 3) one per row."""
    return v @ R if R.ndim == 2 else np.einsum("pi,pij->pj", v, R)


def predict_points(
    problem: CalibrationProblem,
    state: HandEyeState,
    points: np.ndarray,
    R_F: np.ndarray,
    t_F: np.ndarray,
    jacobians: bool,
    camera: bool = False,
) -> PointPrediction:
    """Predict marker corners seen from flange poses (R_F (3, 3) or (P, 3, 3), t_F (3,) or
    (P, 3), base frame): points are the corners in the board frame (P, 3) (board mode) or the
    landmark rows (P,) (landmark mode), C per marker; camera: with the corner bias's derivatives
    for camera_jacobian_rows (QR boards)."""
    R_X, t_X = state.T_flange_cam[:3, :3], state.T_flange_cam[:3, 3]
    corners_board, rows, p_base = base_points(problem, state, points)
    p_flange = _rotated(p_base - t_F, R_F)
    p_cam = (p_flange - t_X) @ R_X
    scale = 1.0 if state.depth_scale is None else state.depth_scale
    predicted, pixels, depth, bias, (d_pix, xy, xy_d) = measurements(problem, p_cam, scale)
    if not jacobians:
        return PointPrediction(predicted, pixels, depth, p_cam)
    fitted = homography_fitted(problem)
    distorted = bias is not None
    gain = float(np.exp(problem.depth_bias[0]))
    tilt = problem.depth_tilt
    P = len(p_cam)
    fit = None
    if distorted or (camera and fitted):
        fit = marker_fit_bias_jacobians(p_cam.reshape(-1, 4, 3), problem.intrinsics, bias)
    d_bias_d_cam = None if bias is None else fit.d_corners_cam
    RXt = R_X.T
    RXt_RFt = RXt @ np.swapaxes(R_F, -1, -2)
    n = state.dim
    # d p_cam / d (perturbations), each (P, 3, k)
    d_cam_d_state = np.zeros((P, 3, n))
    d_cam_d_state[:, :, :6] = np.concatenate([np.broadcast_to(-RXt, (P, 3, 3)), skew_rows(p_cam)], axis=2)
    if corners_board is not None:
        d_base_d_B = np.concatenate(
            [np.broadcast_to(np.eye(3), (P, 3, 3)), -state.T_base_board[:3, :3] @ skew_rows(corners_board)],
            axis=2,
        )
        d_cam_d_state[:, :, 6:12] = RXt_RFt @ d_base_d_B
    else:
        columns = 6 + 3 * rows[:, None, None] + np.arange(3)
        d_cam_d_state[np.arange(P)[:, None, None], np.arange(3)[:, None], columns] = RXt_RFt
    d_cam_d_F = np.concatenate([np.broadcast_to(-RXt_RFt, (P, 3, 3)), RXt @ skew_rows(p_flange)], axis=2)
    if problem.setup == EYE_TO_HAND:  # the flange perturbation is the reported pose's (setup_roles)
        d_cam_d_F = d_cam_d_F @ model_pose_jacobian(R_F, t_F)
    # measurement rows per point: (u, v) then z, (P, 3, 3) d(u, v, depth)/d p_cam
    d_depth = gain * np.array([tilt[0], tilt[1], scale])
    d_meas_d_cam = np.concatenate([d_pix, np.broadcast_to(d_depth, (P, 1, 3))], axis=1)

    J_state = _through_camera_points(d_meas_d_cam, d_cam_d_state, d_bias_d_cam)
    if state.depth_scale is not None:
        J_state[:, 2, -1] = gain * p_cam[:, 2]
    J_flange = _through_camera_points(d_meas_d_cam, d_cam_d_F, d_bias_d_cam)
    return PointPrediction(
        predicted, pixels, depth, p_cam, J_state, J_flange, xy, xy_d, fit, d_meas_d_cam, RXt_RFt
    )


def base_points(
    problem: CalibrationProblem, state: HandEyeState, points: np.ndarray
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
    """predict_points' points in the base frame (P, 3), with the board's corners as bent (P, 3; board
    mode) or the landmark rows (P,; landmark mode), the other None."""
    if state.T_base_board is None:
        return None, points, state.landmarks_base[points]
    corners_board = points
    if problem.board_bend_m != (0.0, 0.0):
        corners_board = corners_board + np.outer(
            _bend_shapes(problem, corners_board) @ problem.board_bend_m, [0, 0, 1]
        )
    return corners_board, None, corners_board @ state.T_base_board[:3, :3].T + state.T_base_board[:3, 3]


def measurements(
    problem: CalibrationProblem, p_cam: np.ndarray, depth_scale: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """What the camera and the detector report for points p_cam (P, 3; C per marker, the markers in
    order) with a depth scale (a number, or one per point): the per-marker layout predicted (3 P,),
    pixels (P, 2) with the detector's corner bias, depths (P,), that bias (K, 2 C) or None, and
    _projection's d(pixel)/d(p_cam) and normalised coordinates."""
    pixels, d_pix, xy, xy_d = _projection(p_cam, problem)
    distorted = homography_fitted(problem) and any(problem.intrinsics.dist)
    bias = marker_fit_bias(p_cam.reshape(-1, 4, 3), problem.intrinsics) if distorted else None
    if bias is not None:
        pixels = pixels + bias.reshape(-1, 2)
    gain = float(np.exp(problem.depth_bias[0]))
    depth = gain * (depth_scale * p_cam[:, 2] + problem.depth_bias[1] + p_cam[:, :2] @ problem.depth_tilt)
    C = problem.points_per_marker
    predicted = np.concatenate([pixels.reshape(-1, 2 * C), depth.reshape(-1, C)], axis=1).reshape(-1)
    return predicted, pixels, depth, bias, (d_pix, xy, xy_d)


def _bend_shapes(problem: CalibrationProblem, corners_board: np.ndarray) -> np.ndarray:
    """(P, 2) the board bend's shapes 1 - u^2, 1 - v^2 at the corners (CalibrationProblem.board_bend_m)."""
    half = 0.5 * np.asarray(problem.board.size_m)
    return 1.0 - (corners_board[:, :2] / half) ** 2


def _through_camera_points(
    d_meas_d_cam: np.ndarray, d_cam: np.ndarray, d_bias_d_cam: np.ndarray | None
) -> np.ndarray:
    """(P, 3, n) d(u, v, depth per point)/d(x) from d(u, v, depth)/d p_cam (P, 3, 3) and d p_cam/d(x)
    (P, 3, n); d_bias_d_cam (M, 8, 12): the detector's corner bias moving with all four corners of
    its marker (hec.estimator.geometry.marker_fit_bias), None without distortion."""
    J = d_meas_d_cam @ d_cam
    if d_bias_d_cam is not None:
        P, _, n = d_cam.shape
        J[:, :2] += (d_bias_d_cam @ d_cam.reshape(-1, 12, n)).reshape(P, 2, n)
    return J


def camera_jacobian_rows(
    problem: CalibrationProblem,
    state: HandEyeState,
    corners_board: np.ndarray,
    whitening: np.ndarray,
    selected: np.ndarray,
    pred: PointPrediction,
) -> tuple[np.ndarray, np.ndarray]:
    """(m, 14) whitened d(prediction)/d(fx, fy, cx, cy, k1, k2, board scale x, board scale y,
    depth log scale, depth offset, board bend x, board bend y, depth tilt x, depth tilt y), and
    (m, 2) d(prediction)/d(a shift of the point's marker along the board's x and y), from the point
    prediction (predict_points with camera) of markers whose points are corners_board (P, 3), their
    measured entries selected and whitened by whitening (one frame's, or a stack's: whitened_point_rows)."""
    k = problem.intrinsics
    xy, xy_d, fit, depth, p_cam = pred.xy, pred.xy_d, pred.fit, pred.depth, pred.p_cam
    # the detector's corner bias moves with the corners only under distortion
    d_bias_d_cam = fit.d_corners_cam if fit is not None and any(k.dist) else None
    P = len(xy)
    J = np.zeros((P, 3, 16))  # per point: (u, v, depth) rows; the last two: the marker's shift
    f = np.array([k.fx, k.fy])
    J[:, 0, 0], J[:, 1, 1] = xy_d[:, 0], xy_d[:, 1]
    J[:, 0, 2] = J[:, 1, 3] = 1.0
    r2 = np.sum(xy * xy, axis=1)
    J[:, :2, 4] = xy * r2[:, None] * f
    J[:, :2, 5] = xy * (r2 * r2)[:, None] * f
    if fit is not None:
        J[:, :2, [0, 1, 4, 5]] += fit.d_camera.reshape(P, 2, 4)
    if state.T_base_board is not None:  # landmarks have no board to scale
        R_B = state.T_base_board[:3, :3]
        shapes = _bend_shapes(problem, corners_board)
        normal = R_B[:, 2]
        d_base = np.zeros((P, 3, 6))  # base-frame motion per unit of scale x, y, bend x, y, shift x, y
        for axis in (0, 1):
            # scaling moves the corners in the plane, and so along the bend (d shape / d log scale)
            d_bend = -2.0 * problem.board_bend_m[axis] * (1.0 - shapes[:, axis])
            d_base[:, :, axis] = R_B[:, axis] * corners_board[:, axis : axis + 1] + np.outer(d_bend, normal)
            d_base[:, :, 2 + axis] = np.outer(shapes[:, axis], normal)
            # a shift moves the corners in the plane, and so along the bend
            half = 0.5 * problem.board.size_m[axis]
            d_shift_bend = -2.0 * problem.board_bend_m[axis] * corners_board[:, axis] / half**2
            d_base[:, :, 4 + axis] = R_B[:, axis] + np.outer(d_shift_bend, normal)
        J[:, :, [6, 7, 10, 11, 14, 15]] = _through_camera_points(
            pred.d_meas_d_cam, pred.d_cam_d_base @ d_base, d_bias_d_cam
        )
    J[:, 2, 8] = depth
    J[:, 2, 9] = np.exp(problem.depth_bias[0])
    J[:, 2, 12:14] = np.exp(problem.depth_bias[0]) * p_cam[:, :2]
    whitened = whitened_point_rows(whitening, selected, J, problem.points_per_marker)
    return whitened[:, :14], whitened[:, 14:]


def whitened_point_rows(
    whitening: np.ndarray, selected: np.ndarray, J_points: np.ndarray, C: int
) -> np.ndarray:
    """(R, n) whitened measurement rows of derivatives per point (P, 3, n), (u, v, depth) of each
    marker's C points (problem.points_per_marker), the markers in order: the per-marker layout (2C
    pixels, C depths), its measured entries selected (r,), times whitening (R, r) (a frame's, or
    every frame's stacked)."""
    K, n = len(J_points) // C, J_points.shape[-1]
    per_marker = np.concatenate(
        [J_points[:, :2].reshape(K, 2 * C, n), J_points[:, 2].reshape(K, C, n)], axis=1
    )
    return whitening @ per_marker.reshape(3 * C * K, n)[selected]
