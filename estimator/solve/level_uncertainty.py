"""The mount's covariance widened for noise levels learned from few residuals.

A noise level learned by variance components (hec.estimator.solve.noise_learning) from a group of
residuals with redundancy rho, its declared level counting as PRIOR_DOF more, is itself uncertain: its
variance follows a scaled inverse chi-square with nu = rho + PRIOR_DOF degrees of freedom, and the
part of the mount's error that the group's measurements carry follows Student's t with nu degrees
of freedom rather than the normal, whose variance is nu / (nu - 2) times larger (student_t_factor).
The mount's covariance is the sum of each group's part, C_g = G_g G_g^T (G: the mount's rows of
inv(J^T J) J^T, J the whitened Jacobian at the optimum; G_g: its columns of group g's rows), and each
part is widened by its group's factor. With many views every group has a large redundancy (the
pixels have thousands of rows) and nothing changes; with a handful, the flange poses' levels come
from a few dozen residuals and widen their part.
"""

from __future__ import annotations

import numpy as np

from hec.estimator.solve.batch import BatchObjective
from hec.estimator.solve.problem import CalibrationProblem
from hec.estimator.solve.self_calibration import SelfCalibrationObjective

# nu / (nu - 2) is infinite at 2 degrees of freedom: at or below 3, this (the value at 3).
MAX_STUDENT_T_FACTOR = 3.0


def student_t_factor(dof: float) -> float:
    """The variance of Student's t with dof degrees of freedom over the normal's, nu / (nu - 2), at
    most MAX_STUDENT_T_FACTOR."""
    return MAX_STUDENT_T_FACTOR if dof <= 3.0 else min(dof / (dof - 2.0), MAX_STUDENT_T_FACTOR)


def row_groups(
    objective: BatchObjective | SelfCalibrationObjective, problem: CalibrationProblem
) -> np.ndarray:
    """The group index of every residual row (0 pixels, 1 depth, 2 flange translation, 3 flange
    rotation: hec.estimator.solve.noise_learning.GROUPS), -1 for the prior rows."""
    labels = [np.full(objective.n + (6 if objective.prior is not None else 0), -1)]
    for f in problem.frames:
        for m in f.markers:
            labels.append(np.r_[np.zeros(m.pixel_rows, int), np.ones(len(m.whitening) - m.pixel_rows, int)])
        if objective.with_robot:
            labels.append(np.array([2, 2, 2, 3, 3, 3]))
    if isinstance(objective, SelfCalibrationObjective):
        labels.append(np.full(len(objective.names), -1))
    return np.concatenate(labels)


def level_widening(
    J: np.ndarray, groups: np.ndarray, dof: dict[int, float], to_local: np.ndarray
) -> np.ndarray:
    """(6, 6) what the mount's covariance gains from its learned levels' uncertainty (module doc):
    sum over groups of (student_t_factor(dof[g]) - 1) C_g, in the mount's local perturbation.

    J: (rows, columns) the whitened Jacobian at the optimum, the mount's parameters its first 6
    columns. groups: (rows,) row_groups. dof: per group index, its level's degrees of freedom (groups
    not in it, the priors among them, are not widened). to_local: (6, 6) from the mount's parameters
    to its local perturbation at the estimate.
    """
    G = to_local @ np.linalg.solve(J.T @ J, J.T)[:6]
    widening = np.zeros((6, 6))
    for g, nu in dof.items():
        part = G[:, groups == g]
        widening += (student_t_factor(nu) - 1.0) * (part @ part.T)
    return 0.5 * (widening + widening.T)
