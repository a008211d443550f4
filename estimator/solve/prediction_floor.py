"""What a held-out view's own noise alone adds to its leave-one-frame-out prediction errors.

With an exact calibration the prediction of frame i still misses by (to first order):

- pixels: the corner noise (the corners' own covariance) and the reported flange pose's error
  (problem.robot_noise) moving the predicted corners, J_flange Sigma_robot J_flange^T;
- base frame: the flange pose's error moving the view's points, E|dp|^2 = 3 sigma_t^2 +
  2 sigma_r^2 |p_flange|^2 (translation per base axis, rotation about the flange axes,
  hec.estimator.geometry.lie), and the error of the view's PnP board pose from its corner pixels,
  Sigma_C = (J^T J)^-1 with J the whitened pixel Jacobian to the board pose.

These are the floors a perfect calibration would show; the calibration's own error adds to them
(in the mean of the squares). Depth is not used: the PnP pose and the pixels are pixels only.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from hec.estimator.geometry.lie import skew_rows
from hec.estimator.geometry.transforms import transform_points
from hec.estimator.solve.measurement_model import HandEyeState, predict_frame
from hec.estimator.solve.problem import CalibrationProblem, FrameMeasurements, MarkerMeasurement


def _pixel_information(m: MarkerMeasurement) -> np.ndarray:
    """(2C, 2C) information of the C point pixels (the pixel block of W^T W; the pixel and depth
    covariances are independent, so the block is the inverse of the pixel covariance)."""
    n = 2 * len(m.corners_px)
    return (m.whitening.T @ m.whitening)[:n, :n]


def view_noise_floor(
    problem: CalibrationProblem, frame: FrameMeasurements, T_flange_cam: np.ndarray, T_cam_board: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Expected squared errors per corner of the frame's markers, (P,) px^2 and (P,) m^2, of the
    leave-one-frame-out prediction at an exact calibration (module doc). T_flange_cam (4, 4): the
    calibration; T_cam_board (4, 4): the frame's PnP board pose; F = frame.T_base_flange."""
    info = [_pixel_information(m) for m in frame.markers]
    cov_px = [np.linalg.inv(i) for i in info]
    corner_px2 = np.concatenate(
        [[np.trace(c[2 * j : 2 * j + 2, 2 * j : 2 * j + 2]) for j in range(len(c) // 2)] for c in cov_px]
    )
    T_base_board = frame.T_base_flange @ T_flange_cam @ T_cam_board
    state = HandEyeState(T_flange_cam, T_base_board=T_base_board)

    # The flange pose error in pixels: unwhitened pixel rows (identity whitening).
    plain = replace(
        frame,
        markers=[replace(m, depth_m=None, whitening=np.eye(2 * len(m.corners_px))) for m in frame.markers],
    )
    J_flange = predict_frame(problem, state, plain).J_flange.reshape(-1, 2, 6)
    robot_cov = problem.robot_noise.covariance()
    robot_px2 = np.einsum("pij,jk,pik->p", J_flange, robot_cov, J_flange)

    # The PnP pose from the whitened pixels: its covariance, then the corners' spread.
    whitened = [
        replace(m, depth_m=None, whitening=np.linalg.cholesky(i).T)
        for m, i in zip(frame.markers, info, strict=True)
    ]
    J_board = predict_frame(problem, state, replace(frame, markers=whitened)).J_state[:, 6:12]
    cov_board = np.linalg.inv(J_board.T @ J_board)
    corners_board = np.concatenate([m.corners_board for m in frame.markers])
    J_point = np.concatenate(
        [
            np.broadcast_to(np.eye(3), (len(corners_board), 3, 3)),
            -T_base_board[:3, :3] @ skew_rows(corners_board),
        ],
        axis=2,
    )
    pnp_m2 = np.einsum("pij,jk,pik->p", J_point, cov_board, J_point)

    p_flange = transform_points(T_flange_cam @ T_cam_board, corners_board)
    n = problem.robot_noise
    robot_m2 = 3 * n.translation_sigma_m**2 + 2 * n.rotation_sigma_rad**2 * np.sum(p_flange**2, axis=1)
    return corner_px2 + robot_px2, robot_m2 + pnp_m2
