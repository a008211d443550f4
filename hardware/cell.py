"""The real cell: a UR arm and a RealSense camera behind the interface of the simulated cell
(plan, move_to, capture), so one calibration session drives either."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict

import numpy as np

from hec.estimator.geometry.move_plan import Branches, plan_joint_moves
from hec.estimator.geometry.waypoints import PlannedMove, Waypoint
from hec.estimator.observe.frames import Capture, Frame
from hec.estimator.targets.target import Target
from hec.hardware.realsense import RealSenseCamera
from hec.hardware.ur_robot import RobotError, URRobot

# Largest joint change (rad) between the reads before and after a capture: more means the
# arm moved while the camera was exposing, and the pose would not belong to the images.
STILL_DURING_CAPTURE_RAD = 1e-4
POSE_FRAMES = ("flange", "tcp")


def plan_moves(
    robot: URRobot,
    inverse: Callable[[np.ndarray, np.ndarray], np.ndarray | None],
    waypoints: list[Waypoint],
    cable_limit_rad: float = np.pi,
    branches: Branches | None = None,
    cell_problem: Callable[[np.ndarray], str | None] | None = None,
) -> list[PlannedMove]:
    """plan_joint_moves from the arm's current joints, within its joint limits, each target
    checked as the arm checks it before moving, and every path sample's flange against its
    workspace box; cell_problem (joints (6,) -> reason or None: the cell model,
    hec.estimator.geometry.cell_model) at each target and path sample."""

    def cell(q: np.ndarray) -> str | None:
        return None if cell_problem is None else cell_problem(q)

    def flange_problem(q: np.ndarray) -> str | None:
        if robot.forward is not None and (problem := robot.limits.problem_with_flange(robot.forward(q))):
            return problem
        return cell(q)

    return plan_joint_moves(
        waypoints,
        robot.joints(),
        np.array(robot.limits.joint_lower_rad),
        np.array(robot.limits.joint_upper_rad),
        cable_limit_rad,
        lambda q: robot.check_joint_target(q) or cell(q),
        flange_problem,
        inverse,
        branches,
    )


class HardwareCell:
    """robot and camera, opened by the caller (closed by close()).

    plan: waypoints -> planned moves from the arm's current joints (plan_moves with the cell's
    limits, cable limit and cell model: the same checks as the session's plan). pose_frame: 'flange' records
    T_base_flange (tool0), 'tcp' the controller's TCP pose (the result is then the camera
    in the TCP frame).
    """

    source = "ur-realsense"

    def __init__(
        self,
        robot: URRobot,
        camera: RealSenseCamera,
        board: Target,
        plan: Callable[[list[Waypoint]], list[PlannedMove]],
        pose_frame: str = "flange",
    ) -> None:
        if pose_frame not in POSE_FRAMES:
            raise ValueError(f"pose_frame must be one of {POSE_FRAMES}, got {pose_frame!r}")
        self.robot, self.camera, self.board = robot, camera, board
        self._plan = plan
        self.pose_frame = pose_frame
        self.intrinsics = camera.intrinsics
        self.depth_scale_m = camera.depth_scale_m

    def plan(self, waypoints: list[Waypoint]) -> list[PlannedMove]:
        return self._plan(waypoints)

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
