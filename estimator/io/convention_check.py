"""Which pose convention fits the data: the common mistakes tried on imported robot poses.

Most wrong hand-eye results come from reading the robot's poses in the wrong convention: poses
inverted (flange-to-base for base-to-flange), a rotation vector read as Euler angles or the wrong
Euler order, degrees for radians, millimetres for metres, quaternions the other way round. Given
the numbers of a pose file and the convention they were read with, the check reads them in each
mistaken convention (alternative_conventions), calibrates each with OpenCV's Park method on the
problem's detected board (cheap, no noise model) and compares the RMS pixel residual: a mistake
is named when its residual is below MISTAKE_RATIO of the stated convention's.

The same is done for the other common mistakes: pose pairs with the robot or the tracking poses
inverted, or both (check_pose_pair_directions); a UR arm's joints in the ROS driver's order
(check_joint_order) or poses in other base and tool frames than the joints' kinematics
(check_joint_frames); a board file whose marker layout is mirrored (check_board_layout).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from hec.estimator.geometry.kinematics import URKinematics, forward, joints_in_arm_order
from hec.estimator.geometry.transforms import invert, pose_error
from hec.estimator.io.pose_file import EULER_SEQUENCES, PoseConvention, PoseFileError, poses_from_values
from hec.estimator.observe.pose_pairs import PosePair
from hec.estimator.solve.baselines import opencv_calibrate
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.initialise import mean_pose
from hec.estimator.solve.pose_pair_methods import PAIR_NOISE_FREE, PosePairModel, opencv_pose_pairs
from hec.estimator.solve.problem import CalibrationInputError, CalibrationProblem

# A mistaken convention is named when it leaves at most this fraction of the stated one's residual.
MISTAKE_RATIO = 0.3
# Joints whose rotations between frames differ from the poses' by more than this (degrees RMS) match
# them in no order: a UR arm's nominal kinematics are within about 0.3 degrees of the real arm's.
JOINT_MISMATCH_DEG = 1.0
# Robot poses within this of the kinematics' flange poses of their joints (metres, radians) are in
# the kinematics' own frames: a controller computes its poses from its joints with them, so the two
# agree to its rounding and any noise added to either.
JOINT_FRAME_TOLERANCE = (1e-3, np.radians(0.1))
JOINT_FRAME_ROUNDS = 10
# Which way a pose pair's board pose maps: camera-to-target is T_cam_board (easy_handeye2's tracking).
TRACKING_DIRECTIONS = ("camera-to-target", "target-to-camera")
_OPTION = {
    "rotation": "--rotation",
    "angle_unit": "--angle-unit",
    "length_unit": "--length-unit",
    "direction": "--pose-direction",
}


@dataclass(frozen=True)
class ConventionTrial:
    """One reading of the poses: the mistake in plain words ("" for the stated convention), its
    convention, the RMS pixel residual of a Park calibration with it (inf when it fails) and the
    convention's fields that differ from the stated one."""

    mistake: str
    convention: PoseConvention
    residual_px: float
    changed_fields: tuple[str, ...] = ()

    @property
    def option(self) -> str:
        """The options that select this convention, for example '--pose-direction flange-to-base'."""
        return " ".join(
            f"{_OPTION[k]} {v}" for k, v in self.convention.to_dict().items() if k in self.changed_fields
        )


@dataclass(frozen=True)
class ConventionReport:
    """The stated convention's trial, every mistake's, and the one that fits (or None)."""

    stated: ConventionTrial
    trials: list[ConventionTrial]
    fits: ConventionTrial | None

    @property
    def message(self) -> str:
        if self.fits is None:
            return (
                f"the robot poses fit the stated convention ({self.stated.residual_px:.2g} px RMS residual); "
                "none of the common mistakes fits better"
            )
        return (
            f"the robot poses look like {self.fits.mistake}: the residual drops from "
            f"{self.stated.residual_px:.3g} px to {self.fits.residual_px:.3g} px; pass {self.fits.option}"
        )


