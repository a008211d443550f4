"""A loopback UR controller for tests: the real ur_rtde clients talk to a simulated arm.

URSim cannot run here, so this module serves, on one loopback address, the
ports ur_rtde 1.6.5 uses: RTDE (30004), the dashboard (29999) and the script
port (30003). It does not run URScript. When RTDEControlInterface uploads its
control script, the controller emulates that script's register protocol:
the client writes a command number into input_int_register_0 and its
arguments into the other input registers; the script answers in
output_int_register_0 (1 ready, 2 done) and returns values in the output
registers. The commands emulated are listed in ``_COMMAND_NAMES``; any other
one halts the program, as a script runtime error would.

The arm is a ``hec.sim.cell.SimCell``. ur_rtde's constructors hold the GIL while
they wait for the controller, so the controller cannot be a thread of the
test process: it runs in a child process, and a bridge thread here applies
each joint setpoint to the SimCell (under the lock the caller gives) and
sends back ``cell.joints`` and ``cell.true_flange_pose()``. What the clients
read as actual_q and actual_TCP_pose is therefore what the SimCell holds.

Usage::

    with LoopbackController(cell, lock, speedup=4.0) as controller:
        rtde_c = rtde_control.RTDEControlInterface(controller.host)
        rtde_r = rtde_receive.RTDEReceiveInterface(controller.host)
        ...
        controller.protective_stop()

Construct the ur_rtde clients after ``start()`` and disconnect them before
``close()``. The ports are fixed by ur_rtde; ``start()`` fails with
``PortBusyError`` when one of them is taken on the chosen address (any
127.x.y.z works, so parallel controllers can use different addresses).
"""

from __future__ import annotations

import collections
import dataclasses
import multiprocessing
import re
import selectors
import socket
import struct
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial.transform import Rotation

from hec.estimator.geometry.kinematics import URKinematics, forward, jacobian, solve_ik

if TYPE_CHECKING:
    from hec.sim.cell import SimCell

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
_JOINT_MODE_RUNNING = 253

