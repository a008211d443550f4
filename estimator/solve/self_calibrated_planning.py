"""View planning for a cell that self-calibrates: a candidate view's information on the whole state
the default method estimates there, the mount's part of it after the rest is marginalised.

On a cell whose camera, board, depth or arm is off its declared model, the default method estimates
the self-calibration groups (hec.estimator.solve.self_calibration.NUISANCE_GROUPS: intrinsics,
lens, print scale and sag, marker shifts, depth bias and tilt, the arm's kinematics) beside the mount
and the board pose. A view that pins the mount down when the camera and board are exact may add
little once they are free: views at one distance cannot tell a print scale from the mount's
distance along the optical axis. Here a candidate's information covers [mount (6), board pose (6),
theta (p)], theta the groups' corrections (group_names' order) with the flange pose noise
marginalised as in hec.estimator.solve.observability.frame_information, and theta's Gaussian priors
(self_calibration.prior_sigma, the declared ones) are a separate (12 + p, 12 + p) information.
hec.estimator.solve.view_planning.plan_views, given that prior, selects on the mount's information
with the board pose and theta eliminated (Schur complement).

The kinematic columns are the flange pose's Jacobian times the arm's (kinematic_jacobian, at the
joints the nominal arm reaches each candidate with: the closed-form solution nearest seed_joints);
a candidate the arm cannot reach is not usable.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hec.estimator.common.setups import EYE_IN_HAND
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.kinematics import IK_RESTARTS, URKinematics, solve_ik_nearest
from hec.estimator.geometry.waypoints import Waypoint
from hec.estimator.observe.synthetic import SyntheticNoise
from hec.estimator.solve.measurement_model import HandEyeState, predict_frame
from hec.estimator.solve.observability import flange_marginalised_information
from hec.estimator.solve.problem import CalibrationProblem, build_problem
from hec.estimator.solve.self_calibration import (
    CAMERA_NUISANCE,
    KINEMATIC_NUISANCE,
    MARKER_SHIFTS,
    NUISANCE_GROUPS,
    group_names,
    kinematic_jacobian,
    prior_sigma,
)
from hec.estimator.solve.view_planning import whole_board_views
from hec.estimator.targets.target import Target

STATE_DIM = 12  # mount, board pose


def planning_groups(board: Target, arm_known: bool) -> tuple[str, ...]:
    """The NUISANCE_GROUPS a self-calibrating cell's default method frees first (and, on the realistic
    cell, keeps): every camera, board and depth group, the marker shifts on a board whose markers are
    placed one by one, the arm's kinematics when the arm is known (arm_known)."""
    placed = board.markers_placed_one_by_one
    return tuple(
        g for g in NUISANCE_GROUPS if (g != "kinematics" or arm_known) and (g != MARKER_SHIFTS or placed)
    )


def frame_jacobian(
    problem: CalibrationProblem,
    state: HandEyeState,
    frame_index: int,
    names: Sequence[str],
    G_kinematic: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """One frame's whitened Jacobians: (m, 12 + p) of the prediction with respect to [mount, board
    pose, theta (names, p)] and (m, 6) with respect to its flange pose error. G_kinematic: (6, 24)
    the frame's kinematic_jacobian, needed when names hold KINEMATIC_NUISANCE."""
    frame = problem.frames[frame_index]
    pred = predict_frame(problem, state, frame, camera_jacobian=True)
    columns = [pred.J_state]
    camera = [CAMERA_NUISANCE.index(n) for n in names if n in CAMERA_NUISANCE]
    if camera:
        columns.append(pred.J_camera[:, camera])
    kinematic = [KINEMATIC_NUISANCE.index(n) for n in names if n in KINEMATIC_NUISANCE]
    if kinematic:
        if G_kinematic is None:
            raise ValueError("the arm's kinematic Jacobian is needed for the kinematics group")
        columns.append(pred.J_flange @ G_kinematic[:, kinematic])
    shifts = [n for n in names if n.startswith("marker")]
    if shifts:
        marker_of_row = np.concatenate([np.full(len(m.whitening), m.marker_id) for m in frame.markers])
        block = np.zeros((len(marker_of_row), len(shifts)))
        for marker in np.unique(marker_of_row):
            rows = marker_of_row == marker
            for axis, letter in enumerate("xy"):
                block[rows, shifts.index(f"marker{marker}_{letter}_m")] = pred.J_marker_shift[rows, axis]
        columns.append(block)
    return np.hstack(columns), pred.J_flange


def frame_full_information(
    problem: CalibrationProblem,
    state: HandEyeState,
    frame_index: int,
    names: Sequence[str],
    G_kinematic: np.ndarray | None,
) -> np.ndarray:
    """(12 + p, 12 + p) Fisher information of [mount, board pose, theta (names, p)] from one frame
    of problem (frame_jacobian), its flange pose error marginalised."""
    J, J_flange = frame_jacobian(problem, state, frame_index, names, G_kinematic)
    return flange_marginalised_information(J, J_flange, problem.robot_noise)


def self_calibrated_informations(
    waypoints: Sequence[Waypoint],
    board: Target,
    intrinsics: CameraIntrinsics,
    T_flange_cam: np.ndarray,
    T_base_board: np.ndarray,
    noise: SyntheticNoise,
    groups: Sequence[str],
    kinematics: URKinematics | None = None,
    seed_joints: np.ndarray | None = None,
    use_depth: bool = True,
    setup: str = EYE_IN_HAND,
) -> tuple[list[int], np.ndarray, np.ndarray]:
    """The waypoints usable for planning (their indices: every marker VIEW_MARGIN_PX inside the image
    and, with the kinematics group, reachable by the nominal arm kinematics from near seed_joints,
    default IK_RESTARTS[0]),
    the (n, 12 + p, 12 + p) information each adds to [mount, board pose, theta] (theta: the groups'
    corrections, group_names' order) from an exact frame with noise's covariances, and the
    (12 + p, 12 + p) information of theta's declared priors (zero on the mount and board pose).
    T_flange_cam, T_base_board: (4, 4) nominal poses, metres."""
    arm = "kinematics" in groups
    if arm and kinematics is None:
        raise ValueError("planning for the arm's kinematics needs the arm's nominal kinematics")
    flanges = [w.T_base_flange for w in waypoints]
    observations, whole = whole_board_views(
        waypoints, board, intrinsics, T_flange_cam, T_base_board, noise, setup
    )
    jacobians: list[np.ndarray | None] = [None] * len(whole)
    if arm:
        seed = IK_RESTARTS[0] if seed_joints is None else np.asarray(seed_joints, float)
        joints = [solve_ik_nearest(kinematics, flanges[i], seed) for i in whole]
        reached = [k for k, q in enumerate(joints) if q is not None]
        whole = [whole[k] for k in reached]
        jacobians = [kinematic_jacobian(kinematics, joints[k]) for k in reached]
    if not whole:
        return [], np.zeros((0, STATE_DIM, STATE_DIM)), np.zeros((STATE_DIM, STATE_DIM))
    problem = build_problem(
        [observations[i] for i in whole], board, intrinsics, noise.robot, use_depth, None, setup=setup
    )
    names = group_names(problem, groups)
    state = HandEyeState(T_flange_cam, T_base_board=T_base_board)
    informations = np.array(
        [frame_full_information(problem, state, k, names, jacobians[k]) for k in range(len(whole))]
    )
    prior = np.zeros((STATE_DIM + len(names),) * 2)
    prior[STATE_DIM:, STATE_DIM:] = np.diag(1.0 / prior_sigma(problem, names) ** 2)
    return whole, informations, prior
