"""A UR arm through ur-rtde: read the flange pose and joints, move with limits, wait until settled.

UR pose vectors [x, y, z, rx, ry, rz] (metres, rotation vector in radians) exist only
here; everything the rest of hec sees is a (4, 4) transform. The controller reports
the TCP pose; the flange pose is T_base_flange = T_base_tcp @ inv(T_flange_tcp) with
the controller's TCP offset, so a calibration is to the flange (tool0) unless asked
for the TCP.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from hec.estimator.geometry.transforms import invert

# UR safety modes (RTDE safety_mode) that stop the arm, in plain words.
_SAFETY_STOPS = {
    3: "protective stop: clear the cause, then unlock it on the teach pendant",
    4: "recovery mode: move the arm back inside its limits on the teach pendant",
    5: "safeguard stop: a safety input stopped the arm; check the guards",
    6: "system emergency stop: release the emergency stop, then power on and release the brakes",
    7: "robot emergency stop: release the emergency stop button, then power on and release the brakes",
    8: "safety violation: see the teach pendant's log",
    9: "safety fault: see the teach pendant's log",
}
# Longest wait for a command's effect (a stop, a new TCP offset) to reach the receive
# stream, which lags the command channel (125-500 Hz packages).
_CAUSE_WAIT_S = 0.5
_NOT_CONNECTED = "check the network cable, the robot's IP address and that the controller is on"


class RobotError(RuntimeError):
    """The arm cannot move or report; the message says what happened and what to check."""


def transform_from_ur_pose(pose: np.ndarray) -> np.ndarray:
    """UR pose vector (6,) [x, y, z, rx, ry, rz] (metres, rotation vector) -> (4, 4)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.asarray(pose[3:], dtype=float)).as_matrix()
    T[:3, 3] = pose[:3]
    return T


def ur_pose_from_transform(T: np.ndarray) -> list[float]:
    """(4, 4) -> UR pose vector [x, y, z, rx, ry, rz] (metres, rotation vector)."""
    return [*map(float, T[:3, 3]), *map(float, Rotation.from_matrix(T[:3, :3]).as_rotvec())]


@dataclass(frozen=True)
class MotionSettings:
    """Speed and acceleration limits (joint moves: rad/s, rad/s^2; linear moves: m/s, m/s^2),
    the settle rule (every joint slower than settle_speed_rad_s for dwell_s), the longest
    a move may take, and how close a finished move must be to its target (rad per joint,
    metres)."""

    joint_speed: float = 0.5
    joint_acceleration: float = 0.8
    linear_speed: float = 0.1
    linear_acceleration: float = 0.3
    settle_speed_rad_s: float = 1e-3
    dwell_s: float = 0.5
    settle_timeout_s: float = 10.0
    move_timeout_s: float = 60.0
    joint_tolerance_rad: float = 1e-3
    position_tolerance_m: float = 1e-3


@dataclass(frozen=True)
class SafetyLimits:
    """Checked before every move. workspace_*: a box in the base frame (metres) that the
    flange must stay in; joint limits in radians (UR5: +-2 pi, elbow +-pi)."""

    workspace_lower_m: tuple[float, float, float] = (-1.0, -1.0, -1.0)
    workspace_upper_m: tuple[float, float, float] = (1.0, 1.0, 1.0)
    joint_lower_rad: tuple[float, ...] = field(default=(-2 * np.pi,) * 2 + (-np.pi,) + (-2 * np.pi,) * 3)
    joint_upper_rad: tuple[float, ...] = field(default=(2 * np.pi,) * 2 + (np.pi,) + (2 * np.pi,) * 3)

    def problem_with_joints(self, q: np.ndarray) -> str | None:
        lower, upper = np.array(self.joint_lower_rad), np.array(self.joint_upper_rad)
        outside = np.nonzero((q < lower) | (q > upper))[0]
        if len(outside):
            return "joints " + ", ".join(f"q{i + 1}={q[i]:.3f} rad" for i in outside) + " outside the limits"
        return None

    def problem_with_flange(self, T_base_flange: np.ndarray) -> str | None:
        p = T_base_flange[:3, 3]
        if np.any(p < self.workspace_lower_m) or np.any(p > self.workspace_upper_m):
            return (
                f"flange position {np.round(p, 3).tolist()} m outside the workspace box "
                f"{list(self.workspace_lower_m)}..{list(self.workspace_upper_m)}"
            )
        return None


