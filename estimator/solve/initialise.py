"""A starting point without a user prior: per-frame board poses (PnP) and closed-form hand-eye.

With F_i = T_base_flange_i and C_i = T_cam_board_i, every frame satisfies
F_i X C_i = T_base_board, so for a pair of frames A X = X B with
A = inv(F_i) F_j and B = C_i inv(C_j). Rotation: the rotation vectors satisfy
log(R_A) = R_X log(R_B) (solved by SVD over all pairs); translation:
(R_A - I) t_X = R_X t_B - t_A (least squares). Both need relative rotations about
at least two different axes; the translation is otherwise undetermined.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from hec.estimator.geometry.lie import so3_log
from hec.estimator.geometry.transforms import invert, make_transform, rotation_angle
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.problem import CalibrationInputError, CalibrationProblem, FrameMeasurements

# Pairs whose flange rotation differs by less than this carry no rotation information.
MIN_PAIR_ROTATION_RAD = np.radians(5.0)
# The rotation axes of the pairs must span a plane: second singular value / first.
MIN_AXIS_SPREAD = 0.1


def board_pose_pnp(problem: CalibrationProblem, frame: FrameMeasurements) -> np.ndarray:
    """T_cam_board (4, 4) of one frame from its corner pixels (SQPnP, then refined)."""
    object_points = np.concatenate([m.corners_board for m in frame.markers])
    image_points = np.concatenate([m.corners_px for m in frame.markers])
    k = problem.intrinsics
    dist = np.array(k.dist, dtype=np.float64)
    ok, rvec, tvec = cv2.solvePnP(object_points, image_points, k.K, dist, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise CalibrationInputError(
            f"frame {frame.frame}: the board pose could not be solved from its corners"
        )
    rvec, tvec = cv2.solvePnPRefineLM(object_points, image_points, k.K, dist, rvec, tvec)
    return make_transform(cv2.Rodrigues(rvec)[0], tvec.ravel())


@dataclass
class ClosedForm:
    """T_flange_cam (4, 4) and T_base_board (4, 4) from the first ``frames_used`` frames."""

    T_flange_cam: np.ndarray
    T_base_board: np.ndarray
    frames_used: int


def rotation_spread(T_base_flange: list[np.ndarray]) -> tuple[float, float]:
    """(largest relative rotation in radians, spread of the rotation axes 0..1) over all pairs.
    A spread near 0 means every relative rotation is about one axis."""
    axes, largest = [], 0.0
    for i in range(len(T_base_flange)):
        for j in range(i + 1, len(T_base_flange)):
            w = so3_log(T_base_flange[i][:3, :3].T @ T_base_flange[j][:3, :3])
            largest = max(largest, float(np.linalg.norm(w)))
            if np.linalg.norm(w) >= MIN_PAIR_ROTATION_RAD:
                axes.append(w / np.linalg.norm(w))
    if len(axes) < 2:
        return largest, 0.0
    s = np.linalg.svd(np.array(axes), compute_uv=False)
    return largest, float(s[1] / s[0])


def solve_hand_eye(T_base_flange: list[np.ndarray], T_cam_board: list[np.ndarray]) -> np.ndarray:
    """Closed-form T_flange_cam from matched flange and board poses (see the module doc)."""
    a_axes, b_axes, A_list, B_list = [], [], [], []
    for i in range(len(T_base_flange)):
        for j in range(i + 1, len(T_base_flange)):
            A = invert(T_base_flange[i]) @ T_base_flange[j]
            B = T_cam_board[i] @ invert(T_cam_board[j])
            if rotation_angle(A[:3, :3]) < MIN_PAIR_ROTATION_RAD:
                continue
            a_axes.append(so3_log(A[:3, :3]))
            b_axes.append(so3_log(B[:3, :3]))
            A_list.append(A)
            B_list.append(B)
    U, _, Vt = np.linalg.svd(np.array(a_axes).T @ np.array(b_axes))
    R_X = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    lhs = np.concatenate([A[:3, :3] - np.eye(3) for A in A_list])
    rhs = np.concatenate([R_X @ B[:3, 3] - A[:3, 3] for A, B in zip(A_list, B_list, strict=True)])
    t_X, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)
    return make_transform(R_X, t_X)


def mean_pose(poses: list[np.ndarray]) -> np.ndarray:
    """Chordal mean of rotations and arithmetic mean of translations of (4, 4) poses."""
    U, _, Vt = np.linalg.svd(sum(T[:3, :3] for T in poses))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return make_transform(R, np.mean([T[:3, 3] for T in poses], axis=0))


def closed_form(problem: CalibrationProblem) -> ClosedForm | None:
    """The closed-form solution from the fewest first frames whose rotations determine it,
    or None when even all frames rotate about fewer than two axes."""
    flange = [f.T_base_flange for f in problem.frames]
    for n in range(3, len(flange) + 1):
        if rotation_spread(flange[:n])[1] >= MIN_AXIS_SPREAD:
            break
    else:
        return None
    boards = [board_pose_pnp(problem, f) for f in problem.frames[:n]]
    X = solve_hand_eye(flange[:n], boards)
    return ClosedForm(X, mean_pose([F @ X @ C for F, C in zip(flange[:n], boards, strict=True)]), n)


def no_rotation_message(problem: CalibrationProblem) -> str:
    largest, spread = rotation_spread([f.T_base_flange for f in problem.frames])
    return (
        f"no rotation: the flange orientations differ by at most {np.degrees(largest):.1f} degrees"
        + (f" and about a single axis (axis spread {spread:.2f})" if largest >= MIN_PAIR_ROTATION_RAD else "")
        + "; the mount's translation cannot be determined. Add rotations of 15 degrees or more about "
        "at least two different axes, or give a prior to estimate from it"
    )


@dataclass
class Start:
    """Where an estimator starts: the state, where it came from, and how many first frames
    the closed form used (0 when it started from the prior)."""

    state: HandEyeState
    source: str
    frames_used: int


def initial_state(problem: CalibrationProblem, options: MethodOptions) -> Start:
    """Closed form when the first frames allow it, else the prior's mean (the board pose then
    from PnP); CalibrationInputError without either."""
    solution = closed_form(problem)
    if solution is not None:
        X, B, used = solution.T_flange_cam, solution.T_base_board, solution.frames_used
        source = f"closed form from the first {used} frames"
    elif options.prior is not None:
        X, used = options.prior.T_flange_cam, 0
        B = mean_pose([f.T_base_flange @ X @ board_pose_pnp(problem, f) for f in problem.frames])
        source = "prior (the frames do not determine a closed-form solution)"
    else:
        raise CalibrationInputError(no_rotation_message(problem))
    scale = 1.0 if options.estimate_depth_scale else None
    if options.map_model == "board":
        return Start(HandEyeState(X, T_base_board=B, depth_scale=scale), source, used)
    corners = np.concatenate([problem.board.marker_corners(i) for i in problem.marker_ids])
    landmarks = corners @ B[:3, :3].T + B[:3, 3]
    return Start(HandEyeState(X, landmarks_base=landmarks, depth_scale=scale), source, used)
