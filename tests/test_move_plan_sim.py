"""The planner's path check on the MuJoCo cell: a move whose two ends are clear but whose joint path
sweeps the wrist through the table top is refused, naming the move and the obstacle."""

from __future__ import annotations

import numpy as np

from hec.estimator.geometry.joint_path import joint_path
from hec.estimator.geometry.move_plan import plan_joint_moves
from hec.estimator.geometry.waypoints import Waypoint
from hec.sim.cell import SimCell
from hec.sim.scenario import load_scenario

LOWER, UPPER = (
    np.radians([-360.0] * 2 + [-180.0] + [-360.0] * 3),
    np.radians([360.0] * 2 + [180.0] + [360.0] * 3),
)
# The base joint swings the bent arm over the cell: both ends clear, the wrist through the table top.
Q_A = np.array([0.88, -1.01, 1.01, -1.57, -1.57, 0.0])
Q_B = np.array([2.8, -1.01, 1.01, -1.57, -1.57, 0.0])


def test_a_move_through_the_table_is_refused_naming_the_move_and_the_obstacle() -> None:
    cell = SimCell(load_scenario(None), np.random.default_rng(0))
    try:
        assert cell.collision_at(Q_A) is None and cell.collision_at(Q_B) is None
        assert any("table_top" in (cell.collision_at(q) or "") for q in joint_path(Q_A, Q_B))
        waypoints = [Waypoint(0, "left", joints=Q_A), Waypoint(1, "right", joints=Q_B)]

        def plan(sample_problem):
            return plan_joint_moves(
                waypoints, Q_A, LOWER, UPPER, np.pi, cell.collision_at, sample_problem, lambda T, q: None
            )

        before = cell.joints.copy()
        first, second = plan(cell.collision_at)
        assert first.joints is not None and second.joints is None
        assert second.problem.startswith("the move from waypoint 0: collision:")
        assert "table_top" in second.problem and "% of the move" in second.problem
        # checked at the targets only, the same move passes: the path check is what refuses it
        assert plan(None)[1].joints is not None
        assert np.array_equal(cell.joints, before)  # checking moves nothing
    finally:
        cell.close()
