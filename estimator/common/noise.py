"""Noise settings shared by every layer: the reported flange pose's noise (what the simulator draws
and the estimators assume) and the levels a calibration learned (what a calibration file records
and verification reuses)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RobotPoseNoise:
    """Noise of the reported flange pose, in the convention of hec.estimator.geometry.lie:
    translation sigma per base axis (metres), rotation sigma per flange axis (radians)."""

    translation_sigma_m: float = 1e-4
    rotation_sigma_rad: float = float(np.radians(0.01))

    def __post_init__(self) -> None:
        if not (self.translation_sigma_m >= 0 and self.rotation_sigma_rad >= 0):
            raise ValueError("robot pose noise sigmas must be >= 0")

    def to_dict(self) -> dict:
        return {
            "translation_sigma_m": self.translation_sigma_m,
            "rotation_sigma_rad": self.rotation_sigma_rad,
        }

    def covariance(self) -> np.ndarray:
        """(6, 6) diagonal covariance of delta = (dt, dtheta)."""
        return np.diag([self.translation_sigma_m**2] * 3 + [self.rotation_sigma_rad**2] * 3)

    @property
    def is_zero(self) -> bool:
        return self.translation_sigma_m == 0.0 and self.rotation_sigma_rad == 0.0


@dataclass(frozen=True)
class LearnedNoiseLevels:
    """The noise levels a calibration learned (its JSON 'noise.learned'): pixel_scale and depth_scale
    multiply the detector's corner and the depth model's sigmas; the flange pose noise per base axis
    (metres) and per flange axis (radians). self_calibration: the corrected camera, board, depth and
    arm parameters by name (hec.estimator.solve.self_calibration), empty when none. depth_used: False
    when the calibration left the depths out, for they disagreed with the pixels
    (hec.estimator.solve.depth_check; 'noise.depth_check.used')."""

    pixel_scale: float
    depth_scale: float
    robot_translation_sigma_m: float
    robot_rotation_sigma_rad: float
    self_calibration: dict[str, float]
    depth_used: bool = True
