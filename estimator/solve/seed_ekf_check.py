"""Do seed-ekf's assumptions hold on these data?

seed-ekf (the paper's method) takes the camera, the depth and the arm as declared: it has no depth
scale, no lens correction and no kinematics in its state, and its marker centres come from the
depth. Its assumptions fail when any of these holds:

- the declared model needed self-calibration of the camera, the depth or the arm (the noise
  learning pass found them off; seed-ekf solved with them as declared; the board's print does not
  matter to it, its map is free marker centres);
- the depth's scale, estimated beside the mount (ekf with a depth scale, on the same problem with
  the board as the self-calibration found it: a print scale would otherwise read as a depth scale),
  is more than SIGNIFICANT sigmas from 1: a 0.1 % scale error moves seed-ekf's mount by about 20 of its
  own sigmas squared (NEES) and is below what the learning pass calls a misfit;
- its mount lies farther from the learning pass's optimum than their joint uncertainty allows
  (Mahalanobis distance with both covariances, chi-square with 6 degrees of freedom, p <
  DISAGREE_PROBABILITY).

Its estimate then carries a bias its covariance does not include.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2

from hec.estimator.geometry.lie import delta_size, pose_minus
from hec.estimator.solve.calibration import Calibration, MethodOptions
from hec.estimator.solve.filters import run_filter
from hec.estimator.solve.noise_learning import LearnedNoise
from hec.estimator.solve.problem import CalibrationProblem
from hec.estimator.solve.self_calibration import MARKER_SHIFTS, adjusted_problem, group_members

# Self-calibrated parts seed-ekf does not depend on (its landmarks are free marker centres).
BOARD_GROUPS = ("board_scale", "board_bend", MARKER_SHIFTS)
# seed-ekf and the optimum disagree when the distance between their mounts has this tail probability.
DISAGREE_PROBABILITY = 1e-3
# A depth scale this many sigmas from 1 breaks seed-ekf's assumption of unbiased depth.
SIGNIFICANT = 3.0


@dataclass(frozen=True)
class AssumptionCheck:
    """distance: Mahalanobis distance (sigmas, 6 dof) between seed-ekf's T_flange_cam and the
    learning pass's optimum, both covariances together; shift_mm, shift_deg: the size of that
    difference; self_calibrated: the parts the declared model had off that seed-ekf depends on
    (empty when it fitted); depth_scale, depth_scale_sigma: the depth's scale estimated beside the
    mount (measured depth = scale x true depth), None without depths."""

    distance: float
    shift_mm: float
    shift_deg: float
    self_calibrated: tuple[str, ...]
    depth_scale: float | None
    depth_scale_sigma: float | None

    @property
    def depth_biased(self) -> bool:
        return (
            self.depth_scale is not None
            and abs(self.depth_scale - 1.0) > SIGNIFICANT * self.depth_scale_sigma
        )

    @property
    def disagrees(self) -> bool:
        return chi2.sf(self.distance**2, 6) < DISAGREE_PROBABILITY

    @property
    def holds(self) -> bool:
        return not (self.self_calibrated or self.depth_biased or self.disagrees)

    def warning(self) -> str | None:
        """The warning seed-ekf's result carries when its assumptions fail, else None."""
        if self.holds:
            return None
        causes = []
        if self.self_calibrated:
            causes.append(
                "the declared model does not fit these data (self-calibration found "
                f"{', '.join(self.self_calibrated)} off) and seed-ekf takes it as declared"
            )
        if self.depth_biased:
            causes.append(
                f"the depth reads {100 * (self.depth_scale - 1.0):+.2f} % off "
                f"(+-{100 * self.depth_scale_sigma:.2f} %) and seed-ekf maps the markers from it"
            )
        causes.append(
            f"its mount is {self.shift_mm:.2f} mm / {self.shift_deg:.3f} deg from the noise learning's "
            f"optimum ({self.distance:.1f} sigma)"
        )
        return (
            "seed-ekf's assumptions fail here: "
            + "; ".join(causes)
            + ": its result is biased beyond its uncertainty; use ekf, iekf, ukf or batch"
        )


def check_assumptions(
    result: Calibration, learned: LearnedNoise, problem: CalibrationProblem, options: MethodOptions
) -> AssumptionCheck:
    """seed-ekf's result against the learning pass (module doc). problem, options: what seed-ekf
    solved (the declared camera at the learned noise levels)."""
    delta = pose_minus(result.T_flange_cam, learned.state.T_flange_cam)
    covariance = result.covariance + learned.mount_covariance
    distance = float(np.sqrt(delta @ np.linalg.solve(covariance, delta)))
    shift_mm, shift_deg = delta_size(delta)
    parts = tuple(group.replace("_", " ") for group in learned.groups_kept if group not in BOARD_GROUPS)
    scale = scale_sigma = None
    if any(m.depth_m is not None for f in problem.frames for m in f.markers):
        board = [
            i
            for i, name in enumerate(learned.theta_names)
            if any(name in group_members(problem, group) for group in BOARD_GROUPS)
        ]
        if board:
            problem = adjusted_problem(problem, learned.theta[board], [learned.theta_names[i] for i in board])
        scaled = run_filter(problem, replace(options, estimate_depth_scale=True, prior=None), iterated=False)
        scale, scale_sigma = scaled.depth_scale, scaled.depth_scale_sigma
    return AssumptionCheck(distance, shift_mm, shift_deg, parts, scale, scale_sigma)
