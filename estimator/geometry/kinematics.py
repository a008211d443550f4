"""UR arm kinematics from UR's published DH parameters, and a damped least-squares IK.

The MJCF models in models/ place each link at its DH frame, so these
functions and MuJoCo agree (tests/test_kinematics.py checks it).
Frames: ``base`` is UR's base frame, ``flange`` is tool0 (DH frame 6).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from hec.estimator.geometry.transforms import invert


@dataclass(frozen=True)
class URKinematics:
    """Classic DH table (d, a, alpha per joint; metres, radians), joint limits, and joint zero
    offsets (radians; the DH angle of joint i is q[i] + theta_offset[i], zero for UR's nominal
    model, non-zero for an arm whose true kinematics differ from it)."""

    name: str
    d: tuple[float, ...]
    a: tuple[float, ...]
    alpha: tuple[float, ...]
    q_lower: tuple[float, ...]
    q_upper: tuple[float, ...]
    theta_offset: tuple[float, ...] = (0.0,) * 6


_HALF_PI = np.pi / 2
_LIMITS = ((-2 * np.pi,) * 2 + (-np.pi,) + (-2 * np.pi,) * 3, (2 * np.pi,) * 2 + (np.pi,) + (2 * np.pi,) * 3)


def _ur(name: str, d1: float, a2: float, a3: float, d4: float, d5: float, d6: float) -> URKinematics:
    """A UR arm from the six lengths of UR's published DH table (the twists are the same on all)."""
    return URKinematics(
        name,
        d=(d1, 0.0, 0.0, d4, d5, d6),
        a=(0.0, a2, a3, 0.0, 0.0, 0.0),
        alpha=(_HALF_PI, 0.0, 0.0, _HALF_PI, -_HALF_PI, 0.0),
        q_lower=_LIMITS[0],
        q_upper=_LIMITS[1],
    )


# UR's published DH tables. The simulated cell has MJCF of the UR5 and UR5e only; the other arms
# serve imports, whose flange poses may be computed from the joints.
UR5 = _ur("ur5", 0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823)
UR5E = _ur("ur5e", 0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996)
UR3 = _ur("ur3", 0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819)
UR10 = _ur("ur10", 0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922)
UR3E = _ur("ur3e", 0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921)
UR10E = _ur("ur10e", 0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655)
UR16E = _ur("ur16e", 0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655)
# The arms of the simulated and the real cell (models/ has their MJCF), and every arm whose
# kinematics hec knows (imports and calibrations of recorded data).
ROBOTS = {k.name: k for k in (UR5, UR5E)}
ARMS = {k.name: k for k in (UR3, UR5, UR10, UR3E, UR5E, UR10E, UR16E)}
# The orders a UR arm's six joint angles are written in: the arm's own (base, shoulder, elbow,
# wrist 1-3) and the ROS driver's /joint_states (names sorted: elbow, shoulder_lift, shoulder_pan,
# wrist 1-3). Swapping the first and third angle turns either into the other.
JOINT_ORDERS = ("arm", "ros-driver")
_DRIVER_SWAP = np.array([2, 1, 0, 3, 4, 5])


def arm_dict(kin: URKinematics) -> dict:
    """The DH table of an arm as dataset.json's 'robot_dh' holds it (metres, radians)."""
    return {
        "d": list(kin.d),
        "a": list(kin.a),
        "alpha": list(kin.alpha),
        "theta_offset": list(kin.theta_offset),
    }


def arm_from_dict(name: str, data: dict) -> URKinematics:
    """The arm of an arm_dict (limits: +-2 pi on every joint); raises KeyError, TypeError or
    ValueError on a malformed one."""
    rows = [tuple(float(v) for v in data[key]) for key in ("d", "a", "alpha", "theta_offset")]
    if any(len(row) != 6 for row in rows):
        raise ValueError("every row of a DH table has 6 numbers")
    return URKinematics(name, rows[0], rows[1], rows[2], (-2 * np.pi,) * 6, (2 * np.pi,) * 6, rows[3])


def joints_in_arm_order(joints: np.ndarray, order: str) -> np.ndarray:
    """(N, 6) joint angles written in order (JOINT_ORDERS) -> the arm's order."""
    if order not in JOINT_ORDERS:
        raise ValueError(f"joint order must be one of {', '.join(JOINT_ORDERS)}, got {order!r}")
    joints = np.asarray(joints, dtype=np.float64)
    return joints[:, _DRIVER_SWAP] if order == "ros-driver" else joints


