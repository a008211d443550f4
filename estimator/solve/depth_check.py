"""Do the depths help, and do they agree with the pixels? A Hausman test; pixels only when not.

Depth errors the model cannot describe (a depth-to-colour misregistration seen on a tilted board,
correlated stereo errors, flying pixels at the markers' edges) pull the mount the same way in every
view: on the realistic cell they moved it by 2-3 mm at 6 sigma, while the pixels alone put it within
0.7 mm. The test compares the mount learned from pixels and depths, X_depth with covariance C_depth,
with the one learned from the pixels alone, X_pixels with C_pixels. When the depths are right, the
estimate with them is the efficient one and the difference d = X_depth - X_pixels (6,) has covariance
C_pixels - C_depth (Hausman). Every direction is tested, chi2 = sum of d's squared components over
their variances follows chi2(6): in the directions where the depths take at least MIN_INFORMATION
of the pixels-only variance away against that (Hausman), in the others against the sum of the two
estimates' variances, as if they were independent (conservative: the share the depths take away is
too small to estimate there, and negative where the depths' run self-calibrated more, a print scale
and a depth scale it cannot tell apart for example). A test
over the informative directions alone passed a 54 mm / 3.8 deg pull in the other four. Where the
depths take less in every direction (renders, whose corners are good to 0.02 px), d is tested
against C_pixels alone, which only catches a pull well beyond the pixels' own uncertainty. The
depths disagree when both tests fail at SIGNIFICANCE: where every estimate is good to 0.01 mm (exact
flange poses), the first alone flagged a pull of 0.01 mm that matters to no one. When the two disagree,
the depths are kept only if they fit the measurements both share (the corners and the flange poses)
clearly better (MISFIT_MARGIN), else the pixels win: misfit is the largest of the learned levels
over the declared ones. Depths the model cannot describe strain the corners (the realistic cell:
corners 2.8x their noise with the depths, 0.6x without); a print scale that only the depths can
tell from the distance strains the arm without them (0.75 mm learned for 0.1 mm declared; 0.12 mm
with the depths).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.geometry.lie import delta_size, pose_minus
from hec.estimator.solve.noise_levels import NoiseLevels
from hec.estimator.solve.problem import CalibrationProblem

# On ideal measurement-level data (40 seeds) the smallest p was 0.0035; the realistic cell's depths
# that moved the mount 2-3 mm gave chi-squares in the hundreds.
SIGNIFICANCE = 1e-3
# Depths that disagree are kept only when the pixels alone fit this many times worse: on a tie the
# pixels, which need no depth model, win.
MISFIT_MARGIN = 1.25
# The depths' share of the pixels-only variance of a direction they must take away to be tested in
# it: on ideal measurement-level data 0.14-0.42 in three directions, below 0.15 (or negative: the
# two learnings' levels differ) in the others.
MIN_INFORMATION = 0.15


@dataclass(frozen=True)
class DepthCheck:
    """delta: (6,) the mount with depths minus the one from the pixels alone (dt metres along the
    flange axes, dtheta radians about the camera axes); chi2 over dof (6) directions and its p_value,
    informative_directions of them tested against what the depths take away (module doc);
    p_pull: the test of delta against the pixels' own covariance (chi2(6));
    informative: whether the depths take enough variance away to be tested against what they take
    (else against the pixels' covariance; module doc);
    misfit_depth, misfit_pixels: the shared measurements' misfit (module doc) with the depths and
    without; used: whether the calibration uses them."""

    delta: np.ndarray
    chi2: float
    dof: int
    p_value: float
    p_pull: float
    informative: bool
    misfit_depth: float
    misfit_pixels: float
    informative_directions: int = 0

    @property
    def agrees(self) -> bool:
        return max(self.p_value, self.p_pull) >= SIGNIFICANCE

    @property
    def used(self) -> bool:
        return self.agrees or MISFIT_MARGIN * self.misfit_depth < self.misfit_pixels

    @property
    def shift_mm(self) -> float:
        """Length of the translation shift, mm."""
        return delta_size(self.delta)[0]

    @property
    def shift_deg(self) -> float:
        """Angle of the rotation shift, degrees."""
        return delta_size(self.delta)[1]

    def describe(self) -> str:
        """One line for the report: whether the depths are used, and why."""
        test = (
            f"with them the mount moves {self.shift_mm:.2f} mm / {self.shift_deg:.3f} deg, "
            f"p = {self.p_value:.2g} over {self.dof} directions"
        )
        if self.informative:
            test += f" ({self.informative_directions} against what the depths add)"
        if self.informative:
            test += f", against the pixels' own uncertainty p = {self.p_pull:.2g}"
        fits = (
            f"the corners and flange poses fit {self.misfit_depth:.2f}x their noise with them, "
            f"{self.misfit_pixels:.2f}x without"
        )
        if self.agrees:
            return f"depth: used; it agrees with the pixels ({test})"
        if self.used:
            return f"depth: used; the pixels alone disagree with it and fit worse ({test}; {fits})"
        return f"depth: not used; it disagrees with the pixels and does not fit better ({test}; {fits})"

    def to_dict(self) -> dict:
        return {
            "used": self.used,
            "informative": self.informative,
            "misfit_depth": self.misfit_depth,
            "misfit_pixels": self.misfit_pixels,
            "delta": self.delta.tolist(),
            "shift_mm": self.shift_mm,
            "shift_deg": self.shift_deg,
            "chi2": self.chi2,
            "dof": self.dof,
            "informative_directions": self.informative_directions,
            "p_value": self.p_value,
            "p_pull": self.p_pull,
            "significance": SIGNIFICANCE,
        }


def has_depth(problem: CalibrationProblem) -> bool:
    return any(m.depth_m is not None for f in problem.frames for m in f.markers)


def pixels_only(problem: CalibrationProblem) -> CalibrationProblem:
    """The problem without its depth measurements (each marker keeps its pixel whitening rows)."""
    frames = [
        replace(
            f,
            markers=[
                replace(m, depth_m=None, whitening=m.whitening[: m.pixel_rows, : 2 * len(m.corners_px)])
                for m in f.markers
            ],
        )
        for f in problem.frames
    ]
    return replace(problem, frames=frames)


def misfit(learned: NoiseLevels, declared: RobotPoseNoise) -> float:
    """The largest of the learned corner scale and the learned flange pose sigmas over the declared
    ones (module doc)."""
    return max(
        learned.pixel_scale,
        learned.robot.translation_sigma_m / declared.translation_sigma_m,
        learned.robot.rotation_sigma_rad / declared.rotation_sigma_rad,
    )


def depth_check(
    T_flange_cam_depth: np.ndarray,
    covariance_depth: np.ndarray,
    T_flange_cam_pixels: np.ndarray,
    covariance_pixels: np.ndarray,
    misfits: tuple[float, float],
) -> DepthCheck:
    """The test of the module doc: mounts (4, 4) with and without depths, their covariances (6, 6)
    (hec.estimator.geometry.lie convention, at each estimate) and misfits (with, without)."""
    delta = pose_minus(T_flange_cam_depth, T_flange_cam_pixels)
    L = np.linalg.cholesky(covariance_pixels)
    removed = np.linalg.solve(L, np.linalg.solve(L, covariance_pixels - covariance_depth).T)
    fraction, directions = np.linalg.eigh(0.5 * (removed + removed.T))
    tested = fraction > MIN_INFORMATION
    pull = float(delta @ np.linalg.solve(covariance_pixels, delta))
    p_pull = float(chi2.sf(pull, 6))
    if not tested.any():
        return DepthCheck(delta, pull, 6, p_pull, p_pull, False, *misfits)
    along = directions.T @ np.linalg.solve(L, delta)
    statistic = float(np.sum(along**2 / np.where(tested, fraction, 2.0 - fraction)))
    return DepthCheck(
        delta, statistic, 6, float(chi2.sf(statistic, 6)), p_pull, True, *misfits, int(tested.sum())
    )
