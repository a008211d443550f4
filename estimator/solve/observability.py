"""Fisher information of T_flange_cam, its Cramer-Rao bound, and a degeneracy check in plain words.

For frame i with whitened Jacobians J_s (state) and J_f (flange pose error delta_i,
prior N(0, Sigma_r)), marginalising delta_i gives the state information
J_s^T inv(I + J_f Sigma_r J_f^T) J_s. Summed over frames and reduced to
T_flange_cam by the Schur complement over the board (or landmarks) and the depth
scale, its inverse is the Cramer-Rao bound: the smallest covariance any unbiased
estimator can reach from these views and this noise (hec.estimator.geometry.lie convention).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hec.estimator.common.noise import RobotPoseNoise
from hec.estimator.solve.measurement_model import HandEyeState, predict_frame
from hec.estimator.solve.problem import CalibrationProblem, FrameMeasurements

# 1-sigma above which a direction is reported as poorly determined / not observable.
POOR_SIGMA_MM, POOR_SIGMA_DEG = 1.0, 0.1
UNOBSERVABLE_SIGMA_MM, UNOBSERVABLE_SIGMA_DEG = 100.0, 10.0
_CAMERA_AXES = (
    "the camera's x axis (image right)",
    "the camera's y axis (image down)",
    "the camera's optical axis",
)
_ADVICE = "add rotations of 15 degrees or more about at least two different axes"


@dataclass
class Observability:
    """information: (6, 6) Fisher information of T_flange_cam (per m^2, rad^2). crb_covariance:
    its inverse, None when singular. crb_sigma_*: (3,) 1-sigma per axis (inf if not observable).
    warnings: one sentence per weak direction. observable: no direction beyond UNOBSERVABLE."""

    information: np.ndarray
    crb_covariance: np.ndarray | None
    crb_sigma_translation_mm: np.ndarray
    crb_sigma_rotation_deg: np.ndarray
    warnings: list[str] = field(default_factory=list)
    observable: bool = True

    def to_dict(self) -> dict:
        return {
            "crb_sigma_translation_mm": [float(v) for v in self.crb_sigma_translation_mm],
            "crb_sigma_rotation_deg": [float(v) for v in self.crb_sigma_rotation_deg],
            "observable": self.observable,
            "warnings": list(self.warnings),
        }


def frame_information(
    problem: CalibrationProblem, state: HandEyeState, frame: FrameMeasurements
) -> np.ndarray:
    """(dim, dim) Fisher information of the state perturbation from one frame, its flange pose
    error marginalised."""
    pred = predict_frame(problem, state, frame)
    return flange_marginalised_information(pred.J_state, pred.J_flange, problem.robot_noise)


def flange_marginalised_information(
    J: np.ndarray, J_flange: np.ndarray, robot_noise: RobotPoseNoise
) -> np.ndarray:
    """(d, d) the information J^T (I + J_flange Sigma J_flange^T)^-1 J of one frame's whitened
    Jacobian J (m, d), its flange pose error (J_flange (m, 6), Sigma robot_noise's covariance)
    marginalised, through the push-through identity: a 6x6 solve, not m x m."""
    if robot_noise.is_zero:
        return J.T @ J
    Sigma = robot_noise.covariance()
    B = J.T @ J_flange
    return J.T @ J - B @ np.linalg.solve(np.eye(6) + Sigma @ (J_flange.T @ J_flange), Sigma @ B.T)


def state_information(problem: CalibrationProblem, state: HandEyeState) -> np.ndarray:
    """(dim, dim) Fisher information of the state perturbation, flange pose errors marginalised."""
    info = np.zeros((state.dim, state.dim))
    for frame in problem.frames:
        info += frame_information(problem, state, frame)
    return info


def mount_information(problem: CalibrationProblem, state: HandEyeState) -> np.ndarray:
    """(6, 6) information of T_flange_cam alone: Schur complement over the map and depth scale."""
    info = state_information(problem, state)
    A, B, C = info[:6, :6], info[:6, 6:], info[6:, 6:]
    return A - B @ np.linalg.pinv(C, hermitian=True) @ B.T


def _describe(vector: np.ndarray, R_flange_cam: np.ndarray, is_translation: bool) -> str:
    """Plain-words direction of a unit (3,) vector: translations are in the flange frame,
    rotations about the camera axes; named by the nearest camera axis when close to one."""
    in_cam = R_flange_cam.T @ vector if is_translation else vector
    axis = int(np.argmax(np.abs(in_cam)))
    if abs(in_cam[axis]) > 0.9:
        name = _CAMERA_AXES[axis]
    else:
        name = "direction ({:+.2f}, {:+.2f}, {:+.2f}) of the camera frame".format(*in_cam)
    return ("translation along " if is_translation else "rotation about ") + name


def _is_translation(v: np.ndarray) -> bool:
    """Whether a direction (6,) of the mount is more translation than rotation."""
    return bool(np.linalg.norm(v[:3]) >= np.linalg.norm(v[3:]))


def _direction(v: np.ndarray, state: HandEyeState) -> str:
    """A direction (6,) of the mount in plain words (_describe of its larger part)."""
    translation = _is_translation(v)
    part = v[:3] if translation else v[3:]
    return _describe(part / np.linalg.norm(part), state.T_flange_cam[:3, :3], translation)


def observability(
    problem: CalibrationProblem, state: HandEyeState, covariance: np.ndarray | None = None
) -> Observability:
    """Cramer-Rao bound of T_flange_cam at ``state`` and the directions it cannot pin down.
    covariance: the estimate's own (6, 6) covariance (hec.estimator.geometry.lie convention): the
    directions it leaves poorly determined are warned about with its own 1-sigma, the bound's
    beside it; None: the bound's directions and sigmas."""
    info = mount_information(problem, state)
    units = np.array([1e-3] * 3 + [np.radians(1.0)] * 3)  # metres per mm, radians per degree
    scaled = units[:, None] * info * units[None, :]  # information per mm^2 / deg^2
    values, vectors = np.linalg.eigh(0.5 * (scaled + scaled.T))
    sigmas = np.where(values > 0, 1.0 / np.sqrt(np.maximum(values, 1e-300)), np.inf)
    result = Observability(info, None, np.full(3, np.inf), np.full(3, np.inf))

    def bound_sigma(v: np.ndarray) -> float:
        """The bound's 1-sigma along a unit direction v (6,) (mm, degrees)."""
        weights = (vectors.T @ v) ** 2
        return float(np.sqrt(np.sum(np.where(weights > 1e-12, weights * sigmas**2, 0.0))))

    for sigma, v in zip(sigmas, vectors.T, strict=True):
        if sigma > (UNOBSERVABLE_SIGMA_MM if _is_translation(v) else UNOBSERVABLE_SIGMA_DEG):
            result.observable = False
            result.warnings.append(f"{_direction(v, state)} is not observable from these views: {_ADVICE}")
    if covariance is None:
        own = list(zip(sigmas, vectors.T, strict=True))
    else:
        own_values, own_vectors = np.linalg.eigh(covariance / units[:, None] / units[None, :])
        own = list(zip(np.sqrt(np.maximum(own_values, 0.0)), own_vectors.T, strict=True))
    for sigma, v in own:
        translation = _is_translation(v)
        bound = bound_sigma(v)
        if bound > (UNOBSERVABLE_SIGMA_MM if translation else UNOBSERVABLE_SIGMA_DEG):
            continue  # said above
        if sigma > (POOR_SIGMA_MM if translation else POOR_SIGMA_DEG):
            unit = "mm" if translation else "degrees"
            whose = (
                f"the Cramer-Rao bound's 1-sigma {sigma:.2g} {unit}"
                if covariance is None
                else f"this estimate's 1-sigma {sigma:.2g} {unit}; the Cramer-Rao bound's {bound:.2g}"
            )
            result.warnings.append(
                f"{_direction(v, state)} is poorly determined ({whose}): {_ADVICE}, or add views"
            )
    unobservable_translations = [w for w in result.warnings if w.startswith("translation") and "not obs" in w]
    if len(unobservable_translations) == 3:
        result.warnings = [w for w in result.warnings if w not in unobservable_translations]
        result.warnings.insert(0, f"the mount's translation is not observable in any direction: {_ADVICE}")
    if result.observable:
        cov = np.linalg.inv(info)
        result.crb_covariance = 0.5 * (cov + cov.T)
        result.crb_sigma_translation_mm = 1e3 * np.sqrt(np.diag(cov)[:3])
        result.crb_sigma_rotation_deg = np.degrees(np.sqrt(np.diag(cov)[3:]))
    return result
