"""hec verify on measurement-level data (fixed seed): a mount moved by 1 mm and 0.2 degrees is found
and its shift estimated, an unmoved one is consistent, and without the calibration's covariance the
verdict says it cannot test. The command line (5 rendered views) exits 2 on an OpenCV method's
calibration (no covariance) and on a file of another format, naming it."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hec.bench.verify import learned_levels
from hec.commands.verify import EXIT_UNTESTED
from hec.estimator.geometry.lie import pose_minus, pose_plus
from hec.estimator.geometry.waypoints import rotation_rich_waypoints
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.method_names import DEFAULT_METHOD
from hec.estimator.solve.methods import run_method
from hec.estimator.solve.noise_learning import learn_noise
from hec.estimator.solve.pick_error import pick_error, true_pick_error_mm
from hec.estimator.solve.problem import build_problem
from hec.estimator.solve.verify import (
    SIGNIFICANCE,
    format_verdict,
    spread_views,
    verification_problem,
    verify_mount,
)
from hec.support.synthetic_scenes import BOARD, INTRINSICS, SCENARIO, T_BASE_BOARD, random_mount
from tests.hec_cli import run_hec, simulated_dataset

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


@pytest.fixture(scope="module")
def five_views(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 5 default views rendered into a dataset (`hec simulate`)."""
    return simulated_dataset(tmp_path_factory.mktemp("verify_cli"), 5)


def test_an_opencv_calibration_gets_the_shift_and_exit_2_it_cannot_be_tested(
    five_views: Path, tmp_path: Path
) -> None:
    cal = tmp_path / "tsai.json"
    argv = [
        "calibrate",
        str(five_views),
        "--method",
        "opencv-tsai",
        "--json",
        str(cal),
        "--quiet",
        "--no-loo",
    ]
    code, _, err = run_hec(argv)
    assert code == 0, err
    code, out, err = run_hec(["verify", str(cal), str(five_views), "--quiet"])
    assert code == EXIT_UNTESTED
    assert "verdict: not tested: the mount differs by about " in out and "covariance none" in out
    assert f"{cal}: field 'covariance' is null (opencv-tsai gives no uncertainty)" in err


@pytest.mark.parametrize(
    ("name", "content", "words"),
    [
        (
            "dataset.json",
            {"format": "hec-dataset", "version": 1},
            "is a 'hec-dataset' file, not a calibration",
        ),
        ("detections.json", {"format": "hec-detections", "version": 1}, "is a 'hec-detections' file"),
        ("rows.json", {"rows": []}, "not a calibration: no field 'T_flange_cam'"),
    ],
)
def test_a_file_of_another_format_exits_2_naming_it(
    five_views: Path, tmp_path: Path, name: str, content: dict, words: str
) -> None:
    path = tmp_path / name
    path.write_text(json.dumps(content))
    code, out, err = run_hec(["verify", str(path), str(five_views), "--quiet"])
    assert code == EXIT_UNTESTED and out == ""
    assert f"{path}: {words}" in err


def test_a_calibration_that_left_the_depths_out_is_verified_without_them(calibrated) -> None:
    _, flange, _, levels, rng = calibrated
    views = synthetic_observations(
        BOARD, INTRINSICS, calibrated[0], T_BASE_BOARD, spread_views(flange), SyntheticNoise(), rng
    )
    problem = build_problem(views, BOARD, INTRINSICS, SyntheticNoise().robot)
    with_depth = verification_problem(problem, levels)
    without = verification_problem(problem, replace(levels, depth_used=False))
    assert all(m.depth_m is not None for f in with_depth.frames for m in f.markers)
    assert all(
        m.depth_m is None and m.whitening.shape[0] == m.pixel_rows for f in without.frames for m in f.markers
    )


@pytest.mark.needs("sim")
def test_hec_verify_of_a_fixed_camera_uses_the_eye_to_hand_model(tmp_path: Path) -> None:
    """The command line verifies an eye-to-hand calibration in its own set-up: on its own dataset it
    is consistent (the set-up once reached build_problem as the arm's name: 'moved 871 mm')."""
    from tests.hec_cli import run_hec

    dataset, cal = tmp_path / "ds", tmp_path / "cal.json"
    code, _, err = run_hec(["simulate", "--scenario", "eye_to_hand", "--out", str(dataset), "--quiet"])
    assert code == 0, err
    code, _, err = run_hec(["calibrate", str(dataset), "--quiet", "--no-loo", "--json", str(cal)])
    assert code == 0, err
    code, out, err = run_hec(["verify", str(cal), str(dataset), "--quiet"])
    assert code == 0 and "verdict: consistent" in out, out + err
