"""Eye-to-hand solved by the eye-in-hand model with the roles swapped
(hec.estimator.solve.setup_roles): the model pose and its Jacobian against finite differences, the
flange perturbation kept in the reported pose's frames, the arm's self-calibration through the
joints, and the estimators on a synthetic eye-to-hand cell against the truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from hec.estimator.common.setups import EYE_IN_HAND, EYE_TO_HAND
from hec.estimator.geometry.kinematics import ROBOTS, forward
from hec.estimator.geometry.lie import pose_minus, pose_nees, pose_plus, so3_right_jacobian
from hec.estimator.geometry.transforms import invert, pose_error
from hec.estimator.geometry.waypoints import eye_to_hand_waypoints
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.measurement_model import HandEyeState, predict_frame
from hec.estimator.solve.methods import solve
from hec.estimator.solve.problem import ReportedArm, build_problem
from hec.estimator.solve.self_calibration import KINEMATIC_NUISANCE, adjusted_kinematics, adjusted_problem
from hec.estimator.solve.setup_roles import (
    flange_minus,
    flange_plus,
    flange_plus_rows,
    model_pose,
    model_pose_jacobian,
)
from hec.sim.scenario import load_scenario

SCENARIO = load_scenario("eye_to_hand")
BOARD = SCENARIO.board_definition()
INTRINSICS = SCENARIO.camera.intrinsics()
T_BASE_CAM = SCENARIO.stand.transform()
T_FLANGE_BOARD = SCENARIO.board_mount.transform()
STEP = 1e-6


def _flange_poses() -> list[np.ndarray]:
    return [w.T_base_flange for w in eye_to_hand_waypoints(T_BASE_CAM, T_FLANGE_BOARD, 0.45)]


def _problem(rng: np.random.Generator, exact: bool = False, arm: ReportedArm | None = None):
    observations = synthetic_observations(
        BOARD,
        INTRINSICS,
        T_BASE_CAM,
        T_FLANGE_BOARD,
        _flange_poses(),
        SyntheticNoise(),
        rng,
        exact,
        setup=EYE_TO_HAND,
    )
    return build_problem(observations, BOARD, INTRINSICS, SyntheticNoise().robot, arm=arm, setup=EYE_TO_HAND)


def test_the_model_pose_is_the_inverse_of_the_reported_one_perturbed_in_its_own_frames() -> None:
    rng = np.random.default_rng(0)
    F = _flange_poses()[3]
    F_model = model_pose(EYE_TO_HAND, F)
    np.testing.assert_allclose(F_model @ F, np.eye(4), atol=1e-12)
    assert model_pose(EYE_IN_HAND, F) is F
    deltas = rng.normal(0.0, 1e-2, (5, 6))
    for delta in deltas:
        moved = flange_plus(EYE_TO_HAND, F_model, delta)
        np.testing.assert_allclose(moved, invert(pose_plus(F, delta)), atol=1e-12)
        np.testing.assert_allclose(flange_minus(EYE_TO_HAND, moved, F_model), delta, atol=1e-12)
    R, t = flange_plus_rows(
        EYE_TO_HAND, np.repeat(F_model[None, :3, :3], 5, 0), np.repeat(F_model[None, :3, 3], 5, 0), deltas
    )
    for k, delta in enumerate(deltas):
        moved = flange_plus(EYE_TO_HAND, F_model, delta)
        np.testing.assert_allclose(R[k], moved[:3, :3], atol=1e-12)
        np.testing.assert_allclose(t[k], moved[:3, 3], atol=1e-12)


def test_the_model_pose_jacobian_matches_finite_differences() -> None:
    F_model = model_pose(EYE_TO_HAND, _flange_poses()[5])
    A = model_pose_jacobian(F_model[:3, :3], F_model[:3, 3])
    numeric = np.column_stack(
        [pose_minus(flange_plus(EYE_TO_HAND, F_model, STEP * e), F_model) / STEP for e in np.eye(6)]
    )
    np.testing.assert_allclose(numeric, A, atol=1e-5)
    # the rotation noise moves the inverted translation by the lever arm: not a diagonal covariance
    assert np.abs(A[:3, 3:]).max() > 0.3


def test_the_flange_jacobian_is_with_respect_to_the_reported_pose() -> None:
    rng = np.random.default_rng(1)
    problem = _problem(rng)
    state = HandEyeState(pose_plus(T_BASE_CAM, rng.normal(0, 1e-3, 6)), T_base_board=T_FLANGE_BOARD)
    for frame in problem.frames[:4]:
        delta = rng.normal(0.0, 1e-3, 6)
        pred = predict_frame(problem, state, frame, delta)
        numeric = np.column_stack(
            [
                -(predict_frame(problem, state, frame, delta + STEP * e, False).residual - pred.residual)
                / STEP
                for e in np.eye(6)
            ]
        )
        J = pred.J_flange.copy()
        J[:, 3:] = J[:, 3:] @ so3_right_jacobian(delta[3:])
        assert np.abs(numeric - J).max() < 1e-4 * np.abs(J).max()


def test_the_arms_self_calibration_corrects_the_reported_pose_before_it_is_inverted() -> None:
    rng = np.random.default_rng(2)
    nominal = ROBOTS["ur5"]
    joints = {i: rng.uniform(-1.5, 1.5, 6) for i in range(len(_flange_poses()))}
    problem = _problem(rng, exact=True, arm=ReportedArm(nominal, joints))
    # the frames as if the arm reported its nominal forward kinematics of these joints
    problem = replace(
        problem,
        frames=[replace(f, T_base_flange=invert(forward(nominal, f.joints))) for f in problem.frames],
    )
    theta = rng.normal(0.0, 1e-3, len(KINEMATIC_NUISANCE))
    adjusted = adjusted_problem(problem, theta, KINEMATIC_NUISANCE)
    corrected = adjusted_kinematics(nominal, dict(zip(KINEMATIC_NUISANCE, theta, strict=True)))
    for frame in adjusted.frames:
        dt, dr = pose_error(frame.T_base_flange, invert(forward(corrected, frame.joints)))
        assert dt < 1e-12 and dr < 1e-12


@pytest.mark.parametrize("method", ["ekf", "batch", "iekf", "ukf"])
def test_the_estimators_find_the_fixed_camera_with_an_honest_covariance(method: str) -> None:
    problem = _problem(np.random.default_rng(7))
    result = solve(method, problem, MethodOptions(), [])
    dt, dr = pose_error(result.T_flange_cam, T_BASE_CAM)  # the result's mount is T_base_cam
    assert dt < 1e-3 and np.degrees(dr) < 0.2
    assert pose_nees(result.T_flange_cam, T_BASE_CAM, result.covariance) < chi2.ppf(0.999, 6)
    dt, _ = pose_error(result.T_base_board, T_FLANGE_BOARD)
    assert dt < 2e-3
