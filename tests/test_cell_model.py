"""The cell model the planner checks every move against before the arm moves, without a simulator:
its link capsules contain the arm's collision shapes in the MJCF files and sit where the kinematics
puts them; a moveJ through the table and a moveL into the wall are refused, naming the obstacle."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from hec.estimator.common.models import models_dir
from hec.estimator.geometry.cell_model import FLANGE, UR_LINK_CAPSULES, link_frames
from hec.estimator.geometry.joint_path import joint_path, linear_move_problem, path_problem
from hec.estimator.geometry.kinematics import ROBOTS, forward, solve_ik_nearest
from hec.estimator.geometry.move_plan import plan_joint_moves
from hec.estimator.geometry.waypoints import Waypoint
from hec.session.cell_config import CellConfig

LOWER, UPPER = (
    np.radians([-360.0] * 2 + [-180.0] + [-360.0] * 3),
    np.radians([360.0] * 2 + [180.0] + [360.0] * 3),
)
UR5 = ROBOTS["ur5"]
Q_HOME = np.array([-1.57, -1.57, 1.57, -1.57, -1.57, 0.0])
# The base joint swings the bent arm over the cell: both ends clear, the wrist through the table top.
Q_A = np.array([0.88, -1.01, 1.01, -1.57, -1.57, 0.0])
Q_B = np.array([2.8, -1.01, 1.01, -1.57, -1.57, 0.0])
LINKS = ("upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link")


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    s = np.clip(np.dot(p - a, b - a) / max(np.dot(b - a, b - a), 1e-18), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + s * (b - a))))


def _shape_points(geom: ET.Element) -> tuple[np.ndarray, float]:
    """Points (N, 3) in the body frame and a radius whose spheres cover the MJCF geom (a z-axis
    cylinder: its two rims, radius 0; a capsule: its two ends and its radius)."""
    size = [float(v) for v in geom.get("size", "").split()]
    if geom.get("type") == "capsule":
        return np.array([float(v) for v in geom.get("fromto", "").split()]).reshape(2, 3), size[0]
    r, h = size
    pos = np.array([float(v) for v in geom.get("pos", "0 0 0").split()])
    angles = np.linspace(0.0, 2.0 * np.pi, 36, endpoint=False)
    rim = np.column_stack([r * np.cos(angles), r * np.sin(angles), np.zeros_like(angles)])
    return np.vstack([pos + rim + [0, 0, -h], pos + rim + [0, 0, h]]), 0.0


@pytest.mark.parametrize("arm", ["ur5.xml", "ur5e.xml"])
def test_the_link_capsules_contain_the_arms_collision_shapes(arm: str) -> None:
    root = ET.parse(models_dir() / arm).getroot()
    for link, name in enumerate(LINKS, start=2):
        body = root.find(f".//body[@name='{name}']")
        assert body is not None
        shapes = [g for g in body.findall("geom") if g.get("contype", "1") != "0"]
        capsules = [c for c in UR_LINK_CAPSULES if c.link == link]
        assert shapes and capsules
        for geom in shapes:
            points, radius = _shape_points(geom)
            inside = [
                max(_segment_distance(p, np.array(c.p0_m), np.array(c.p1_m)) for p in points) + radius
                <= c.radius_m + 1e-9
                for c in capsules
            ]
            assert any(inside), f"{arm} {name}: {geom.attrib} outside every capsule of link {link}"


def test_the_flange_frame_is_the_kinematics_flange() -> None:
    q = np.array([0.3, -1.2, 1.0, -1.0, -1.4, 0.5])
    np.testing.assert_allclose(link_frames(UR5, q)[FLANGE], forward(UR5, q), atol=1e-12)


def test_a_move_planned_through_the_table_is_refused_naming_the_table() -> None:
    cell = CellConfig().cell_model.cell_model("ur5")
    assert cell.problem(Q_A) is None and cell.problem(Q_B) is None
    waypoints = [Waypoint(0, "left", joints=Q_A), Waypoint(1, "right", joints=Q_B)]
    first, second = plan_joint_moves(
        waypoints, Q_A, LOWER, UPPER, np.pi, cell.problem, cell.problem, lambda T, q: None
    )
    assert first.joints is not None and second.joints is None
    assert second.problem.startswith("the move from waypoint 0: the ") and "the table top" in second.problem
    assert "% of the move" in second.problem
    # the same obstacle moved out of the way: the move passes
    away = CellConfig(cell_model={"obstacles": []}).cell_model.cell_model("ur5")
    assert path_problem(joint_path(Q_A, Q_B), LOWER, UPPER, 0.0, np.pi, away.problem) is None


def test_a_linear_move_into_the_wall_is_refused_naming_the_wall() -> None:
    cell = CellConfig().cell_model.cell_model("ur5")
    T_home = forward(UR5, Q_HOME)
    assert cell.problem(Q_HOME) is None and T_home[2, 3] > 0.3  # the flange 0.43 m out of the wall

    def move_to(z_m: float) -> str | None:
        T_to = T_home.copy()
        T_to[2, 3] = z_m
        return linear_move_problem(
            Q_HOME,
            T_to,
            lambda q: forward(UR5, q),
            lambda T, q: solve_ik_nearest(UR5, T, q),
            lambda path: path_problem(path, LOWER, UPPER, 0.0, np.pi, cell.problem),
        )

    problem = move_to(0.0)  # straight back to the wall's face
    assert problem is not None and "the camera" in problem and "the wall" in problem
    assert "% of the move" in problem
    assert move_to(T_home[2, 3] + 0.1) is None  # away from it
