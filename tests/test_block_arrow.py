"""The Schur-complement normal equations equal the dense ones on the batch objective's Jacobian."""

from __future__ import annotations

import numpy as np
import pytest

from hec.estimator.solve.batch import BatchObjective
from hec.estimator.solve.block_arrow import global_inverse, hat_diagonal, normal_solve
from hec.estimator.solve.calibration import MethodOptions, Prior
from hec.estimator.solve.filters import initial_covariance
from hec.estimator.solve.initialise import initial_state
from hec.estimator.solve.problem import build_problem
from hec.estimator.solve.self_calibration import SelfCalibrationObjective
from hec.support.synthetic_scenes import BOARD, INTRINSICS, random_mount, scene


def _objective(self_calibrated: bool) -> BatchObjective | SelfCalibrationObjective:
    rng = np.random.default_rng(3)
    X = random_mount(rng)
    problem = build_problem(scene(X, rng, views=6), BOARD, INTRINSICS)
    start = initial_state(problem, MethodOptions()).state
    P0 = initial_covariance(start, MethodOptions())
    prior = Prior(X, np.diag([1e-6] * 3 + [1e-4] * 3))
    if not self_calibrated:
        return BatchObjective(problem, start, P0, prior)
    return SelfCalibrationObjective(problem, lambda p: BatchObjective(p, start, P0, prior), ("fx_px", "k1"))


@pytest.mark.parametrize("self_calibrated", [False, True])
def test_schur_complement_equals_the_dense_normal_equations(self_calibrated: bool) -> None:
    objective = _objective(self_calibrated)
    params = np.random.default_rng(0).normal(0.0, 1e-4, objective.size)
    J, r = objective.jacobian(params), objective.residuals(params)
    layout = objective.layout
    assert layout.local, "the objective has per-frame deltas"
    N = J.T @ J
    x = normal_solve(J, r, layout)
    np.testing.assert_allclose(x, np.linalg.solve(N, J.T @ r), rtol=1e-8, atol=1e-12 * np.abs(x).max())
    g = layout.global_columns
    dense_inverse = np.linalg.inv(N)
    np.testing.assert_allclose(global_inverse(J, layout), dense_inverse[np.ix_(g, g)], rtol=1e-8, atol=0)
    np.testing.assert_allclose(
        hat_diagonal(J, layout), np.einsum("ij,ji->i", J, dense_inverse @ J.T), rtol=1e-8, atol=1e-12
    )
