"""What the loopback UR controller shares: ports, RTDE message types and variable types, the codes of the
RTDE guide, UR pose vectors, and the motion profile of a move (controller time, seconds)."""

from __future__ import annotations

import re
import struct
from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003
# A CB3 controller: ur_rtde then streams at 125 Hz instead of the e-Series 500 Hz.
DEFAULT_CONTROLLER_VERSION = (3, 15, 8, 0)

# Robot, safety and runtime codes as the RTDE guide defines them.
ROBOT_MODE_POWER_OFF, ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING = 3, 5, 7
SAFETY_MODE_NORMAL, SAFETY_MODE_PROTECTIVE_STOP, SAFETY_MODE_ROBOT_EMERGENCY_STOP = 1, 3, 7
SAFETY_BIT_NORMAL, SAFETY_BIT_PROTECTIVE_STOPPED = 0, 2
SAFETY_BIT_ROBOT_EMERGENCY_STOPPED, SAFETY_BIT_EMERGENCY_STOPPED, SAFETY_BIT_STOPPED_DUE_TO_SAFETY = 6, 7, 10
ROBOT_STATUS_BIT_POWER_ON, ROBOT_STATUS_BIT_PROGRAM_RUNNING = 0, 1
RUNTIME_STOPPED, RUNTIME_PLAYING, RUNTIME_PAUSED = 1, 2, 4
JOINT_MODE_RUNNING = 253

# Control script handshake values in output_int_register_0.
READY, DONE = 1, 2
# Command numbers of ur_rtde's control script that this controller emulates.
COMMAND_NAMES = {
    1: "movej",
    2: "movej_ik",
    3: "movel",
    4: "movel_fk",
    17: "set_payload",
    18: "teach_mode",
    19: "end_teach_mode",
    29: "set_tcp",
    31: "protective_stop",
    33: "stopl",
    34: "stopj",
    40: "get_tcp_offset",
    47: "is_steady",
    52: "freedrive_mode",
    53: "end_freedrive_mode",
    255: "stop_script",
}
# Commands the script handles without waiting for the client to clear the command register.
REALTIME_COMMANDS = {6, 9, 10, 11, 24, 25, 26, 27, 38, 58}

# RTDE message types.
RTDE_PROTOCOL_VERSION, RTDE_CONTROLLER_VERSION = ord("V"), ord("v")
RTDE_DATA, RTDE_SETUP_OUTPUTS, RTDE_SETUP_INPUTS = ord("U"), ord("O"), ord("I")
RTDE_START, RTDE_PAUSE = ord("S"), ord("P")
RTDE_HEADER = struct.Struct(">HB")
# struct codes of the RTDE types.
TYPE_CODES = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}
VECTOR_SIZES = {"VECTOR3D": 3, "VECTOR6D": 6, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}
_OUTPUT_TYPES = {
    **dict.fromkeys(
        [
            "target_q", "target_qd", "target_qdd", "target_current", "target_moment", "actual_q",
            "actual_qd", "actual_current", "joint_control_output", "actual_TCP_pose",
            "actual_TCP_speed", "actual_TCP_force", "target_TCP_pose", "target_TCP_speed",
            "joint_temperatures", "actual_joint_voltage", "payload_inertia", "ft_raw_wrench",
        ],
        "VECTOR6D",
    ),
    **dict.fromkeys(
        [
            "timestamp", "actual_execution_time", "speed_scaling", "target_speed_fraction",
            "actual_momentum", "actual_main_voltage", "actual_robot_voltage", "actual_robot_current",
            "standard_analog_input0", "standard_analog_input1", "standard_analog_output0",
            "standard_analog_output1", "io_current", "tool_analog_input0", "tool_analog_input1",
            "tool_output_current", "tool_temperature", "tcp_force_scalar", "payload",
        ],
        "DOUBLE",
    ),
    **dict.fromkeys(
        [
            "runtime_state", "robot_status_bits", "safety_status_bits", "analog_io_types",
            "tool_mode", "tool_analog_input_types", "script_control_line",
            "output_bit_registers0_to_31", "output_bit_registers32_to_63",
            "input_bit_registers0_to_31", "input_bit_registers32_to_63",
        ],
        "UINT32",
    ),
    "actual_digital_input_bits": "UINT64",
    "actual_digital_output_bits": "UINT64",
    "robot_mode": "INT32",
    "safety_mode": "INT32",
    "tool_output_voltage": "INT32",
    "joint_mode": "VECTOR6INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "payload_cog": "VECTOR3D",
}  # fmt: skip
_INPUT_TYPES = {
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "external_force_torque": "VECTOR6D",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    **dict.fromkeys(
        [
            "standard_digital_output_mask", "standard_digital_output", "configurable_digital_output_mask",
            "configurable_digital_output", "tool_digital_output_mask", "tool_digital_output",
            "standard_analog_output_mask", "standard_analog_output_type",
        ],
        "UINT8",
    ),
}  # fmt: skip
_REGISTER = re.compile(r"(input|output)_(int|double|bit)_register_(\d+)$")
_REGISTER_TYPES = {"int": "INT32", "double": "DOUBLE", "bit": "BOOL"}


