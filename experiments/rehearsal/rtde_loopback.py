"""A loopback UR controller for tests and rehearsals: the real ur_rtde clients talk to a simulated arm.

URSim cannot run here, so this module serves, on one loopback address, the
ports ur_rtde 1.6.5 uses: RTDE (30004), the dashboard (29999) and the script
port (30003). It does not run URScript. When RTDEControlInterface uploads its
control script, the controller emulates that script's register protocol:
the client writes a command number into input_int_register_0 and its
arguments into the other input registers; the script answers in
output_int_register_0 (1 ready, 2 done) and returns values in the output
registers. The commands emulated are listed in ``COMMAND_NAMES``; any other
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

import multiprocessing
import threading
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any

import numpy as np

from hec.rehearsal.rtde_controller import Config, controller_main
from hec.rehearsal.rtde_protocol import DEFAULT_CONTROLLER_VERSION, PortBusyError

if TYPE_CHECKING:
    from hec.sim.cell import SimCell

# --- the parent side --------------------------------------------------------------------------


class LoopbackController:
    """A UR controller on a loopback address whose arm is ``cell``.

    cell: the simulated arm; the controller moves it with ``cell.set_joints``.
    lock: guards ``cell``; held around every read and write the controller makes.
    host: loopback address to serve on (ports 30004, 29999 and 30003 are fixed by ur_rtde).
    speedup: each control cycle (1/125 s or 1/500 s of wall time on a quiet machine) advances
        controller time by speedup cycles, so moves finish sooner; speeds, accelerations and
        timestamps are in controller time, a simulated clock counted in cycles (a loaded
        machine slows it down rather than making it skip).
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
        config = Config(
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
            target=controller_main, args=(config, child_commands, child_arm), daemon=True
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
