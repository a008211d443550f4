"""Noise levels of a calibration problem and the problem scaled to them: the corner and depth
whitening divided by their scales, the flange pose noise replaced (hec.estimator.solve.noise_learning
learns the levels)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.solve.problem import CalibrationProblem, MarkerMeasurement


@dataclass(frozen=True)
class NoiseLevels:
    """Noise levels of a problem: pixel_scale and depth_scale multiply the declared corner and
    depth sigmas; robot is the flange pose noise itself."""

    pixel_scale: float
    depth_scale: float
    robot: RobotPoseNoise

    def to_dict(self) -> dict:
        return {
            "pixel_scale": self.pixel_scale,
            "depth_scale": self.depth_scale,
            "robot_translation_sigma_m": self.robot.translation_sigma_m,
            "robot_rotation_sigma_rad": self.robot.rotation_sigma_rad,
        }


def declared_levels(problem: CalibrationProblem) -> NoiseLevels:
    return NoiseLevels(1.0, 1.0, problem.robot_noise)


def scaled_problem(
    problem: CalibrationProblem, levels: NoiseLevels, leave_out: set[tuple[int, int]] = frozenset()
) -> CalibrationProblem:
    """The problem with its pixel and depth whitening divided by the levels' scales, its robot
    noise replaced, and the (frame, marker_id) pairs of leave_out removed (frames left without a
    marker are dropped)."""
    frames = []
    for f in problem.frames:
        markers = [_scaled(m, levels) for m in f.markers if (f.frame, m.marker_id) not in leave_out]
        if markers:
            frames.append(replace(f, markers=markers))
    return replace(problem, frames=frames, robot_noise=levels.robot)


def _scaled(m: MarkerMeasurement, levels: NoiseLevels) -> MarkerMeasurement:
    if levels.pixel_scale == 1.0 and levels.depth_scale == 1.0:
        return m
    scale = np.ones(len(m.whitening))
    scale[: m.pixel_rows] = 1.0 / levels.pixel_scale
    scale[m.pixel_rows :] = 1.0 / levels.depth_scale
    return replace(m, whitening=m.whitening * scale[:, None])
