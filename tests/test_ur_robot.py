"""hec.hardware.ur_robot.URRobot on the real ur_rtde clients, against the loopback controller."""

from __future__ import annotations

import _thread
import faulthandler
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from hec.estimator.geometry.kinematics import forward
from hec.estimator.geometry.transforms import make_transform, pose_error
from hec.hardware.ur_robot import MotionSettings, RobotError, SafetyLimits, URRobot
from hec.rehearsal.rtde_loopback import LoopbackController
from hec.sim.cell import SimCell
from hec.sim.scenario import load_scenario
from tests.test_rtde_loopback import Q_HOME, hang_guard

HOST = "127.0.0.3"  # apart from test_rtde_loopback's addresses
FAST = MotionSettings(joint_speed=2.0, joint_acceleration=4.0, dwell_s=0.1)


@pytest.fixture
def cell_and_controller() -> Iterator[tuple[SimCell, threading.Lock, LoopbackController]]:
    hang_guard()
    cell = SimCell(load_scenario(None), np.random.default_rng(0))
    cell.set_joints(Q_HOME)
    lock = threading.Lock()
    controller = LoopbackController(cell, lock, host=HOST, speedup=4.0).start()
    try:
        yield cell, lock, controller
    finally:
        controller.close()
        cell.close()
        faulthandler.cancel_dump_traceback_later()


def _robot(cell: SimCell, **kwargs: object) -> URRobot:
    return URRobot(HOST, FAST, forward=lambda q: forward(cell.cell.kinematics, q), **kwargs)


def test_reads_the_flange_pose_and_joints_of_the_simulated_arm(cell_and_controller) -> None:
    cell, lock, _ = cell_and_controller
    with _robot(cell) as robot:
        with lock:
            truth_q, truth_T = cell.joints.copy(), cell.true_flange_pose()
        np.testing.assert_allclose(robot.joints(), truth_q, atol=1e-6)
        dt, dr = pose_error(robot.flange_pose(), truth_T)
        assert dt < 1e-6 and dr < 1e-6


def test_moves_settle_and_the_tcp_offset_is_taken_off(cell_and_controller) -> None:
    cell, lock, _ = cell_and_controller
    with _robot(cell) as robot:
        target = Q_HOME + np.array([0.2, -0.1, 0.15, 0.1, -0.2, 0.3])
        robot.move_joints(target)
        robot.set_tcp_offset(make_transform(np.eye(3), np.array([0.0, 0.0, 0.1])))
        with lock:
            np.testing.assert_allclose(cell.joints, target, atol=1e-6)
            truth_T = cell.true_flange_pose()
        dt, dr = pose_error(robot.flange_pose(), truth_T)
        assert dt < 1e-6 and dr < 1e-6
        goal = truth_T @ make_transform(np.eye(3), np.array([0.02, -0.01, 0.03]))
        robot.move_flange(goal)
        with lock:
            dt, dr = pose_error(cell.true_flange_pose(), goal)
        assert dt < 1e-4 and dr < 1e-3


def test_a_read_only_robot_reads_but_cannot_move(cell_and_controller) -> None:
    cell, lock, _ = cell_and_controller
    with _robot(cell, read_only=True) as robot:
        with lock:
            truth_T = cell.true_flange_pose()
        assert pose_error(robot.flange_pose(), truth_T)[0] < 1e-6
        with pytest.raises(RobotError, match="read-only"):
            robot.move_joints(Q_HOME)


def test_refuses_targets_outside_the_limits_before_moving(cell_and_controller) -> None:
    cell, lock, _ = cell_and_controller
    box = SafetyLimits(workspace_lower_m=(-0.2, -0.2, -0.2), workspace_upper_m=(0.2, 0.2, 0.2))
    with _robot(cell, limits=box) as robot:
        with pytest.raises(RobotError, match="refused to move: flange position .* outside the workspace box"):
            robot.move_joints(Q_HOME)
        with pytest.raises(RobotError, match=r"refused to move: joints q3=4\.000 rad outside the limits"):
            robot.move_joints(np.array([0, -1.57, 4.0, 0, 0, 0]))
    with lock:
        np.testing.assert_allclose(cell.joints, Q_HOME)


def test_protective_stop_and_short_moves_are_reported(cell_and_controller) -> None:
    cell, _, controller = cell_and_controller
    with _robot(cell) as robot:
        controller.obstruct_next_move(0.5)
        with pytest.raises(RobotError, match="rad short of the joint target"):
            robot.move_joints(Q_HOME + 0.2)
        controller.protective_stop()
        with pytest.raises(RobotError, match="protective stop"):
            robot.move_joints(Q_HOME)


def test_a_lost_connection_is_reported(cell_and_controller) -> None:
    cell, _, controller = cell_and_controller
    with _robot(cell) as robot:
        robot.joints()
        controller.drop_connections()
        with pytest.raises(RobotError, match="lost the connection to the UR controller at 127.0.0.3"):
            for _ in range(200):
                robot.joints()
                threading.Event().wait(0.01)


def test_ctrl_c_during_a_move_stops_the_arm(cell_and_controller) -> None:
    """Moves are asynchronous, so an interrupted session must stop the arm itself."""
    cell, lock, controller = cell_and_controller
    slow = MotionSettings(joint_speed=0.5, joint_acceleration=1.0, dwell_s=0.1)
    target = Q_HOME + np.array([1.5, 0.0, 0.0, 0.0, 0.0, 0.0])  # 3 s of motion, 0.75 s at speedup 4
    with URRobot(HOST, slow, forward=lambda q: forward(cell.cell.kinematics, q)) as robot:
        ctrl_c = threading.Timer(0.15, _thread.interrupt_main)
        ctrl_c.start()
        with pytest.raises(KeyboardInterrupt):
            robot.move_joints(target)
        robot.wait_settled()
        assert not controller.status()["moving"]
        with lock:
            short_by = float(np.max(np.abs(cell.joints - target)))
    assert short_by > 0.5