def alternative_conventions(stated: PoseConvention) -> list[tuple[str, PoseConvention]]:
    """The common mistakes from a stated convention: (what it means in words, the convention)."""
    out = [
        (
            f"{_other(stated.direction)} (inverted)",
            replace(stated, direction=_other(stated.direction)),
        ),
        (
            f"lengths in {_swap(stated.length_unit, 'm', 'mm')}",
            replace(stated, length_unit=_swap(stated.length_unit, "m", "mm")),
        ),
    ]
    rotation = stated.rotation
    if rotation.startswith("quat"):
        other = _swap(rotation, "quat-wxyz", "quat-xyzw")
        out.append((f"quaternions {other.removeprefix('quat-')}", replace(stated, rotation=other)))
    elif rotation != "matrix":
        out.append(
            (
                f"angles in {_swap(stated.angle_unit, 'rad', 'deg')}",
                replace(stated, angle_unit=_swap(stated.angle_unit, "rad", "deg")),
            )
        )
        kinds = ["rotvec", *(f"euler-{s}" for s in EULER_SEQUENCES)]
        for kind in kinds:
            if kind != rotation:
                words = (
                    "a rotation vector" if kind == "rotvec" else f"Euler angles {kind.removeprefix('euler-')}"
                )
                out.append((words, replace(stated, rotation=kind)))
    return out


def check_pose_convention(
    problem: CalibrationProblem, values: np.ndarray, stated: PoseConvention
) -> ConventionReport:
    """Try the stated convention and every mistake on the problem's board observations. values:
    (N, k) the pose file's numbers of the dataset's frames, row i for frame i (problem frames
    name theirs)."""
    trials = [_trial(problem, values, "", stated)]
    for mistake, convention in alternative_conventions(stated):
        trials.append(_trial(problem, values, mistake, convention, stated))
    stated_trial, others = trials[0], trials[1:]
    best = min(others, key=lambda t: t.residual_px)
    fits = best if best.residual_px < MISTAKE_RATIO * stated_trial.residual_px else None
    return ConventionReport(stated_trial, others, fits)


def _trial(
    problem: CalibrationProblem,
    values: np.ndarray,
    mistake: str,
    convention: PoseConvention,
    stated: PoseConvention | None = None,
) -> ConventionTrial:
    changed = tuple(
        k for k, v in convention.to_dict().items() if stated is not None and stated.to_dict()[k] != v
    )
    try:
        T_base_flange = poses_from_values(values, convention)
        frames = [replace(f, T_base_flange=T_base_flange[f.frame], joints=None) for f in problem.frames]
        result = opencv_calibrate(
            replace(problem, frames=frames, kinematics=None), MethodOptions(), "opencv-park"
        )
        residual = result.residual_rms_px
    except (CalibrationInputError, PoseFileError, ValueError, np.linalg.LinAlgError):
        residual = float("inf")
    return ConventionTrial(mistake, convention, residual if np.isfinite(residual) else float("inf"), changed)


def _other(direction: str) -> str:
    return _swap(direction, "base-to-flange", "flange-to-base")


def _swap(value: str, a: str, b: str) -> str:
    return b if value == a else a


@dataclass(frozen=True)
class PairReading:
    """One reading of imported pose pairs: the mistake in words ("" as stated), the options that
    select it, the RMS translation (metres) of the board pose over the pairs at Park's solution for
    it (inf when Park fails) and the lengths (metres) of that solution's mount and board translations."""

    mistake: str
    option: str
    residual_m: float
    mount_m: float = float("nan")
    board_m: float = float("nan")


def check_pose_pair_directions(pairs: list[PosePair], robot_direction: str, tracking_direction: str) -> str:
    """Which reading of pose pairs fits: as stated (pairs read in robot_direction and
    tracking_direction), the robot poses inverted, the camera-to-target poses inverted, or both; in
    words, with the residual before and after (the board pose's RMS translation over the pairs at
    Park's solution).

    Inverting both fits exactly as well as not, with the roles swapped: the mount comes out as the
    board's pose in the base frame and the board's as the mount. So only readings that put the
    camera nearer the flange than the board is to the base are taken (a camera on a flange is not
    across the cell from it), unless none does."""
    other_robot, other_tracking = _other(robot_direction), _swap(tracking_direction, *TRACKING_DIRECTIONS)
    readings = [
        ("", "", False, False),
        (f"robot poses {other_robot} (inverted)", f"--pose-direction {other_robot}", True, False),
        (
            f"tracking poses {other_tracking} (inverted)",
            f"--tracking-direction {other_tracking}",
            False,
            True,
        ),
        (
            "both inverted",
            f"--pose-direction {other_robot} --tracking-direction {other_tracking}",
            True,
            True,
        ),
    ]
    trials = [_pair_reading(pairs, m, o, a, z) for m, o, a, z in readings]
    stated = trials[0]
    best = min([t for t in trials if t.mount_m < t.board_m] or trials, key=lambda t: t.residual_m)
    if best is not stated and best.residual_m < MISTAKE_RATIO * stated.residual_m:
        after = f"{1e3 * best.residual_m:.3g} mm"
        change = (
            f"as stated Park finds no solution, read so the board pose's spread is {after}"
            if not np.isfinite(stated.residual_m)
            else f"the board pose's spread drops from {1e3 * stated.residual_m:.3g} mm to {after}"
        )
        return f"the pose pairs look like {best.mistake}: {change}; pass {best.option}"
    if best is not stated and not stated.mount_m < stated.board_m:
        return (
            f"the pose pairs look like {best.mistake}: they fit as well either way (board pose spread "
            f"{1e3 * stated.residual_m:.3g} mm as stated, {1e3 * best.residual_m:.3g} mm read so), but as "
            f"stated the camera sits {stated.mount_m:.2f} m from the flange and the board "
            f"{stated.board_m:.2f} m from the base, read so {best.mount_m:.2f} m and {best.board_m:.2f} m; "
            f"pass {best.option}"
        )
    return (
        f"the pose pairs fit the stated directions (the board pose's spread {1e3 * stated.residual_m:.3g} mm "
        "RMS); none of the common mistakes fits better"
    )


