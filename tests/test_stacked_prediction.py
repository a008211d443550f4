"""All frames predicted at once: the same residuals and Jacobians as frame by frame."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.lie import pose_plus_jacobian, pose_plus_jacobian_rows, so3_exp, so3_exp_rows
from hec.estimator.geometry.transforms import transform_points
from hec.estimator.solve.measurement_model import HandEyeState, predict_frame
from hec.estimator.solve.noise_levels import NoiseLevels, scaled_problem
from hec.estimator.solve.problem import build_problem
from hec.estimator.solve.stacked_prediction import predict_frames, stacked_frames
from hec.support.synthetic_scenes import BOARD, INTRINSICS, T_BASE_BOARD, random_mount, scene

DISTORTED = CameraIntrinsics(640, 480, 600.0, 612.0, 331.3, 228.6, (0.08, -0.2, 1e-3, -2e-3, 0.1))
# The corner bias's derivatives under distortion are forward differences (step 1e-7): a rounding
# change in the camera points moves them by ~1e-16 / 1e-7 of their size.
DIFFERENCE_NOISE = 1e-7


def _close(a: np.ndarray, b: np.ndarray, tolerance: float = 1e-12) -> None:
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=tolerance * np.max(np.abs(b)))


@pytest.mark.parametrize("intrinsics", [INTRINSICS, DISTORTED])
@pytest.mark.parametrize("landmarks", [False, True])
def test_predict_frames_equals_predict_frame_per_frame(intrinsics: CameraIntrinsics, landmarks: bool) -> None:
    rng = np.random.default_rng(5)
    X = random_mount(rng)
    observations = scene(X, rng, views=6)
    # one frame's markers without depth: pixel-only and pixel-and-depth markers stacked together
    observations[2] = replace(
        observations[2], markers=[replace(m, depth_m=None) for m in observations[2].markers]
    )
    problem = build_problem(observations, BOARD, intrinsics)
    problem = replace(problem, depth_bias=(0.01, 0.002), depth_tilt=(0.003, -0.002), board_bend_m=(1e-3, 0.0))
    if landmarks:
        corners = [transform_points(T_BASE_BOARD, BOARD.marker_corners(i)) for i in problem.marker_ids]
        state = HandEyeState(X, landmarks_base=np.concatenate(corners), depth_scale=0.99)
    else:
        state = HandEyeState(X, T_base_board=T_BASE_BOARD, depth_scale=1.01)
    deltas = rng.normal(0.0, 1e-3, (len(problem.frames), 6))
    stacked = stacked_frames(problem, board=not landmarks)
    together = predict_frames(problem, stacked, state, deltas, jacobians=True)
    alone = [predict_frame(problem, state, f, d) for f, d in zip(problem.frames, deltas, strict=True)]
    _close(together.residual, np.concatenate([p.residual for p in alone]))
    tolerance = DIFFERENCE_NOISE if any(intrinsics.dist) else 1e-12
    _close(together.J_state, np.concatenate([p.J_state for p in alone]), tolerance)
    _close(together.J_flange, np.concatenate([p.J_flange for p in alone]), tolerance)
    residual_only = predict_frames(problem, stacked, state, deltas, jacobians=False)
    np.testing.assert_array_equal(residual_only.residual, together.residual)


def test_scaled_stack_holds_the_scaled_problems_whitening() -> None:
    rng = np.random.default_rng(6)
    problem = build_problem(scene(random_mount(rng), rng, views=4), BOARD, INTRINSICS)
    levels = NoiseLevels(1.7, 0.6, RobotPoseNoise())
    scaled = stacked_frames(problem, board=True).scaled(levels.pixel_scale, levels.depth_scale)
    expected = stacked_frames(scaled_problem(problem, levels), board=True)
    np.testing.assert_array_equal(scaled.whitening.toarray(), expected.whitening.toarray())


def test_rows_of_rotations_and_plus_jacobians_equal_lies() -> None:
    rng = np.random.default_rng(7)
    deltas = np.vstack([rng.normal(0.0, 0.3, (4, 6)), np.r_[1.0, 2.0, 3.0, 1e-10, 0.0, -1e-10], np.zeros(6)])
    _close(so3_exp_rows(deltas[:, 3:]), np.array([so3_exp(d[3:]) for d in deltas]))
    _close(pose_plus_jacobian_rows(deltas), np.array([pose_plus_jacobian(d) for d in deltas]))
