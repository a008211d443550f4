"""The real-cell session's plan as the user reads it before the arm moves: a line per waypoint
with its joints, its flange position and the move's largest joint swing, and the motion's rough
duration."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hec.estimator.geometry.waypoints import PlannedMove
from hec.session.cell_config import CellConfig


def format_plan(moves: list[PlannedMove], forward_fk: Callable[[np.ndarray], np.ndarray]) -> str:
    """One line per waypoint: joint target (degrees), the flange position it gives (nominal
    kinematics, metres) and the move's largest single-joint swing, or why it is skipped; then the
    median and largest swing when the planner measured them."""
    lines = [f"{'#':>3}  {'label':<22} {'joints q1..q6 [deg]':<50} {'flange [m]':<22} largest swing"]
    swings = []
    for move in moves:
        w = move.waypoint
        if move.joints is None:
            lines.append(f"{w.index:>3}  {w.label:<22} skipped: {move.problem}")
            continue
        q = " ".join(f"{v:+7.1f}" for v in np.degrees(move.joints))
        p = " ".join(f"{v:+.3f}" for v in forward_fk(move.joints)[:3, 3])
        swing = ""
        if move.swing is not None:
            joint, angle = move.swing
            swing = f"q{joint + 1} {np.degrees(angle):5.1f} deg"
            swings.append(np.degrees(angle))
        lines.append(f"{w.index:>3}  {w.label:<22} {q:<50} {p:<22} {swing}".rstrip())
    if swings:
        lines.append(
            f"largest single-joint swing per move: median {np.median(swings):.1f} deg, "
            f"most {max(swings):.1f} deg"
        )
    return "\n".join(lines)


def motion_time_s(moves: list[PlannedMove], q_start: np.ndarray, config: CellConfig) -> float:
    """Rough duration of the session's motion: a trapezoid per joint move at the configured
    speed and acceleration, plus the dwell and one camera burst per waypoint."""
    speed = np.radians(config.robot.joint_speed_deg_s)
    acceleration = np.radians(config.robot.joint_acceleration_deg_s2)
    capture_s = config.camera.burst / config.camera.fps + 0.1
    total, q = 0.0, q_start
    for move in moves:
        if move.joints is None:
            continue
        distance = float(np.max(np.abs(move.joints - q)))
        ramp = speed / acceleration
        total += distance / speed + ramp if distance > speed * ramp else 2 * np.sqrt(distance / acceleration)
        total += config.robot.dwell_s + capture_s
        q = move.joints
    return total


def print_plan(moves: list[PlannedMove], forward_fk: Callable[[np.ndarray], np.ndarray]) -> None:
    """Print the plan: how many waypoints are visited and skipped, then format_plan."""
    usable = sum(m.joints is not None for m in moves)
    print(f"plan: {len(moves)} waypoints, {usable} to visit, {len(moves) - usable} skipped")
    print(format_plan(moves, forward_fk))
