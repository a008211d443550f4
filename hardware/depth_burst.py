"""Depth from a burst of aligned frames: per-pixel averaging and the depth axis of the colour camera.

No camera library here: arrays in, arrays out.
"""

from __future__ import annotations

import cv2
import numpy as np

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.transforms import invert


class DepthResampler:
    """Depth at each colour pixel sampled from the depth image where that pixel's 3-D point
    projects, starting from an aligned depth that is within a pixel of it.

    ``rs.align`` fills every colour pixel that a depth pixel's footprint touches with that
    depth pixel's value and keeps the nearest where footprints overlap (adjacent ones
    always share their edge pixels). On a slanted surface that is short by up to the depth
    change across one depth pixel, and with noise the nearest of several noisy values is
    short again. Re-sampling the depth image bilinearly at the projected point removes both.
    colour, depth: intrinsics; T_colour_depth: (4, 4) depth imager in the colour optical frame.
    """

    def __init__(self, colour: CameraIntrinsics, depth: CameraIntrinsics, T_colour_depth: np.ndarray) -> None:
        self.axis = DepthAlongColourAxis(colour, T_colour_depth)
        self.depth_intrinsics = depth
        T_depth_colour = invert(T_colour_depth)
        self._R, self._t = T_depth_colour[:3, :3], T_depth_colour[:3, 3]
        self._rays = self.axis.rays.reshape(-1, 3)

    def resample(
        self, aligned_depth_axis_m: np.ndarray, depth_image_m: np.ndarray, iterations: int = 3
    ) -> np.ndarray:
        """aligned_depth_axis_m: (H, W) rs.align output in metres along the depth imager's axis.
        depth_image_m: (h, w) the depth image it came from, metres, 0 = none. Returns (H, W)
        float64 metres along the colour axis; 0 where the four depth pixels around the
        projected point are not all valid."""
        k = self.depth_intrinsics
        shape = aligned_depth_axis_m.shape
        z_colour = self.axis.apply(aligned_depth_axis_m).ravel()
        source = np.asarray(depth_image_m, dtype=np.float32)
        valid_source = (source > 0).astype(np.float32)
        for _ in range(iterations):
            known = z_colour > 0
            p_depth = (self._rays * z_colour[:, None]) @ self._R.T + self._t
            p_depth[~known] = (0.0, 0.0, 1.0)  # any point in front; its result is discarded
            uv, _ = cv2.projectPoints(p_depth, np.zeros(3), np.zeros(3), k.K, np.asarray(k.dist, float))
            map_u = uv[:, 0, 0].astype(np.float32).reshape(shape)
            map_v = uv[:, 0, 1].astype(np.float32).reshape(shape)
            z_depth = cv2.remap(source, map_u, map_v, cv2.INTER_LINEAR, borderValue=0.0).ravel()
            support = cv2.remap(valid_source, map_u, map_v, cv2.INTER_LINEAR, borderValue=0.0).ravel()
            z_depth = np.where(known & (support > 1.0 - 1e-6), z_depth.astype(np.float64), 0.0)
            z_colour = self.axis.apply(z_depth.reshape(shape)).ravel()
        return z_colour.reshape(shape)


class DepthAlongColourAxis:
    """Re-express depth aligned to the colour image along the colour camera's optical axis.
    ``rays``: (H, W, 3) the colour pixels' undistorted rays (x, y, 1).

    librealsense's ``align`` moves each depth pixel into the colour image but keeps
    its value: the distance along the *depth* imager's optical axis. For the colour
    pixel (u, v) with undistorted ray r = (x, y, 1) and T_depth_colour = (R, t),
    z_depth = z_colour * (R r)_z + t_z, so z_colour = (z_depth - t_z) / (R r)_z.
    intrinsics: the colour camera. T_colour_depth: (4, 4) depth imager in the colour
    optical frame, metres.
    """

    def __init__(self, intrinsics: CameraIntrinsics, T_colour_depth: np.ndarray) -> None:
        T_depth_colour = invert(T_colour_depth)
        R_depth_colour, t_depth_colour = T_depth_colour[:3, :3], T_depth_colour[:3, 3]
        u, v = np.meshgrid(np.arange(intrinsics.width), np.arange(intrinsics.height))
        pixels = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
        rays = cv2.undistortPoints(
            pixels.reshape(-1, 1, 2), intrinsics.K, np.asarray(intrinsics.dist, dtype=np.float64)
        ).reshape(-1, 2)
        self.rays = np.concatenate([rays, np.ones((len(rays), 1))], axis=1).reshape(
            intrinsics.height, intrinsics.width, 3
        )
        z_per_colour_z = rays @ R_depth_colour[2, :2] + R_depth_colour[2, 2]
        self.scale = (1.0 / z_per_colour_z).reshape(intrinsics.height, intrinsics.width)
        self.offset_m = float(t_depth_colour[2])

    def apply(self, depth_along_depth_axis_m: np.ndarray) -> np.ndarray:
        """(H, W) metres along the depth imager's axis, 0 = none -> (H, W) float64 along the
        colour camera's axis, 0 kept."""
        z = np.asarray(depth_along_depth_axis_m, dtype=np.float64)
        return np.where(z > 0.0, (z - self.offset_m) * self.scale, 0.0)


class DepthAverage:
    """Running per-pixel mean over the valid (> 0) samples of a burst of depth images."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self._sum = np.zeros(shape, dtype=np.float64)
        self._count = np.zeros(shape, dtype=np.int64)

    def add(self, depth_m: np.ndarray) -> None:
        """depth_m: (H, W) metres, 0 = no depth."""
        if depth_m.shape != self._sum.shape:
            raise ValueError(f"depth image {depth_m.shape} does not match the burst's {self._sum.shape}")
        valid = depth_m > 0.0
        self._sum[valid] += depth_m[valid]
        self._count += valid

    def mean(self) -> np.ndarray:
        """Mean depth (H, W) float32 metres, 0 where no sample was valid."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self._count > 0, self._sum / self._count, 0.0).astype(np.float32)