def _pair_reading(
    pairs: list[PosePair], mistake: str, option: str, invert_robot: bool, invert_tracking: bool
) -> PairReading:
    read = [
        PosePair(
            p.frame,
            invert(p.T_base_flange) if invert_robot else p.T_base_flange,
            invert(p.T_cam_board) if invert_tracking else p.T_cam_board,
        )
        for p in pairs
    ]
    try:
        X, B = opencv_pose_pairs(read, "opencv-park")
    except (CalibrationInputError, np.linalg.LinAlgError, ValueError):
        return PairReading(mistake, option, float("inf"))
    residual = PosePairModel(read, PAIR_NOISE_FREE).rms(X, B)[0]
    return PairReading(
        mistake, option, residual, float(np.linalg.norm(X[:3, 3])), float(np.linalg.norm(B[:3, 3]))
    )


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


def check_board_layout(problem: CalibrationProblem) -> str:
    """Whether the board file's marker layout fits the images, or fits them mirrored (the markers'
    centres reflected left to right or top to bottom about the board's origin, each marker's own
    points kept, as a board file written in a frame with x or y the other way would be); in words,
    with the RMS pixel residual of each frame's board pose (PnP) before and after. A board of
    one-point markers mirrored is the same points seen from behind, a rigid change the board pose
    absorbs: nothing to name."""
    stated = _board_residual_px(problem, np.ones(3))
    readings = [
        ("left to right (x)", np.array([-1.0, 1.0, 1.0])),
        ("top to bottom (y)", np.array([1.0, -1.0, 1.0])),
    ]
    words, residual = min(((w, _board_residual_px(problem, m)) for w, m in readings), key=lambda t: t[1])
    if residual < MISTAKE_RATIO * stated:
        return (
            f"the board file's marker layout looks mirrored {words}: the residual of the board poses drops "
            f"from {stated:.3g} px to {residual:.3g} px with the markers' centres reflected; correct the "
            "board file's marker centres"
        )
    return f"the board file's layout fits the images ({stated:.2g} px RMS residual of the board poses)"


def _board_residual_px(problem: CalibrationProblem, mirror: np.ndarray) -> float:
    """RMS pixel residual of each frame's PnP board pose, the markers' centres scaled by mirror (3,)."""
    K, dist = problem.intrinsics.K, np.array(problem.intrinsics.dist, dtype=np.float64)
    squared, count = 0.0, 0
    for frame in problem.frames:
        points = []
        for m in frame.markers:
            center = m.corners_board.mean(axis=0)
            points.append(m.corners_board - center + mirror * center)
        object_points = np.concatenate(points)
        image_points = np.concatenate([m.corners_px for m in frame.markers])
        ok, rvec, tvec = cv2.solvePnP(object_points, image_points, K, dist, flags=cv2.SOLVEPNP_SQPNP)
        if not ok:
            return float("inf")
        projected = cv2.projectPoints(object_points, rvec, tvec, K, dist)[0].reshape(-1, 2)
        squared += float(np.sum((projected - image_points) ** 2))
        count += len(image_points)
    return float(np.sqrt(squared / max(count, 1)))


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
