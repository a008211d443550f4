"""seed-ekf says when its assumptions fail: a warning whenever its error is far beyond its own
uncertainty (NEES over 20) on depths read with a scale error, none on the ideal scene, and its row
of the method table says so."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest

from hec.calibration.comparison import format_comparison
from hec.estimator.geometry.lie import pose_nees
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.methods import run_method
from hec.estimator.solve.problem import build_problem
from hec.support.synthetic_scenes import BOARD, INTRINSICS, random_mount, scene

FAILS = "seed-ekf's assumptions fail here"
ROW_SAYS = "its assumptions fail here: biased, do not use"


def _seed_ekf(seed: int, depth_scale: float):
    """seed-ekf's result and its NEES on the ideal scene with every depth read depth_scale x true."""
    rng = np.random.default_rng(seed)
    X = random_mount(rng)
    observations = [
        replace(
            o,
            markers=[
                replace(m, depth_m=depth_scale * m.depth_m, points_cam=depth_scale * m.points_cam)
                for m in o.markers
            ],
        )
        for o in scene(X, rng)
    ]
    result = run_method(
        "seed-ekf", build_problem(observations, BOARD, INTRINSICS), MethodOptions(), observations
    )
    return result, pose_nees(result.T_flange_cam, X, result.covariance)


@pytest.mark.parametrize("depth_scale", [1.0, 0.999, 0.98])
def test_seed_ekf_warns_whenever_it_is_far_off_and_not_on_the_ideal_scene(depth_scale: float) -> None:
    for seed in range(3):
        result, nees = _seed_ekf(seed, depth_scale)
        warned = [w for w in result.warnings if w.startswith(FAILS)]
        if nees > 20.0:
            assert warned, (depth_scale, seed, nees, result.warnings)
        if depth_scale == 1.0:
            assert not warned, (seed, nees, warned)
        row = format_comparison([result]).splitlines()[1]
        assert (ROW_SAYS in row) == bool(warned), row


def test_the_warning_names_the_depth_scale_it_found() -> None:
    result, _ = _seed_ekf(0, 0.999)
    (warning,) = [w for w in result.warnings if w.startswith(FAILS)]
    found = re.search(r"the depth reads ([-+][\d.]+) % off \(\+-([\d.]+) %\)", warning)
    assert found is not None and "use ekf, iekf, ukf or batch" in warning, warning
    assert abs(float(found.group(1)) - (-0.1)) < 3 * float(found.group(2)), warning
