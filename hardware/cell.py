"""The real cell: a UR arm and a RealSense camera behind the interface of the simulated cell
(plan, move_to, capture), so one calibration session drives either."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict

import numpy as np

from hec.estimator.geometry.joint_path import joint_path, largest_swing, least_swing_branches, path_problem
from hec.estimator.geometry.waypoints import PlannedMove, Waypoint
from hec.estimator.observe.frames import Capture, Frame
from hec.estimator.targets.target import Target
from hec.hardware.realsense import RealSenseCamera
from hec.hardware.ur_robot import RobotError, URRobot

# Largest joint change (rad) between the reads before and after a capture: more means the
# arm moved while the camera was exposing, and the pose would not belong to the images.
STILL_DURING_CAPTURE_RAD = 1e-4
POSE_FRAMES = ("flange", "tcp")


_REPLANS = 200  # how often the least-swing choice of branches is made again around a failing move


def plan_moves(
    robot: URRobot,
    inverse: Callable[[np.ndarray, np.ndarray], np.ndarray | None],
    waypoints: list[Waypoint],
    cable_limit_rad: float = np.pi,
    branches: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> list[PlannedMove]:
    """Joint targets from the arm's current joints on (pose waypoints through inverse, seeded
    with the previous target, the wrist's last joint turned by whole turns to stay within
    cable_limit_rad of where it started), each move checked along its joint path (joint_path, 0.5
    degree steps) against the joint limits, the cable limit and the flange's workspace box; a
    waypoint that fails is skipped, named with why and where, and the next starts from the one
    before. Each usable move carries its largest single-joint swing. branches: (T_base_flange,
    q_near, lower, upper) -> (M, 6) every joint solution within the bounds; given, the pose
    waypoints' solutions are chosen together for the least total swing (least_swing_branches)."""
    q = robot.joints()
    q6_start = float(q[5])
    lower, upper = np.array(robot.limits.joint_lower_rad), np.array(robot.limits.joint_upper_rad)

    def flange_problem(q_path: np.ndarray) -> str | None:
        if robot.forward is None:
            return None
        return robot.limits.problem_with_flange(robot.forward(q_path))

    window_lower, window_upper = lower.copy(), upper.copy()
    window_lower[5] = max(lower[5], q6_start - cable_limit_rad)
    window_upper[5] = min(upper[5], q6_start + cable_limit_rad)

    def move_problem(q_from: np.ndarray, q_to: np.ndarray) -> str | None:
        problem = robot.check_joint_target(q_to)
        if problem is None:
            path = joint_path(q_from, q_to)
            problem = path_problem(path, lower, upper, q6_start, cable_limit_rad, flange_problem)
        return problem

    chosen = _least_swing_targets(waypoints, q, window_lower, window_upper, branches, move_problem)
    moves = []
    previous = "the start"
    for i, waypoint in enumerate(waypoints):
        if chosen is not None:
            target = chosen[i]
        elif waypoint.joints is not None:
            target = waypoint.joints
        else:
            target = inverse(waypoint.T_base_flange, q)
        if target is None:
            moves.append(
                PlannedMove(waypoint, None, "no inverse kinematics solution within the joint limits")
            )
            continue
        target = np.asarray(target, dtype=float)
        if waypoint.joints is None and chosen is None:
            target = wrist_turn_nearest(target, q[5], window_lower[5], window_upper[5])
        problem = move_problem(q, target)
        if problem is not None:
            problem = f"the move from {previous}: {problem}"
        if problem is not None:
            moves.append(PlannedMove(waypoint, None, problem))
            continue
        moves.append(PlannedMove(waypoint, target, swing=largest_swing(q, target)))
        q = target
        previous = f"waypoint {waypoint.index}"
    return moves


def _least_swing_targets(
    waypoints: list[Waypoint],
    q_start: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    branches: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None,
    move_problem: Callable[[np.ndarray, np.ndarray], str | None],
) -> list[np.ndarray] | None:
    """Each waypoint's joint target (6,) chosen together for the least total swing from q_start
    with every move passing move_problem (q_from, q_to -> reason or None): a sequence with a move
    that fails is chosen again without that move, up to _REPLANS times. None: no branches given, a
    pose waypoint without a solution within lower, upper, or no sequence found."""
    if branches is None:
        return None
    candidates = [
        np.asarray(w.joints, dtype=float)[None]
        if w.joints is not None
        else branches(w.T_base_flange, q_start, lower, upper)
        for w in waypoints
    ]
    forbidden: set[tuple[int, int, int]] = set()
    for _ in range(_REPLANS):
        picks = least_swing_branches(candidates, q_start, frozenset(forbidden))
        if picks is None:
            return None
        q, a = q_start, 0
        for i, b in enumerate(picks):
            target = candidates[i][b]
            if move_problem(q, target) is not None:
                forbidden.add((i, a, b))
                break
            q, a = target, b
        else:
            return [c[i] for c, i in zip(candidates, picks, strict=True)]
    return None


