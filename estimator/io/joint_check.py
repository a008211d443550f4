"""Whether imported joints fit their robot poses: a UR arm's joints in the ROS driver's order
(check_joint_order), or poses in other base and tool frames than the joints' kinematics
(check_joint_frames)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hec.estimator.geometry.kinematics import URKinematics, forward, joints_in_arm_order
from hec.estimator.geometry.transforms import invert, pose_error
from hec.estimator.io.convention_check import MISTAKE_RATIO
from hec.estimator.solve.initialise import mean_pose

# Joints whose rotations between frames differ from the poses' by more than this (degrees RMS) match
# them in no order: a UR arm's nominal kinematics are within about 0.3 degrees of the real arm's.
JOINT_MISMATCH_DEG = 1.0
# Robot poses within this of the kinematics' flange poses of their joints (metres, radians) are in
# the kinematics' own frames: a controller computes its poses from its joints with them, so the two
# agree to its rounding and any noise added to either.
JOINT_FRAME_TOLERANCE = (1e-3, np.radians(0.1))
JOINT_FRAME_ROUNDS = 10


def check_joint_order(
    T_base_flange: np.ndarray, joints: np.ndarray, kinematics: URKinematics, stated_order: str
) -> str:
    """Whether a UR arm's joints (N, 6, radians, read in stated_order and put in the arm's order)
    match the robot poses (N, 4, 4) or match them with the first and third angle swapped (the ROS
    driver's order for the arm's, or the other way); in words, with the residual of each: the RMS
    difference, over all pairs of frames, between the rotation angle from one frame to the other
    by the poses and by the kinematics (independent of the base and tool frames either uses)."""
    swapped = "arm" if stated_order == "ros-driver" else "ros-driver"
    stated_deg = _joint_residual_deg(T_base_flange, joints, kinematics)
    swapped_deg = _joint_residual_deg(T_base_flange, joints_in_arm_order(joints, "ros-driver"), kinematics)
    words = {
        "arm": "the arm's order (base joint first)",
        "ros-driver": "the ROS driver's order (elbow first)",
    }
    if swapped_deg < MISTAKE_RATIO * stated_deg:
        return (
            f"the joints look like {words[swapped]}: the rotation between frames by the kinematics differs "
            f"from the robot poses' by {stated_deg:.3g} deg RMS as stated, {swapped_deg:.3g} deg read so; "
            f"pass --joint-order {swapped}"
        )
    if stated_deg > JOINT_MISMATCH_DEG:
        return (
            f"the joints do not match the robot poses in either order ({stated_deg:.3g} deg RMS as stated, "
            f"{swapped_deg:.3g} deg swapped): are they these images' joints, in --joint-unit?"
        )
    return f"the joints fit the robot poses in {words[stated_order]} ({stated_deg:.2g} deg RMS)"


def _joint_residual_deg(T_base_flange: np.ndarray, joints: np.ndarray, kinematics: URKinematics) -> float:
    i, j = np.triu_indices(len(joints), k=1)

    def angles(R: np.ndarray) -> np.ndarray:
        return Rotation.from_matrix(np.swapaxes(R[i], 1, 2) @ R[j]).magnitude()

    by_joints = angles(np.array([forward(kinematics, q)[:3, :3] for q in joints]))
    return float(
        np.degrees(np.sqrt(np.mean(np.square(angles(np.asarray(T_base_flange)[:, :3, :3]) - by_joints))))
    )


def check_joint_frames(T_base_flange: np.ndarray, joints: np.ndarray, kinematics: URKinematics) -> str | None:
    """Whether the robot poses (N, 4, 4) are the kinematics' flange poses of the joints (N, 6, the
    arm's order) in other base and tool frames, T_i = L FK(q_i) R with L or R not the identity (a ROS
    tf pose from base_link is the controller's base turned 180 degrees about z): in words, or None
    when they are the kinematics' own (within JOINT_FRAME_TOLERANCE) or no such L and R fit."""
    F = [forward(kinematics, q) for q in joints]
    if _largest_error(T_base_flange, F, np.eye(4), np.eye(4)) < 1.0:
        return None
    L, R = np.eye(4), np.eye(4)
    for _ in range(JOINT_FRAME_ROUNDS):  # alternate: each is a mean given the other
        L = mean_pose([T @ invert(f @ R) for T, f in zip(T_base_flange, F, strict=True)])
        R = mean_pose([invert(L @ f) @ T for T, f in zip(T_base_flange, F, strict=True)])
    if _largest_error(T_base_flange, F, L, R) > 1.0:
        return None
    parts = [
        f"{what} frame {_describe_transform(T)}"
        for what, T in (("base", L), ("tool", R))
        if _tolerances(T, np.eye(4)) >= 1.0
    ]
    return (
        f"the robot poses are the joints' flange poses in another {' and '.join(parts)} than the arm's "
        "kinematics use (a ROS pose from base_link has the base turned 180 deg about z); the arm's "
        "self-calibration assumes the kinematics' frames: give the poses in them (UR's base and flange)"
    )


def _largest_error(T: list[np.ndarray], F: list[np.ndarray], L: np.ndarray, R: np.ndarray) -> float:
    """The largest of T_i against L F_i R, in _tolerances."""
    return max(_tolerances(t, L @ f @ R) for t, f in zip(T, F, strict=True))


def _tolerances(T_a: np.ndarray, T_b: np.ndarray) -> float:
    """How far apart two poses are in units of JOINT_FRAME_TOLERANCE (the worse of translation and
    rotation)."""
    metres, radians = pose_error(T_a, T_b)
    return max(metres / JOINT_FRAME_TOLERANCE[0], radians / JOINT_FRAME_TOLERANCE[1])


def _describe_transform(T: np.ndarray) -> str:
    rotvec = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    angle = float(np.linalg.norm(rotvec))
    axis = rotvec / angle if angle > 0.0 else np.array([0.0, 0.0, 1.0])
    return (
        f"(turned {np.degrees(angle):.3g} deg about [{axis[0]:.2f} {axis[1]:.2f} {axis[2]:.2f}], "
        f"moved {1e3 * np.linalg.norm(T[:3, 3]):.3g} mm)"
    )
