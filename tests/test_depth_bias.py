"""A biased depth is calibrated and used, not dropped, and it does not pull the mount: on
measurement-level synthetic scenes (the default two-distance views) whose depth reads a known scale
and offset off, the noise learning frees only the depth's own groups (the corners and the flange
poses fit), recovers the bias within 3 sigma with its sign, keeps the depths, and leaves the mount
where the pixels alone put it, within its reported uncertainty."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from hec.estimator.geometry.lie import pose_minus
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.depth_check import pixels_only
from hec.estimator.solve.noise_learning import learn_noise
from hec.estimator.solve.problem import build_problem
from hec.estimator.solve.self_calibration import DEPTH_GROUPS
from hec.support.synthetic_scenes import BOARD, INTRINSICS, random_mount, scene

# A 6-dof Mahalanobis distance beyond this happens once in a thousand honest trials.
NEES_LIMIT = float(chi2.ppf(0.999, 6))


def _biased(observations: list, scale: float, offset_m: float) -> list:
    """The observations with every depth read as scale x depth + offset_m."""
    return [
        replace(o, markers=[replace(m, depth_m=scale * m.depth_m + offset_m) for m in o.markers])
        for o in observations
    ]


@pytest.mark.parametrize(("scale", "offset_m", "seed"), [(0.98, 0.004, 4601), (1.02, -0.003, 4602)])
def test_a_biased_depth_is_recovered_within_3_sigma_and_does_not_pull_the_mount(
    scale: float, offset_m: float, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    X = random_mount(rng)
    observations = _biased(scene(X, rng), scale, offset_m)
    problem = build_problem(observations, BOARD, INTRINSICS)
    learned = learn_noise(problem, MethodOptions())

    # Only the depth misfits: the camera's intrinsics, distortion and the board's bend stay declared.
    assert learned.groups_tried and set(learned.groups_tried) <= set(DEPTH_GROUPS), learned.groups_tried
    assert "depth_bias" in learned.groups_kept, learned.groups_kept
    assert learned.depth is not None and learned.depth.used, learned.depth.describe()

    # measured = exp(depth_scale) (z + depth_offset_m) = scale z + offset_m
    theta = dict(zip(learned.theta_names, learned.theta, strict=True))
    sigma = dict(zip(learned.theta_names, learned.theta_sigma, strict=True))
    true_theta = {"depth_scale": np.log(scale), "depth_offset_m": offset_m / scale}
    for name, truth in true_theta.items():
        assert abs(theta[name] - truth) < 3 * sigma[name], (name, theta[name], truth, sigma[name])
    assert np.sign(theta["depth_scale"]) == np.sign(scale - 1.0)

    # The mount: honest against the truth, and where the pixels alone put it.
    delta = pose_minus(learned.state.T_flange_cam, X)
    assert float(delta @ np.linalg.solve(learned.mount_covariance, delta)) < NEES_LIMIT
    pixels = learn_noise(pixels_only(problem), MethodOptions())
    pull = pose_minus(learned.state.T_flange_cam, pixels.state.T_flange_cam)
    assert float(pull @ np.linalg.solve(pixels.mount_covariance, pull)) < NEES_LIMIT
