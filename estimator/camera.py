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
