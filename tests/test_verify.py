"""hec verify on measurement-level data (fixed seed): a mount moved by 1 mm and 0.2 degrees is found
and its shift estimated, an unmoved one is consistent, and without the calibration's covariance the
verdict says it cannot test."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.geometry.lie import pose_minus, pose_plus
from estimator.geometry.waypoints import rotation_rich_waypoints
from estimator.observe.synthetic import SyntheticNoise, synthetic_observations
from estimator.solve.calibration import MethodOptions
from estimator.solve.methods import DEFAULT_METHOD, run_method
from estimator.solve.noise_learning import learn_noise
from estimator.solve.pick_error import pick_error, true_pick_error_mm
from estimator.solve.problem import build_problem
from estimator.solve.verify import (
    SIGNIFICANCE,
    format_verdict,
    spread_views,
    verification_problem,
    verify_mount,
)
from experiments.bench.verify import learned_levels
from experiments.synthetic_scenes import BOARD, INTRINSICS, SCENARIO, T_BASE_BOARD, random_mount

SHIFT = np.array([0.0006, -0.0006, 0.0005, *np.radians([0.12, 0.1, -0.12])])  # ~1 mm, ~0.2 deg


@pytest.fixture(scope="module")
def calibrated():
    rng = np.random.default_rng(3)
    X = random_mount(rng)
    flange = [
        w.T_base_flange for w in rotation_rich_waypoints(T_BASE_BOARD, X, SCENARIO.trajectory.distance_m)
    ]
    observations = synthetic_observations(BOARD, INTRINSICS, X, T_BASE_BOARD, flange, SyntheticNoise(), rng)
    problem = build_problem(observations, BOARD, INTRINSICS, SyntheticNoise().robot)
    learned = learn_noise(problem, MethodOptions())
    cal = run_method(DEFAULT_METHOD, problem, MethodOptions(), observations, learned)
    return X, flange, cal, learned_levels(learned), rng


def _verify(calibrated, T_flange_cam_now: np.ndarray, covariance: bool = True):
    _, flange, cal, levels, rng = calibrated
    views = synthetic_observations(
        BOARD, INTRINSICS, T_flange_cam_now, T_BASE_BOARD, spread_views(flange), SyntheticNoise(), rng
    )
    problem = verification_problem(build_problem(views, BOARD, INTRINSICS, SyntheticNoise().robot), levels)
    return verify_mount(problem, cal.T_flange_cam, cal.covariance if covariance else None)


def test_an_unmoved_mount_is_consistent(calibrated) -> None:
    v = _verify(calibrated, calibrated[0])
    assert v.frames == 5 and v.p_value > SIGNIFICANCE and not v.moved
    assert format_verdict(v).startswith("consistent (p = ")
    assert 0.5 < v.fit_chi2_dof < 1.5


def test_a_mount_moved_1_mm_and_0_2_degrees_is_found_with_its_shift(calibrated) -> None:
    X, _, cal, _, _ = calibrated
    v = _verify(calibrated, pose_plus(X, SHIFT))
    assert v.moved and v.p_value < 1e-3
    assert format_verdict(v).startswith("the camera has moved: about ")
    true_shift = pose_minus(pose_plus(X, SHIFT), cal.T_flange_cam)
    sigma = np.sqrt(np.diag(v.covariance_verify + v.covariance_calibration))
    assert np.all(np.abs(v.delta - true_shift) < 4 * sigma)


def test_without_the_calibrations_covariance_it_says_it_cannot_test(calibrated) -> None:
    v = _verify(calibrated, calibrated[0], covariance=False)
    assert v.moved is None and v.p_value is None
    assert format_verdict(v).startswith("not tested: ")


def test_the_pick_error_from_the_covariance_matches_the_truth_on_average(calibrated) -> None:
    X, _, cal, _, rng = calibrated
    pick = pick_error(cal.T_flange_cam, cal.covariance, 0.45)
    draws = [
        pose_plus(cal.T_flange_cam, d) for d in rng.multivariate_normal(np.zeros(6), cal.covariance, 400)
    ]
    errors = np.array([true_pick_error_mm(T, cal.T_flange_cam, 0.45) for T in draws])
    assert pick.rms_mm == pytest.approx(np.sqrt(np.mean(errors**2)), rel=0.15)
    assert pick.p95_mm == pytest.approx(np.quantile(errors, 0.95), rel=0.15)
    assert true_pick_error_mm(cal.T_flange_cam, X, 0.45) < 4 * pick.rms_mm
