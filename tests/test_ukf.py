"""ukf: the update against the ekf's where the model is linear, a positive covariance from the wide start,
exactness without noise, accuracy against the Cramer-Rao bound and NEES with noise, gating, landmarks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.geometry.lie import pose_minus
from hec.estimator.geometry.transforms import transform_points
from hec.estimator.observe.synthetic import SyntheticNoise
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.filters import IEKF_MAX_ITERATIONS, initial_covariance
from hec.estimator.solve.filters import update as ekf_update
from hec.estimator.solve.initialise import initial_state
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.observability import observability
from hec.estimator.solve.problem import build_problem
from hec.estimator.solve.ukf import ukf, update_frame
from hec.support.synthetic_scenes import BOARD, INTRINSICS, T_BASE_BOARD, random_mount, scene

# Measured over 3 x 30 random mounts (default noise, board model): RMS error / CRB 0.85-0.90 for
# translation and 0.87-1.05 for rotation (ekf: the same), mean NEES 4.9-5.5 (6 dof).
TRIALS = 16
MAX_RMS_OVER_CRB = 1.5
NEES_BAND = (3.5, 9.0)


def _errors(T_flange_cam: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation rad) error of an estimate."""
    e = pose_minus(T_flange_cam, T_true)
    return float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))


def test_update_matches_ekf_when_the_covariance_is_small() -> None:
    """Where the model is linear over the covariance, the unscented update is the Kalman update:
    this pins the signs of the innovation and the cross covariance. The two differ by the
    second-order terms, 1e-2 (relative) at 1 mm and 1 mrad, 2e-4 at 0.1 mm and 0.1 mrad."""
    rng = np.random.default_rng(2)
    X = random_mount(rng)
    problem = build_problem(scene(X, rng), BOARD, INTRINSICS)
    state = HandEyeState(X, T_base_board=T_BASE_BOARD, depth_scale=1.0)
    P = np.diag(rng.uniform(0.5, 2.0, state.dim) * 1e-4**2)
    frame = problem.frames[5]
    new, P_new, rejected = update_frame(problem, state, P, frame, robust=True)
    ekf_new, ekf_P, _, _ = ekf_update(problem, state, P, [frame], 1, True)
    step, ekf_step = new.minus(state), ekf_new.minus(state)
    assert rejected == []
    assert np.linalg.norm(step - ekf_step) < 1e-3 * np.linalg.norm(ekf_step)
    assert np.abs(P_new - ekf_P).max() < 1e-6 * np.abs(ekf_P).max()


@pytest.mark.parametrize("map_model", ["board", "landmarks"])
def test_covariance_stays_positive_from_the_wide_start(map_model: str) -> None:
    """The first update samples the wide starting covariance (0.5 m, 1 rad) with a large negative
    centre weight; the covariance must still come out symmetric positive definite and smaller."""
    rng = np.random.default_rng(4)
    problem = build_problem(scene(random_mount(rng), rng), BOARD, INTRINSICS)
    options = MethodOptions(map_model=map_model, estimate_depth_scale=True)
    state = initial_state(problem, options).state
    P = initial_covariance(state, options)
    for frame in problem.frames[:3]:
        state, P_new, _ = update_frame(problem, state, P, frame, robust=True)
        assert np.array_equal(P_new, P_new.T)
        assert np.linalg.eigvalsh(P_new).min() > 0.0
        assert np.all(np.diag(P_new) <= np.diag(P) * (1 + 1e-9))
        P = P_new


@pytest.mark.parametrize(
    ("robot_noise", "depth_scale"),
    [(RobotPoseNoise(), False), (RobotPoseNoise(), True), (RobotPoseNoise(0.0, 0.0), False)],
)
def test_noise_free_data_give_the_truth(robot_noise: RobotPoseNoise, depth_scale: bool) -> None:
    """Exact data, board model. The first update (the closed form's frames together) is iterated,
    the others are single: one update per remaining frame and a few iterations more."""
    rng = np.random.default_rng(1)
    X = random_mount(rng)
    observations = scene(X, rng, SyntheticNoise(robot=robot_noise), exact=True)
    problem = build_problem(observations, BOARD, INTRINSICS, robot_noise)
    options = MethodOptions(estimate_depth_scale=depth_scale)
    result = ukf(problem, options)
    t_err, r_err = _errors(result.T_flange_cam, X)
    assert t_err < 1e-6 and r_err < 1e-6
    assert result.method == "ukf"
    assert result.observations_rejected == 0
    updates = len(problem.frames) - initial_state(problem, options).frames_used + 1
    assert updates < result.diagnostics["iterations"] < updates + IEKF_MAX_ITERATIONS
    if depth_scale:
        assert abs(result.depth_scale - 1.0) < 1e-5


def test_accuracy_reaches_the_cramer_rao_bound_and_nees_is_honest() -> None:
    rng = np.random.default_rng(1)
    errors, crb, nees = [], [], []
    for _ in range(TRIALS):
        X = random_mount(rng)
        problem = build_problem(scene(X, rng), BOARD, INTRINSICS)
        result = ukf(problem, MethodOptions())
        e = pose_minus(result.T_flange_cam, X)
        errors.append(e)
        nees.append(float(e @ np.linalg.solve(result.covariance, e)))
        bound = observability(problem, HandEyeState(X, T_base_board=T_BASE_BOARD)).crb_covariance
        crb.append(np.diag(bound))
    errors, crb = np.array(errors), np.array(crb)
    for axes in (slice(0, 3), slice(3, 6)):
        rms = np.sqrt(np.mean(np.sum(errors[:, axes] ** 2, axis=1)))
        assert rms < MAX_RMS_OVER_CRB * np.sqrt(np.mean(np.sum(crb[:, axes], axis=1)))
    assert NEES_BAND[0] < np.mean(nees) < NEES_BAND[1]


def test_gate_rejects_a_displaced_marker() -> None:
    rng = np.random.default_rng(6)
    X = random_mount(rng)
    observations = scene(X, rng)
    bad = observations[8].markers[2]
    observations[8].markers[2] = replace(bad, corners_px=bad.corners_px + np.array([25.0, -15.0]))
    problem = build_problem(observations, BOARD, INTRINSICS)
    result = ukf(problem, MethodOptions())
    unused = [(r.frame, r.marker_id) for r in result.residuals if not r.used]
    assert unused == [(8, bad.marker_id)]
    assert result.observations_rejected == 1
    t_err, r_err = _errors(result.T_flange_cam, X)
    assert t_err < 1e-3 and r_err < np.radians(0.2)


def test_landmark_model_error_is_within_its_reported_sigma() -> None:
    """About 100 state dimensions. Over 3 x 30 mounts its NEES averages 5.0-5.7 (6 dof); the
    4-sigma bound here is loose."""
    rng = np.random.default_rng(3)
    X = random_mount(rng)
    problem = build_problem(scene(X, rng), BOARD, INTRINSICS)
    result = ukf(problem, MethodOptions(map_model="landmarks"))
    e = pose_minus(result.T_flange_cam, X)
    assert np.all(np.abs(e) < 4.0 * np.sqrt(np.diag(result.covariance)))
    assert result.T_base_board is None
    assert sorted(result.landmarks_base) == problem.marker_ids
    for marker_id, corners in result.landmarks_base.items():
        assert np.abs(corners - transform_points(T_BASE_BOARD, BOARD.marker_corners(marker_id))).max() < 2e-3
