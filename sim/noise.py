"""Sensor and robot noise models applied to the renderer's ideal outputs.

Depth (D435-like stereo): systematic bias, Gaussian noise growing with z^2,
invalid pixels at grazing angles and at random, and quantisation to the steps
of a uint16 depth image. Colour: Gaussian blur and additive Gaussian noise. The
Gaussian fields are sim.fast_normal's 16-bit quantised ones; arithmetic is float32.
Robot: a noisy reported flange pose. Pure numpy/scipy/OpenCV (no MuJoCo).

All randomness comes from the ``numpy.random.Generator`` passed in; the same
settings and generator state give bit-identical results. Depth is in metres
along the optical axis, 0.0 marks an invalid pixel.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation

from estimator.geometry.camera import CameraIntrinsics
from estimator.io.depth_png import UINT16_MAX
from estimator.observe.depth import DepthNoiseModel
from estimator.solve.problem import RobotPoseNoise as RobotPoseNoiseModel
from sim.depth_errors import correlated_unit_noise
from sim.fast_normal import normal_table, quantised_normal, uniform_levels
from sim.scenario import DepthNoise, NoiseSettings, RGBNoise, RobotPoseNoise

# Depths beyond this (e.g. the renderer's far plane where nothing was hit) are invalid, metres.
MAX_RANGE_M = 10.0
# Tags the per-waypoint streams, apart from default_rng(seed) (which draws the true cell).
_WAYPOINT_STREAM = 1


def waypoint_rng(seed: int, waypoint_index: int) -> np.random.Generator:
    """The generator of one waypoint's capture noise: drawn per waypoint index, so a recording
    resumed at waypoint 7 draws what an uninterrupted one draws there."""
    return np.random.default_rng([seed, _WAYPOINT_STREAM, waypoint_index])


def depth_sigma(z_m: np.ndarray, settings: DepthNoise) -> np.ndarray:
    """Standard deviation of stereo depth noise, sigma(z) = z^2 * subpixel / (focal_px * baseline_m).

    z_m: depth along the optical axis, metres, any shape. Returns the same shape, metres (float64).
    """
    z = np.asarray(z_m, dtype=np.float64)
    return z * z * (settings.subpixel / (settings.focal_px * settings.baseline_m))


def depth_noise_model(noise: NoiseSettings) -> DepthNoiseModel:
    """The per-pixel depth noise these settings produce, as the measurement layer models it
    (written to dataset.json as 'depth_noise'). Pixels are independent (correlation 1 px)."""
    depth = noise.depth
    return DepthNoiseModel(
        subpixel=depth.subpixel if depth.enabled else 0.0,
        baseline_m=depth.baseline_m,
        focal_px=depth.focal_px,
        depth_step_m=noise.depth_quantisation.depth_scale_m,
        correlation_px=1.0,
    )


def robot_pose_noise_model(noise: NoiseSettings) -> RobotPoseNoiseModel:
    """The reported flange pose noise these settings produce, as the estimators model it
    (written to dataset.json as 'robot_pose_noise'; zero when disabled)."""
    robot = noise.robot_pose
    if not robot.enabled:
        return RobotPoseNoiseModel(0.0, 0.0)
    return RobotPoseNoiseModel(robot.translation_sigma_m, float(np.radians(robot.rotation_sigma_deg)))


def _valid_mask(depth_m: np.ndarray) -> np.ndarray:
    """(H, W) bool: finite depth in (0, MAX_RANGE_M]."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(depth_m) & (depth_m > 0.0) & (depth_m <= MAX_RANGE_M)


