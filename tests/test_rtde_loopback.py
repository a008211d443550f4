"""The real ur_rtde 1.6.5 clients against the loopback controller (hec.rehearsal.rtde_loopback).

What ur_rtde does, as these tests record it:
- A blocking moveJ returns False when a protective or emergency stop happens during the
  move, and every later moveJ returns False at once until the program runs again
  (protective stop: dashboard "unlock protective stop", then reuploadScript()).
- A move whose target has no IK solution returns False and leaves the control script
  stopped (isProgramRunning() False) until reuploadScript().
- When the controller drops the connections and refuses new ones, both clients notice:
  isConnected() turns False (no exception); RTDEReceiveInterface.getActualQ() keeps
  returning the last values it received. reconnect() works on both once the controller
  accepts connections again. A moveJ sent while disconnected does not raise: it waits
  for an answer that never comes, so the tests never send one.

ur_rtde's constructors hold the GIL while they wait for the controller, so a hang there
cannot be interrupted from Python; a faulthandler watchdog ends the process instead.
"""

from __future__ import annotations

import faulthandler
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hec.estimator.geometry.kinematics import forward
from hec.rehearsal.rtde_loopback import LoopbackController
from hec.rehearsal.rtde_protocol import (
    RUNTIME_PAUSED,
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    SAFETY_MODE_NORMAL,
    SAFETY_MODE_PROTECTIVE_STOP,
    SAFETY_MODE_ROBOT_EMERGENCY_STOP,
    PortBusyError,
    pose_matrix,
    pose_vector,
)

if TYPE_CHECKING:
    from hec.sim.cell import SimCell

rtde_control = pytest.importorskip("rtde_control")
rtde_receive = pytest.importorskip("rtde_receive")
dashboard_client = pytest.importorskip("dashboard_client")

Q_HOME = np.array([-1.57, -1.57, 1.57, -1.57, -1.57, 0.0])
SPEEDUP = 4.0
# Longest a test, or a fixture's setup or teardown, may take before the watchdog ends the process.
HANG_LIMIT_S = 60.0


@dataclass
class Rig:
    """A simulated arm behind a loopback controller, with the real ur_rtde clients."""

    cell: SimCell
    lock: threading.Lock
    controller: LoopbackController
    receive: Any
    control: Any

    def joints(self) -> np.ndarray:
        with self.lock:
            return self.cell.joints.copy()

    def flange_pose(self) -> np.ndarray:
        with self.lock:
            return self.cell.true_flange_pose()


def hang_guard(seconds: float = HANG_LIMIT_S) -> None:
    faulthandler.dump_traceback_later(seconds, exit=True)


