"""What a real camera and room do to the renderer's ideal view, beyond the white noise of
hec.sim.noise: lens distortion (the view is rendered through a larger pinhole camera and
resampled), depth misregistered to colour, flying pixels and holes, and vignetting, a light
gradient, a specular highlight, exposure and motion blur (hec.sim.scenario.ModelErrors lens, depth
and image). With those sections off nothing here changes the image or draws a random number.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.geometry.transforms import invert
from hec.sim.depth_errors import depth_holes, flying_pixels, misregister_depth
from hec.sim.image_effects import (
    light_gradient,
    mirror_point,
    motion_blur,
    motion_blur_shift,
    specular_highlight,
    vignetting,
)
from hec.sim.lens import (
    DepthSampling,
    depth_sampling,
    distort_depth,
    distort_rgb,
    distortion_maps,
    render_camera_for,
)
from hec.sim.model_errors import TrueCell
from hec.sim.scenario import Scenario


class RealCamera:
    """The true camera of a cell. render_intrinsics: the pinhole camera MuJoCo renders (the true
    K, or with a lens a larger one the distorted image is resampled from); intrinsics: the true
    camera of the output image (K and distortion)."""

    def __init__(self, scenario: Scenario, true_cell: TrueCell) -> None:
        errors = scenario.errors
        k = true_cell.intrinsics
        self.intrinsics = k
        self.T_cam_depthmeasured = true_cell.T_cam_depthmeasured
        self._maps: tuple[np.ndarray, np.ndarray] | None = None
        self._depth_sampling: DepthSampling | None = None
        if any(k.dist):
            K_render, width, height = render_camera_for(k.K, np.array(k.dist), k.width, k.height)
            self._maps = distortion_maps(k.K, np.array(k.dist), k.width, k.height, K_render)
            fx, fy, cx, cy = K_render[0, 0], K_render[1, 1], K_render[0, 2], K_render[1, 2]
            self.render_intrinsics = CameraIntrinsics(
                width, height, float(fx), float(fy), float(cx), float(cy)
            )
            self._depth_sampling = depth_sampling(*self._maps, (height, width))
        else:
            self.render_intrinsics = replace(k, dist=(0.0,) * 5)
        self.depth = errors.depth if errors.depth.enabled else None
        self.image = errors.image if errors.image.enabled else None
        self._gain: np.ndarray | None = None
        if self.image is not None:
            ones = np.ones((k.height, k.width, 3), np.float32)
            image = self.image
            gain = vignetting(ones, k.K, image.vignetting_corner_falloff)
            gain = light_gradient(gain, np.radians(image.light_gradient_direction_deg), image.light_gradient)
            self._gain = np.ascontiguousarray(gain)

    def depth_correlation_px(self) -> float:
        """The 1/e correlation length of the depth noise, pixels (1: independent pixels)."""
        return self.depth.correlation_px if self.depth is not None else 1.0

    def view(
        self, rgb: np.ndarray, depth_m: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """The render (render_intrinsics) as the true camera sees it, before sensor noise: depth
        misregistered and with flying pixels (in the pinhole render), then both resampled
        through the lens. rgb (H, W, 3) uint8, depth (H, W) float32 metres."""
        depth = depth_m
        if not np.array_equal(self.T_cam_depthmeasured, np.eye(4)):
            depth = misregister_depth(depth, self.render_intrinsics.K, self.T_cam_depthmeasured)
        if self.depth is not None and self.depth.flying_pixel_probability > 0:
            d = self.depth
            depth = flying_pixels(
                depth, rng, d.flying_pixel_edge_m, d.flying_pixel_probability, d.flying_pixel_width_px
            )
        if self._maps is not None:
            rgb = distort_rgb(rgb, *self._maps)
            depth = distort_depth(depth, self._depth_sampling)
        return rgb, depth

    def light(self, rgb: np.ndarray, T_cam_board: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Vignetting, light gradient, exposure, the lamp's highlight and motion blur on the
        colour image (H, W, 3) uint8 -> float32 grey levels (unclipped), or rgb unchanged when
        errors.image is off. T_cam_board: (4, 4) the true board pose in the camera frame."""
        if self.image is None:
            return rgb
        image = self.image
        exposure = 1.0 + image.exposure_sigma * rng.standard_normal()
        out = cv2.multiply(rgb, self._gain, scale=exposure, dtype=cv2.CV_32F)
        peak = self._highlight_px(T_cam_board)
        if peak is not None and image.highlight_peak_grey > 0:
            out = _add_glare(out, peak, image.highlight_radius_px, image.highlight_peak_grey)
        speed = image.motion_speed_sigma_m_s * rng.standard_normal(3)
        rate = np.radians(image.motion_rate_sigma_deg_s) * rng.standard_normal(3)
        shift = motion_blur_shift(
            self.intrinsics.K, float(T_cam_board[2, 3]), speed, rate, image.exposure_time_s
        )
        return motion_blur(out, shift)

    def holes(self, depth_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Depth (H, W) with the holes of errors.depth cut in (unchanged when off)."""
        if self.depth is None or self.depth.holes_per_megapixel <= 0:
            return depth_m
        return depth_holes(depth_m, rng, self.depth.holes_per_megapixel, self.depth.hole_radius_px)

    def _highlight_px(self, T_cam_board: np.ndarray) -> np.ndarray | None:
        """Where the lamp's mirror image on the board plane appears (2,) pixels, or None."""
        camera_board = invert(T_cam_board)[:3, 3]
        lamp = np.array(self.image.light_position_board_m, dtype=float)
        if camera_board[2] <= 0 or lamp[2] <= 0:
            return None
        p_cam = T_cam_board[:3, :3] @ mirror_point(camera_board, lamp) + T_cam_board[:3, 3]
        if p_cam[2] <= 0:
            return None
        k = self.intrinsics
        uv, _ = cv2.projectPoints(p_cam.reshape(1, 3), np.zeros(3), np.zeros(3), k.K, np.array(k.dist))
        return uv.reshape(2)


def _add_glare(rgb: np.ndarray, centre_px: np.ndarray, radius_px: float, peak_grey: float) -> np.ndarray:
    """rgb (H, W, 3) float32, changed in place, plus a white Gaussian blob (half width at half
    maximum radius_px) at centre_px, computed only within 4 half widths of it."""
    h, w = rgb.shape[:2]
    reach = int(np.ceil(4.0 * radius_px))
    u0, v0 = int(round(centre_px[0])), int(round(centre_px[1]))
    left, right, top, bottom = (
        max(u0 - reach, 0),
        min(u0 + reach + 1, w),
        max(v0 - reach, 0),
        min(v0 + reach + 1, h),
    )
    if left >= right or top >= bottom:
        return rgb
    patch = specular_highlight(
        rgb[top:bottom, left:right], (centre_px[0] - left, centre_px[1] - top), radius_px, peak_grey
    )
    rgb[top:bottom, left:right] = patch
    return rgb
