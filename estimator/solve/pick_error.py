"""The pick error: how far off a point the camera sees at the working distance lands in the base
frame because of the calibration's own uncertainty.

The point is on the optical axis at the median distance of the board centre from the camera over
the calibration's frames, p_cam = (0, 0, d). With the covariance C (6, 6) of the perturbation
(dt, dtheta) of T_flange_cam (hec.estimator.geometry.lie), its error in the flange frame is
e = dt - R_flange_cam skew(p_cam) dtheta, covariance J C J^T with J = [I, -R skew(p_cam)] (3, 6); the
robot's rotation to the base frame keeps its length. RMS = sqrt(trace); the 95 % radius is that of
sum(lambda_i z_i^2) (lambda the eigenvalues, z standard normal) by Satterthwaite's approximation
(a scaled chi-square with the same mean and variance).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from hec.estimator.geometry.lie import skew
from hec.estimator.geometry.transforms import invert, transform_points
from hec.estimator.solve.problem import CalibrationProblem

PICK_PROBABILITY = 0.95


@dataclass(frozen=True)
class PickError:
    """distance_m: the working distance (median camera-to-board-centre distance, metres);
    rms_mm, p95_mm: the RMS and 95 % radius of the base-frame error of a point on the optical axis
    there, from the calibration's covariance; covariance_m2: (3, 3) its covariance in the flange
    frame, metres squared."""

    distance_m: float
    rms_mm: float
    p95_mm: float
    covariance_m2: np.ndarray

    def to_dict(self) -> dict:
        return {
            "distance_m": self.distance_m,
            "rms_mm": self.rms_mm,
            "p95_mm": self.p95_mm,
            "point": "on the camera's optical axis at the median camera-to-board-centre distance",
        }


def working_point_cam(distance_m: float) -> np.ndarray:
    """(3,) the point on the optical axis at distance_m, camera frame, metres."""
    return np.array([0.0, 0.0, distance_m])


def working_distance(problem: CalibrationProblem, T_flange_cam: np.ndarray, centre_base: np.ndarray) -> float:
    """Median over the problem's frames of the distance (metres) of the board centre (3,), base
    frame, from the camera, at the reported flange poses."""
    distances = [
        np.linalg.norm(transform_points(invert(f.T_base_flange @ T_flange_cam), centre_base[None])[0])
        for f in problem.frames
    ]
    return float(np.median(distances))


def pick_error(T_flange_cam: np.ndarray, covariance: np.ndarray, distance_m: float) -> PickError:
    """The pick error (module doc) of a mount (4, 4) with covariance (6, 6) at distance_m."""
    p_cam = working_point_cam(distance_m)
    J = np.hstack([np.eye(3), -T_flange_cam[:3, :3] @ skew(p_cam)])
    cov = J @ covariance @ J.T
    lam = np.clip(np.linalg.eigvalsh(cov), 0.0, None)
    mean, spread = lam.sum(), (lam**2).sum()
    p95 = 0.0 if mean == 0 else np.sqrt(spread / mean * chi2.ppf(PICK_PROBABILITY, mean**2 / spread))
    return PickError(distance_m, 1e3 * float(np.sqrt(mean)), 1e3 * float(p95), cov)


def true_pick_error_mm(T_flange_cam: np.ndarray, T_true: np.ndarray, distance_m: float) -> float:
    """In simulation: how far (mm) the working point lands from where the true mount puts it."""
    p_cam = working_point_cam(distance_m)[None]
    return 1e3 * float(
        np.linalg.norm(transform_points(T_flange_cam, p_cam) - transform_points(T_true, p_cam))
    )
