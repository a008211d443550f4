"""The loopback controller's emulation of ur_rtde's control script (its register protocol), its
dashboard server and its RTDE outputs, as a part of the controller class (rtde_controller)."""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from hec.estimator.geometry.kinematics import forward, jacobian, solve_ik
from hec.rehearsal.rtde_protocol import (
    COMMAND_NAMES,
    DONE,
    JOINT_MODE_RUNNING,
    READY,
    REALTIME_COMMANDS,
    ROBOT_MODE_IDLE,
    ROBOT_MODE_POWER_OFF,
    ROBOT_MODE_RUNNING,
    ROBOT_STATUS_BIT_POWER_ON,
    ROBOT_STATUS_BIT_PROGRAM_RUNNING,
    RUNTIME_PAUSED,
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    SAFETY_BIT_NORMAL,
    SAFETY_MODE_NORMAL,
    SAFETY_MODE_PROTECTIVE_STOP,
    SAFETY_MODE_ROBOT_EMERGENCY_STOP,
    VECTOR_SIZES,
    output_type,
    pose_matrix,
    pose_vector,
)


class ScriptEmulation:
    """The control script, dashboard and outputs of ``rtde_controller.Controller`` (which holds the
    state these methods read and write)."""

    # --- the emulated control script -------------------------------------------------------------

    def program_received(self, text: str) -> None:
        name = re.match(r"(?:def|sec)\s+(\w+)", text)
        if name is None or name.group(1) != "rtde_control":
            shown = text.strip().splitlines()[0][:80] if text.strip() else ""
            self.end_program(f"cannot run URScript {shown!r}: only ur_rtde's control script is emulated")
            return
        if self.safety_mode != SAFETY_MODE_NORMAL or self.robot_mode != ROBOT_MODE_RUNNING:
            self.event("rtde_control: not started, the robot is not ready (safety stop or power off)")
            return
        offset = re.search(r"# int register offset\n(\d+)", text)
        self.register_offset = int(offset.group(1)) if offset else 0
        self.halt_motion()
        self.program_name = name.group(1)
        self.runtime_state = RUNTIME_PLAYING
        self.executing_command = False
        self.waiting_for = None
        self.async_move = None
        self.write_async_progress(-1)
        self.write_int(0, READY)
        self.event("rtde_control: program started")

    def end_program(self, reason: str) -> None:
        if self.runtime_state != RUNTIME_STOPPED:
            self.event(f"program stopped: {reason}")
        else:
            self.event(reason)
        self.runtime_state = RUNTIME_STOPPED
        self.waiting_for = None
        self.async_move = None
        self.teach_mode = False  # freedrive ends with the program

    def runtime_error(self, message: str) -> None:
        """A script runtime error: the controller stops the program."""
        self.halt_motion()
        self.end_program(f"runtime error: {message}")

    def read_int(self, index: int) -> int:
        return int(self.inputs.get(f"input_int_register_{index + self.register_offset}", 0))

    def read_double(self, index: int) -> float:
        return float(self.inputs.get(f"input_double_register_{index + self.register_offset}", 0.0))

    def read_vector(self, index: int) -> np.ndarray:
        return np.array([self.read_double(index + i) for i in range(6)])

    def write_int(self, index: int, value: int) -> None:
        self.outputs[f"output_int_register_{index + self.register_offset}"] = int(value)

    def write_vector(self, index: int, values: np.ndarray) -> None:
        for i, value in enumerate(values):
            self.outputs[f"output_double_register_{index + i + self.register_offset}"] = float(value)

    def write_async_progress(self, value: int) -> None:
        """The script's async progress register: op id, write count, running bit, progress."""
        self.async_write_count = (self.async_write_count + 1) % 128
        if value == 0:
            self.async_operation_id = (self.async_operation_id + 1) % 128
        register = self.async_write_count * 65536 + self.async_operation_id * 16777216
        if value >= 0:
            register += min(value, 32767) + 32768
        self.write_int(2, register)

    def step_program(self) -> None:
        """One pass of the control script's main loop (it runs once per control cycle)."""
        if self.async_move is not None and self.async_move is not self.move and self.pending is None:
            self.async_move = None
            self.write_async_progress(-1)
        if self.runtime_state != RUNTIME_PLAYING:
            return
        if self.waiting_for is not None:
            if not self.waiting_for():
                return
            self.waiting_for = None
            self.write_int(0, DONE)
            return
        command = self.read_int(0)
        if command in REALTIME_COMMANDS:
            self.process(command)
            if self.runtime_state == RUNTIME_PLAYING:
                self.write_int(0, READY)
        elif command == 0:
            self.executing_command = False
            self.write_int(0, READY)
        elif not self.executing_command:
            self.executing_command = True
            self.process(command)
            if self.runtime_state == RUNTIME_PLAYING and self.waiting_for is None and command != 255:
                self.write_int(0, DONE)

    def process(self, command: int) -> None:
        name = COMMAND_NAMES.get(command)
        self.received_commands.append(name or str(command))
        if name is None:
            self.runtime_error(f"command {command} of ur_rtde's control script is not emulated")
            return
        self.event(name)
        if command in (1, 2, 3, 4):
            self.process_move(command, name)
        elif command == 17:
            self.payload = (self.read_double(0), [self.read_double(i) for i in (1, 2, 3)])
        elif command in (18, 52):
            self.halt_motion()
            self.teach_mode = True
        elif command in (19, 53):
            self.teach_mode = False
        elif command == 29:
            self.T_flange_tcp = pose_matrix(self.read_vector(0))
        elif command == 31:
            self.cmd_protective_stop()
        elif command in (33, 34):
            self.process_stop()
        elif command == 40:
            self.write_vector(0, pose_vector(self.T_flange_tcp))
        elif command == 47:
            self.write_int(1, 0 if self.moving() else 1)
        elif command == 255:
            self.halt_motion()
            self.end_program("rtde_control: stop script received")

    def process_move(self, command: int, name: str) -> None:
        if self.async_move is not None:  # the script kills its move thread first
            self.async_move = None
            self.write_async_progress(-1)
        target = self.read_vector(0)
        speed, acceleration = self.read_double(6), self.read_double(7)
        asynchronous = self.read_int(1) == 1
        if command == 1:
            move = self.joint_move(name, target, speed, acceleration)
        elif command == 2:
            result = solve_ik(
                self.kinematics, pose_matrix(target) @ np.linalg.inv(self.T_flange_tcp), self.q_setpoint
            )
            if not result.converged:
                self.runtime_error(f"{name}: no inverse kinematics solution for the target pose")
                return
            move = self.joint_move(name, result.q, speed, acceleration)
        else:
            T_base_tcp = (
                pose_matrix(target) if command == 3 else forward(self.kinematics, target) @ self.T_flange_tcp
            )
            move = self.linear_move(name, T_base_tcp, speed, acceleration)
        if move is None:
            return
        if asynchronous:
            self.async_move = move
            self.write_async_progress(0)
        else:
            self.waiting_for = lambda: self.move is not move and self.pending is None

    def process_stop(self) -> None:
        deceleration = self.read_double(0)
        self.brake(deceleration)
        if self.read_int(1) != 1:
            move = self.move
            self.waiting_for = lambda: move is None or (self.move is not move and self.pending is None)

    # --- dashboard ---------------------------------------------------------------------------

    def dashboard(self, request: str) -> str:
        """Answer one dashboard command the way a CB3 dashboard server words it."""
        major, minor, bugfix, build = self.config.controller_version
        key = request.lower()
        runtime = {RUNTIME_STOPPED: "STOPPED", RUNTIME_PLAYING: "PLAYING", RUNTIME_PAUSED: "PAUSED"}
        robot_modes = {
            ROBOT_MODE_POWER_OFF: "POWER_OFF",
            ROBOT_MODE_IDLE: "IDLE",
            ROBOT_MODE_RUNNING: "RUNNING",
        }
        safety = {
            SAFETY_MODE_NORMAL: "NORMAL",
            SAFETY_MODE_PROTECTIVE_STOP: "PROTECTIVE_STOP",
            SAFETY_MODE_ROBOT_EMERGENCY_STOP: "ROBOT_EMERGENCY_STOP",
        }
        if key == "polyscopeversion":
            return f"URSoftware {major}.{minor}.{bugfix}.{build} (loopback)"
        if key == "robotmode":
            return f"Robotmode: {robot_modes[self.robot_mode]}"
        if key in ("safetymode", "safetystatus"):
            return f"{key.capitalize()}: {safety[self.safety_mode]}"
        if key == "programstate":
            return f"{runtime[self.runtime_state]} {self.program_name}"
        if key == "running":
            return f"Program running: {str(self.runtime_state == RUNTIME_PLAYING).lower()}"
        if key == "stop":
            self.halt_motion()
            self.end_program("dashboard: stop")
            return "Stopped"
        if key == "pause":
            if self.runtime_state == RUNTIME_PLAYING:
                self.halt_motion()
                self.runtime_state = RUNTIME_PAUSED
            return "Pausing program"
        if key == "play":
            if self.runtime_state == RUNTIME_PAUSED and self.safety_mode == SAFETY_MODE_NORMAL:
                self.runtime_state = RUNTIME_PLAYING
                return "Starting program"
            return "Failed to execute: play"
        if key == "unlock protective stop":
            if self.safety_mode != SAFETY_MODE_PROTECTIVE_STOP:
                return "Cannot unlock protective stop: the robot is not protective stopped"
            self.safety_mode, self.safety_bits = SAFETY_MODE_NORMAL, 1 << SAFETY_BIT_NORMAL
            return "Protective stop releasing"
        if key == "power on":
            if self.safety_mode == SAFETY_MODE_ROBOT_EMERGENCY_STOP:
                return "Failed to execute: power on"
            self.robot_mode = max(self.robot_mode, ROBOT_MODE_IDLE)
            return "Powering on"
        if key == "brake release":
            if self.robot_mode != ROBOT_MODE_IDLE:
                return "Failed to execute: brake release"
            self.robot_mode = ROBOT_MODE_RUNNING
            return "Brake releasing"
        if key == "power off":
            self.halt_motion()
            self.robot_mode = ROBOT_MODE_POWER_OFF
            self.end_program("dashboard: power off")
            return "Powering off"
        simple = {
            "close popup": "closing popup",
            "close safety popup": "closing safety popup",
            "get robot model": self.kinematics.name.upper().removesuffix("E"),
            "get loaded program": f"Loaded program: {self.program_name}",
            "is in remote control": "true",
            "get serial number": "20000000000",
            "isprogramsaved": f"true {self.program_name}",
            "quit": "Disconnected",
        }
        return simple.get(key, f"could not understand: '{request}'")

    # --- RTDE outputs --------------------------------------------------------------------------

    def output_value(self, name: str, t: float, cache: dict[str, Any]) -> Any:
        """Value of an output variable now; ``cache`` holds what this tick already computed."""
        if name in cache:
            return cache[name]
        value = self.compute_output(name, t)
        cache[name] = value
        return value

    def compute_output(self, name: str, t: float) -> Any:
        zeros6 = [0.0] * 6
        if name == "timestamp":
            return t
        if name == "actual_q":
            return list(self.q_actual)
        if name == "actual_qd":
            return list(self.qd_actual)
        if name == "target_q":
            return list(self.q_setpoint)
        if name == "target_qd":
            return list(self.qd_setpoint if self.moving() else np.zeros(6))
        if name == "actual_TCP_pose":
            return list(pose_vector(self.T_base_flange @ self.T_flange_tcp))
        if name == "target_TCP_pose":
            return list(pose_vector(forward(self.kinematics, self.q_setpoint) @ self.T_flange_tcp))
        if name == "actual_TCP_speed":
            return list(self.tcp_speed(self.q_actual, self.qd_actual))
        if name == "target_TCP_speed":
            return list(self.tcp_speed(self.q_setpoint, self.qd_setpoint if self.moving() else np.zeros(6)))
        if name == "robot_mode":
            return self.robot_mode
        if name == "safety_mode":
            return self.safety_mode
        if name == "safety_status_bits":
            return self.safety_bits
        if name == "runtime_state":
            return self.runtime_state
        if name == "robot_status_bits":
            power = self.robot_mode >= ROBOT_MODE_IDLE
            playing = self.runtime_state == RUNTIME_PLAYING
            return (power << ROBOT_STATUS_BIT_POWER_ON) | (playing << ROBOT_STATUS_BIT_PROGRAM_RUNNING)
        if name == "joint_mode":
            return [JOINT_MODE_RUNNING] * 6
        if name in ("speed_scaling", "target_speed_fraction"):
            return 1.0
        if name == "payload":
            return self.payload[0]
        if name == "payload_cog":
            return self.payload[1]
        if name in ("actual_main_voltage", "actual_robot_voltage"):
            return 48.0
        if name == "joint_temperatures":
            return [30.0] * 6
        if name == "actual_tool_accelerometer":
            return [0.0, 0.0, 9.81]
        rtde_type = output_type(name)
        if name in self.outputs or name in self.inputs:
            return self.outputs.get(name, self.inputs.get(name))
        if rtde_type in VECTOR_SIZES:
            return zeros6[: VECTOR_SIZES[rtde_type]]
        return False if rtde_type == "BOOL" else 0

    def tcp_speed(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """TCP twist [vx, vy, vz, wx, wy, wz] in the base frame (m/s, rad/s) for joint speeds qd."""
        if not np.any(qd):
            return np.zeros(6)
        twist = jacobian(self.kinematics, q) @ qd
        T_base_flange = forward(self.kinematics, q)
        lever = T_base_flange[:3, :3] @ self.T_flange_tcp[:3, 3]
        return np.concatenate([twist[:3] + np.cross(twist[3:], lever), twist[3:]])
