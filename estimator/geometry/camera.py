"""Pinhole camera intrinsics in OpenCV's convention.

The camera frame is OpenCV's optical frame: x right, y down, z forward.
Pixel coordinates (u, v) have their origin at the *centre* of the top-left
pixel, u to the right and v down, so an image of width W spans
u in [-0.5, W - 0.5] and a centred principal point is cx = (W - 1) / 2.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class CameraIntrinsics:
    """Image size in pixels, focal lengths and principal point in pixels,
    and OpenCV distortion coefficients (k1, k2, p1, p2, k3)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @property
    def K(self) -> np.ndarray:
        """(3, 3) camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy_rad: float) -> CameraIntrinsics:
        """Square pixels, centred principal point, vertical field of view."""
        f = (height / 2.0) / np.tan(fovy_rad / 2.0)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    def to_dict(self) -> dict:
        return {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "dist": list(self.dist),
            "model": "opencv-pinhole",
            "pixel_origin": "centre of the top-left pixel",
        }

    @classmethod
    def from_dict(cls, d: dict) -> CameraIntrinsics:
        return cls(
            int(d["width"]),
            int(d["height"]),
            float(d["fx"]),
            float(d["fy"]),
            float(d["cx"]),
            float(d["cy"]),
            tuple(float(c) for c in d.get("dist", (0.0,) * 5)),
        )


def project_points(T_cam_board: np.ndarray, p_board: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Project board points into the image (no distortion).

    T_cam_board: (4, 4) pose of the board in the camera frame.
    p_board: (N, 3) points in the board frame, metres.
    K: (3, 3) camera matrix.
    Returns (N, 2) pixel coordinates (u right, v down).
    """
    p_cam = p_board @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    uvw = p_cam @ K.T
    return uvw[:, :2] / uvw[:, 2:3]


def project(T_cam_x: np.ndarray, p_x: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Project points through the camera, lens distortion included.

    T_cam_x: (4, 4) pose of frame x in the camera frame. p_x: (N, 3) points in frame x, metres
    (in front of the camera). Returns (N, 2) pixel coordinates (u right, v down).
    """
    p_cam = p_x @ T_cam_x[:3, :3].T + T_cam_x[:3, 3]
    xy = p_cam[:, :2] / p_cam[:, 2:3]
    if any(intrinsics.dist):
        xy = distort(xy, intrinsics.dist)
    return np.column_stack(
        [intrinsics.fx * xy[:, 0] + intrinsics.cx, intrinsics.fy * xy[:, 1] + intrinsics.cy]
    )


UNDISTORT_ITERATIONS = 30


def distort(xy: np.ndarray, dist: tuple) -> np.ndarray:
    """OpenCV's distortion (k1, k2, p1, p2, k3) of normalised image points xy (..., 2) (x/z, y/z):
    the distorted normalised coordinates (..., 2). Each coefficient is a number, or an array that
    broadcasts against xy[..., 0] (a camera per point)."""
    k1, k2, p1, p2, k3 = (tuple(dist) + (0.0,) * 5)[:5]
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def distort_normalized(xy: np.ndarray, dist: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's distortion (k1, k2, p1, p2, k3) of normalised image points, with its Jacobian.

    xy: (N, 2) undistorted normalised coordinates (x/z, y/z).
    Returns (N, 2) distorted normalised coordinates (distort) and (N, 2, 2) d(distorted)/d(xy).
    """
    k1, k2, p1, p2, k3 = (tuple(dist) + (0.0,) * 5)[:5]
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial_dr2 = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    jac = np.empty((len(x), 2, 2))
    jac[:, 0, 0] = radial + 2.0 * x * x * dradial_dr2 + 2.0 * p1 * y + 6.0 * p2 * x
    jac[:, 0, 1] = 2.0 * x * y * dradial_dr2 + 2.0 * p1 * x + 2.0 * p2 * y
    jac[:, 1, 0] = 2.0 * x * y * dradial_dr2 + 2.0 * p1 * x + 2.0 * p2 * y
    jac[:, 1, 1] = radial + 2.0 * y * y * dradial_dr2 + 6.0 * p1 * y + 2.0 * p2 * x
    return distort(xy, dist), jac


def pixel_rays(uv: np.ndarray, intrinsics: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Viewing rays of pixels, scaled to z = 1, and their Jacobian.

    uv: (N, 2) pixel coordinates in the (distorted) image.
    Returns (N, 3) rays (x/z, y/z, 1) in the camera frame and (N, 3, 2) d(ray)/d(uv).
    """
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    k = intrinsics
    xy_distorted = np.column_stack([(uv[:, 0] - k.cx) / k.fx, (uv[:, 1] - k.cy) / k.fy])
    if any(k.dist):
        xy = xy_distorted.copy()  # Newton on distort(xy) = xy_distorted
        for _ in range(UNDISTORT_ITERATIONS):
            distorted, d_distorted_d_xy = distort_normalized(xy, k.dist)
            step = np.linalg.solve(d_distorted_d_xy, (distorted - xy_distorted)[:, :, None])[:, :, 0]
            xy -= step
            if np.abs(step).max() < 1e-15:
                break
        _, d_distorted_d_xy = distort_normalized(xy, k.dist)
        d_xy_d_distorted = np.linalg.inv(d_distorted_d_xy)
    else:
        xy = xy_distorted
        d_xy_d_distorted = np.broadcast_to(np.eye(2), (len(uv), 2, 2))
    jac = np.zeros((len(uv), 3, 2))
    jac[:, :2, :] = d_xy_d_distorted * np.array([1.0 / k.fx, 1.0 / k.fy])[None, None, :]
    return np.column_stack([xy, np.ones(len(uv))]), jac


def back_project(uv: np.ndarray, z_m: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Camera-frame points from pixels and depth along the optical axis.

    The paper's x = z (u - cx) / fx, y = z (v - cy) / fy, with distortion removed first.
    uv: (N, 2) pixels. z_m: (N,) depth, metres. Returns (N, 3) metres, camera frame.
    """
    rays, _ = pixel_rays(uv, intrinsics)
    return rays * np.asarray(z_m, dtype=np.float64).reshape(-1, 1)