def wrist_turn_nearest(q: np.ndarray, q6_previous: float, q6_lower: float, q6_upper: float) -> np.ndarray:
    """q (6,) with its last joint moved by whole turns (the same flange pose) to the turn nearest
    q6_previous within [q6_lower, q6_upper], radians (the cable window and the joint limits), or q
    unchanged when no turn is within them (the path check then refuses it)."""
    turn = 2.0 * np.pi
    candidates = q[5] + turn * np.arange(-3, 4)
    candidates = candidates[(candidates >= q6_lower) & (candidates <= q6_upper)]
    if len(candidates) == 0:
        return q
    out = q.copy()
    out[5] = candidates[np.argmin(np.abs(candidates - q6_previous))]
    return out


class HardwareCell:
    """robot and camera, opened by the caller (closed by close()).

    inverse: (T_base_flange (4, 4), seed joints (6,)) -> joints (6,) or None, the arm's
    nominal inverse kinematics for waypoints given as poses. pose_frame: 'flange' records
    T_base_flange (tool0), 'tcp' the controller's TCP pose (the result is then the camera
    in the TCP frame).
    """

    source = "ur-realsense"

    def __init__(
        self,
        robot: URRobot,
        camera: RealSenseCamera,
        board: Target,
        inverse: Callable[[np.ndarray, np.ndarray], np.ndarray | None],
        pose_frame: str = "flange",
    ) -> None:
        if pose_frame not in POSE_FRAMES:
            raise ValueError(f"pose_frame must be one of {POSE_FRAMES}, got {pose_frame!r}")
        self.robot, self.camera, self.board = robot, camera, board
        self.inverse = inverse
        self.pose_frame = pose_frame
        self.intrinsics = camera.intrinsics
        self.depth_scale_m = camera.depth_scale_m

    def plan(self, waypoints: list[Waypoint]) -> list[PlannedMove]:
        return plan_moves(self.robot, self.inverse, waypoints)

    def move_to(self, move: PlannedMove) -> None:
        """moveJ to the planned joints; returns once the arm has settled. Raises RobotError."""
        if move.joints is None:
            raise ValueError(f"waypoint {move.waypoint.index} has no joint target: {move.problem}")
        self.robot.move_joints(move.joints)

    def pose(self) -> np.ndarray:
        """The reported T_base_flange (or T_base_tcp with pose_frame 'tcp'), (4, 4)."""
        return self.robot.tcp_pose() if self.pose_frame == "tcp" else self.robot.flange_pose()

    def capture(self) -> Capture:
        """The pose and joints, then a camera burst taken after that moment; the joints are
        read again after the burst to be sure the arm stood still throughout."""
        q_before = self.robot.joints()
        T_base_pose = self.pose()
        taken = self.camera.capture(not_before_s=time.time())
        moved = float(np.max(np.abs(self.robot.joints() - q_before)))
        if moved > STILL_DURING_CAPTURE_RAD:
            raise RobotError(
                f"the arm moved {moved:.5f} rad during the capture; is someone guiding it or is "
                "the settle dwell too short?"
            )
        frame = Frame(taken.rgb, taken.depth_m, self.intrinsics, T_base_pose, q_before, taken.time_s)
        return Capture(frame, depth_samples=taken.depth_samples)

    def describe(self) -> dict:
        """What dataset.json records about the cell."""
        r = self.robot
        return {
            "robot": {
                "host": r.host,
                "pose_frame": self.pose_frame,
                "T_flange_tcp": [[float(v) for v in row] for row in r.T_flange_tcp],
                "motion": asdict(r.motion),
                "limits": asdict(r.limits),
            },
            "camera": self.camera.describe(),
        }

    def close(self) -> None:
        self.camera.close()
        self.robot.close()