class PortBusyError(OSError):
    """A port the loopback controller needs is already taken."""


def _register_type(name: str) -> str | None:
    """RTDE type of a general purpose register name (CB3 3.9+ ranges), or None."""
    match = _REGISTER.match(name)
    if match is None:
        return None
    kind, index = match.group(2), int(match.group(3))
    valid = 64 <= index <= 127 if kind == "bit" else 0 <= index <= 47
    return _REGISTER_TYPES[kind] if valid else None


def output_type(name: str) -> str | None:
    """RTDE type of an output variable (the controller's state, readable registers), or None."""
    return _OUTPUT_TYPES.get(name) or _INPUT_TYPES.get(name) or _register_type(name)


def input_type(name: str) -> str | None:
    """RTDE type of an input variable a client may write, or None."""
    if name.startswith("output_"):
        return None
    return _INPUT_TYPES.get(name) or _register_type(name)


def pose_vector(T: np.ndarray) -> np.ndarray:
    """UR pose [x, y, z, rx, ry, rz] (metres, rotation vector in radians) of a (4, 4) pose."""
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])


def pose_matrix(pose: np.ndarray) -> np.ndarray:
    """(4, 4) pose of a UR pose vector [x, y, z, rx, ry, rz]."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.asarray(pose[3:6], dtype=float)).as_matrix()
    T[:3, 3] = pose[:3]
    return T


class Profile:
    """Scalar motion s(t) along a path, in controller time: segments of constant acceleration.

    segments: (t_begin, s_begin, v_begin, acceleration) in order; the motion ends at t_end, s_end.
    """

    def __init__(self, segments: list[tuple[float, float, float, float]], t_end: float, s_end: float):
        self.segments = segments
        self.t_end = t_end
        self.s_end = s_end

    @classmethod
    def trapezoid(cls, length: float, speed: float, acceleration: float, t0: float) -> Profile:
        """Accelerate, cruise at ``speed``, decelerate over ``length`` (a triangle when short)."""
        t_acc = speed / acceleration
        if acceleration * t_acc**2 >= length:
            t_acc = np.sqrt(length / acceleration)
            speed = acceleration * t_acc
        t_cruise = (length - acceleration * t_acc**2) / speed if speed > 0 else 0.0
        s_acc = 0.5 * acceleration * t_acc**2
        segments = [
            (t0, 0.0, 0.0, acceleration),
            (t0 + t_acc, s_acc, speed, 0.0),
            (t0 + t_acc + t_cruise, length - s_acc, speed, -acceleration),
        ]
        return cls(segments, t0 + 2 * t_acc + t_cruise, length)

    def at(self, t: float) -> tuple[float, float]:
        """Path position s and speed ds/dt at controller time t."""
        if t >= self.t_end:
            return self.s_end, 0.0
        t_begin, s_begin, v_begin, acceleration = self.segments[0]
        for segment in self.segments[1:]:
            if t < segment[0]:
                break
            t_begin, s_begin, v_begin, acceleration = segment
        tau = max(t - t_begin, 0.0)
        s = s_begin + v_begin * tau + 0.5 * acceleration * tau**2
        return min(s, self.s_end), v_begin + acceleration * tau

    def stopped(self, t: float, deceleration: float) -> Profile:
        """This motion braking from time t at ``deceleration``."""
        s, v = self.at(t)
        if v <= 0 or deceleration <= 0:
            return Profile([(t, s, 0.0, 0.0)], t, s)
        t_stop = v / deceleration
        s_stop = min(s + 0.5 * v * t_stop, self.s_end)
        return Profile([(t, s, v, -deceleration)], t + t_stop, s_stop)


# Joints (6,) at path position s, from the seed joints; None when IK finds no solution.
PathFunction = Callable[[float, np.ndarray], np.ndarray | None]


class Move:
    """A move along a path of length ``length`` (radians of the leading joint for joint
    moves, metres or radians of the TCP for linear ones) following ``profile``."""

    def __init__(self, name: str, length: float, profile: Profile, q_at: PathFunction):
        self.name = name
        self.length = length
        self.profile = profile
        self.q_at = q_at
        self.limit = length  # where an obstruction stops it
        self.limit_protective_stop = False
