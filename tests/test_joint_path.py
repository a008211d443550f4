"""Moves checked along the path the controller takes (joint_path): a move whose two ends are
inside the cell but whose path dips through the table is refused, naming the waypoint and the
obstacle; the wrist stays within its cable limit; branches are chosen for short swings."""

from __future__ import annotations

import numpy as np
import pytest

from hec.estimator.geometry.joint_path import (
    PATH_STEP_RAD,
    joint_path,
    largest_swing,
    least_swing_branches,
    path_problem,
    short_visit_order,
)
from hec.estimator.geometry.kinematics import ROBOTS, forward, ur_ik_branches

UR5 = ROBOTS["ur5"]
LOWER, UPPER = (
    np.radians([-360.0, -360.0, -180.0, -360.0, -360.0, -360.0]),
    np.radians([360.0] * 2 + [180.0] + [360.0] * 3),
)
Q_HOME = np.array([-1.57, -1.57, 1.57, -1.57, -1.57, 0.0])


def _above_table(z_table_m: float):
    """A pose check: the flange must stay above a table top at base z = z_table_m."""

    def problem(q: np.ndarray) -> str | None:
        z = forward(UR5, q)[2, 3]
        return None if z > z_table_m else f"the flange hits the table (z {z:+.3f} m)"

    return problem


def test_the_path_is_sampled_at_fine_steps_with_both_ends() -> None:
    q_to = Q_HOME + np.radians([40.0, -10.0, 5.0, 0.0, 90.0, -3.0])
    path = joint_path(Q_HOME, q_to)
    assert np.allclose(path[0], Q_HOME) and np.allclose(path[-1], q_to)
    assert np.max(np.abs(np.diff(path, axis=0))) <= PATH_STEP_RAD + 1e-12
    assert len(path) == 181  # 90 degrees in 0.5 degree steps
    assert largest_swing(Q_HOME, q_to) == (4, pytest.approx(np.radians(90.0)))


def test_a_move_through_the_table_is_refused_though_both_ends_are_clear() -> None:
    """The shoulder swings the stretched arm from one side down through vertical to the other:
    both ends above a table 0.3 m below the base, the middle of the joint path 0.8 m below."""
    q_a = np.array([0.0, 0.2, 0.0, -1.57, -1.57, 0.0])
    q_b = np.array([0.0, 2.9, 0.0, -1.57, -1.57, 0.0])
    path = joint_path(q_a, q_b)
    z = np.array([forward(UR5, q)[2, 3] for q in path])
    z_table = -0.3
    assert min(z[0], z[-1]) > z_table > z.min() + 0.4  # the ends clear the table, the path does not
    problem = path_problem(path, LOWER, UPPER, 0.0, np.pi, _above_table(z_table))
    assert problem is not None and "hits the table" in problem and "% of the move" in problem
    assert path_problem(path, LOWER, UPPER, 0.0, np.pi, _above_table(z.min() - 0.01)) is None
    # an arm that starts below the table top may rise out of it, and may not end below it
    assert path_problem(path[len(path) // 2 :], LOWER, UPPER, 0.0, np.pi, _above_table(z_table)) is None
    assert path_problem(path[: len(path) // 2], LOWER, UPPER, 0.0, np.pi, _above_table(z_table)) is not None


def test_joint_limit_and_cable_limit_along_the_path() -> None:
    q_b = Q_HOME.copy()
    q_b[5] = np.radians(200.0)
    problem = path_problem(joint_path(Q_HOME, q_b), LOWER, UPPER, 0.0, np.pi)
    assert problem is not None and "wind the camera cable" in problem
    assert path_problem(joint_path(Q_HOME, q_b), LOWER, UPPER, 0.0, np.radians(210.0)) is None
    q_c = Q_HOME.copy()
    q_c[2] = np.radians(185.0)
    problem = path_problem(joint_path(Q_HOME, q_c), LOWER, UPPER, 0.0, np.pi)
    assert problem is not None and problem.startswith("q3 passes its limit")


def test_branches_reach_the_pose_and_the_least_swing_sequence_is_chosen() -> None:
    poses = [forward(UR5, Q_HOME + np.radians(d)) for d in ([20, 0, 0, 0, 0, 0], [20, 10, -10, 0, 30, 40])]
    candidates = [ur_ik_branches(UR5, T, Q_HOME, LOWER, UPPER) for T in poses]
    for T, c in zip(poses, candidates, strict=True):
        assert len(c) >= 8 and all(np.abs(forward(UR5, q) - T).max() < 1e-9 for q in c)
    picks = least_swing_branches(candidates, Q_HOME)
    assert picks is not None
    chosen = [c[i] for c, i in zip(candidates, picks, strict=True)]
    assert np.allclose(chosen[0], Q_HOME + np.radians([20, 0, 0, 0, 0, 0]), atol=1e-6)
    assert np.allclose(chosen[1], Q_HOME + np.radians([20, 10, -10, 0, 30, 40]), atol=1e-6)
    # forbidding the first move's best branch picks another that reaches the same pose
    again = least_swing_branches(candidates, Q_HOME, frozenset({(0, 0, picks[0])}))
    assert again is not None and again[0] != picks[0]


def test_the_visit_order_shortens_the_joint_travel_and_keeps_the_first_waypoint() -> None:
    """Waypoints given zig-zag along the base joint (0, 40, 10, 30, 20 degrees) are visited 0, 10, 20,
    30, 40: a travel of 40 degrees where the given order takes 130; the first stays first."""
    base = [0.0, 40.0, 10.0, 30.0, 20.0]
    candidates = [
        ur_ik_branches(UR5, forward(UR5, Q_HOME + np.radians([b, 0, 0, 0, 0, 0])), Q_HOME, LOWER, UPPER)
        for b in base
    ]
    order = short_visit_order(candidates, Q_HOME)
    assert order == [0, 2, 4, 3, 1]
    picks = least_swing_branches([candidates[k] for k in order], Q_HOME)
    assert picks is not None
    chosen = [candidates[k][i] for k, i in zip(order, picks, strict=True)]
    travel = sum(largest_swing(a, b)[1] for a, b in zip([Q_HOME, *chosen], chosen, strict=False))
    assert np.degrees(travel) == pytest.approx(40.0, abs=1e-4)
    # a start near the far end still keeps waypoint 0 first
    assert short_visit_order(candidates, Q_HOME + np.radians([40, 0, 0, 0, 0, 0]))[0] == 0