@lru_cache(maxsize=4)
def _rays(intrinsics: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x = (u - cx) / fx, y = (v - cy) / fy and x^2 + y^2 + 1 of every pixel: three (H, W) float32."""
    w, h = intrinsics.width, intrinsics.height
    rx = ((np.arange(w, dtype=np.float32) - intrinsics.cx) / intrinsics.fx)[None, :]
    ry = ((np.arange(h, dtype=np.float32) - intrinsics.cy) / intrinsics.fy)[:, None]
    rays = np.broadcast_arrays(rx, ry, rx * rx + ry * ry + np.float32(1.0))
    return tuple(np.ascontiguousarray(r) for r in rays)


@njit(cache=True, nogil=True)
def _grazing_kernel(z: np.ndarray, valid: np.ndarray, rays: tuple, focal: tuple, cos2: float) -> np.ndarray:
    """(H, W) bool grazing mask of _grazing_mask; z (H, W) float32, rays (rx, ry, r2) of _rays,
    focal (fx, fy) and cos2 = cos(angle)^2 float32. Differences as np.gradient's: central, one-sided
    on the border."""
    rx, ry, r2 = rays
    fx, fy = focal
    h, w = z.shape
    out = np.ones((h, w), dtype=np.bool_)
    half, one = np.float32(0.5), np.float32(1.0)
    for j in range(h):
        up, down = max(j - 1, 0), min(j + 1, h - 1)
        step_v = half if 0 < j < h - 1 else one
        for i in range(w):
            left, right = max(i - 1, 0), min(i + 1, w - 1)
            if not (valid[j, i] and valid[j, left] and valid[j, right] and valid[up, i] and valid[down, i]):
                continue  # no normal: a depth edge
            step_u = half if 0 < i < w - 1 else one
            gu = (z[j, right] - z[j, left]) * step_u * fx
            gv = (z[down, i] - z[up, i]) * step_v * fy
            m_z = gu * rx[j, i] + gv * ry[j, i] + z[j, i]
            m2 = (gu * gu + gv * gv + m_z * m_z) * r2[j, i] * cos2
            out[j, i] = not (z[j, i] * z[j, i] >= m2)
    return out


def _grazing_mask(
    depth_true_m: np.ndarray, valid: np.ndarray, intrinsics: CameraIntrinsics, grazing_angle_deg: float
) -> np.ndarray:
    """(H, W) bool: pixels seen at more than grazing_angle_deg between the viewing ray and the surface normal.

    Normals come from the back-projected true depth (camera frame, metres) by
    central differences (one-sided at the image border). A pixel next to an
    invalid pixel gets no normal and is counted as grazing (a depth edge).
    """
    h, w = depth_true_m.shape
    if h < 2 or w < 2:
        return np.ones((h, w), dtype=bool)
    # Viewing ray r = (x, y, 1), x = (u - cx) / fx, y = (v - cy) / fy; the point is p = z r. The
    # tangents dp/du = z_u r + (z / fx) e_x, dp/dv = z_v r + (z / fy) e_y have the normal
    # n = (z / (fx fy)) (-fx z_u, -fy z_v, fx z_u x + fy z_v y + z), and n . r = z^2 / (fx fy), so
    # cos(angle) = z / (|m| |r|) with m = (-gu, -gv, gu x + gv y + z), gu = fx z_u, gv = fy z_v.
    z = np.asarray(depth_true_m, dtype=np.float32)
    focal = (np.float32(intrinsics.fx), np.float32(intrinsics.fy))
    cos2 = np.float32(np.cos(np.radians(grazing_angle_deg)) ** 2)
    return _grazing_kernel(z, valid, _rays(intrinsics), focal, cos2)


@njit(cache=True, nogil=True)
def _measured_depth_kernel(
    z_true: np.ndarray, valid: np.ndarray, unit: np.ndarray, bias: tuple, sigma_unit: float, step_m: float
) -> np.ndarray:
    """(H, W) float32 depth of apply_depth_models from the true depth and the pixels kept so far:
    bias (scale, offset) float32, plus sigma_unit z_true^2 unit (unit (H, W) float32, unit-variance
    noise), 0 where not valid or not positive, then rounded to multiples of step_m (> 0; what does
    not fit a uint16 becomes 0) or, for step_m = 0, not rounded."""
    scale, offset = bias
    h, w = z_true.shape
    out = np.zeros((h, w), dtype=np.float32)
    for j in range(h):
        for i in range(w):
            if not valid[j, i]:
                continue
            zt = z_true[j, i]
            z = unit[j, i] * (zt * zt) * sigma_unit + (scale * zt + offset)
            if not z > 0.0:
                continue
            if step_m == 0.0:
                out[j, i] = z
                continue
            steps = np.rint(np.float64(z) / step_m)
            if steps <= UINT16_MAX:
                out[j, i] = np.float32(steps * step_m)
    return out


def apply_depth_models(
    depth_true_m: np.ndarray,
    intrinsics: CameraIntrinsics,
    noise: NoiseSettings,
    rng: np.random.Generator,
    correlation_px: float = 1.0,
) -> np.ndarray:
    """The measured depth image from the true one.

    depth_true_m: (H, W) depth along the optical axis, metres; values <= 0, non-finite
    or > MAX_RANGE_M (e.g. the far plane) are invalid. intrinsics: the depth image's camera.
    correlation_px: the 1/e correlation length of the noise (1: independent pixels).
    Returns (H, W) float32 metres, 0.0 = invalid. Applied in order: bias, Gaussian noise
    with sigma(z_true), invalidation (grazing angle from the true depth, random dropout),
    quantisation to multiples of depth_scale_m (what does not fit a uint16 becomes 0).
    """
    depth_true_m = np.asarray(depth_true_m)
    if depth_true_m.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {depth_true_m.shape}")
    if depth_true_m.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(
            f"depth shape {depth_true_m.shape} does not match the intrinsics "
            f"({intrinsics.height}, {intrinsics.width})"
        )
    valid = _valid_mask(depth_true_m)
    z_true = np.asarray(depth_true_m, dtype=np.float32)

    bias = noise.depth_bias
    scale_offset = (bias.scale, bias.offset_m) if bias.enabled else (1.0, 0.0)
    sigma_unit = depth_sigma(1.0, noise.depth) if noise.depth.enabled else 0.0
    if not noise.depth.enabled:
        unit = np.zeros(z_true.shape, dtype=np.float32)
    elif correlation_px > 1.0:
        unit = correlated_unit_noise(z_true.shape, correlation_px, rng)
    else:
        unit = quantised_normal(rng, z_true.shape)

    invalid = noise.invalid_depth
    if invalid.enabled:
        valid &= ~_grazing_mask(z_true, valid, intrinsics, invalid.grazing_angle_deg)
        if invalid.dropout_fraction > 0.0:  # a Bernoulli field, drawn as its count and its pixels
            count = rng.binomial(valid.size, invalid.dropout_fraction)
            valid.ravel()[rng.choice(valid.size, count, replace=False)] = False

    quant = noise.depth_quantisation
    return _measured_depth_kernel(
        z_true,
        valid,
        unit,
        tuple(np.float32(v) for v in scale_offset),
        np.float32(sigma_unit),
        quant.depth_scale_m if quant.enabled else 0.0,
    )


@njit(cache=True, nogil=True)
def _noisy_grey_levels(grey: np.ndarray, levels: np.ndarray, table: np.ndarray) -> np.ndarray:
    """(N,) uint8: grey (N,) float32 plus the noise table[levels] (levels (N,) uint16), clipped to
    0..255 and rounded to the nearest level (half to even, as np.rint)."""
    out = np.empty(grey.size, dtype=np.uint8)
    top = np.float32(255.0)
    for i in range(grey.size):
        out[i] = np.uint8(np.rint(min(max(grey[i] + table[levels[i]], np.float32(0.0)), top)))
    return out


def apply_rgb_models(rgb: np.ndarray, settings: RGBNoise, rng: np.random.Generator) -> np.ndarray:
    """The measured colour image: Gaussian blur (sigma blur_sigma_px, pixels), then additive
    Gaussian noise (std sigma, grey levels; sim.fast_normal's quantised one), rounded and
    clipped to 0..255.

    rgb: (H, W, 3) uint8, or float32 grey levels (unclipped, as sim.real_camera lights it).
    Returns a new (H, W, 3) uint8 array (unchanged but rounded and clipped when disabled).
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype not in (np.uint8, np.float32):
        raise ValueError(f"rgb must be (H, W, 3) uint8 or float32, got shape {rgb.shape} dtype {rgb.dtype}")
    if not settings.enabled:
        return rgb.copy() if rgb.dtype == np.uint8 else np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    img = rgb.astype(np.float32)
    if settings.blur_sigma_px > 0.0:
        img = cv2.GaussianBlur(
            img,
            (0, 0),
            sigmaX=settings.blur_sigma_px,
            sigmaY=settings.blur_sigma_px,
            borderType=cv2.BORDER_REFLECT_101,
        )
    if settings.sigma > 0.0:
        levels = uniform_levels(rng, (img.size,))
        return _noisy_grey_levels(img.ravel(), levels, normal_table(settings.sigma)).reshape(img.shape)
    return np.rint(np.clip(img, 0, 255, out=img), out=img).astype(np.uint8)


def perturb_flange_pose(
    T_base_flange: np.ndarray, settings: RobotPoseNoise, rng: np.random.Generator
) -> np.ndarray:
    """The reported flange pose from the true one.

    T_base_flange: (4, 4) true pose of the flange in the base frame, metres.
    Returns (4, 4): translation + N(0, translation_sigma_m^2) per base axis, rotation
    R @ Exp(w) with w ~ N(0, rotation_sigma^2) per flange axis (radians). A copy when disabled.
    """
    T = np.array(T_base_flange, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"T_base_flange must be (4, 4), got {T.shape}")
    if not settings.enabled:
        return T
    dt = rng.normal(0.0, settings.translation_sigma_m, 3)
    w = rng.normal(0.0, np.radians(settings.rotation_sigma_deg), 3)
    T[:3, 3] += dt
    T[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(w).as_matrix()
    return T