@lru_cache(maxsize=32)
def _dh_table(kin: URKinematics) -> tuple[np.ndarray, ...]:
    """Per joint (6,) float64: theta_offset, a, cos(alpha), sin(alpha), and the (6, 4, 4) steps with
    the entries that do not depend on the joint angle filled in."""
    a = np.array(kin.a)
    ca, sa = np.cos(kin.alpha), np.sin(kin.alpha)
    steps = np.zeros((6, 4, 4))
    steps[:, 2, 1], steps[:, 2, 2], steps[:, 2, 3], steps[:, 3, 3] = sa, ca, kin.d, 1.0
    return np.array(kin.theta_offset), a, ca, sa, steps


def dh_frames(kin: URKinematics, q: np.ndarray) -> np.ndarray:
    """(7, 4, 4) poses T_base_i of DH frames 0..6 for joint angles q (6,)."""
    offset, a, ca, sa, template = _dh_table(kin)
    q = np.asarray(q, dtype=float)
    theta = np.where(offset != 0.0, q + offset, q)  # nominal: q exactly
    ct, st = np.cos(theta), np.sin(theta)
    steps = template.copy()
    steps[:, 0, 0], steps[:, 0, 1], steps[:, 0, 2], steps[:, 0, 3] = ct, -st * ca, st * sa, a * ct
    steps[:, 1, 0], steps[:, 1, 1], steps[:, 1, 2], steps[:, 1, 3] = st, ct * ca, -ct * sa, a * st
    frames = np.empty((7, 4, 4))
    frames[0] = np.eye(4)
    for i in range(6):
        np.matmul(frames[i], steps[i], out=frames[i + 1])
    return frames


def forward(kin: URKinematics, q: np.ndarray) -> np.ndarray:
    """T_base_flange (4, 4) for joint angles q (6,), radians."""
    return dh_frames(kin, q)[6]


def jacobian(kin: URKinematics, q: np.ndarray) -> np.ndarray:
    """(6, 6) geometric Jacobian of the flange: rows (v, omega) in the base frame."""
    return _jacobian_from_frames(dh_frames(kin, q))


def _jacobian_from_frames(frames: np.ndarray) -> np.ndarray:
    """(6, 6) Jacobian from the (7, 4, 4) DH frames: column i is (z_i x (p_6 - p_i), z_i)."""
    z = frames[:6, :3, 2].T  # (3, 6): z axis of each joint
    r = frames[6, :3, 3, None] - frames[:6, :3, 3].T  # (3, 6): joint origin to flange
    J = np.empty((6, 6), order="F")  # Fortran order as ever: solve_ik's BLAS products round by layout
    J[0] = z[1] * r[2] - z[2] * r[1]
    J[1] = z[2] * r[0] - z[0] * r[2]
    J[2] = z[0] * r[1] - z[1] * r[0]
    J[3:] = z
    return J


def _norm(v: np.ndarray) -> float:
    """Euclidean norm of a (3,) vector (as np.linalg.norm computes it)."""
    return math.sqrt(v.dot(v))


