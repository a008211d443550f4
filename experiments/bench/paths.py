"""Benchmark: the real cell's planner (hec.estimator.geometry.move_plan, least-swing IK branches, each
move checked along its joint path) on simulated cells, every planned move then checked again in
MuJoCo at steps of at most 1 mm at the flange and 0.5 degree per joint: contacts of the arm and the
camera with the cell (wall, floor, table, board), the joint limits, the wrist's cable limit, and each
move's largest single-joint swing.

    python -m hec.bench.paths [--placements 50] [--seed 0]

Cells: the default and the realistic scenario, then `--placements` random placements of the board
(+-0.1 m along each base axis, +-10 degrees about each) and the mount (+-20 mm, +-10 degrees) around
the default. The planner sees the MuJoCo cell through SimCell.collision_at at each target and path
sample; the start is the rehearsal's home joints.
"""

from __future__ import annotations

import argparse

import numpy as np

from hec.estimator.common.models import models_dir
from hec.estimator.geometry.joint_path import CABLE_LIMIT_RAD, PATH_STEP_RAD, joint_path, path_problem
from hec.estimator.geometry.kinematics import ROBOTS, URKinematics, forward, solve_ik_nearest, ur_ik_branches
from hec.estimator.geometry.move_plan import plan_joint_moves
from hec.rehearsal.rig import HOME_JOINTS
from hec.session.cell_config import RobotSection
from hec.sim.cell import SimCell
from hec.sim.scenario import Scenario, load_scenario
from hec.sim.simulate import scenario_waypoints

CHECK_STEP_M = 0.001  # the verification's largest flange step, metres


def _limits() -> tuple[np.ndarray, np.ndarray]:
    robot = RobotSection()
    return np.radians(robot.joint_lower_deg), np.radians(robot.joint_upper_deg)


def random_placement(base: Scenario, rng: np.random.Generator) -> Scenario:
    """base with the board and the mount moved at random (module doc)."""
    board, mount = base.board, base.mount
    board = board.model_copy(
        update={
            "translation_m": tuple(np.add(board.translation_m, rng.uniform(-0.1, 0.1, 3))),
            "rotation_rpy_deg": tuple(np.add(board.rotation_rpy_deg, rng.uniform(-10, 10, 3))),
        }
    )
    mount = mount.model_copy(
        update={
            "translation_m": tuple(np.add(mount.translation_m, rng.uniform(-0.02, 0.02, 3))),
            "rotation_rpy_deg": tuple(np.add(mount.rotation_rpy_deg, rng.uniform(-10, 10, 3))),
        }
    )
    return base.model_copy(update={"board": board, "mount": mount})


def _fine_path(kinematics: URKinematics, q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
    """(N, 6) the moveJ's joint path at steps of at most 0.5 degree per joint and CHECK_STEP_M at
    the flange (the 0.5 degree path's largest flange step, divided down)."""
    coarse = joint_path(q_from, q_to, PATH_STEP_RAD)
    flange = np.array([forward(kinematics, q)[:3, 3] for q in coarse])
    largest = float(np.max(np.linalg.norm(np.diff(flange, axis=0), axis=1), initial=0.0))
    return joint_path(q_from, q_to, PATH_STEP_RAD * min(1.0, CHECK_STEP_M / max(largest, 1e-12)))


def plan_and_check(scenario: Scenario, seed: int) -> dict:
    """Plan the scenario's trajectory on its MuJoCo cell and check every planned move (module doc):
    counts, the problems found along the planned paths, and the swings (degrees)."""
    kinematics = ROBOTS["ur5"]
    lower, upper = _limits()
    cell = SimCell(scenario, np.random.default_rng(seed))
    try:
        cell.set_joints(HOME_JOINTS)
        moves = plan_joint_moves(
            scenario_waypoints(scenario),
            HOME_JOINTS,
            lower,
            upper,
            CABLE_LIMIT_RAD,
            cell.collision_at,
            cell.collision_at,
            lambda T, q: solve_ik_nearest(kinematics, T, q),
            lambda T, q, lo, hi: ur_ik_branches(kinematics, T, q, lo, hi),
        )
        problems, swings, q = [], [], HOME_JOINTS
        for move in moves:
            if move.joints is None:
                continue
            swings.append(np.degrees(move.swing[1]))
            path = _fine_path(kinematics, q, move.joints)
            problem = path_problem(path, lower, upper, HOME_JOINTS[5], CABLE_LIMIT_RAD, cell.collision_at)
            if problem is not None:
                problems.append(f"waypoint {move.waypoint.index}: {problem}")
            q = move.joints
    finally:
        cell.close()
    return {
        "waypoints": len(moves),
        "planned": sum(m.joints is not None for m in moves),
        "refused": [f"{m.waypoint.index}: {m.problem}" for m in moves if m.joints is None],
        "path_problems": problems,
        "median_swing_deg": float(np.median(swings)) if swings else float("nan"),
        "largest_swing_deg": float(max(swings, default=float("nan"))),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hec.bench.paths", description=__doc__.split("\n\n")[0])
    parser.add_argument("--placements", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    default = load_scenario(None)
    cells = [
        ("default", default),
        ("realistic", load_scenario(models_dir() / "scenarios" / "realistic.toml")),
    ]
    rng = np.random.default_rng(args.seed)
    cells += [(f"placement {i}", random_placement(default, rng)) for i in range(args.placements)]
    print(f"{'cell':<14} {'planned':>9} {'path problems':>14} {'median swing':>13} {'largest swing':>14}")
    medians, total_problems, refused = [], 0, 0
    for name, scenario in cells:
        result = plan_and_check(scenario, args.seed)
        planned = f"{result['planned']}/{result['waypoints']}"
        print(
            f"{name:<14} {planned:>9} {len(result['path_problems']):>14} "
            f"{result['median_swing_deg']:>9.1f} deg {result['largest_swing_deg']:>10.1f} deg"
        )
        for line in result["path_problems"] + result["refused"]:
            print(f"    {line}")
        if name.startswith("placement"):
            medians.append(result["median_swing_deg"])
        total_problems += len(result["path_problems"])
        refused += len(result["refused"])
    median = float(np.median(medians)) if medians else float("nan")
    print(
        f"{len(cells)} cells: {total_problems} planned moves with a problem along the path, {refused} "
        f"waypoints refused; placements' median of the median swing {median:.1f} deg"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