def wait_until(predicate: Callable[[], bool], what: str, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting until {what}")
        time.sleep(0.002)


def call_in_thread(function: Callable[..., Any], *args: Any) -> tuple[threading.Thread, dict[str, Any]]:
    """Run a blocking client call (ur_rtde releases the GIL in them) in a daemon thread."""
    outcome: dict[str, Any] = {}

    def run() -> None:
        try:
            outcome["result"] = function(*args)
        except Exception as error:  # recorded for the test to report
            outcome["error"] = error

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread, outcome


def join(thread: threading.Thread, outcome: dict[str, Any], timeout_s: float = 5.0) -> Any:
    thread.join(timeout_s)
    assert not thread.is_alive(), f"the client call did not return within {timeout_s} s"
    if "error" in outcome:
        raise outcome["error"]
    return outcome["result"]


def pose_errors(pose: list[float], T_expected: np.ndarray) -> tuple[float, float]:
    """Position error (m) and rotation error (rad) of a UR pose vector against a (4, 4) pose."""
    R = Rotation.from_rotvec(pose[3:6]).as_matrix()
    rotation_error = Rotation.from_matrix(R.T @ T_expected[:3, :3]).magnitude()
    return float(np.linalg.norm(np.asarray(pose[:3]) - T_expected[:3, 3])), float(rotation_error)


def open_rig(host: str) -> Rig:
    from hec.sim.cell import SimCell
    from hec.sim.scenario import load_scenario

    cell = SimCell(load_scenario(None), np.random.default_rng(0))
    cell.set_joints(Q_HOME)
    lock = threading.Lock()
    controller = LoopbackController(cell, lock, host=host, speedup=SPEEDUP).start()
    try:
        receive = rtde_receive.RTDEReceiveInterface(controller.host)
        control = rtde_control.RTDEControlInterface(controller.host)
    except BaseException:
        controller.close()
        cell.close()
        raise
    return Rig(cell, lock, controller, receive, control)


def close_rig(rig: Rig) -> None:
    """Disconnect the clients first (they talk to the controller while they do), then stop it."""
    try:
        for client in (rig.control, rig.receive):
            client.disconnect()
    finally:
        rig.controller.close()
        rig.cell.close()
    bridge = f"rtde-loopback-bridge-{rig.controller.host}"
    assert not any(thread.name == bridge for thread in threading.enumerate())


@pytest.fixture(autouse=True)
def _watchdog() -> Iterator[None]:
    hang_guard()
    yield
    faulthandler.cancel_dump_traceback_later()


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    """A rig shared by the tests that leave the controller healthy."""
    hang_guard()
    shared = open_rig("127.0.0.1")
    faulthandler.cancel_dump_traceback_later()
    yield shared
    hang_guard()
    close_rig(shared)
    faulthandler.cancel_dump_traceback_later()


@pytest.fixture
def fresh_rig() -> Iterator[Rig]:
    """A rig of its own, for tests that stop, break or disconnect the controller.

    The ports are fixed, so it serves on another loopback address than the shared rig.
    """
    own = open_rig("127.0.0.2")
    yield own
    close_rig(own)


def move_home(rig: Rig) -> None:
    assert rig.control.moveJ(list(Q_HOME), 1.05, 1.4)


def test_receive_interface_reports_the_simulated_arm(rig: Rig) -> None:
    move_home(rig)
    wait_until(
        lambda: np.allclose(rig.receive.getActualQ(), rig.joints(), atol=1e-6, rtol=0), "actual_q settles"
    )
    np.testing.assert_allclose(rig.receive.getActualQ(), rig.joints(), atol=1e-6, rtol=0)
    position_error, rotation_error = pose_errors(rig.receive.getActualTCPPose(), rig.flange_pose())
    assert position_error < 1e-6 and rotation_error < 1e-6
    assert rig.receive.getActualQd() == [0.0] * 6
    assert rig.receive.getSafetyMode() == SAFETY_MODE_NORMAL
    assert rig.receive.getRuntimeState() == RUNTIME_PLAYING


def test_movej_moves_the_arm_to_the_waypoint(rig: Rig) -> None:
    move_home(rig)
    target = Q_HOME + np.array([0.12, -0.08, 0.1, 0.05, -0.1, 0.2])
    assert rig.control.moveJ(list(target), 1.05, 1.4)
    np.testing.assert_allclose(rig.joints(), target, atol=1e-12, rtol=0)
    wait_until(
        lambda: np.allclose(rig.receive.getActualQ(), target, atol=1e-9, rtol=0), "actual_q is the target"
    )


def test_movel_moves_the_tcp_to_the_pose(rig: Rig) -> None:
    move_home(rig)
    T_base_target = forward(rig.cell.cell.kinematics, Q_HOME + np.array([0.1, -0.1, 0.15, 0.05, 0.1, -0.2]))
    assert rig.control.moveL(list(pose_vector(T_base_target)), 0.25, 1.2)
    position_error, rotation_error = pose_errors(list(pose_vector(rig.flange_pose())), T_base_target)
    assert position_error < 1e-9 and rotation_error < 1e-9


def test_set_tcp_offsets_the_reported_pose_and_movel_targets(rig: Rig) -> None:
    move_home(rig)
    tcp = [0.01, -0.02, 0.15, 0.0, 0.0, np.pi / 2]
    T_flange_tcp = pose_matrix(np.array(tcp))
    try:
        assert rig.control.setTcp(tcp)
        np.testing.assert_allclose(rig.control.getTCPOffset(), tcp, atol=1e-12)
        np.testing.assert_allclose(rig.controller.status()["T_flange_tcp"], T_flange_tcp, atol=1e-12)

        def reported_error() -> float:
            return sum(pose_errors(rig.receive.getActualTCPPose(), rig.flange_pose() @ T_flange_tcp))

        wait_until(lambda: reported_error() < 1e-6, "actual_TCP_pose includes the TCP offset")
        T_base_tcp = forward(rig.cell.cell.kinematics, Q_HOME + 0.1) @ T_flange_tcp
        assert rig.control.moveL(list(pose_vector(T_base_tcp)), 0.25, 1.2)
        position_error, rotation_error = pose_errors(
            list(pose_vector(rig.flange_pose() @ T_flange_tcp)), T_base_tcp
        )
        assert position_error < 1e-9 and rotation_error < 1e-9
    finally:
        assert rig.control.setTcp([0.0] * 6)


def test_velocity_is_nonzero_while_moving_and_zero_once_settled(rig: Rig) -> None:
    move_home(rig)
    target = Q_HOME + 0.3
    assert rig.control.moveJ(list(target), 0.25, 0.5, True)
    wait_until(lambda: np.linalg.norm(rig.receive.getActualQd()) > 0.05, "the arm moves")
    assert np.linalg.norm(rig.receive.getActualTCPSpeed()) > 0
    assert rig.control.getAsyncOperationProgress() >= 0  # the async move is running
    wait_until(lambda: rig.control.getAsyncOperationProgress() < 0, "the async move ends")
    wait_until(lambda: rig.receive.getActualQd() == [0.0] * 6, "actual_qd is zero")
    np.testing.assert_allclose(rig.receive.getActualQ(), target, atol=1e-9, rtol=0)
    assert rig.receive.getActualTCPSpeed() == [0.0] * 6
    assert rig.control.isSteady()


def test_stopj_and_stopl_brake_asynchronous_moves(rig: Rig) -> None:
    move_home(rig)
    assert rig.control.moveJ(list(Q_HOME + 0.5), 0.25, 0.5, True)
    wait_until(lambda: np.linalg.norm(rig.receive.getActualQd()) > 0.05, "the arm moves")
    rig.control.stopJ(2.0)  # blocking: returns once the arm stands still
    assert rig.control.isSteady()
    travelled = rig.joints() - Q_HOME
    assert np.all(travelled > 0) and np.all(travelled < 0.5)
    T_base_target = forward(rig.cell.cell.kinematics, Q_HOME)
    assert rig.control.moveL(list(pose_vector(T_base_target)), 0.05, 0.2, True)
    wait_until(lambda: np.linalg.norm(rig.receive.getActualTCPSpeed()) > 0.01, "the TCP moves")
    rig.control.stopL(1.0)
    assert rig.control.isSteady()
    assert np.linalg.norm(rig.flange_pose()[:3, 3] - T_base_target[:3, 3]) > 1e-3  # stopped short
    move_home(rig)


def test_teach_mode_lets_the_arm_be_guided_by_hand(rig: Rig) -> None:
    move_home(rig)
    with pytest.raises(RuntimeError, match="teach"):
        rig.controller.hand_guide(Q_HOME + 0.05)
    assert rig.control.teachMode()
    try:
        rig.controller.hand_guide(Q_HOME + 0.05)
        np.testing.assert_allclose(rig.joints(), Q_HOME + 0.05, atol=1e-12, rtol=0)
        wait_until(
            lambda: np.allclose(rig.receive.getActualQ(), Q_HOME + 0.05, atol=1e-9), "the guided joints show"
        )
    finally:
        assert rig.control.endTeachMode()
    move_home(rig)


def test_an_obstructed_move_reports_done_but_stops_short(rig: Rig) -> None:
    move_home(rig)
    target = Q_HOME + 0.2
    rig.controller.obstruct_next_move(0.5)
    assert rig.control.moveJ(list(target), 1.05, 1.4)  # the controller reports the move done
    np.testing.assert_allclose(rig.joints(), Q_HOME + 0.1, atol=1e-12, rtol=0)


def test_a_second_controller_on_the_same_address_fails_clearly(rig: Rig) -> None:
    with pytest.raises(PortBusyError, match="127.0.0.1:30004"):
        LoopbackController(rig.cell, rig.lock).start()


def test_unreachable_movel_fails_and_reupload_recovers(fresh_rig: Rig) -> None:
    rig = fresh_rig
    assert not rig.control.moveL([3.0, 0.0, 0.0, 0.0, 3.14, 0.0], 0.25, 1.2)
    assert not rig.control.isProgramRunning()
    assert "runtime error: movel: no inverse kinematics solution" in "\n".join(
        rig.controller.status()["events"]
    )
    np.testing.assert_allclose(rig.joints(), Q_HOME, atol=1e-12, rtol=0)
    assert rig.control.reuploadScript()
    wait_until(rig.control.isProgramRunning, "the control script runs again")
    assert rig.control.moveJ(list(Q_HOME + 0.1), 1.05, 1.4)


def test_protective_stop_is_reported_and_moves_fail(fresh_rig: Rig) -> None:
    rig = fresh_rig
    target = Q_HOME + 0.5
    thread, outcome = call_in_thread(rig.control.moveJ, list(target), 0.2, 0.5)
    wait_until(lambda: np.linalg.norm(rig.receive.getActualQd()) > 0.05, "the arm moves")
    rig.controller.protective_stop()
    assert join(thread, outcome) is False  # the blocking moveJ returns False
    wait_until(rig.receive.isProtectiveStopped, "the protective stop shows")
    assert rig.receive.getSafetyMode() == SAFETY_MODE_PROTECTIVE_STOP
    assert rig.receive.getSafetyStatusBits() & (1 << 2)
    assert rig.receive.getRuntimeState() == RUNTIME_PAUSED
    assert rig.receive.getRobotStatus() == 0b01  # powered, program not running
    wait_until(lambda: rig.receive.getActualQd() == [0.0] * 6, "the arm stands still")
    assert np.max(np.abs(rig.joints() - target)) > 0.05  # stopped short of the target
    assert rig.control.moveJ(list(Q_HOME), 1.05, 1.4) is False
    # The real recovery path: unlock through the dashboard, then upload the control script again.
    dashboard = dashboard_client.DashboardClient(rig.controller.host)
    dashboard.connect()
    try:
        dashboard.unlockProtectiveStop()
    finally:
        dashboard.disconnect()
    wait_until(lambda: rig.receive.getSafetyMode() == SAFETY_MODE_NORMAL, "the protective stop is unlocked")
    assert rig.control.reuploadScript()
    wait_until(rig.control.isProgramRunning, "the control script runs again")
    assert rig.control.moveJ(list(Q_HOME), 1.05, 1.4)
    # A collision halfway: the move fails with a protective stop, the arm halfway.
    rig.controller.obstruct_next_move(0.5, protective_stop=True)
    assert rig.control.moveJ(list(Q_HOME + 0.2), 1.05, 1.4) is False
    wait_until(rig.receive.isProtectiveStopped, "the protective stop shows")
    np.testing.assert_allclose(rig.joints(), Q_HOME + 0.1, atol=1e-12, rtol=0)


def test_emergency_stop_is_reported_and_moves_fail(fresh_rig: Rig) -> None:
    rig = fresh_rig
    thread, outcome = call_in_thread(rig.control.moveJ, list(Q_HOME + 0.5), 0.2, 0.5)
    wait_until(lambda: np.linalg.norm(rig.receive.getActualQd()) > 0.05, "the arm moves")
    rig.controller.emergency_stop()
    assert join(thread, outcome) is False
    wait_until(rig.receive.isEmergencyStopped, "the emergency stop shows")
    assert rig.receive.getSafetyMode() == SAFETY_MODE_ROBOT_EMERGENCY_STOP
    assert rig.receive.getSafetyStatusBits() & (1 << 7)
    assert rig.receive.getRuntimeState() == RUNTIME_STOPPED
    assert rig.receive.getRobotStatus() == 0  # arm power off, no program
    assert rig.control.moveJ(list(Q_HOME), 1.05, 1.4) is False
    # Recovery: release the button, power on and release the brakes, upload the script again.
    rig.controller.release_emergency_stop()
    dashboard = dashboard_client.DashboardClient(rig.controller.host)
    dashboard.connect()
    try:
        dashboard.powerOn()
        dashboard.brakeRelease()
        assert dashboard.robotmode() == "Robotmode: RUNNING"
    finally:
        dashboard.disconnect()
    assert rig.control.reuploadScript()
    wait_until(rig.control.isProgramRunning, "the control script runs again")
    assert rig.control.moveJ(list(Q_HOME), 1.05, 1.4)


def test_dropped_connections_are_noticed_and_reconnect_works(fresh_rig: Rig) -> None:
    rig = fresh_rig
    rig.controller.drop_connections()
    wait_until(lambda: not rig.receive.isConnected(), "RTDEReceiveInterface notices")
    # RTDEControlInterface tries to reconnect once from its receive thread, fails, and gives up.
    wait_until(lambda: not rig.control.isConnected(), "RTDEControlInterface notices")
    # The arm moves (by hand, say) while the link is down: the receiver keeps the old values.
    with rig.lock:
        rig.cell.set_joints(Q_HOME + 0.05)
    time.sleep(0.1)
    np.testing.assert_allclose(rig.receive.getActualQ(), Q_HOME, atol=1e-12, rtol=0)
    rig.controller.restore_connections()
    assert rig.receive.reconnect()
    assert rig.control.reconnect()
    wait_until(
        lambda: np.allclose(rig.receive.getActualQ(), Q_HOME + 0.05, atol=1e-12), "the receiver is current"
    )
    wait_until(rig.control.isProgramRunning, "the control script runs again")
    assert rig.control.moveJ(list(Q_HOME + 0.1), 1.05, 1.4)
    wait_until(
        lambda: np.allclose(rig.receive.getActualQ(), Q_HOME + 0.1, atol=1e-9), "the receiver sees the move"
    )
