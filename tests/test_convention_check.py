"""The convention check names each common pose mistake injected into a correct set, and none on the
correct set itself (synthetic board observations of the rotation-rich views)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from hec.estimator.io.convention_check import check_pose_convention
from hec.estimator.io.pose_file import PoseConvention, values_from_poses
from hec.estimator.solve.problem import CalibrationProblem, build_problem
from hec.support.synthetic_scenes import BOARD, INTRINSICS, random_mount, scene


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
