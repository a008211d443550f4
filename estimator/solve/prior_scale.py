"""How wide the self-calibration's priors really are, learned from the corrections themselves.

Self-calibration (hec.estimator.solve.self_calibration) gives each correction a Gaussian prior: an
arm's DH deltas of a calibrated UR, a factory camera's intrinsics, an office print. A cell further
off than that (an arm never calibrated, a lens twice as strong) makes the corrections larger than
their priors, and the directions the views cannot pin down keep the prior's too small spread: the
mount's covariance, which carries them (the consider covariance), is then too small. The prior of
each group is one more variance component: its whitened rows theta / sigma have, at the optimum,
an expected sum of squares equal to their redundancy sum(1 - hat) when the prior is right, so each
group's prior sigma is rescaled by that ratio (Helmert, as the noise levels; shrunk toward the
declared prior by PRIOR_DOF degrees of freedom) and never made narrower than declared: a prior is
what the cell file promises at best, and the data of a few views cannot show it to be too wide.
"""

from __future__ import annotations

import numpy as np

from hec.estimator.solve.problem import CalibrationProblem
from hec.estimator.solve.self_calibration import NUISANCE_GROUPS, group_members

# The declared prior is worth this many degrees of freedom (as the noise levels' PRIOR_DOF).
PRIOR_DOF = 3.0
# A group whose prior rows have less redundancy than this says nothing about its prior's width.
MIN_REDUNDANCY = 0.5


def name_groups(problem: CalibrationProblem, names: tuple[str, ...]) -> np.ndarray:
    """(len(names),) the index into NUISANCE_GROUPS of each theta name's group."""
    group_of = {n: g for g, group in enumerate(NUISANCE_GROUPS) for n in group_members(problem, group)}
    return np.array([group_of[n] for n in names], dtype=int)


def updated_prior_scale(
    scale: np.ndarray, groups: np.ndarray, whitened: np.ndarray, redundancy: np.ndarray
) -> np.ndarray:
    """(p,) each theta prior's scale (its sigma over the declared one, per name, the same within a
    group) after one variance-component step. scale: (p,) the current scales; groups: (p,)
    name_groups; whitened: (p,) the prior rows' residuals theta / (scale sigma) at the optimum;
    redundancy: (p,) each prior row's 1 - hat."""
    new = scale.astype(float).copy()
    for g in np.unique(groups):
        rows = groups == g
        rho = float(np.sum(redundancy[rows]))
        if rho < MIN_REDUNDANCY:
            continue
        current = float(scale[rows][0])
        squares = float(np.sum(whitened[rows] ** 2))
        variance = (squares * current**2 + PRIOR_DOF) / (rho + PRIOR_DOF)
        new[rows] = max(1.0, float(np.sqrt(variance)))
    return new
