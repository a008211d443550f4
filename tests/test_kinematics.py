"""The MJCF arms agree with UR's DH kinematics; the IK solves reachable poses within the limits."""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from hec.estimator.common.models import models_dir
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.kinematics import (
    ROBOTS,
    forward,
    has_ur_structure,
    jacobian,
    solve_ik,
    solve_ik_nearest,
    ur_ik_nearest_first,
)
from hec.estimator.geometry.transforms import invert, make_transform, pose_error
from hec.estimator.io.board_file import load_board
from hec.sim.scene import ARM_PREFIX, build_cell


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_mujoco_flange_matches_dh_forward_kinematics(robot: str) -> None:
    cell = build_cell(
        robot,
        make_transform(np.eye(3), [0.0, 0.006, 0.04]),
        CameraIntrinsics.from_fovy(640, 480, np.radians(42.5)),
        load_board(models_dir() / "boards" / "hec_8qr.json"),
        make_transform(np.eye(3), [0.0, -0.7, 0.45]),
    )
    data = mujoco.MjData(cell.model)
    flange = cell.model.body(ARM_PREFIX + "flange").id
    rng = np.random.default_rng(7)
    kin = ROBOTS[robot]
    for _ in range(200):
        q = rng.uniform(kin.q_lower, kin.q_upper)
        data.qpos[cell.joint_qpos_addresses()] = q
        mujoco.mj_kinematics(cell.model, data)
        T_world_flange = make_transform(data.xmat[flange].reshape(3, 3), data.xpos[flange])
        dt, dr = pose_error(invert(cell.T_world_base) @ T_world_flange, forward(kin, q))
        assert dt < 1e-6 and dr < 1e-6


def test_base_frame_follows_the_paper_on_the_wall() -> None:
    """Base +Z out of the wall (world -y), +Y up (world +z), +X right (world +x)."""
    cell = build_cell(
        "ur5",
        np.eye(4),
        CameraIntrinsics.from_fovy(640, 480, 0.7),
        load_board(models_dir() / "boards" / "hec_8qr.json"),
        make_transform(np.eye(3), [0.0, -0.7, 0.45]),
    )
    np.testing.assert_allclose(cell.T_world_base[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)


def test_jacobian_matches_finite_differences() -> None:
    kin = ROBOTS["ur5"]
    q = np.array([0.3, -1.2, 1.4, -0.5, 0.8, 0.2])
    J = jacobian(kin, q)
    eps = 1e-7
    T0 = forward(kin, q)
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = eps
        T1 = forward(kin, q + dq)
        np.testing.assert_allclose((T1[:3, 3] - T0[:3, 3]) / eps, J[:3, i], atol=1e-6)
        dR = T1[:3, :3] @ T0[:3, :3].T
        omega = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]) / (2 * eps)
        np.testing.assert_allclose(omega, J[3:, i], atol=1e-6)


def test_ik_reaches_random_reachable_poses_within_limits() -> None:
    kin = ROBOTS["ur5"]
    rng = np.random.default_rng(3)
    for _ in range(50):
        q_true = rng.uniform(-2.5, 2.5, 6)
        target = forward(kin, q_true)
        result = solve_ik(kin, target, q_true + rng.normal(0.0, 0.2, 6))
        assert result.converged
        assert np.all(result.q >= kin.q_lower) and np.all(result.q <= kin.q_upper)
        dt, dr = pose_error(forward(kin, result.q), target)
        assert dt < 1e-9 and dr < 1e-9


def test_ik_reports_an_unreachable_pose() -> None:
    kin = ROBOTS["ur5"]
    target = make_transform(np.eye(3), [2.0, 0.0, 1.0])
    assert not solve_ik(kin, target, np.zeros(6)).converged


@pytest.mark.parametrize("robot", ["ur5", "ur5e"])
def test_closed_form_ik_finds_every_configuration(robot: str) -> None:
    """From random joints: every closed-form solution reaches the pose within the limits, the
    joints the pose came from are among them (each angle at the turn nearest), up to 8, no repeats,
    the least move first; solve_ik_nearest picks the one that moves the joints least."""
    kin = ROBOTS[robot]
    assert has_ur_structure(kin)
    rng = np.random.default_rng(5)
    counts = []
    for _ in range(100):
        q_true = rng.uniform(-np.pi, np.pi, 6)
        target = forward(kin, q_true)
        solutions = list(ur_ik_nearest_first(kin, target, q_true))
        counts.append(len(solutions))
        assert any(np.allclose(q, q_true, atol=1e-7) for q in solutions)
        moves = [np.max(np.abs(q - q_true)) for q in solutions]
        assert np.all(np.diff(moves) >= -1e-9), "the least move first"
        for q in solutions:
            assert np.all(q >= kin.q_lower) and np.all(q <= kin.q_upper)
            dt, dr = pose_error(forward(kin, q), target)
            assert dt < 1e-9 and dr < 1e-9
        np.testing.assert_allclose(solve_ik_nearest(kin, target, q_true + 0.05), q_true, atol=1e-7)
    assert max(counts) == 8 and np.median(counts) == 8
    assert list(ur_ik_nearest_first(kin, make_transform(np.eye(3), [2.0, 0.0, 1.0]), np.zeros(6))) == []


def test_an_arm_off_the_nominal_model_is_not_solved_in_closed_form() -> None:
    kin = ROBOTS["ur5"]
    offset = replace(kin, theta_offset=(0.001, 0.0, 0.0, 0.0, 0.0, 0.0))
    twisted = replace(kin, alpha=(kin.alpha[0] + 1e-4, *kin.alpha[1:]))
    assert not has_ur_structure(offset) and not has_ur_structure(twisted)
    q = np.array([0.3, -1.2, 1.4, -0.5, 1.1, 0.2])
    # solve_ik_nearest still solves them, from the seed
    np.testing.assert_allclose(solve_ik_nearest(offset, forward(offset, q), q + 0.05), q, atol=1e-7)
