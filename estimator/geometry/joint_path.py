"""The path a joint move (UR moveJ) takes: every joint interpolated linearly from start to target, so
all arrive together; and a linear move's (UR moveL): the flange along a straight line, turning along
the shortest rotation, its joints followed by inverse kinematics. Sampled at fine steps, it is checked
before the arm moves: joint limits, the wrist's cable limit (the last joint within a span of where
the session started, so a cable on the flange does not wind up) and, through a caller's check, the
cell (hec.estimator.geometry.cell_model) and the flange's workspace at every sample."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

PATH_STEP_RAD = float(np.radians(0.5))  # the largest joint step between two checked samples
CABLE_LIMIT_RAD = float(np.pi)  # the wrist's default cable limit (the cell file's wrist_cable_limit_deg)


def joint_path(q_from: np.ndarray, q_to: np.ndarray, step_rad: float = PATH_STEP_RAD) -> np.ndarray:
    """(N, 6) joint samples of the moveJ from q_from (6,) to q_to (6,), radians, both ends
    included, no joint moving more than step_rad between two samples."""
    q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
    steps = max(1, int(np.ceil(np.max(np.abs(q_to - q_from)) / step_rad)))
    s = np.linspace(0.0, 1.0, steps + 1)[:, None]
    return q_from + s * (q_to - q_from)


LINEAR_STEP_M = 0.001  # the largest flange step between two checked samples of a moveL
_JUMP_RAD = float(np.radians(5.0))  # a joint turning this much in one moveL step: a singularity


def linear_move_problem(
    q_from: np.ndarray,
    T_base_flange_to: np.ndarray,
    forward: Callable[[np.ndarray], np.ndarray],
    inverse_near: Callable[[np.ndarray, np.ndarray], np.ndarray | None],
    check: Callable[[np.ndarray], str | None],
) -> str | None:
    """Why the moveL from joints q_from (6,) to the flange pose T_base_flange_to (4, 4) may not be
    driven, or None: the flange poses at most LINEAR_STEP_M and PATH_STEP_RAD apart (straight
    line, shortest rotation from forward(q_from)), each turned into joints by inverse_near (pose,
    the previous joints -> joints or None); a pose without a solution, a joint turning more than
    5 degrees between two samples (a singularity on the way), or check (the joint path (N, 6) ->
    reason or None, e.g. path_problem with the cell model) objecting to the path so followed."""
    from scipy.spatial.transform import Rotation, Slerp

    T_from = forward(q_from)
    distance = float(np.linalg.norm(T_base_flange_to[:3, 3] - T_from[:3, 3]))
    rotations = Rotation.from_matrix(np.stack([T_from[:3, :3], T_base_flange_to[:3, :3]]))
    angle = float((rotations[0].inv() * rotations[1]).magnitude())
    steps = max(1, int(np.ceil(max(distance / LINEAR_STEP_M, angle / PATH_STEP_RAD))))
    s = np.linspace(0.0, 1.0, steps + 1)
    turned = Slerp([0.0, 1.0], rotations)(s).as_matrix()
    path, q = [np.asarray(q_from, dtype=float)], np.asarray(q_from, dtype=float)
    for i in range(1, steps + 1):
        T = np.eye(4)
        T[:3, :3] = turned[i]
        T[:3, 3] = T_from[:3, 3] + s[i] * (T_base_flange_to[:3, 3] - T_from[:3, 3])
        q_next = inverse_near(T, q)
        if q_next is None:
            return f"the flange leaves the arm's reach {_along(i, steps + 1)}"
        if np.max(np.abs(q_next - q)) > _JUMP_RAD:
            return f"the arm passes a singularity (a joint flips) {_along(i, steps + 1)}"
        path.append(q_next)
        q = q_next
    return check(np.array(path))


def largest_swing(q_from: np.ndarray, q_to: np.ndarray) -> tuple[int, float]:
    """The joint (0-based) that moves most from q_from (6,) to q_to (6,), and by how much, radians."""
    dq = np.abs(np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float))
    joint = int(np.argmax(dq))
    return joint, float(dq[joint])


def path_problem(
    path: np.ndarray,
    q_lower: np.ndarray,
    q_upper: np.ndarray,
    q6_start: float,
    cable_limit_rad: float,
    pose_problem: Callable[[np.ndarray], str | None] | None = None,
) -> str | None:
    """Why the joint path (N, 6) may not be driven, or None: a sample outside the joint limits
    q_lower, q_upper (6,), the last joint farther than cable_limit_rad from q6_start (radians), or
    the first sample pose_problem (joints (6,) -> reason or None) objects to once the path has been
    clear (an arm that starts where it objects may leave; it may not end there). The reason says how
    far along the path (per cent) it happens."""
    lower, upper = np.asarray(q_lower, dtype=float), np.asarray(q_upper, dtype=float)
    n = len(path)
    outside = (path < lower) | (path > upper)
    if outside.any():
        i, j = np.argwhere(outside)[0]
        return (
            f"q{j + 1} passes its limit ({np.degrees(path[i, j]):+.1f} deg, limits "
            f"{np.degrees(lower[j]):+.0f}..{np.degrees(upper[j]):+.0f}) {_along(i, n)}"
        )
    wound = np.abs(path[:, 5] - q6_start) > cable_limit_rad + 1e-9
    if wound.any():
        i = int(np.argmax(wound))
        return (
            f"the wrist would wind the camera cable: q6 at {np.degrees(path[i, 5]):+.1f} deg, more than "
            f"{np.degrees(cable_limit_rad):.0f} deg from its start {np.degrees(q6_start):+.1f} deg "
            f"{_along(i, n)}"
        )
    if pose_problem is not None:
        clear = False  # an arm that starts where pose_problem objects may move out of there
        for i, q in enumerate(path):
            problem = pose_problem(q)
            if problem is None:
                clear = True
            elif clear or i == n - 1:
                return f"{problem} {_along(i, n)}"
    return None


def _along(i: int, n: int) -> str:
    return f"at {100.0 * i / max(n - 1, 1):.0f} % of the move"


def least_swing_branches(
    candidates: list[np.ndarray],
    q_start: np.ndarray,
    forbidden: frozenset[tuple[int, int, int]] = frozenset(),
) -> list[int] | None:
    """The candidate per waypoint (an index into each candidates[i], (M_i, 6) joint solutions of
    waypoint i, radians) that keeps the moves short: the sequence from q_start (6,) with the least
    sum of each move's largest single-joint swing (dynamic programming over the branches), never
    using a forbidden move (i, a, b): from candidate a of waypoint i - 1 (a = 0: q_start for i = 0)
    to candidate b of waypoint i. None when no sequence is left."""
    picks, _ = _least_swing(candidates, q_start, forbidden)
    return picks


def short_visit_order(candidates: list[np.ndarray], q_start: np.ndarray) -> list[int]:
    """An order of the waypoints (indices into candidates, (M_i, 6) joint solutions of waypoint i,
    radians) whose least-swing branches (least_swing_branches) from q_start (6,) sum to a short
    joint travel: the given order improved by 2-opt (a stretch of the visits reversed while that
    shortens it), the first waypoint kept first. The given order when a waypoint has no candidate."""
    order = list(range(len(candidates)))
    _, best = _least_swing(candidates, q_start)
    if not np.isfinite(best):
        return order
    improved = True
    while improved:
        improved = False
        for i in range(1, len(order) - 1):
            for j in range(i + 1, len(order)):
                trial = order[:i] + order[i : j + 1][::-1] + order[j + 1 :]
                _, total = _least_swing([candidates[k] for k in trial], q_start)
                if total < best - 1e-9:
                    order, best, improved = trial, total, True
    return order


def _least_swing(
    candidates: list[np.ndarray],
    q_start: np.ndarray,
    forbidden: frozenset[tuple[int, int, int]] = frozenset(),
) -> tuple[list[int] | None, float]:
    """least_swing_branches's choice and its sum of largest swings, radians (inf: none left)."""
    if not candidates or any(len(c) == 0 for c in candidates):
        return None, float("inf")
    cost = np.max(np.abs(candidates[0] - q_start), axis=1)
    cost[[b for i, _, b in forbidden if i == 0]] = np.inf
    back: list[np.ndarray] = []
    for i, (previous, current) in enumerate(zip(candidates, candidates[1:], strict=False), start=1):
        swing = np.max(np.abs(current[:, None, :] - previous[None, :, :]), axis=2)  # (M_i, M_i-1)
        for j, a, b in forbidden:
            if j == i:
                swing[b, a] = np.inf
        total = swing + cost[None, :]
        back.append(np.argmin(total, axis=1))
        cost = np.min(total, axis=1)
    if not np.isfinite(cost.min()):
        return None, float("inf")
    chosen = [int(np.argmin(cost))]
    for pointers in reversed(back):
        chosen.append(int(pointers[chosen[-1]]))
    return chosen[::-1], float(cost.min())