def _rotation_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) of a (3, 3) rotation."""
    skew = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    sin2 = _norm(skew)
    angle = np.arctan2(0.5 * sin2, 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0))
    if angle > np.pi - 1e-3:
        return Rotation.from_matrix(R).as_rotvec()
    return skew * (0.5 if sin2 < 1e-12 else angle / sin2)


@dataclass(frozen=True)
class IKResult:
    q: np.ndarray
    converged: bool
    position_error_m: float
    rotation_error_rad: float
    iterations: int


def solve_ik(
    kin: URKinematics,
    T_base_flange: np.ndarray,
    q_seed: np.ndarray,
    damping: float = 1e-3,
    max_step_rad: float = 0.3,
    tol: float = 1e-10,
    max_iterations: int = 300,
    stall_window: int = 40,
) -> IKResult:
    """Damped least squares from q_seed toward the target flange pose.

    Joint angles are clamped to the limits after each step, so a target
    reachable only outside them does not converge.
    """
    lower, upper = np.array(kin.q_lower), np.array(kin.q_upper)
    q = np.clip(np.asarray(q_seed, dtype=float), lower, upper)
    R_target, p_target = T_base_flange[:3, :3], T_base_flange[:3, 3]
    damping_eye = damping**2 * np.eye(6)
    e = np.empty(6)
    e_p, e_r = e[:3], e[3:]
    history: list[float] = []
    for iteration in range(max_iterations + 1):
        frames = dh_frames(kin, q)
        T = frames[6]
        np.subtract(p_target, T[:3, 3], out=e_p)
        e_r[:] = _rotation_log(R_target @ T[:3, :3].T)
        error = _norm(e_p) + _norm(e_r)
        if error < tol or iteration == max_iterations:
            break
        # Stop early when the error has not halved in the last stall_window iterations.
        history.append(error)
        if len(history) > stall_window and error > 0.5 * history[-stall_window - 1]:
            break
        J = _jacobian_from_frames(frames)
        dq = J.T @ np.linalg.solve(J @ J.T + damping_eye, e)
        largest = np.abs(dq).max()
        if largest > max_step_rad:
            dq *= max_step_rad / largest
        q = np.minimum(np.maximum(q + dq, lower), upper)
    pos_err, rot_err = _norm(e_p), _norm(e_r)
    converged = pos_err < 1e-8 and rot_err < 1e-8
    return IKResult(q, converged, pos_err, rot_err, iteration)


# Fixed IK restarts, tried when the current joints do not lead to a solution.
IK_RESTARTS = np.array(
    [
        [-2.4, -2.25, 1.95, 0.3, -2.4, 0.0],
        [-0.8, -0.9, -1.95, -0.3, 2.4, 0.0],
        [-1.57, -1.57, 1.57, -1.57, -1.57, 0.0],
        [1.57, -1.57, 1.57, 0.0, 1.57, 0.0],
        [0.0, -1.0, 2.0, -1.0, -1.57, 0.0],
        [-3.14, -2.0, 1.0, 1.0, -1.57, 0.0],
    ]
)


def solve_ik_nearest(kin: URKinematics, T_base_flange: np.ndarray, q_seed: np.ndarray) -> np.ndarray | None:
    """Joints (6,) reaching T_base_flange that move the joints least from q_seed (the largest joint
    move): of every closed-form solution for a UR arm's nominal model (ur_ik_nearest_first); otherwise
    from q_seed if that converges, else of the solutions from IK_RESTARTS. None when none is found."""
    if has_ur_structure(kin):
        return next(ur_ik_nearest_first(kin, T_base_flange, q_seed), None)
    first = solve_ik(kin, T_base_flange, q_seed)
    if first.converged:
        return first.q
    solutions = [r.q for r in (solve_ik(kin, T_base_flange, seed) for seed in IK_RESTARTS) if r.converged]
    if not solutions:
        return None
    return min(solutions, key=lambda q: float(np.max(np.abs(q - q_seed))))


def has_ur_structure(kin: URKinematics) -> bool:
    """Whether kin is a UR arm's nominal DH model (twists pi/2, 0, 0, pi/2, -pi/2, 0; a1 = a4 = a5 = a6
    = 0; d2 = d3 = 0; no joint offsets), for which ur_ik_nearest_first is exact."""
    return (
        np.allclose(kin.alpha, (_HALF_PI, 0.0, 0.0, _HALF_PI, -_HALF_PI, 0.0), rtol=0, atol=1e-12)
        and kin.a[0] == kin.a[3] == kin.a[4] == kin.a[5] == 0.0
        and kin.d[1] == kin.d[2] == 0.0
        and not any(kin.theta_offset)
    )


def _dh_steps(kin: URKinematics, joint: int, theta: np.ndarray) -> np.ndarray:
    """(N, 4, 4) DH transforms of one joint (frame joint -> joint + 1) at the DH angles theta (N,)."""
    _, a, ca, sa, template = _dh_table(kin)
    ct, st = np.cos(theta), np.sin(theta)
    steps = np.repeat(template[joint][None], len(theta), axis=0)
    steps[:, 0, 0], steps[:, 0, 1], steps[:, 0, 2] = ct, -st * ca[joint], st * sa[joint]
    steps[:, 1, 0], steps[:, 1, 1], steps[:, 1, 2] = st, ct * ca[joint], -ct * sa[joint]
    steps[:, 0, 3], steps[:, 1, 3] = a[joint] * ct, a[joint] * st
    return steps


def _ur_closed_form(kin: URKinematics, T_base_flange: np.ndarray, q_near: np.ndarray) -> list[np.ndarray]:
    """The closed-form joint solutions (6,) of a UR arm (has_ur_structure) reaching T_base_flange,
    not refined (up to 8: shoulder, wrist and elbow each one way or the other, in that nesting
    order), each angle at its turn within the limits nearest q_near's; none where an angle has no
    turn within them. The branches are computed side by side as arrays."""
    a2, a3, d4, d6 = kin.a[1], kin.a[2], kin.d[3], kin.d[5]
    R, p = T_base_flange[:3, :3], T_base_flange[:3, 3]
    wrist = p - d6 * R[:, 2]  # origin of DH frame 5
    radius = math.hypot(wrist[0], wrist[1])
    if radius < abs(d4):
        return []
    psi, phi = math.atan2(wrist[1], wrist[0]), math.asin(d4 / radius)
    shoulder = np.array([psi + phi, psi + math.pi - phi])
    z1 = np.column_stack([np.sin(shoulder), -np.cos(shoulder), np.zeros(2)])  # (2, 3)
    c5 = np.arccos(np.clip(z1 @ R[:, 2], -1.0, 1.0))
    q1 = np.repeat(shoulder, 2)  # (4,): each shoulder with the wrist one way, then the other
    q5 = np.column_stack([c5, -c5]).ravel()
    v = np.repeat(z1 @ R, 2, axis=0)  # R^T z1 per branch
    s5 = np.sin(q5)
    singular = np.abs(s5) < 1e-9  # wrist singular: any q6, keep the current one
    s5 = np.where(singular, 1.0, s5)
    q6 = np.where(singular, q_near[5], np.arctan2(-v[:, 1] / s5, v[:, 0] / s5))
    # T_1_4 = inv(T_0_1) T_base_flange inv(T_4_6), T_4_6 = T_4_5(q5) T_5_6(q6)
    T46 = _dh_steps(kin, 4, q5) @ _dh_steps(kin, 5, q6)
    T14 = invert(_dh_steps(kin, 0, q1)) @ T_base_flange @ invert(T46)
    x, y = T14[:, 0, 3], T14[:, 1, 3]
    c3 = (x * x + y * y - a2 * a2 - a3 * a3) / (2.0 * a2 * a3)
    elbow = np.arccos(np.clip(c3, -1.0, 1.0))
    q3 = np.column_stack([elbow, -elbow])  # (4, 2)
    q2 = np.arctan2(y, x)[:, None] - np.arctan2(a3 * np.sin(q3), a2 + a3 * np.cos(q3))
    q4 = np.arctan2(T14[:, 1, 0], T14[:, 0, 0])[:, None] - q2 - q3
    branches = np.column_stack(
        [np.repeat(q1, 2), q2.ravel(), q3.ravel(), q4.ravel(), np.repeat(q5, 2), np.repeat(q6, 2)]
    )
    nearest, within_limits = _nearest_turns(kin, branches, q_near)
    reached = np.repeat(np.abs(c3) <= 1.0, 2)
    return list(nearest[reached & within_limits])


def ur_ik_nearest_first(
    kin: URKinematics, T_base_flange: np.ndarray, q_near: np.ndarray
) -> Iterator[np.ndarray]:
    """The joint solutions (6,) of a UR arm (has_ur_structure) reaching T_base_flange within the
    limits, the one that moves the joints least from q_near (the largest joint move) first: each
    closed-form solution refined by solve_ik when it is asked for (a caller that takes the first
    refines one); those that converge, without repeats."""
    closed_form = _ur_closed_form(kin, T_base_flange, q_near)
    given: list[np.ndarray] = []
    for q in sorted(closed_form, key=lambda q: float(np.max(np.abs(q - q_near)))):
        refined = solve_ik(kin, T_base_flange, q)
        if refined.converged and all(np.abs(refined.q - s).max() > 1e-6 for s in given):
            given.append(refined.q)
            yield refined.q


def _nearest_turns(kin: URKinematics, q: np.ndarray, q_near: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """q (N, 6) with each angle moved by whole turns to the one within the limits nearest q_near's
    (6,), and (N,) whether every angle has a turn within them (where not, the row is meaningless)."""
    turn = 2.0 * np.pi
    nearest = q + turn * np.round((q_near - q) / turn)
    turns = nearest[:, :, None] + turn * np.array([-1.0, 0.0, 1.0])  # (N, 6, 3)
    inside = (turns >= np.array(kin.q_lower)[:, None]) & (turns <= np.array(kin.q_upper)[:, None])
    distance = np.where(inside, np.abs(turns - q_near[:, None]), np.inf)
    choice = np.take_along_axis(turns, np.argmin(distance, axis=2)[:, :, None], axis=2)[:, :, 0]
    return choice, inside.any(axis=2).all(axis=1)


def ur_ik_branches(
    kin: URKinematics, T_base_flange: np.ndarray, q_near: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> np.ndarray:
    """(M, 6) joint solutions of a UR arm (has_ur_structure) reaching T_base_flange within lower,
    upper (6,), radians: every closed-form branch at the turns nearest q_near (6,), and each with
    its base and last joint a whole turn either way where that stays within the bounds (the same
    pose, a different way there). Refined by solve_ik; those that do not converge are left out."""
    lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    turn = 2.0 * np.pi
    found: list[np.ndarray] = []
    for q in _ur_closed_form(kin, T_base_flange, q_near):
        refined = solve_ik(kin, T_base_flange, q)
        if not refined.converged:
            continue
        for d1 in (-turn, 0.0, turn):
            for d6 in (-turn, 0.0, turn):
                variant = refined.q + np.array([d1, 0.0, 0.0, 0.0, 0.0, d6])
                inside = np.all(variant >= lower) and np.all(variant <= upper)
                if inside and all(np.abs(variant - s).max() > 1e-6 for s in found):
                    found.append(variant)
    return np.array(found).reshape(-1, 6)
