"""The measurement model: analytic Jacobians against finite differences, and residuals at the truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.lie import (
    pose_minus,
    pose_plus,
    so3_exp,
    so3_log,
    so3_right_jacobian,
    so3_right_jacobian_inverse,
)
from hec.estimator.geometry.transforms import transform_points
from hec.estimator.geometry.waypoints import rotation_rich_waypoints
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations
from hec.estimator.solve.measurement_model import HandEyeState, predict_frame
from hec.estimator.solve.problem import build_problem
from hec.support.synthetic_scenes import BOARD, INTRINSICS, SCENARIO, T_BASE_BOARD, random_mount, scene

STEP = 1e-6


def _problem(rng, intrinsics=INTRINSICS, exact=False):
    X = random_mount(rng)
    return build_problem(scene(X, rng, exact=exact), BOARD, intrinsics), X


def _states(problem, X, rng):
    landmarks = np.concatenate(
        [transform_points(T_BASE_BOARD, BOARD.marker_corners(i)) for i in problem.marker_ids]
    )
    return [
        HandEyeState(X, T_base_board=T_BASE_BOARD),
        HandEyeState(X, T_base_board=T_BASE_BOARD, depth_scale=1.01),
        HandEyeState(X, landmarks_base=landmarks + rng.normal(0, 1e-3, landmarks.shape), depth_scale=0.99),
    ]


@pytest.mark.parametrize(
    ("intrinsics", "depth_error"),
    [
        (INTRINSICS, False),
        (CameraIntrinsics(640, 480, 600.0, 612.0, 331.3, 228.6, (0.08, -0.2, 1e-3, -2e-3, 0.1)), True),
    ],
)
def test_jacobians_match_finite_differences(intrinsics: CameraIntrinsics, depth_error: bool) -> None:
    """depth_error: with a depth bias and tilt (self-calibration's) in the model."""
    rng = np.random.default_rng(3)
    problem, X = _problem(rng, intrinsics)
    if depth_error:
        problem = replace(problem, depth_bias=(0.01, 0.002), depth_tilt=(0.003, -0.002))
    for state in _states(problem, X, rng):
        for frame in problem.frames[:4]:
            delta = rng.normal(0.0, 1e-3, 6)
            pred = predict_frame(problem, state, frame, delta)
            # residual = W (z - h): d residual = -J
            num_state = np.column_stack(
                [
                    -(
                        predict_frame(problem, state.plus(STEP * e), frame, delta, False).residual
                        - pred.residual
                    )
                    / STEP
                    for e in np.eye(state.dim)
                ]
            )
            num_flange = np.column_stack(
                [
                    -(predict_frame(problem, state, frame, delta + STEP * e, False).residual - pred.residual)
                    / STEP
                    for e in np.eye(6)
                ]
            )
            # The flange perturbation composes additively only to first order: compare at delta
            # through the right Jacobian of the rotation part.
            J_flange = pred.J_flange.copy()
            J_flange[:, 3:] = J_flange[:, 3:] @ so3_right_jacobian(delta[3:])
            scale = np.abs(pred.J_state).max()
            assert np.abs(num_state - pred.J_state).max() < 1e-4 * scale
            assert np.abs(num_flange - J_flange).max() < 1e-4 * np.abs(J_flange).max()


def test_residuals_vanish_at_the_truth_and_are_standard_normal_with_noise() -> None:
    rng = np.random.default_rng(4)
    problem, X = _problem(rng, exact=True)
    state = HandEyeState(X, T_base_board=T_BASE_BOARD)
    for frame in problem.frames:
        assert np.abs(predict_frame(problem, state, frame).residual).max() < 1e-6
    noisy, X = _problem(rng)
    state = HandEyeState(X, T_base_board=T_BASE_BOARD)
    # With exact flange poses removed from the picture the whitened residuals are N(0, 1);
    # robot noise inflates them, so compare against the sum of both.
    chi2, dof = 0.0, 0
    for frame in noisy.frames:
        pred = predict_frame(noisy, state, frame)
        S = pred.J_flange @ noisy.robot_noise.covariance() @ pred.J_flange.T + np.eye(len(pred.residual))
        chi2 += float(pred.residual @ np.linalg.solve(S, pred.residual))
        dof += len(pred.residual)
    assert 0.9 < chi2 / dof < 1.1


def test_exact_frames_through_a_distorted_lens_have_no_residual() -> None:
    """The synthetic corners of a distorted lens are where the detector's homography fit puts them
    (the marker-fit bias of each corner), which is what the model predicts."""
    rng = np.random.default_rng(6)
    X = random_mount(rng)
    lens = replace(INTRINSICS, dist=(0.13, -0.30, 1e-3, -2e-3, 0.05))
    flanges = [
        w.T_base_flange for w in rotation_rich_waypoints(T_BASE_BOARD, X, SCENARIO.trajectory.distance_m)
    ]
    observations = synthetic_observations(
        BOARD, lens, X, T_BASE_BOARD, flanges, SyntheticNoise(), rng, exact=True
    )
    problem = build_problem(observations, BOARD, lens)
    state = HandEyeState(X, T_base_board=T_BASE_BOARD)
    assert problem.observation_count > 8 * 10
    for frame in problem.frames:
        assert np.abs(predict_frame(problem, state, frame).residual).max() < 1e-6


def test_lie_helpers_invert_each_other() -> None:
    rng = np.random.default_rng(5)
    for _ in range(20):
        w = rng.normal(0.0, 1.0, 3)
        assert np.allclose(so3_log(so3_exp(w)), w) or np.linalg.norm(w) > np.pi
        assert np.allclose(so3_right_jacobian(w) @ so3_right_jacobian_inverse(w), np.eye(3))
        e = 1e-7 * rng.normal(size=3)
        lhs = so3_exp(w + e)
        rhs = so3_exp(w) @ so3_exp(so3_right_jacobian(w) @ e)
        assert np.abs(lhs - rhs).max() < 1e-12
        T = pose_plus(np.eye(4), rng.normal(0.0, 0.5, 6))
        d = rng.normal(0.0, 0.3, 6)
        assert np.allclose(pose_minus(pose_plus(T, d), T), d)
