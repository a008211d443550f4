"""The OpenCV hand-eye baselines, run on the same corners as our estimators.

Each frame's board pose T_cam_board comes from its corner pixels
(hec.estimator.solve.initialise.board_pose_pnp); OpenCV then solves for the mount from these poses
and the reported flange poses T_base_flange.

- ``opencv-tsai|park|horaud|andreff|daniilidis``: ``cv2.calibrateHandEye`` (AX = XB). In OpenCV's names
  gripper2base = T_base_flange, target2cam = T_cam_board, and the result cam2gripper = T_flange_cam.
  The board pose is then the mean over frames of T_base_flange @ T_flange_cam @ T_cam_board.
- ``opencv-shah|li``: ``cv2.calibrateRobotWorldHandEye`` (AX = ZB), with the board as OpenCV's world:
  world2cam = T_cam_board, base2gripper = T_flange_base; it returns base2world = T_board_base and
  gripper2cam = T_cam_flange, which are inverted to T_base_board and T_flange_cam.

OpenCV gives no uncertainty (covariance None) and uses only the pixels (no depth, no robot noise model).

andreff and li solve for the nine rotation entries and the translation together; only the translations fix
the rotation's scale. When every view looks at one point from one distance (an orbit of the board centre;
the default trajectory alternates two distances for this reason among others), every motion is a rotation
about that point and the scale is lost: OpenCV then fails (CalibrationInputError here) or, less often,
returns a translation tens of centimetres off.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from hec.estimator.geometry.transforms import invert, make_transform
from hec.estimator.solve.calibration import Calibration, MethodOptions, marker_residuals
from hec.estimator.solve.initialise import (
    MIN_AXIS_SPREAD,
    board_pose_pnp,
    mean_pose,
    no_rotation_message,
    rotation_spread,
)
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.problem import CalibrationInputError, CalibrationProblem

OPENCV_METHODS: dict[str, int] = {
    "opencv-tsai": cv2.CALIB_HAND_EYE_TSAI,
    "opencv-park": cv2.CALIB_HAND_EYE_PARK,
    "opencv-horaud": cv2.CALIB_HAND_EYE_HORAUD,
    "opencv-andreff": cv2.CALIB_HAND_EYE_ANDREFF,
    "opencv-daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
    "opencv-shah": cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH,
    "opencv-li": cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI,
}
ROBOT_WORLD_METHODS = ("opencv-shah", "opencv-li")
# Methods that solve rotation and translation in one linear system (see the module doc).
JOINT_LINEAR_METHODS = ("opencv-andreff", "opencv-li")
# A result whose reprojection residual exceeds this is not a solution (a good one is < 1 px).
MISFIT_RESIDUAL_PX = 20.0


def opencv_calibrate(problem: CalibrationProblem, options: MethodOptions, method: str) -> Calibration:
    """T_flange_cam (4, 4) and T_base_board (4, 4) with one of the OPENCV_METHODS.

    options: taken for the interface every method shares; OpenCV uses neither a prior nor a map model,
    so it is ignored. Raises ValueError for an unknown method, CalibrationInputError when the flange
    rotations do not span two axes (OpenCV would return an arbitrary answer) or OpenCV finds no solution.
    """
    if method not in OPENCV_METHODS:
        raise ValueError(f"unknown OpenCV method {method!r}; valid: {', '.join(OPENCV_METHODS)}")
    T_base_flange = [f.T_base_flange for f in problem.frames]
    if rotation_spread(T_base_flange)[1] < MIN_AXIS_SPREAD:
        raise CalibrationInputError(no_rotation_message(problem))
    start = time.perf_counter()
    T_cam_board = [board_pose_pnp(problem, f) for f in problem.frames]
    R_cam_board, t_cam_board = _split(T_cam_board)
    try:
        if method in ROBOT_WORLD_METHODS:
            R_flange_base, t_flange_base = _split([invert(F) for F in T_base_flange])
            R_board_base, t_board_base, R_cam_flange, t_cam_flange = cv2.calibrateRobotWorldHandEye(
                R_cam_board, t_cam_board, R_flange_base, t_flange_base, method=OPENCV_METHODS[method]
            )
            X = invert(make_transform(R_cam_flange, t_cam_flange.ravel()))
            B = invert(make_transform(R_board_base, t_board_base.ravel()))
        else:
            R_base_flange, t_base_flange = _split(T_base_flange)
            R_flange_cam, t_flange_cam = cv2.calibrateHandEye(
                R_base_flange, t_base_flange, R_cam_board, t_cam_board, method=OPENCV_METHODS[method]
            )
            X = make_transform(R_flange_cam, t_flange_cam.ravel())
            if not np.linalg.det(X[:3, :3]) > 0.0:  # NaN or a reflection: the poses fit no mount
                raise CalibrationInputError(
                    f"{method}: OpenCV found no solution (its rotation is not a rotation: do the robot "
                    "poses fit the camera's views at all?)"
                )
            B = mean_pose([F @ X @ C for F, C in zip(T_base_flange, T_cam_board, strict=True)])
    except cv2.error as e:
        hint = (
            "; it cannot fix the rotation's scale when every view looks at one point from one distance: "
            "vary the distance to the board or use another method"
            if method in JOINT_LINEAR_METHODS
            else ""
        )
        raise CalibrationInputError(f"{method}: OpenCV found no solution ({e.err}){hint}") from None
    elapsed = time.perf_counter() - start
    result = Calibration(
        method=method,
        T_flange_cam=X,
        covariance=None,
        T_base_board=B,
        landmarks_base=None,
        residuals=marker_residuals(problem, HandEyeState(X, T_base_board=B)),
        observations_used=problem.observation_count,
        observations_rejected=0,
        diagnostics={"iterations": 0, "time_s": elapsed, "pnp_frames": len(T_cam_board)},
    )
    return result


def _split(poses: list[np.ndarray]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(4, 4) poses -> lists of (3, 3) rotations and (3, 1) translations, as OpenCV takes them."""
    return [T[:3, :3].copy() for T in poses], [T[:3, 3:4].copy() for T in poses]