# Control script handshake values in output_int_register_0.
_READY, _DONE = 1, 2
# Command numbers of ur_rtde's control script that this controller emulates.
_COMMAND_NAMES = {
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
_REALTIME_COMMANDS = {6, 9, 10, 11, 24, 25, 26, 27, 38, 58}

# RTDE message types.
_RTDE_PROTOCOL_VERSION, _RTDE_CONTROLLER_VERSION = ord("V"), ord("v")
_RTDE_DATA, _RTDE_SETUP_OUTPUTS, _RTDE_SETUP_INPUTS = ord("U"), ord("O"), ord("I")
_RTDE_START, _RTDE_PAUSE = ord("S"), ord("P")
_RTDE_HEADER = struct.Struct(">HB")
# struct codes of the RTDE types.
_TYPE_CODES = {
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
_VECTOR_SIZES = {"VECTOR3D": 3, "VECTOR6D": 6, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}
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


# --- the parent side --------------------------------------------------------------------------


class LoopbackController:
    """A UR controller on a loopback address whose arm is ``cell``.

    cell: the simulated arm; the controller moves it with ``cell.set_joints``.
    lock: guards ``cell``; held around every read and write the controller makes.
    host: loopback address to serve on (ports 30004, 29999 and 30003 are fixed by ur_rtde).
    speedup: controller time runs this many times faster than wall time, so moves finish
        sooner; speeds, accelerations and timestamps are in controller time.
    controller_version: (major, minor, bugfix, build) reported over RTDE; major 3 is a CB3
        (125 Hz), major 5 an e-Series (500 Hz).
    """

    def __init__(
        self,
        cell: SimCell,
        lock: threading.Lock,
        *,
        host: str = "127.0.0.1",
        speedup: float = 1.0,
        controller_version: tuple[int, int, int, int] = DEFAULT_CONTROLLER_VERSION,
    ) -> None:
        if speedup <= 0:
            raise ValueError(f"speedup must be positive, got {speedup}")
        self.cell = cell
        self.lock = lock
        self.host = host
        self.speedup = float(speedup)
        self.controller_version = controller_version
        self._process: multiprocessing.process.BaseProcess | None = None
        self._commands: Connection | None = None
        self._arm: Connection | None = None
        self._call_lock = threading.Lock()
        self._arm_send_lock = threading.Lock()
        self._bridge: threading.Thread | None = None
        self._stop_bridge = threading.Event()
        self._reported_q: np.ndarray | None = None

    def __enter__(self) -> LoopbackController:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self, timeout_s: float = 30.0) -> LoopbackController:
        """Start the controller process and bind its ports; return when it accepts clients."""
        if self._process is not None:
            raise RuntimeError("the loopback controller is already started")
        with self.lock:
            q = self.cell.joints.copy()
            T_base_flange = self.cell.true_flange_pose()
        config = _Config(
            host=self.host,
            kinematics=self.cell.cell.kinematics,
            q=q,
            T_base_flange=T_base_flange,
            speedup=self.speedup,
            controller_version=self.controller_version,
        )
        context = multiprocessing.get_context("spawn")
        self._commands, child_commands = context.Pipe()
        self._arm, child_arm = context.Pipe()
        self._reported_q = q
        self._process = context.Process(
            target=_controller_main, args=(config, child_commands, child_arm), daemon=True
        )
        self._process.start()
        child_commands.close()
        child_arm.close()
        try:
            if not self._commands.poll(timeout_s):
                raise TimeoutError(f"the loopback controller did not start within {timeout_s} s")
            status, detail = self._commands.recv()
        except EOFError:
            self._process.join(5.0)
            code = self._process.exitcode
            self.close()
            raise RuntimeError(
                f"the loopback controller process died at start-up (exit code {code})"
            ) from None
        except BaseException:
            self.close()
            raise
        if status != "ready":
            self.close()
            raise PortBusyError(detail) if status == "port busy" else RuntimeError(detail)
        self._bridge = threading.Thread(
            target=self._run_bridge, name=f"rtde-loopback-bridge-{self.host}", daemon=True
        )
        self._bridge.start()
        return self

    def close(self) -> None:
        """Stop the controller: close every socket, end the process and the bridge thread."""
        if self._process is not None:
            if self._process.is_alive():
                try:
                    self._call("shutdown", timeout_s=5.0)
                except (OSError, EOFError, TimeoutError, RuntimeError):
                    pass
            self._process.join(5.0)
            if self._process.is_alive():
                self._process.kill()
                self._process.join(5.0)
            self._process = None
        self._stop_bridge.set()
        if self._bridge is not None:
            self._bridge.join(5.0)
            self._bridge = None
        for connection in (self._commands, self._arm):
            if connection is not None:
                connection.close()
        self._commands = self._arm = None
        self._stop_bridge.clear()

    # --- fault injection and test hooks -------------------------------------------------------

    def protective_stop(self) -> None:
        """Protective stop: motion halts where it is and the program pauses."""
        self._call("protective_stop")

    def emergency_stop(self) -> None:
        """Emergency stop (robot e-stop button): motion halts, the program stops, arm power off."""
        self._call("emergency_stop")

    def release_emergency_stop(self) -> None:
        """Release the e-stop button; the arm stays powered off until the dashboard powers it on."""
        self._call("release_emergency_stop")

    def drop_connections(self, refuse: bool = True) -> None:
        """Close every client connection at once (the clients read end of file).

        refuse: the link stays down: new connections are refused until
            ``restore_connections()``. With False the controller stays reachable; beware that
            RTDEControlInterface 1.6.5 then reconnects from its receive thread, tears the new
            connection down again, loops, and crashes the process within seconds.
        """
        self._call("drop_connections", refuse)

    def restore_connections(self) -> None:
        """Accept connections again after ``drop_connections()``."""
        self._call("restore_connections")

    def obstruct_next_move(self, fraction: float, protective_stop: bool = False) -> None:
        """Make the next move stop at ``fraction`` (0..1) of its path.

        protective_stop: trigger a protective stop there (a collision); otherwise the move
            simply ends short and the program reports it done.
        """
        if not 0.0 <= fraction <= 1.0:
            raise ValueError(f"fraction must be in [0, 1], got {fraction}")
        self._call("obstruct_next_move", float(fraction), protective_stop)

    def hand_guide(self, q: np.ndarray) -> None:
        """Move the arm by hand to joints q (6,), radians; only in teach or freedrive mode."""
        q = np.asarray(q, dtype=float)
        self._call("check_hand_guide", q)
        with self._arm_send_lock:
            self._report(*self._apply(q))

    def status(self) -> dict[str, Any]:
        """The controller's state: modes, program, motion, TCP offset, received commands."""
        return self._call("status")

    # --- internals ---------------------------------------------------------------------------

    def _call(self, name: str, *args: object, timeout_s: float = 5.0) -> Any:
        if self._commands is None:
            raise RuntimeError("the loopback controller is not started")
        with self._call_lock:
            self._commands.send((name, args))
            if not self._commands.poll(timeout_s):
                raise TimeoutError(f"the loopback controller did not answer {name!r} within {timeout_s} s")
            ok, result = self._commands.recv()
        if not ok:
            raise RuntimeError(result)
        return result

    def _apply(self, q: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Set the cell's joints to q (unless None); return its joints and T_base_flange."""
        with self.lock:
            if q is not None:
                self.cell.set_joints(q)
            return self.cell.joints.copy(), self.cell.true_flange_pose()

    def _report(self, q: np.ndarray, T_base_flange: np.ndarray, seq: int | None = None) -> None:
        assert self._arm is not None
        self._arm.send(("actual", seq, q, T_base_flange))
        self._reported_q = q

    def _run_bridge(self) -> None:
        """Apply the controller's setpoints to the cell; report the cell's state back."""
        assert self._arm is not None
        try:
            while not self._stop_bridge.is_set():
                if self._arm.poll(0.02):
                    _, seq, q = self._arm.recv()
                    with self._arm_send_lock:
                        self._report(*self._apply(q), seq)
                    continue
                # Someone else moved the cell (cell.set_joints): let the controller see it.
                with self._arm_send_lock:
                    q_now, T_now = self._apply(None)
                    if not np.array_equal(q_now, self._reported_q):
                        self._report(q_now, T_now)
        except (EOFError, OSError):
            pass  # the controller process has ended


# --- the controller process ---------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _Config:
    host: str
    kinematics: URKinematics
    q: np.ndarray
    T_base_flange: np.ndarray
    speedup: float
    controller_version: tuple[int, int, int, int]


def _controller_main(config: _Config, commands: Connection, arm: Connection) -> None:
    """Entry point of the controller process."""
    try:
        controller = _Controller(config, commands, arm)
    except PortBusyError as error:
        commands.send(("port busy", str(error)))
        return
    except Exception as error:  # report any start-up failure to the parent
        commands.send(("error", f"{type(error).__name__}: {error}"))
        return
    commands.send(("ready", None))
    controller.run()


class _Profile:
    """Scalar motion s(t) along a path, in controller time: segments of constant acceleration.

    segments: (t_begin, s_begin, v_begin, acceleration) in order; the motion ends at t_end, s_end.
    """

    def __init__(self, segments: list[tuple[float, float, float, float]], t_end: float, s_end: float):
        self.segments = segments
        self.t_end = t_end
        self.s_end = s_end

    @classmethod
    def trapezoid(cls, length: float, speed: float, acceleration: float, t0: float) -> _Profile:
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

    def stopped(self, t: float, deceleration: float) -> _Profile:
        """This motion braking from time t at ``deceleration``."""
        s, v = self.at(t)
        if v <= 0 or deceleration <= 0:
            return _Profile([(t, s, 0.0, 0.0)], t, s)
        t_stop = v / deceleration
        s_stop = min(s + 0.5 * v * t_stop, self.s_end)
        return _Profile([(t, s, v, -deceleration)], t + t_stop, s_stop)


# Joints (6,) at path position s, from the seed joints; None when IK finds no solution.
_PathFunction = Callable[[float, np.ndarray], np.ndarray | None]


class _Move:
    """A move along a path of length ``length`` (radians of the leading joint for joint
    moves, metres or radians of the TCP for linear ones) following ``profile``."""

    def __init__(self, name: str, length: float, profile: _Profile, q_at: _PathFunction):
        self.name = name
        self.length = length
        self.profile = profile
        self.q_at = q_at
        self.limit = length  # where an obstruction stops it
        self.limit_protective_stop = False


class _Session:
    """A client connection with non-blocking buffered output."""

    # A client that lets this much output pile up is dropped, as the real controller does.
    MAX_PENDING_BYTES = 1 << 20

    def __init__(self, controller: _Controller, sock: socket.socket, port: int) -> None:
        self.controller = controller
        self.sock = sock
        self.port = port
        self.inbox = bytearray()
        self.outbox = bytearray()
        self.closed = False

    def on_open(self) -> None:
        """Called once the session is registered with the selector."""

    def send(self, data: bytes) -> None:
        if self.closed:
            return
        self.outbox += data
        self.flush()

    def flush(self) -> None:
        try:
            while self.outbox:
                sent = self.sock.send(self.outbox)
                del self.outbox[:sent]
        except BlockingIOError:
            if len(self.outbox) > self.MAX_PENDING_BYTES:
                self.controller.event(f"port {self.port}: client does not read, dropping it")
                self.controller.close_session(self)
                return
        except OSError:
            self.controller.close_session(self)
            return
        self.controller.watch_writes(self, bool(self.outbox))

    def on_readable(self) -> None:
        try:
            data = self.sock.recv(65536)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self.controller.close_session(self)
            return
        self.inbox += data
        self.on_data()

    def on_data(self) -> None:
        raise NotImplementedError


class _RtdeSession(_Session):
    """One RTDE client (protocol version 2)."""

    def __init__(self, controller: _Controller, sock: socket.socket, port: int) -> None:
        super().__init__(controller, sock, port)
        self.output_names: list[str] = []
        self.output_struct: struct.Struct | None = None
        self.period_s = 1.0
        self.credit_s = 0.0
        self.started = False
        self.input_recipes: dict[int, tuple[list[str], list[str], struct.Struct]] = {}

    def reply(self, message_type: int, payload: bytes) -> None:
        self.send(_RTDE_HEADER.pack(_RTDE_HEADER.size + len(payload), message_type) + payload)

    def on_data(self) -> None:
        while len(self.inbox) >= _RTDE_HEADER.size and not self.closed:
            size, message_type = _RTDE_HEADER.unpack_from(self.inbox)
            if size < _RTDE_HEADER.size:
                self.controller.event("RTDE: malformed header, dropping the client")
                self.controller.close_session(self)
                return
            if len(self.inbox) < size:
                return
            payload = bytes(self.inbox[_RTDE_HEADER.size : size])
            del self.inbox[:size]
            self.handle(message_type, payload)

    def handle(self, message_type: int, payload: bytes) -> None:
        if message_type == _RTDE_DATA:
            self.receive_inputs(payload)
        elif message_type == _RTDE_PROTOCOL_VERSION:
            (version,) = struct.unpack(">H", payload[:2])
            self.reply(message_type, bytes([version == 2]))
        elif message_type == _RTDE_CONTROLLER_VERSION:
            self.reply(message_type, struct.pack(">4I", *self.controller.config.controller_version))
        elif message_type == _RTDE_SETUP_OUTPUTS:
            self.setup_outputs(payload)
        elif message_type == _RTDE_SETUP_INPUTS:
            self.setup_inputs(payload)
        elif message_type == _RTDE_START:
            self.started = self.output_struct is not None
            self.credit_s = self.period_s
            self.reply(message_type, bytes([self.started]))
        elif message_type == _RTDE_PAUSE:
            self.started = False
            self.reply(message_type, b"\x01")
        else:
            self.controller.event(f"RTDE: ignored message type {message_type}")

    def setup_outputs(self, payload: bytes) -> None:
        (frequency,) = struct.unpack(">d", payload[:8])
        names = [name for name in payload[8:].decode("ascii").split(",") if name]
        types = [output_type(name) or "NOT_FOUND" for name in names]
        valid = bool(names) and "NOT_FOUND" not in types and frequency > 0
        if valid:
            self.output_names = names
            self.output_struct = struct.Struct(">B" + "".join(_TYPE_CODES[t] for t in types))
            # The controller cannot stream faster than its control loop.
            self.period_s = 1.0 / min(frequency, self.controller.max_frequency_hz)
        self.reply(_RTDE_SETUP_OUTPUTS, bytes([1 if valid else 0]) + ",".join(types).encode("ascii"))

    def setup_inputs(self, payload: bytes) -> None:
        names = [name for name in payload.decode("ascii").split(",") if name]
        types = [input_type(name) or "NOT_FOUND" for name in names]
        owners = self.controller.input_owners
        types = [
            "IN_USE" if owners.get(name, self) is not self else t
            for name, t in zip(names, types, strict=True)
        ]
        if names and all(t in _TYPE_CODES for t in types):
            recipe_id = len(self.input_recipes) + 1
            self.input_recipes[recipe_id] = (
                names,
                types,
                struct.Struct(">B" + "".join(_TYPE_CODES[t] for t in types)),
            )
            for name in names:
                owners[name] = self
        else:
            recipe_id = 0
        self.reply(_RTDE_SETUP_INPUTS, bytes([recipe_id]) + ",".join(types).encode("ascii"))

    def receive_inputs(self, payload: bytes) -> None:
        recipe = self.input_recipes.get(payload[0]) if payload else None
        if recipe is None or recipe[2].size != len(payload):
            self.controller.event(f"RTDE: ignored input package of {len(payload)} bytes")
            return
        names, types, layout = recipe
        values = layout.unpack(payload)[1:]
        position = 0
        for name, rtde_type in zip(names, types, strict=True):
            count = _VECTOR_SIZES.get(rtde_type, 1)
            value = values[position : position + count]
            self.controller.inputs[name] = list(value) if count > 1 else value[0]
            position += count

    def stream(self, tick_s: float, values: Callable[[str], Any]) -> None:
        """Called every control tick of tick_s seconds: send a data package if one is due."""
        if not self.started or self.output_struct is None:
            return
        self.credit_s += tick_s
        if self.credit_s < self.period_s - 1e-9:
            return
        self.credit_s = min(self.credit_s - self.period_s, self.period_s)
        fields: list[Any] = [1]
        for name in self.output_names:
            value = values(name)
            if isinstance(value, list | tuple | np.ndarray):
                fields.extend(value)
            else:
                fields.append(value)
        self.reply(_RTDE_DATA, self.output_struct.pack(*fields))


class _DashboardSession(_Session):
    """One dashboard client: a line in, a line out."""

    def on_open(self) -> None:
        self.send(b"Connected: Universal Robots Dashboard Server\n")

    def on_data(self) -> None:
        while b"\n" in self.inbox and not self.closed:
            line, _, rest = bytes(self.inbox).partition(b"\n")
            self.inbox[:] = rest
            request = line.decode("utf-8", "replace").strip()
            self.send((self.controller.dashboard(request) + "\n").encode("utf-8"))
            if request == "quit":
                self.controller.close_session(self)


class _ScriptSession(_Session):
    """One script client: programs (``def name():`` .. ``end``) or single lines of URScript."""

    def on_data(self) -> None:
        while True:
            text = self.inbox.decode("utf-8", "replace")
            stripped = text.lstrip()
            if not stripped:
                self.inbox.clear()
                return
            if re.match(r"(def|sec)\s", stripped):
                end = re.search(r"^end[ \t]*\r?$\n?", stripped, re.MULTILINE)
                if end is None:
                    return
                program = stripped[: end.end()]
            elif "\n" in stripped:
                program = stripped[: stripped.index("\n") + 1]
            else:
                return
            self.inbox[:] = stripped[len(program) :].encode("utf-8")
            self.controller.program_received(program)


class _Controller:
    """The controller process: sockets, the emulated control script and the arm's motion.

    Everything runs on one thread: a selector loop with a control tick at the RTDE rate.
    """

    def __init__(self, config: _Config, commands: Connection, arm: Connection) -> None:
        self.config = config
        self.kinematics = config.kinematics
        self.q_lower = np.array(config.kinematics.q_lower)
        self.q_upper = np.array(config.kinematics.q_upper)
        self.max_frequency_hz = 125.0 if config.controller_version[0] <= 3 else 500.0
        self.tick_s = 1.0 / self.max_frequency_hz
        self.commands = commands
        self.arm = arm
        self.selector = selectors.DefaultSelector()
        self.sessions: set[_Session] = set()
        self.listeners: dict[int, socket.socket] = {}
        self.events: collections.deque[str] = collections.deque(maxlen=1000)
        self.received_commands: collections.deque[str] = collections.deque(maxlen=1000)
        self.running = True
        self.t0_wall = time.monotonic()
        # RTDE registers and input ownership.
        self.inputs: dict[str, Any] = {}
        self.outputs: dict[str, Any] = {}
        self.input_owners: dict[str, _RtdeSession] = {}
        # Robot and safety state.
        self.robot_mode = ROBOT_MODE_RUNNING
        self.safety_mode = SAFETY_MODE_NORMAL
        self.safety_bits = 1 << SAFETY_BIT_NORMAL
        self.teach_mode = False
        self.payload = (0.0, [0.0, 0.0, 0.0])
        self.T_flange_tcp = np.eye(4)
        # Program (the emulated control script).
        self.runtime_state = RUNTIME_STOPPED
        self.program_name = "<unnamed>"
        self.register_offset = 0
        self.executing_command = False
        self.waiting_for: Callable[[], bool] | None = None
        self.async_write_count = 0
        self.async_operation_id = 0
        self.async_move: _Move | None = None
        # Arm: the actual state comes from the parent's SimCell; setpoints go there.
        self.q_actual = np.array(config.q, dtype=float)
        self.T_base_flange = np.array(config.T_base_flange, dtype=float)
        self.qd_actual = np.zeros(6)
        self.q_setpoint = self.q_actual.copy()
        self.qd_setpoint = np.zeros(6)
        self.t_setpoint = 0.0
        self.move: _Move | None = None
        self.obstruction: tuple[float, bool] | None = None
        self.pending: tuple[int, np.ndarray, bool] | None = None  # (seq, qd, final) in flight
        self.sequence = 0
        self.open_listeners()
        self.selector.register(commands, selectors.EVENT_READ, self.on_command)
        self.selector.register(arm, selectors.EVENT_READ, self.on_arm)

    # --- event loop --------------------------------------------------------------------------

    def run(self) -> None:
        next_tick = time.monotonic()
        while self.running:
            for key, mask in self.selector.select(max(next_tick - time.monotonic(), 0.0)):
                if isinstance(key.data, _Session):
                    self.on_session_event(key.data, mask)
                else:
                    key.data(key.fileobj)
                if not self.running:
                    break
            now = time.monotonic()
            if now >= next_tick and self.running:
                self.tick(now)
                next_tick = max(next_tick + self.tick_s, now)
        for session in list(self.sessions):
            self.close_session(session)
        self.close_listeners()
        self.selector.close()

    def tick(self, now: float) -> None:
        t = self.controller_time(now)
        self.advance_move(t)
        self.step_program()
        cache: dict[str, Any] = {}
        for session in list(self.sessions):
            if isinstance(session, _RtdeSession):
                session.stream(self.tick_s, lambda name: self.output_value(name, t, cache))

    def controller_time(self, now: float | None = None) -> float:
        return self.config.speedup * ((time.monotonic() if now is None else now) - self.t0_wall)

    def event(self, text: str) -> None:
        self.events.append(f"{self.controller_time():9.3f} {text}")

    # --- sockets -----------------------------------------------------------------------------

    def open_listeners(self) -> None:
        sessions = {RTDE_PORT: _RtdeSession, DASHBOARD_PORT: _DashboardSession, SCRIPT_PORT: _ScriptSession}
        for port, session_type in sessions.items():
            listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                listener.bind((self.config.host, port))
            except OSError as error:
                listener.close()
                self.close_listeners()
                raise PortBusyError(
                    f"cannot serve the loopback UR controller on {self.config.host}:{port}: {error} "
                    "(is another controller, URSim or a test still running?)"
                ) from error
            listener.listen(8)
            listener.setblocking(False)
            self.listeners[port] = listener
            self.selector.register(listener, selectors.EVENT_READ, self.acceptor(port, session_type))

    def close_listeners(self) -> None:
        for listener in self.listeners.values():
            if listener.fileno() >= 0:
                self.selector.unregister(listener)
            listener.close()
        self.listeners.clear()

    def acceptor(self, port: int, session_type: type[_Session]) -> Callable[[socket.socket], None]:
        def accept(listener: socket.socket) -> None:
            try:
                sock, _ = listener.accept()
            except BlockingIOError:
                return
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            session = session_type(self, sock, port)
            self.sessions.add(session)
            self.selector.register(sock, selectors.EVENT_READ, session)
            self.event(f"port {port}: client connected")
            session.on_open()

        return accept

    def on_session_event(self, session: _Session, mask: int) -> None:
        if mask & selectors.EVENT_WRITE and not session.closed:
            session.flush()
        if mask & selectors.EVENT_READ and not session.closed:
            session.on_readable()

    def watch_writes(self, session: _Session, pending: bool) -> None:
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if pending else 0)
        if self.selector.get_key(session.sock).events != events:
            self.selector.modify(session.sock, events, session)

    def close_session(self, session: _Session) -> None:
        if session.closed:
            return
        session.closed = True
        self.sessions.discard(session)
        self.selector.unregister(session.sock)
        try:  # unread input would turn the close into a reset
            while session.sock.recv(65536):
                pass
        except OSError:
            pass
        session.sock.close()
        for name in [name for name, owner in self.input_owners.items() if owner is session]:
            del self.input_owners[name]
        self.event(f"port {session.port}: client gone")

    # --- the parent's requests ---------------------------------------------------------------

    def on_command(self, connection: Connection) -> None:
        try:
            name, args = connection.recv()
        except (EOFError, OSError):
            self.running = False  # the test process has gone
            return
        try:
            result = getattr(self, f"cmd_{name}")(*args)
        except Exception as error:  # the parent re-raises it
            connection.send((False, f"{type(error).__name__}: {error}"))
        else:
            connection.send((True, result))

    def cmd_shutdown(self) -> None:
        self.running = False

    def cmd_status(self) -> dict[str, Any]:
        return {
            "robot_mode": self.robot_mode,
            "safety_mode": self.safety_mode,
            "runtime_state": self.runtime_state,
            "teach_mode": self.teach_mode,
            "moving": self.moving(),
            "T_flange_tcp": self.T_flange_tcp.copy(),
            "clients": sorted(session.port for session in self.sessions),
            "commands": list(self.received_commands),
            "events": list(self.events),
        }

    def cmd_protective_stop(self) -> None:
        self.halt_motion()
        self.safety_mode = SAFETY_MODE_PROTECTIVE_STOP
        self.safety_bits = (1 << SAFETY_BIT_PROTECTIVE_STOPPED) | (1 << SAFETY_BIT_STOPPED_DUE_TO_SAFETY)
        if self.runtime_state == RUNTIME_PLAYING:
            self.runtime_state = RUNTIME_PAUSED
        self.event("protective stop")

    def cmd_emergency_stop(self) -> None:
        self.halt_motion()
        self.safety_mode = SAFETY_MODE_ROBOT_EMERGENCY_STOP
        self.safety_bits = (
            (1 << SAFETY_BIT_ROBOT_EMERGENCY_STOPPED)
            | (1 << SAFETY_BIT_EMERGENCY_STOPPED)
            | (1 << SAFETY_BIT_STOPPED_DUE_TO_SAFETY)
        )
        self.robot_mode = ROBOT_MODE_POWER_OFF
        self.end_program("emergency stop")

    def cmd_release_emergency_stop(self) -> None:
        if self.safety_mode == SAFETY_MODE_ROBOT_EMERGENCY_STOP:
            self.safety_mode = SAFETY_MODE_NORMAL
            self.safety_bits = 1 << SAFETY_BIT_NORMAL

    def cmd_drop_connections(self, refuse: bool) -> None:
        if refuse:  # first, so that no client gets back in before its old connection is gone
            self.close_listeners()
        for session in list(self.sessions):
            self.close_session(session)
        self.event(f"dropped every connection{', refusing new ones' if refuse else ''}")

    def cmd_restore_connections(self) -> None:
        if not self.listeners:
            self.open_listeners()

    def cmd_obstruct_next_move(self, fraction: float, protective_stop: bool) -> None:
        self.obstruction = (fraction, protective_stop)

    def cmd_check_hand_guide(self, q: np.ndarray) -> None:
        if not self.teach_mode:
            raise RuntimeError("hand guiding needs teach or freedrive mode (teachMode() / freedriveMode())")
        if q.shape != (6,) or np.any(q < self.q_lower) or np.any(q > self.q_upper):
            raise ValueError(f"hand-guided joints {q} are not 6 angles within the joint limits")

    # --- the arm -------------------------------------------------------------------------------

    def on_arm(self, connection: Connection) -> None:
        """The parent's report of the cell: ("actual", seq or None, q, T_base_flange)."""
        try:
            _, seq, q, T_base_flange = connection.recv()
        except (EOFError, OSError):
            self.running = False
            return
        self.q_actual, self.T_base_flange = q, T_base_flange
        if seq is None:  # moved from outside (hand guiding, cell.set_joints)
            self.qd_actual = np.zeros(6)
            if self.move is None and self.pending is None:
                self.q_setpoint = q.copy()
            return
        if self.pending is not None and self.pending[0] == seq:
            _, qd, final = self.pending
            self.pending = None
            self.qd_actual = qd if self.move is not None else np.zeros(6)
            if final and self.move is not None:
                self.finish_move()

    def send_setpoint(self, q: np.ndarray, qd: np.ndarray, t: float, final: bool) -> None:
        self.sequence += 1
        self.pending = (self.sequence, qd, final)
        self.q_setpoint, self.qd_setpoint, self.t_setpoint = q, qd, t
        self.arm.send(("setpoint", self.sequence, q))

    def moving(self) -> bool:
        return self.move is not None or self.pending is not None

    def start_move(
        self, name: str, length: float, speed: float, acceleration: float, q_at: _PathFunction
    ) -> _Move | None:
        """Plan a move from the current setpoint; None (and the program halted) if impossible."""
        if self.teach_mode:
            self.runtime_error(f"{name}: the arm is in teach mode")
            return None
        if speed <= 0 or acceleration <= 0:
            self.runtime_error(f"{name}: speed and acceleration must be positive")
            return None
        t = self.controller_time()
        self.halt_motion()
        move = _Move(name, length, _Profile.trapezoid(length, speed, acceleration, t), q_at)
        if self.obstruction is not None:
            fraction, protective = self.obstruction
            self.obstruction = None
            move.limit, move.limit_protective_stop = fraction * length, protective
        self.move = move
        self.t_setpoint = t
        self.event(f"{name}: {length:.4f} along the path in {move.profile.t_end - t:.3f} s")
        return move

    def advance_move(self, t: float) -> None:
        move = self.move
        if move is None or self.pending is not None:
            return
        s, _ = move.profile.at(t)
        final = t >= move.profile.t_end or s >= move.limit
        s = min(s, move.limit)
        q = move.q_at(s, self.q_setpoint)
        if q is None:
            self.runtime_error(f"{move.name}: no inverse kinematics solution along the path")
            return
        dt = t - self.t_setpoint
        qd = np.zeros(6) if final or dt <= 0 else (q - self.q_setpoint) / dt
        self.send_setpoint(q, qd, t, final)

    def finish_move(self) -> None:
        move = self.move
        self.move = None
        self.qd_actual = np.zeros(6)
        if move is not None and move.limit < move.length:
            self.event(f"{move.name}: obstructed at {move.limit / max(move.length, 1e-12):.0%} of the path")
            if move.limit_protective_stop:
                self.cmd_protective_stop()

    def halt_motion(self) -> None:
        """Stop at once where the arm is (a setpoint in flight still lands)."""
        self.move = None
        self.qd_actual = np.zeros(6)
        self.qd_setpoint = np.zeros(6)
        if self.pending is not None:
            self.pending = (self.pending[0], np.zeros(6), False)

    def brake(self, deceleration: float) -> None:
        """stopj/stopl: decelerate the current move to rest."""
        if self.move is not None:
            self.move.profile = self.move.profile.stopped(self.controller_time(), deceleration)

    def joint_move(self, name: str, q_target: np.ndarray, speed: float, acceleration: float) -> _Move | None:
        if np.any(q_target < self.q_lower) or np.any(q_target > self.q_upper):
            self.runtime_error(f"{name}: target {np.round(q_target, 4)} is outside the joint limits")
            return None
        q_start = self.q_setpoint.copy()
        delta = q_target - q_start
        length = float(np.max(np.abs(delta)))
        return self.start_move(
            name,
            length,
            speed,
            acceleration,
            lambda s, _: q_start + delta * (s / length if length > 0 else 1.0),
        )

    def linear_move(
        self, name: str, T_base_tcp: np.ndarray, speed: float, acceleration: float
    ) -> _Move | None:
        """Straight TCP line with a slerp of its orientation; IK at every setpoint."""
        T_tcp_flange = np.linalg.inv(self.T_flange_tcp)
        q_start = self.q_setpoint.copy()
        T_start = forward(self.kinematics, q_start) @ self.T_flange_tcp
        target = solve_ik(self.kinematics, T_base_tcp @ T_tcp_flange, q_start)
        if not target.converged:
            self.runtime_error(f"{name}: no inverse kinematics solution for the target pose")
            return None
        p0, dp = T_start[:3, 3], T_base_tcp[:3, 3] - T_start[:3, 3]
        R0 = Rotation.from_matrix(T_start[:3, :3])
        rotvec = (R0.inv() * Rotation.from_matrix(T_base_tcp[:3, :3])).as_rotvec()
        length = float(max(np.linalg.norm(dp), np.linalg.norm(rotvec)))

        def q_at(s: float, seed: np.ndarray) -> np.ndarray | None:
            u = min(s / length, 1.0) if length > 0 else 1.0
            T = np.eye(4)
            T[:3, :3] = (R0 * Rotation.from_rotvec(u * rotvec)).as_matrix()
            T[:3, 3] = p0 + u * dp
            result = solve_ik(self.kinematics, T @ T_tcp_flange, seed)
            if result.converged:
                return result.q
            return target.q if u >= 1.0 else None

        return self.start_move(name, length, speed, acceleration, q_at)

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
        self.write_int(0, _READY)
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
            self.write_int(0, _DONE)
            return
        command = self.read_int(0)
        if command in _REALTIME_COMMANDS:
            self.process(command)
            if self.runtime_state == RUNTIME_PLAYING:
                self.write_int(0, _READY)
        elif command == 0:
            self.executing_command = False
            self.write_int(0, _READY)
        elif not self.executing_command:
            self.executing_command = True
            self.process(command)
            if self.runtime_state == RUNTIME_PLAYING and self.waiting_for is None and command != 255:
                self.write_int(0, _DONE)

    def process(self, command: int) -> None:
        name = _COMMAND_NAMES.get(command)
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
            return [_JOINT_MODE_RUNNING] * 6
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
        if rtde_type in _VECTOR_SIZES:
            return zeros6[: _VECTOR_SIZES[rtde_type]]
        return False if rtde_type == "BOOL" else 0

    def tcp_speed(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """TCP twist [vx, vy, vz, wx, wy, wz] in the base frame (m/s, rad/s) for joint speeds qd."""
        if not np.any(qd):
            return np.zeros(6)
        twist = jacobian(self.kinematics, q) @ qd
        T_base_flange = forward(self.kinematics, q)
        lever = T_base_flange[:3, :3] @ self.T_flange_tcp[:3, 3]
        return np.concatenate([twist[:3] + np.cross(twist[3:], lever), twist[3:]])
