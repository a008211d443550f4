"""The planner's path check on the MuJoCo cell: a move whose two ends are clear but whose joint path
sweeps the wrist through the table top is refused, naming the move and the obstacle; the cell model
(no simulator) is at least as cautious as MuJoCo's contacts; the default and realistic trajectories
are planned whole by the simulated session's planner, in short moves."""

from __future__ import annotations

import numpy as np
import pytest

from hec.estimator.common.models import models_dir
from hec.estimator.geometry.joint_path import joint_path
from hec.estimator.geometry.move_plan import plan_joint_moves
from hec.estimator.geometry.waypoints import Waypoint
from hec.sim.cell import SimCell
from hec.sim.scenario import load_scenario
from hec.sim.session_cell import SimulatedCell
from hec.sim.simulate import scenario_waypoints

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


def test_the_cell_model_sees_every_contact_mujoco_sees() -> None:
    """On 300 random joint vectors, wherever MuJoCo finds the arm or the camera touching the wall,
    floor, table or board, the cell model (capsules, boxes, 10 mm clearance) refuses too."""
    cell = SimCell(load_scenario(None), np.random.default_rng(0))
    try:
        model = cell.cell_model()
        assert {b.name for b in model.obstacles} == {"wall", "floor", "table_top", "table_leg", "board_plate"}
        rng = np.random.default_rng(1)
        contacts = 0
        for q in rng.uniform(-np.pi, np.pi, (300, 6)):
            if cell.collision_at(q) is not None:
                contacts += 1
                assert model.problem(q) is not None, f"MuJoCo: {cell.collision_at(q)}; the model: clear"
        assert contacts > 50  # the sample reaches into the obstacles often
    finally:
        cell.close()


@pytest.mark.parametrize("scenario", [None, "realistic.toml"])
def test_the_default_and_realistic_trajectories_are_planned_whole_in_short_moves(
    scenario: str | None,
) -> None:
    loaded = load_scenario(None if scenario is None else models_dir() / "scenarios" / scenario)
    cell = SimulatedCell(SimCell(loaded, np.random.default_rng(0)), 0)
    try:
        moves = cell.plan(scenario_waypoints(loaded))
    finally:
        cell.close()
    assert [m.problem for m in moves if m.joints is None] == []
    assert moves[0].waypoint.index == 0 and sorted(m.waypoint.index for m in moves) == list(range(17))
    swings = [np.degrees(m.swing[1]) for m in moves]
    assert np.median(swings) < 45.0
