"""The loopback controller process: one thread, a selector loop over the client sessions with a
control tick at the RTDE rate, the arm's motion in controller time, and a pipe to the parent that
applies each setpoint to the simulated cell."""

from __future__ import annotations

import collections
import dataclasses
import selectors
import socket
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from hec.estimator.geometry.kinematics import URKinematics, forward, solve_ik
from hec.rehearsal.rtde_protocol import (
    DASHBOARD_PORT,
    ROBOT_MODE_POWER_OFF,
    ROBOT_MODE_RUNNING,
    RTDE_PORT,
    RUNTIME_PAUSED,
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    SAFETY_BIT_EMERGENCY_STOPPED,
    SAFETY_BIT_NORMAL,
    SAFETY_BIT_PROTECTIVE_STOPPED,
    SAFETY_BIT_ROBOT_EMERGENCY_STOPPED,
    SAFETY_BIT_STOPPED_DUE_TO_SAFETY,
    SAFETY_MODE_NORMAL,
    SAFETY_MODE_PROTECTIVE_STOP,
    SAFETY_MODE_ROBOT_EMERGENCY_STOP,
    SCRIPT_PORT,
    Move,
    PathFunction,
    PortBusyError,
    Profile,
)
from hec.rehearsal.rtde_script import ScriptEmulation
from hec.rehearsal.rtde_sessions import DashboardSession, RtdeSession, ScriptSession, Session

# --- the controller process ---------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Config:
    host: str
    kinematics: URKinematics
    q: np.ndarray
    T_base_flange: np.ndarray
    speedup: float
    controller_version: tuple[int, int, int, int]


def controller_main(config: Config, commands: Connection, arm: Connection) -> None:
    """Entry point of the controller process."""
    try:
        controller = Controller(config, commands, arm)
    except PortBusyError as error:
        commands.send(("port busy", str(error)))
        return
    except Exception as error:  # report any start-up failure to the parent
        commands.send(("error", f"{type(error).__name__}: {error}"))
        return
    commands.send(("ready", None))
    controller.run()


class Controller(ScriptEmulation):
    """The controller process: sockets, the emulated control script and the arm's motion.

    Everything runs on one thread: a selector loop with a control tick at the RTDE rate.
    """

    def __init__(self, config: Config, commands: Connection, arm: Connection) -> None:
        self.config = config
        self.kinematics = config.kinematics
        self.q_lower = np.array(config.kinematics.q_lower)
        self.q_upper = np.array(config.kinematics.q_upper)
        self.max_frequency_hz = 125.0 if config.controller_version[0] <= 3 else 500.0
        self.tick_s = 1.0 / self.max_frequency_hz
        self.commands = commands
        self.arm = arm
        self.selector = selectors.DefaultSelector()
        self.sessions: set[Session] = set()
        self.listeners: dict[int, socket.socket] = {}
        self.events: collections.deque[str] = collections.deque(maxlen=1000)
        self.received_commands: collections.deque[str] = collections.deque(maxlen=1000)
        self.running = True
        self.ticks = 0  # control cycles run: the controller's clock (controller_time)
        # RTDE registers and input ownership.
        self.inputs: dict[str, Any] = {}
        self.outputs: dict[str, Any] = {}
        self.input_owners: dict[str, RtdeSession] = {}
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
        self.async_move: Move | None = None
        # Arm: the actual state comes from the parent's SimCell; setpoints go there.
        self.q_actual = np.array(config.q, dtype=float)
        self.T_base_flange = np.array(config.T_base_flange, dtype=float)
        self.qd_actual = np.zeros(6)
        self.q_setpoint = self.q_actual.copy()
        self.qd_setpoint = np.zeros(6)
        self.t_setpoint = 0.0
        self.move: Move | None = None
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
                if isinstance(key.data, Session):
                    self.on_session_event(key.data, mask)
                else:
                    key.data(key.fileobj)
                if not self.running:
                    break
            now = time.monotonic()
            if now >= next_tick and self.running:
                self.tick()
                next_tick = max(next_tick + self.tick_s, now)
        for session in list(self.sessions):
            self.close_session(session)
        self.close_listeners()
        self.selector.close()

    def tick(self) -> None:
        """One control cycle: the clock advances by one cycle, whenever the cycle runs."""
        self.ticks += 1
        t = self.controller_time()
        self.advance_move(t)
        self.step_program()
        cache: dict[str, Any] = {}
        for session in list(self.sessions):
            if isinstance(session, RtdeSession):
                session.stream(self.tick_s, lambda name: self.output_value(name, t, cache))

    def controller_time(self) -> float:
        """Seconds on the controller's simulated clock: speedup x the control cycles run. A loaded
        machine runs the cycles later, not fewer, so a move takes the same cycles and passes the
        same setpoints whatever the load."""
        return self.config.speedup * self.ticks * self.tick_s

    def event(self, text: str) -> None:
        self.events.append(f"{self.controller_time():9.3f} {text}")

    # --- sockets -----------------------------------------------------------------------------

    def open_listeners(self) -> None:
        sessions = {RTDE_PORT: RtdeSession, DASHBOARD_PORT: DashboardSession, SCRIPT_PORT: ScriptSession}
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

    def acceptor(self, port: int, session_type: type[Session]) -> Callable[[socket.socket], None]:
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

    def on_session_event(self, session: Session, mask: int) -> None:
        if mask & selectors.EVENT_WRITE and not session.closed:
            session.flush()
        if mask & selectors.EVENT_READ and not session.closed:
            session.on_readable()

    def watch_writes(self, session: Session, pending: bool) -> None:
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if pending else 0)
        if self.selector.get_key(session.sock).events != events:
            self.selector.modify(session.sock, events, session)

    def close_session(self, session: Session) -> None:
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
        self, name: str, length: float, speed: float, acceleration: float, q_at: PathFunction
    ) -> Move | None:
        """Plan a move from the current setpoint; None (and the program halted) if impossible."""
        if self.teach_mode:
            self.runtime_error(f"{name}: the arm is in teach mode")
            return None
        if speed <= 0 or acceleration <= 0:
            self.runtime_error(f"{name}: speed and acceleration must be positive")
            return None
        t = self.controller_time()
        self.halt_motion()
        move = Move(name, length, Profile.trapezoid(length, speed, acceleration, t), q_at)
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

    def joint_move(self, name: str, q_target: np.ndarray, speed: float, acceleration: float) -> Move | None:
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
    ) -> Move | None:
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
