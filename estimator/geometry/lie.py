"""Small perturbations of rotations and rigid transforms.

The one perturbation convention every estimator, covariance and Jacobian uses:
a pose T = (R, t) is perturbed by delta = (dt, dtheta), (6,), as

    R' = R @ Exp(dtheta)      (dtheta in the pose's own, local frame, radians)
    t' = t + dt               (dt in the parent frame, metres)

so for T_flange_cam the translation part is in the flange frame and the rotation
part about the camera's axes. This is also how the simulator perturbs reported
flange poses (hec.sim.noise.perturb_flange_pose).
"""

from __future__ import annotations

import numpy as np

from hec.estimator.geometry.transforms import make_transform

SMALL_ANGLE = 1e-8
# so3_log takes scipy's route within this of a half turn (radians).
NEAR_PI = 1e-3


def skew(v: np.ndarray) -> np.ndarray:
    """(3,) -> (3, 3) matrix with skew(v) @ w = cross(v, w)."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def skew_rows(v: np.ndarray) -> np.ndarray:
    """(P, 3) -> (P, 3, 3) cross-product matrices."""
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -v[:, 2], v[:, 1]
    S[:, 1, 0], S[:, 1, 2] = v[:, 2], -v[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -v[:, 1], v[:, 0]
    return S


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation vector (3,), radians -> (3, 3) rotation (Rodrigues)."""
    angle = float(np.linalg.norm(w))
    W = skew(w)
    if angle < SMALL_ANGLE:
        return np.eye(3) + W + 0.5 * W @ W
    return np.eye(3) + np.sin(angle) / angle * W + (1.0 - np.cos(angle)) / angle**2 * W @ W


def _rodrigues(w: np.ndarray, sine: np.ndarray, cosine: np.ndarray) -> np.ndarray:
    """(N, 3, 3) I + sine W + cosine W^2 for rotation vectors w (N, 3), coefficients (N,)."""
    W = skew_rows(w)
    return np.eye(3) + sine[:, None, None] * W + cosine[:, None, None] * (W @ W)


def so3_exp_rows(w: np.ndarray) -> np.ndarray:
    """(N, 3, 3) so3_exp of each rotation vector (N, 3)."""
    angle = np.linalg.norm(w, axis=1)
    small = angle < SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    sine = np.where(small, 1.0, np.sin(safe) / safe)
    cosine = np.where(small, 0.5, (1.0 - np.cos(safe)) / safe**2)
    return _rodrigues(w, sine, cosine)


def pose_plus_jacobian_rows(delta: np.ndarray) -> np.ndarray:
    """(N, 6, 6) pose_plus_jacobian of each perturbation (N, 6)."""
    w = delta[:, 3:]
    angle = np.linalg.norm(w, axis=1)
    small = angle < SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    sine = np.where(small, -0.5, -(1.0 - np.cos(safe)) / safe**2)
    cosine = np.where(small, 1.0 / 6.0, (safe - np.sin(safe)) / safe**3)
    J = np.broadcast_to(np.eye(6), (len(delta), 6, 6)).copy()
    J[:, 3:, 3:] = _rodrigues(w, sine, cosine)
    return J


def so3_log(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> rotation vector (3,), radians, angle in [0, pi]. Closed form (the angle from
    atan2 of the skew part and the trace, accurate down to zero); within NEAR_PI of a half turn, where
    the skew part vanishes, scipy's quaternion route."""
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    sine2 = float(np.linalg.norm(v))  # 2 sin(angle)
    cosine2 = float(R[0, 0] + R[1, 1] + R[2, 2] - 1.0)  # 2 cos(angle)
    angle = np.arctan2(sine2, cosine2)
    if angle > np.pi - NEAR_PI:
        from scipy.spatial.transform import Rotation  # loaded on first use: 0.2 s at start-up otherwise

        return Rotation.from_matrix(R).as_rotvec()
    if angle < SMALL_ANGLE:
        return 0.5 * v * (1.0 + angle * angle / 6.0)
    return angle / sine2 * v


def so3_right_jacobian(w: np.ndarray) -> np.ndarray:
    """(3, 3) right Jacobian of SO(3): Exp(w + e) ~= Exp(w) @ Exp(Jr(w) @ e) for small e."""
    angle = float(np.linalg.norm(w))
    W = skew(w)
    if angle < SMALL_ANGLE:
        return np.eye(3) - 0.5 * W + W @ W / 6.0
    return np.eye(3) - (1.0 - np.cos(angle)) / angle**2 * W + (angle - np.sin(angle)) / angle**3 * W @ W


def so3_right_jacobian_inverse(w: np.ndarray) -> np.ndarray:
    """(3, 3) inverse of so3_right_jacobian(w)."""
    angle = float(np.linalg.norm(w))
    W = skew(w)
    if angle < SMALL_ANGLE:
        return np.eye(3) + 0.5 * W + W @ W / 12.0
    return (
        np.eye(3) + 0.5 * W + (1.0 / angle**2 - (1.0 + np.cos(angle)) / (2.0 * angle * np.sin(angle))) * W @ W
    )


def pose_plus(T: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """(4, 4) pose perturbed by delta = (dt, dtheta), (6,): (R Exp(dtheta), t + dt)."""
    return make_transform(T[:3, :3] @ so3_exp(delta[3:]), T[:3, 3] + delta[:3])


def pose_minus(T: np.ndarray, T_ref: np.ndarray) -> np.ndarray:
    """The delta (6,) with pose_plus(T_ref, delta) == T."""
    return np.concatenate([T[:3, 3] - T_ref[:3, 3], so3_log(T_ref[:3, :3].T @ T[:3, :3])])


def delta_size(delta: np.ndarray) -> tuple[float, float]:
    """The size of a perturbation (6,) (dt, dtheta): the length of dt in millimetres and the angle of
    dtheta in degrees."""
    return 1e3 * float(np.linalg.norm(delta[:3])), float(np.degrees(np.linalg.norm(delta[3:])))


# chi2(6)'s 95 % quantile: an honest pose NEES exceeds it in 5 % of the trials.
NEES_95_LINE = 12.592


def pose_nees(T_estimate: np.ndarray, T_true: np.ndarray, covariance: np.ndarray) -> float:
    """Squared Mahalanobis distance of the (4, 4) estimate from the truth, pose_minus(T_estimate,
    T_true), under the estimate's (6, 6) covariance: about 6 on average when it is honest. Raises
    numpy.linalg.LinAlgError for a singular covariance."""
    delta = pose_minus(T_estimate, T_true)
    return float(delta @ np.linalg.solve(covariance, delta))


def pose_plus_jacobian(delta: np.ndarray) -> np.ndarray:
    """(6, 6) d(local perturbation at pose_plus(T, delta)) / d(delta): block diag(I, Jr(dtheta))."""
    J = np.eye(6)
    J[3:, 3:] = so3_right_jacobian(delta[3:])
    return J
