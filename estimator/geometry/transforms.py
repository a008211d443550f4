"""Rigid transforms as 4x4 homogeneous matrices.

Convention: ``T_a_b`` is the pose of frame ``b`` in frame ``a``; it maps
points in ``b`` to ``a`` (``p_a = T_a_b @ p_b``) and ``T_a_c = T_a_b @ T_b_c``.
Lengths are metres, angles radians.
"""

from __future__ import annotations

import numpy as np


def _rotation() -> type:
    """scipy's Rotation, imported on first use: scipy.spatial takes about 0.2 s to load, which every
    command would otherwise pay at start-up (`hec export --help` included)."""
    from scipy.spatial.transform import Rotation

    return Rotation


def make_transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(3, 3) rotation and (3,) translation -> (4, 4) transform."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def invert(T_a_b: np.ndarray) -> np.ndarray:
    """Inverse of a (4, 4) rigid transform, or of each in a stack (..., 4, 4): returns T_b_a."""
    R_t = np.swapaxes(T_a_b[..., :3, :3], -1, -2)
    T_b_a = np.zeros(np.shape(T_a_b))
    T_b_a[..., :3, :3] = R_t
    T_b_a[..., :3, 3] = (-R_t @ T_a_b[..., :3, 3, None])[..., 0]
    T_b_a[..., 3, 3] = 1.0
    return T_b_a


def transform_points(T_a_b: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """Map (N, 3) points from frame b to frame a."""
    return p_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def rotation_angle(R: np.ndarray) -> float:
    """Geodesic angle of a (3, 3) rotation, radians in [0, pi].

    atan2 of sine and cosine keeps full precision near 0, where arccos loses it.
    """
    sin = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    cos = (np.trace(R) - 1.0) / 2.0
    return float(np.arctan2(sin, cos))


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(translation error in m, geodesic rotation error in rad) between two poses."""
    dt = float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))
    return dt, rotation_angle(T_est[:3, :3].T @ T_true[:3, :3])


def transform_from_xyz_quat(xyz: np.ndarray, quat_wxyz: np.ndarray) -> np.ndarray:
    """Translation (3,) and unit quaternion (w, x, y, z) -> (4, 4)."""
    w, x, y, z = quat_wxyz
    return make_transform(_rotation().from_quat([x, y, z, w]).as_matrix(), xyz)


def xyz_quat_from_transform(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(4, 4) -> translation (3,) and quaternion (w, x, y, z) with w >= 0."""
    x, y, z, w = _rotation().from_matrix(T[:3, :3]).as_quat()
    q = np.array([w, x, y, z])
    return T[:3, 3].copy(), q if w >= 0 else -q


def transform_from_xyz_rpy(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
    """Translation (3,) and roll-pitch-yaw (3,) radians -> (4, 4).

    R = Rz(yaw) @ Ry(pitch) @ Rx(roll), rotations about the fixed axes x, y, z.
    """
    return make_transform(_rotation().from_euler("xyz", rpy).as_matrix(), xyz)


def rpy_from_transform(T: np.ndarray) -> np.ndarray:
    """(4, 4) -> roll-pitch-yaw (3,) radians, inverse of transform_from_xyz_rpy."""
    return _rotation().from_matrix(T[:3, :3]).as_euler("xyz")


def rotation_about(axis: str, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about the local 'x', 'y' or 'z' axis."""
    return _rotation().from_euler(axis, angle).as_matrix()
