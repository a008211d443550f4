"""Planning a session's moves: joint targets for the waypoints and every move checked along its path
before the arm moves (joint_path), shared by the real cell's planner and the path benchmark."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hec.estimator.geometry.joint_path import (
    joint_path,
    largest_swing,
    least_swing_branches,
    path_problem,
    short_visit_order,
)
from hec.estimator.geometry.waypoints import PlannedMove, Waypoint

# (T_base_flange (4, 4), q_near (6,), lower (6,), upper (6,)) -> (M, 6) joint solutions within the bounds
Branches = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]

_REPLANS = 200  # how often the least-swing choice of branches is made again around a failing move


def plan_joint_moves(
    waypoints: list[Waypoint],
    q_start: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    cable_limit_rad: float,
    target_problem: Callable[[np.ndarray], str | None],
    sample_problem: Callable[[np.ndarray], str | None] | None,
    inverse: Callable[[np.ndarray, np.ndarray], np.ndarray | None],
    branches: Branches | None = None,
) -> list[PlannedMove]:
    """Joint targets from q_start (6,) on, within lower, upper (6,), radians: pose waypoints
    through inverse (seeded with the previous target, the last joint turned by whole turns to stay
    within cable_limit_rad of q_start's), each target checked by target_problem and each move along
    its joint path (joint_path, 0.5 degree steps) against the limits, the cable limit and
    sample_problem (joints -> reason or None: the workspace, collisions); a waypoint that fails is
    skipped, named with why and where, and the next starts from the one before. Each usable move
    carries its largest single-joint swing. branches: (T_base_flange, q_near, lower, upper) ->
    (M, 6) every joint solution within the bounds; given, the waypoints are visited in an order
    that keeps the joint travel short (short_visit_order, the first kept first; the moves come back
    in that order) and their solutions are chosen together for the least total swing
    (least_swing_branches), around moves that fail."""
    q = np.asarray(q_start, dtype=float)
    q6_start = float(q[5])
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)

    window_lower, window_upper = lower.copy(), upper.copy()
    window_lower[5] = max(lower[5], q6_start - cable_limit_rad)
    window_upper[5] = min(upper[5], q6_start + cable_limit_rad)

    def move_problem(q_from: np.ndarray, q_to: np.ndarray) -> str | None:
        problem = target_problem(q_to)
        if problem is not None:
            return f"{problem} at the waypoint"
        path = joint_path(q_from, q_to)
        return path_problem(path, lower, upper, q6_start, cable_limit_rad, sample_problem)

    planned = _least_swing_targets(
        waypoints, q, window_lower, window_upper, branches, target_problem, move_problem
    )
    chosen: list[np.ndarray | None] = [None] * len(waypoints)
    if planned is not None:
        order, chosen = planned
        waypoints = [waypoints[k] for k in order]
    moves = []
    previous = "the start"
    for waypoint, target in zip(waypoints, chosen, strict=True):
        if target is None:
            target = waypoint.joints if waypoint.joints is not None else inverse(waypoint.T_base_flange, q)
            if target is None:
                moves.append(
                    PlannedMove(waypoint, None, "no inverse kinematics solution within the joint limits")
                )
                continue
            target = np.asarray(target, dtype=float)
            if waypoint.joints is None:
                target = wrist_turn_nearest(target, q[5], window_lower[5], window_upper[5])
        problem = move_problem(q, target)
        if problem is not None:
            moves.append(PlannedMove(waypoint, None, f"the move from {previous}: {problem}"))
            continue
        moves.append(PlannedMove(waypoint, target, swing=largest_swing(q, target)))
        q = target
        previous = f"waypoint {waypoint.index}"
    return moves


def _least_swing_targets(
    waypoints: list[Waypoint],
    q_start: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    branches: Branches | None,
    target_problem: Callable[[np.ndarray], str | None],
    move_problem: Callable[[np.ndarray, np.ndarray], str | None],
) -> tuple[list[int], list[np.ndarray | None]] | None:
    """The visit order (indices into waypoints) and each visited waypoint's joint target (6,) in
    that order. The waypoints with a solution within lower, upper that target_problem (joints ->
    reason or None) accepts come first, in short_visit_order from q_start, their targets chosen
    together for the least total swing with every move passing move_problem (q_from, q_to -> reason
    or None): a sequence with a move that fails is chosen again without that move, up to _REPLANS
    times. The others follow with target None (the caller says why). None: no branches given, or no
    sequence found."""
    if branches is None:
        return None
    candidates = []
    for w in waypoints:
        solutions = (
            np.asarray(w.joints, dtype=float)[None]
            if w.joints is not None
            else branches(w.T_base_flange, q_start, lower, upper)
        )
        candidates.append(np.array([q for q in solutions if target_problem(q) is None]).reshape(-1, 6))
    usable = [k for k, c in enumerate(candidates) if len(c)]
    unusable = [k for k, c in enumerate(candidates) if not len(c)]
    if not usable:
        return list(range(len(waypoints))), [None] * len(waypoints)
    order = [usable[k] for k in short_visit_order([candidates[k] for k in usable], q_start)]
    visited = [candidates[k] for k in order]
    forbidden: set[tuple[int, int, int]] = set()
    for _ in range(_REPLANS):
        picks = least_swing_branches(visited, q_start, frozenset(forbidden))
        if picks is None:
            return None
        q, a = q_start, 0
        for i, b in enumerate(picks):
            target = visited[i][b]
            if move_problem(q, target) is not None:
                forbidden.add((i, a, b))
                break
            q, a = target, b
        else:
            targets: list[np.ndarray | None] = [c[i] for c, i in zip(visited, picks, strict=True)]
            return order + unusable, targets + [None] * len(unusable)
    return None


def wrist_turn_nearest(q: np.ndarray, q6_previous: float, q6_lower: float, q6_upper: float) -> np.ndarray:
    """q (6,) with its last joint moved by whole turns (the same flange pose) to the turn nearest
    q6_previous within [q6_lower, q6_upper], radians (the cable window and the joint limits), or q
    unchanged when no turn is within them (the path check then refuses it)."""
    turn = 2.0 * np.pi
    candidates = q[5] + turn * np.arange(-3, 4)
    candidates = candidates[(candidates >= q6_lower) & (candidates <= q6_upper)]
    if len(candidates) == 0:
        return q
    out = q.copy()
    out[5] = candidates[np.argmin(np.abs(candidates - q6_previous))]
    return out
