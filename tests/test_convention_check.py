"""The convention check names each common pose mistake injected into a correct set, and none on the
correct set itself (synthetic board observations of the rotation-rich views); it names no reading
that leaves more than NOISE_RATIO times the data's noise, names a pose off by one, and says "cannot
check" for motion that cannot tell readings apart."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from hec.estimator.geometry.lie import so3_exp
from hec.estimator.geometry.transforms import make_transform
from hec.estimator.io.convention_check import NOISE_RATIO, check_pose_convention
from hec.estimator.io.pose_file import PoseConvention, values_from_poses
from hec.estimator.observe.synthetic import SyntheticNoise, synthetic_observations
from hec.estimator.solve.problem import CalibrationProblem, build_problem
from hec.support.synthetic_scenes import BOARD, INTRINSICS, T_BASE_BOARD, random_mount, scene


@cache
def _problem() -> tuple[CalibrationProblem, np.ndarray]:
    rng = np.random.default_rng(3)
    problem = build_problem(scene(random_mount(rng), rng), BOARD, INTRINSICS)
    T_base_flange = np.tile(np.eye(4), (1 + max(f.frame for f in problem.frames), 1, 1))  # row i: frame i
    for f in problem.frames:
        T_base_flange[f.frame] = f.T_base_flange
    return problem, T_base_flange


@pytest.mark.parametrize(
    ("stated", "written", "named", "option"),
    [
        (
            PoseConvention("rotvec"),
            PoseConvention("rotvec", direction="flange-to-base"),
            "flange-to-base (inverted)",
            "--pose-direction flange-to-base",
        ),
        (PoseConvention("rotvec"), PoseConvention("euler-xyz"), "Euler angles xyz", "--rotation euler-xyz"),
        (
            PoseConvention("euler-ZYX", "deg"),
            PoseConvention("euler-XYZ", "deg"),
            "Euler angles XYZ",
            "--rotation euler-XYZ",
        ),
        (
            PoseConvention("euler-xyz", "rad"),
            PoseConvention("euler-xyz", "deg"),
            "angles in deg",
            "--angle-unit deg",
        ),
        (
            PoseConvention("quat-wxyz"),
            PoseConvention("quat-xyzw"),
            "quaternions xyzw",
            "--rotation quat-xyzw",
        ),
        (
            PoseConvention("quat-wxyz", length_unit="m"),
            PoseConvention("quat-wxyz", length_unit="mm"),
            "lengths in mm",
            "--length-unit mm",
        ),
    ],
)
def test_each_mistake_is_named_with_the_option_that_fixes_it(
    stated: PoseConvention, written: PoseConvention, named: str, option: str
) -> None:
    problem, T_base_flange = _problem()
    report = check_pose_convention(problem, values_from_poses(T_base_flange, written), stated)
    assert report.fits is not None, report.message
    assert report.fits.mistake == named and report.fits.option == option
    assert report.fits.residual_px < 1.0 < report.stated.residual_px
    assert report.fits.residual_px <= NOISE_RATIO * report.noise_px
    assert f"pass {option}" in report.message


@pytest.mark.parametrize(
    "convention",
    [PoseConvention("rotvec"), PoseConvention("euler-xyz", "deg", "mm"), PoseConvention("matrix")],
)
def test_no_mistake_is_reported_on_a_correct_set(convention: PoseConvention) -> None:
    problem, T_base_flange = _problem()
    report = check_pose_convention(problem, values_from_poses(T_base_flange, convention), convention)
    assert report.fits is None, report.message
    assert report.stated.residual_px < 1.0
    assert all(t.residual_px > 3 * report.stated.residual_px for t in report.trials)
    assert report.stated_fits and "fit the stated convention" in report.message
    assert report.stated.residual_px <= NOISE_RATIO * report.noise_px


@pytest.mark.parametrize("shift", [1, -1])
def test_a_pose_off_by_one_is_named_as_a_pairing_mistake(shift: int) -> None:
    problem, T_base_flange = _problem()
    values = values_from_poses(np.roll(T_base_flange, shift, axis=0), PoseConvention("rotvec"))
    report = check_pose_convention(problem, values, PoseConvention("rotvec"))
    assert report.fits is not None and report.fits.shift == shift, report.message
    neighbour = "previous" if shift > 0 else "next"  # np.roll by +1 gives image i the pose of i - 1
    assert f"each image paired with the {neighbour} image's pose" in report.message
    assert "check the pairing of images and poses" in report.message


def test_poses_no_reading_explains_name_no_convention() -> None:
    """Poses of the right views in a shuffled order: no reading fits, and the check says so with the
    residuals and what to check, naming no fix."""
    problem, T_base_flange = _problem()
    shuffled = T_base_flange[np.random.default_rng(0).permutation(len(T_base_flange))]
    report = check_pose_convention(
        problem, values_from_poses(shuffled, PoseConvention("rotvec")), PoseConvention("rotvec")
    )
    assert report.fits is None and not report.stated_fits
    assert report.message.startswith("no reading of the poses fits near the data's noise"), report.message
    assert "pass " not in report.message and "inf" not in report.message


def _views(flange_poses: list[np.ndarray]) -> CalibrationProblem:
    X = random_mount(np.random.default_rng(3))  # _problem's mount, whose views see the board
    observations = synthetic_observations(
        BOARD, INTRINSICS, X, T_BASE_BOARD, flange_poses, SyntheticNoise(), np.random.default_rng(5), False
    )
    return build_problem(observations, BOARD, INTRINSICS)


@pytest.mark.parametrize(
    ("motion", "words"),
    [("translation", "the flange barely rotates between views"), ("one axis", "rotates about one axis only")],
)
def test_motion_that_cannot_tell_readings_apart_cannot_be_checked(motion: str, words: str) -> None:
    """Views that only translate, or rotate about the flange's z axis only: "cannot check", never a
    pass, and no inf."""
    rng = np.random.default_rng(7)
    _, T_base_flange = _problem()
    start = T_base_flange[0]
    poses = []
    for k in range(8):
        turn = so3_exp(np.array([0.0, 0.0, np.radians(8.0 * k)])) if motion == "one axis" else np.eye(3)
        poses.append(
            make_transform(np.eye(3), rng.uniform(-0.03, 0.03, 3)) @ start @ make_transform(turn, np.zeros(3))
        )
    problem = _views(poses)
    values = values_from_poses(np.array(poses), PoseConvention("rotvec"))
    report = check_pose_convention(problem, values, PoseConvention("rotvec"))
    assert report.cannot_check is not None and not report.stated_fits and report.fits is None
    assert report.message.startswith("cannot check the pose convention: ") and words in report.message
    assert "inf" not in report.message