class URRobot:
    """A UR arm on ``host``, through RTDEReceiveInterface and RTDEControlInterface.

    forward: joint angles (6,) -> T_base_flange (4, 4), to check joint targets against the
    workspace box (the UR5's DH model in experiments); None checks only their joint limits.
    read_only: connect only the receive interface (a dry run, teaching by hand); the TCP
    offset cannot be read then, so give it as T_flange_tcp (identity: the TCP is the flange).
    Otherwise T_flange_tcp is read from the controller.
    """

    def __init__(
        self,
        host: str,
        motion: MotionSettings | None = None,
        limits: SafetyLimits | None = None,
        forward: Callable[[np.ndarray], np.ndarray] | None = None,
        read_only: bool = False,
        T_flange_tcp: np.ndarray | None = None,
    ) -> None:
        import rtde_receive

        self.host = host
        self.motion = motion or MotionSettings()
        self.limits = limits or SafetyLimits()
        self.forward = forward
        try:
            self._receive = rtde_receive.RTDEReceiveInterface(host)
        except RuntimeError as exc:
            raise RobotError(f"cannot reach the UR controller at {host} ({exc}); {_NOT_CONNECTED}") from None
        self._control = None
        self.T_flange_tcp = np.eye(4) if T_flange_tcp is None else np.asarray(T_flange_tcp, dtype=float)
        self.read_only = read_only
        if not read_only:
            self._controller()

    # --- reading ---------------------------------------------------------------------------

    def joints(self) -> np.ndarray:
        """Actual joint angles (6,), radians."""
        self._check_connected()
        return np.array(self._receive.getActualQ())

    def tcp_pose(self) -> np.ndarray:
        """Actual T_base_tcp (4, 4) with the controller's TCP offset."""
        self._check_connected()
        return transform_from_ur_pose(np.array(self._receive.getActualTCPPose()))

    def flange_pose(self) -> np.ndarray:
        """Actual T_base_flange (4, 4): the TCP pose with the TCP offset taken off."""
        return self.tcp_pose() @ invert(self.T_flange_tcp)

    # --- moving ----------------------------------------------------------------------------

    def check_joint_target(self, q: np.ndarray) -> str | None:
        """Why the joint target may not be used, or None."""
        problem = self.limits.problem_with_joints(q)
        if problem is None and self.forward is not None:
            problem = self.limits.problem_with_flange(self.forward(q))
        return problem

    def set_tcp_offset(self, T_flange_tcp: np.ndarray) -> None:
        """Set the controller's TCP offset (4, 4), the TCP in the flange frame, with the arm
        still. Returns once the reported TCP pose shows it: the receive stream lags the
        command, and a flange pose from the new offset and an old TCP pose is wrong by the
        offset's change."""
        T_flange_tcp = np.asarray(T_flange_tcp, dtype=float)
        T_base_flange = self.flange_pose()
        if not self._controller().setTcp(ur_pose_from_transform(T_flange_tcp)):
            raise RobotError("the controller refused the TCP offset")
        expected = T_base_flange @ T_flange_tcp
        deadline = time.monotonic() + _CAUSE_WAIT_S
        # 1e-5 (m, or rotation-matrix entries): above a still arm's encoder jitter.
        while np.max(np.abs(self.tcp_pose() - expected)) > 1e-5:
            if time.monotonic() > deadline:
                raise RobotError("the reported TCP pose did not take the new TCP offset; is the arm moving?")
            time.sleep(0.005)
        self.T_flange_tcp = T_flange_tcp

    def move_joints(self, q: np.ndarray) -> None:
        """moveJ to q (6,) radians with the configured limits; returns when settled."""
        q = np.asarray(q, dtype=float)
        problem = self.check_joint_target(q)
        if problem:
            raise RobotError(f"refused to move: {problem}")
        m = self.motion
        self._run_move(
            "moveJ", lambda control: control.moveJ(q.tolist(), m.joint_speed, m.joint_acceleration, True)
        )
        reached = np.max(np.abs(self.joints() - q))
        if reached > self.motion.joint_tolerance_rad:
            raise RobotError(
                f"the arm stopped {reached:.4f} rad short of the joint target; check for obstacles"
            )

    def move_flange(self, T_base_flange: np.ndarray) -> None:
        """moveL of the flange to T_base_flange (4, 4); returns when settled."""
        problem = self.limits.problem_with_flange(T_base_flange)
        if problem:
            raise RobotError(f"refused to move: {problem}")
        target_tcp = ur_pose_from_transform(T_base_flange @ self.T_flange_tcp)
        m = self.motion
        self._run_move(
            "moveL", lambda control: control.moveL(target_tcp, m.linear_speed, m.linear_acceleration, True)
        )
        miss = np.linalg.norm(self.flange_pose()[:3, 3] - T_base_flange[:3, 3])
        if miss > self.motion.position_tolerance_m:
            raise RobotError(f"the arm stopped {1e3 * miss:.1f} mm short of the target; check for obstacles")

    def teach_mode(self, on: bool) -> None:
        """Let the arm be moved by hand (UR teach mode, freedrive) or end it."""
        control = self._controller()
        if not (control.teachMode() if on else control.endTeachMode()):
            raise RobotError(f"the controller refused to {'start' if on else 'end'} teach mode")

    def wait_settled(self) -> None:
        """Return once every joint has been slower than settle_speed_rad_s for dwell_s."""
        m = self.motion
        deadline = time.monotonic() + m.settle_timeout_s
        still_since = None
        while time.monotonic() < deadline:
            self._check_connected()
            self._check_safety()
            now = time.monotonic()
            if np.max(np.abs(self._receive.getActualQd())) < m.settle_speed_rad_s:
                still_since = now if still_since is None else still_since
                if now - still_since >= m.dwell_s:
                    return
            else:
                still_since = None
            time.sleep(0.01)
        raise RobotError(f"the arm did not settle within {m.settle_timeout_s:g} s")

    def close(self) -> None:
        for interface in (self._control, self._receive):
            if interface is not None and interface.isConnected():
                interface.disconnect()

    def __enter__(self) -> URRobot:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    # --- internals -------------------------------------------------------------------------

    def _controller(self) -> object:
        """The RTDEControlInterface, connected on first use (reads the TCP offset), for one
        command. The connection is checked every time: a command sent to a lost controller
        waits for its answer (a move up to 300 s, endTeachMode forever)."""
        if self.read_only:
            raise RobotError("this robot was opened read-only (a dry run); it cannot move")
        self._check_connected()
        if self._control is None:
            import rtde_control

            self._check_safety()
            try:
                self._control = rtde_control.RTDEControlInterface(self.host)
            except RuntimeError as exc:
                raise RobotError(
                    f"cannot start control on {self.host} ({exc}); put the robot in remote control, "
                    "power it on and release the brakes"
                ) from None
            self.T_flange_tcp = transform_from_ur_pose(np.array(self._control.getTCPOffset()))
        return self._control

    def _run_move(self, command: str, send: Callable[[object], bool]) -> None:
        """Send an asynchronous move, watch it to its end, then wait until settled.

        A blocking ur_rtde move never returns when the connection drops during the move
        (measured against the loopback controller), so the move is asynchronous and this
        loop checks the connection, the safety mode and the program every 10 ms; Ctrl-C stops
        the arm (stopJ) before it is passed on. A failed move is given _CAUSE_WAIT_S for a
        stop or a lost connection to reach the receive stream (it lags the command channel)
        before it is reported without a cause.
        """
        control = self._controller()
        try:
            failed = not send(control)
            deadline = time.monotonic() + self.motion.move_timeout_s
            while not failed:
                self._check_connected()
                self._check_safety()
                if control.getAsyncOperationProgress() < 0:
                    break
                if not control.isProgramRunning():
                    failed = True
                elif time.monotonic() > deadline:
                    control.stopJ(self.motion.joint_acceleration)
                    raise RobotError(f"{command} did not finish within {self.motion.move_timeout_s:g} s")
                time.sleep(0.01)
        except KeyboardInterrupt:
            control.stopJ(self.motion.joint_acceleration)  # Ctrl-C: an asynchronous move would go on
            raise
        if failed:
            cause_deadline = time.monotonic() + _CAUSE_WAIT_S
            while time.monotonic() < cause_deadline:
                self._check_connected()
                self._check_safety()
                time.sleep(0.01)
            raise RobotError(f"{command} failed: the controller stopped the program; see the teach pendant")
        self.wait_settled()

    def _check_connected(self) -> None:
        if not self._receive.isConnected() or (self._control is not None and not self._control.isConnected()):
            raise RobotError(f"lost the connection to the UR controller at {self.host}; {_NOT_CONNECTED}")

    def _check_safety(self) -> None:
        mode = int(self._receive.getSafetyMode())
        if mode in _SAFETY_STOPS:
            raise RobotError(f"the arm is in {_SAFETY_STOPS[mode]}")
