"""The mount's covariance widened for noise levels learned from few residuals
(hec.estimator.solve.level_uncertainty): the groups' parts add up to the covariance, a group learned
from many residuals adds nothing, and on synthetic views the widening matters with 6 views and not
with 17."""

from __future__ import annotations

import numpy as np
import pytest

from hec.estimator.observe.synthetic import SyntheticNoise
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.level_uncertainty import MAX_STUDENT_T_FACTOR, level_widening, student_t_factor
from hec.estimator.solve.noise_learning import learn_noise
from hec.estimator.solve.problem import build_problem
from hec.support.synthetic_scenes import BOARD, INTRINSICS, random_mount, scene


def test_student_t_factor() -> None:
    assert student_t_factor(4.0) == pytest.approx(2.0)
    assert student_t_factor(10.0) == pytest.approx(1.25)
    assert student_t_factor(3.0) == student_t_factor(1.0) == MAX_STUDENT_T_FACTOR
    assert 1.0 < student_t_factor(1e4) < 1.001


def test_the_parts_add_up_to_the_covariance() -> None:
    rng = np.random.default_rng(0)
    J = rng.normal(size=(60, 9))
    groups = np.repeat([0, 1, 2], 20)
    to_local = np.eye(6) + 0.1 * rng.normal(size=(6, 6))
    covariance = to_local @ np.linalg.inv(J.T @ J)[:6, :6] @ to_local.T
    # Every group at 4 degrees of freedom (factor 2): the widening is the covariance itself.
    np.testing.assert_allclose(level_widening(J, groups, dict.fromkeys(range(3), 4.0), to_local), covariance)
    # Groups left out or learned from very many residuals add (almost) nothing.
    assert np.abs(level_widening(J, groups, {0: 1e9}, to_local)).max() < 1e-8 * np.abs(covariance).max()
    one = level_widening(J, groups, {1: 4.0}, to_local)
    assert np.all(np.linalg.eigvalsh(one) > -1e-12) and 0 < np.trace(one) < np.trace(covariance)


def test_few_views_widen_the_mount_and_many_hardly() -> None:
    """Synthetic views with the flange poses 3x noisier than declared: the levels learned from 6 views
    are uncertain enough to widen the mount's covariance by several percent, from 17 by less."""
    rng = np.random.default_rng(5)
    X = random_mount(rng)
    declared = SyntheticNoise()
    data = SyntheticNoise(
        robot=type(declared.robot)(
            3 * declared.robot.translation_sigma_m, 3 * declared.robot.rotation_sigma_rad
        )
    )
    share = {}
    for views in (6, 17):
        problem = build_problem(scene(X, rng, noise=data, views=views), BOARD, INTRINSICS, declared.robot)
        learned = learn_noise(problem, MethodOptions())
        share[views] = np.trace(learned.level_widening) / np.trace(learned.mount_covariance)
    assert share[6] > 0.05 and share[17] < share[6], share
