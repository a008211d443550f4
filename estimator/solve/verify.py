"""Does a calibration still hold? A test of T_flange_cam on a few new frames.

From the verification frames alone, with the board pose in the base frame free (a nuisance: the
board may have been moved too) and every reported flange pose's error an unknown, the batch
problem (hec.estimator.solve.batch: the same measurement model, Gauss-Newton, Huber loss) estimates the
mount, started at the calibration's. Its shift from the calibration is

    delta = pose_minus(T_flange_cam_verify, T_flange_cam_cal)     (6,): dt (m, flange axes), dtheta
                                                                  (rad, camera axes), lie convention

with covariance C_v (the verification's) + C_cal (the calibration's). If nothing moved, delta is
N(0, C_v + C_cal) and chi2 = delta^T (C_v + C_cal)^-1 delta follows chi2(6): a p-value below
SIGNIFICANCE says the camera moved on its mount. The verification problem uses the noise levels the
calibration learned (and its self-calibrated camera, board, depth and arm), so C_v is as honest as
C_cal; with the declared levels instead C_v would be too small wherever the data are noisier than
declared, and the test would cry wolf.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from scipy.stats import chi2

from hec.estimator.common.noise import LearnedNoiseLevels, RobotPoseNoise
from hec.estimator.geometry.lie import delta_size, pose_minus
from hec.estimator.solve.batch import BatchObjective, gauss_newton, one_blas_thread, state_covariance
from hec.estimator.solve.calibration import MethodOptions
from hec.estimator.solve.depth_check import pixels_only
from hec.estimator.solve.filters import initial_covariance
from hec.estimator.solve.initialise import board_pose_pnp, mean_pose
from hec.estimator.solve.measurement_model import HandEyeState
from hec.estimator.solve.noise_levels import NoiseLevels, scaled_problem
from hec.estimator.solve.problem import CalibrationProblem
from hec.estimator.solve.self_calibration import adjusted_problem

SIGNIFICANCE = 0.01  # p below this: "moved"
VERIFY_VIEWS = 5  # views of a verification session (hec run --verify)
DOF = 6

Item = TypeVar("Item")


def spread_views(items: list[Item], count: int = VERIFY_VIEWS) -> list[Item]:
    """count of the items, the one nearest the middle of each of count equal parts of the list (so on
    the default trajectory they mix both distances, tilts and rolls); all if fewer."""
    if len(items) <= count:
        return list(items)
    return [items[int(i)] for i in np.round((np.arange(count) + 0.5) * len(items) / count)]


def verification_problem(problem: CalibrationProblem, noise: LearnedNoiseLevels | None) -> CalibrationProblem:
    """The verification frames' problem at the calibration's learned noise levels, with its
    self-calibrated parameters applied and without the depths when it left them out (the problem as
    it is when noise is None)."""
    if noise is None:
        return problem
    if not noise.depth_used:
        problem = pixels_only(problem)
    if noise.self_calibration:
        names = tuple(noise.self_calibration)
        problem = adjusted_problem(problem, np.array([noise.self_calibration[n] for n in names]), names)
    robot = RobotPoseNoise(noise.robot_translation_sigma_m, noise.robot_rotation_sigma_rad)
    return scaled_problem(problem, NoiseLevels(noise.pixel_scale, noise.depth_scale, robot))


@dataclass(frozen=True)
class Verification:
    """T_flange_cam_verify: (4, 4) the mount the verification frames give; T_base_board: (4, 4) the
    board they give. delta: (6,) its shift from the calibration (module doc); covariance_verify,
    covariance_calibration: (6, 6), the latter None when the calibration has none. chi2, p_value:
    the test (None without the calibration's covariance). fit_chi2_dof: the verification frames'
    whitened measurement residuals per degree of freedom (about 1 when the noise model fits them).
    frames: frames used."""

    T_flange_cam_verify: np.ndarray
    T_base_board: np.ndarray
    delta: np.ndarray
    covariance_verify: np.ndarray
    covariance_calibration: np.ndarray | None
    chi2: float | None
    p_value: float | None
    fit_chi2_dof: float
    frames: int

    @property
    def shift_mm(self) -> float:
        """Length of the translation shift, mm."""
        return delta_size(self.delta)[0]

    @property
    def shift_deg(self) -> float:
        """Angle of the rotation shift, degrees."""
        return delta_size(self.delta)[1]

    @property
    def moved(self) -> bool | None:
        """True when the test rejects "nothing moved" at SIGNIFICANCE; None when it cannot test."""
        return None if self.p_value is None else self.p_value < SIGNIFICANCE

    @property
    def test_sigma(self) -> tuple[float, float]:
        """Root-sum-square 1-sigma of the test's covariance: translation (mm), rotation (degrees)."""
        cov = self.covariance_verify + (
            0.0 if self.covariance_calibration is None else self.covariance_calibration
        )
        d = np.diag(cov)
        return 1e3 * float(np.sqrt(d[:3].sum())), float(np.degrees(np.sqrt(d[3:].sum())))

    def to_dict(self) -> dict:
        return {
            "T_flange_cam_verify": self.T_flange_cam_verify.tolist(),
            "T_base_board": self.T_base_board.tolist(),
            "delta": self.delta.tolist(),
            "delta_convention": "(dt_x, dt_y, dt_z) m along the flange axes, then (dtheta_x, dtheta_y, "
            "dtheta_z) rad about the camera axes: T_verify = (R_cal Exp(dtheta), t_cal + dt)",
            "shift_mm": self.shift_mm,
            "shift_deg": self.shift_deg,
            "covariance_verify": self.covariance_verify.tolist(),
            "chi2": self.chi2,
            "dof": DOF,
            "p_value": self.p_value,
            "significance": SIGNIFICANCE,
            "moved": self.moved,
            "fit_chi2_per_dof": self.fit_chi2_dof,
            "frames": self.frames,
        }


def _board_start(problem: CalibrationProblem, T_flange_cam: np.ndarray) -> np.ndarray:
    """T_base_board (4, 4) the calibrated mount and each frame's PnP board pose give, averaged."""
    return mean_pose([f.T_base_flange @ T_flange_cam @ board_pose_pnp(problem, f) for f in problem.frames])


def verify_mount(
    problem: CalibrationProblem,
    T_flange_cam: np.ndarray,
    covariance: np.ndarray | None,
    depth_scale: float | None = None,
) -> Verification:
    """Test the calibration T_flange_cam (4, 4) with covariance (6, 6) or None against the
    verification problem (built with verification_problem); depth_scale: the calibration's, a
    nuisance here too, or None (fixed at 1). See the module doc."""
    start = HandEyeState(T_flange_cam, _board_start(problem, T_flange_cam), depth_scale=depth_scale)
    options = MethodOptions()
    objective = BatchObjective(problem, start, initial_covariance(start, options), None)
    with one_blas_thread():
        optimum = gauss_newton(objective, np.zeros(objective.size), options.robust)
        params = optimum.params
        cov_state = state_covariance(objective, params, options.robust, optimum)
    state = start.plus(params[: objective.n])
    residual = np.concatenate(objective.frame_residuals(params))
    fit = float(residual @ residual) / max(len(residual) - objective.size, 1)
    delta = pose_minus(state.T_flange_cam, T_flange_cam)
    C_v = cov_state[:6, :6]
    stat = p = None
    if covariance is not None:
        stat = float(delta @ np.linalg.solve(C_v + covariance, delta))
        p = float(chi2.sf(stat, DOF))
    return Verification(
        state.T_flange_cam, state.T_base_board, delta, C_v, covariance, stat, p, fit, len(problem.frames)
    )


def format_verdict(v: Verification) -> str:
    """One line: "consistent (p = 0.42)" or "the camera has moved: about 1.2 mm and 0.15 degrees
    (p < 0.001)"; without the calibration's covariance, the shift and that it cannot be tested."""
    shift = f"about {v.shift_mm:.2f} mm and {v.shift_deg:.3f} degrees"
    if v.p_value is None:
        return (
            f"not tested: the mount differs by {shift}, but the calibration has no covariance to test "
            "it against"
        )
    p = "p < 0.001" if v.p_value < 1e-3 else f"p = {v.p_value:.3g}"
    return f"the camera has moved: {shift} ({p})" if v.moved else f"consistent ({p})"
