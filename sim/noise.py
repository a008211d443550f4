"""Sensor and robot noise models applied to the renderer's ideal outputs.

Depth (D435-like stereo): systematic bias, Gaussian noise growing with z^2,
invalid pixels at grazing angles and at random, and quantisation to the steps
of a uint16 depth image. Colour: Gaussian blur and additive Gaussian noise. The
Gaussian fields are hec.sim.fast_normal's 16-bit quantised ones; arithmetic is float32,
per pixel in compiled passes (hec.sim.compiled). Robot: a noisy reported flange pose.
numpy/scipy/OpenCV/numba (no MuJoCo).

All randomness comes from the ``numpy.random.Generator`` passed in; the same
settings and generator state give bit-identical results. Depth is in metres
along the optical axis, 0.0 marks an invalid pixel.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from hec.estimator.common.depth_png import UINT16_MAX
from hec.estimator.common.noise import RobotPoseNoise as RobotPoseNoiseModel
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.estimator.observe.depth import DepthNoiseModel
from hec.sim.compiled import compiled, compiled_inline
from hec.sim.depth_errors import correlated_unit_noise
from hec.sim.fast_normal import normal_table, quantised_normal, uniform_levels
from hec.sim.scenario import DepthNoise, NoiseSettings, RGBNoise, RobotPoseNoise

# Depths beyond this (e.g. the renderer's far plane where nothing was hit) are invalid, metres.
MAX_RANGE_M = 10.0
# The colour blur's kernel reaches the taps of at least 1/1000 of the centre one: sqrt(2 ln 1000) sigma.
_BLUR_REACH = float(np.sqrt(2.0 * np.log(1000.0)))
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


@lru_cache(maxsize=4)
def _rays(intrinsics: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x = (u - cx) / fx, y = (v - cy) / fy and x^2 + y^2 + 1 of every pixel: three (H, W) float32."""
    w, h = intrinsics.width, intrinsics.height
    rx = ((np.arange(w, dtype=np.float32) - intrinsics.cx) / intrinsics.fx)[None, :]
    ry = ((np.arange(h, dtype=np.float32) - intrinsics.cy) / intrinsics.fy)[:, None]
    rays = np.broadcast_arrays(rx, ry, rx * rx + ry * ry + np.float32(1.0))
    return tuple(np.ascontiguousarray(r) for r in rays)


@compiled_inline
def _in_range(z: float) -> bool:
    """A depth the camera measures: in (0, MAX_RANGE_M] (NaN is not). Branch-free, so that loops
    over pixels vectorise."""
    return (z > np.float32(0.0)) & (z <= np.float32(MAX_RANGE_M))


@compiled_inline
def _measure_pixel(
    out: np.ndarray, z_true: np.ndarray, unit: np.ndarray, at: tuple, models: tuple, grazing: tuple
) -> None:
    """out[j, i] of _measured_depth_kernel; at: (j, i, (up, down), (left, right)), the neighbours
    the normal is taken from (central differences, one-sided on the image border as np.gradient).

    Grazing: viewing ray r = (x, y, 1), x = (u - cx) / fx, y = (v - cy) / fy; the point is p = z r.
    The tangents dp/du = z_u r + (z / fx) e_x, dp/dv = z_v r + (z / fy) e_y have the normal
    n = (z / (fx fy)) (-fx z_u, -fy z_v, fx z_u x + fy z_v y + z), and n . r = z^2 / (fx fy), so
    cos(angle) = z / (|m| |r|) with m = (-gu, -gv, gu x + gv y + z), gu = fx z_u, gv = fy z_v.
    A neighbour out of range leaves no normal: a depth edge, counted as grazing.
    """
    j, i, (up, down), (left, right) = at
    (scale, offset), sigma_unit, step_m = models
    test, (rx, ry, r2), (fx, fy), cos2 = grazing
    zt = z_true[j, i]
    a, b, c, d = z_true[j, right], z_true[j, left], z_true[down, i], z_true[up, i]
    gu = (a - b) / np.float32(right - left) * fx
    gv = (c - d) / np.float32(down - up) * fy
    m_z = gu * rx[j, i] + gv * ry[j, i] + zt
    facing = _in_range(a) & _in_range(b) & _in_range(c) & _in_range(d)
    facing &= zt * zt >= (gu * gu + gv * gv + m_z * m_z) * r2[j, i] * cos2
    z = unit[j, i] * (zt * zt) * sigma_unit + (scale * zt + offset)
    steps = np.rint(np.float64(z) / step_m) if step_m > 0.0 else 0.0
    value = np.float32(steps * step_m) if step_m > 0.0 else z
    kept = _in_range(zt) & (facing | (not test)) & (z > np.float32(0.0)) & (steps <= UINT16_MAX)
    out[j, i] = value if kept else np.float32(0.0)


@compiled
def _measured_depth_kernel(z_true: np.ndarray, unit: np.ndarray, models: tuple, grazing: tuple) -> np.ndarray:
    """(H, W) float32 depth of apply_depth_models (all but the dropout) from the true depth z_true
    (H, W) float32 and the unit-variance noise unit (H, W) float32. models: the bias (scale, offset)
    and sigma(z) / z^2 (float32) and the quantisation step (metres; 0: none). grazing: whether to
    test, the rays of _rays, (fx, fy) and the grazing angle's cos^2 (float32)."""
    h, w = z_true.shape
    out = np.empty((h, w), dtype=np.float32)
    for j in range(h):
        rows = (max(j - 1, 0), min(j + 1, h - 1))
        _measure_pixel(out, z_true, unit, (j, 0, rows, (0, min(1, w - 1))), models, grazing)
        for i in range(1, w - 1):
            _measure_pixel(out, z_true, unit, (j, i, rows, (i - 1, i + 1)), models, grazing)
        if w > 1:
            _measure_pixel(out, z_true, unit, (j, w - 1, rows, (w - 2, w - 1)), models, grazing)
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
    with sigma(z_true), invalidation (grazing angle from the true depth, see _measure_pixel; random
    dropout), quantisation to multiples of depth_scale_m (what does not fit a uint16 becomes 0).
    """
    z_true = np.ascontiguousarray(depth_true_m, dtype=np.float32)
    if z_true.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {z_true.shape}")
    if z_true.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(
            f"depth shape {z_true.shape} does not match the intrinsics "
            f"({intrinsics.height}, {intrinsics.width})"
        )
    if not noise.depth.enabled:
        unit = np.zeros(z_true.shape, dtype=np.float32)
    elif correlation_px > 1.0:
        unit = correlated_unit_noise(z_true.shape, correlation_px, rng)
    else:
        unit = quantised_normal(rng, z_true.shape)
    invalid = noise.invalid_depth
    dropped = np.zeros(0, dtype=np.intp)
    if invalid.enabled and invalid.dropout_fraction > 0.0:  # a Bernoulli field: its count, its pixels
        dropped = rng.choice(z_true.size, rng.binomial(z_true.size, invalid.dropout_fraction), replace=False)

    bias, quant = noise.depth_bias, noise.depth_quantisation
    models = (
        (np.float32(bias.scale), np.float32(bias.offset_m))
        if bias.enabled
        else (np.float32(1), np.float32(0)),
        np.float32(depth_sigma(1.0, noise.depth) if noise.depth.enabled else 0.0),
        quant.depth_scale_m if quant.enabled else 0.0,
    )
    grazing = (
        invalid.enabled,
        _rays(intrinsics),
        (np.float32(intrinsics.fx), np.float32(intrinsics.fy)),
        np.float32(np.cos(np.radians(invalid.grazing_angle_deg)) ** 2),
    )
    out = _measured_depth_kernel(z_true, unit, models, grazing)
    out.ravel()[dropped] = 0.0
    return out


@lru_cache(maxsize=8)
def _blur_kernel(sigma_px: float) -> np.ndarray:
    """The colour blur's (K, 1) float32 Gaussian, K = 2 floor(sigma _BLUR_REACH) + 1 taps; as a
    separable filter it gives cv2.GaussianBlur's result bit for bit, 30 % faster."""
    return cv2.getGaussianKernel(2 * int(sigma_px * _BLUR_REACH) + 1, sigma_px, cv2.CV_32F)


@compiled
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
    Gaussian noise (std sigma, grey levels; hec.sim.fast_normal's quantised one), rounded and
    clipped to 0..255. The blur keeps the taps of at least 1/1000 of the centre one: 3 at
    sigma 0.5, where OpenCV's default of 5 changes a rendered frame by < 0.17 grey levels.

    rgb: (H, W, 3) uint8, or float32 grey levels (unclipped, as hec.sim.real_camera lights it).
    Returns a new (H, W, 3) uint8 array (unchanged but rounded and clipped when disabled).
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype not in (np.uint8, np.float32):
        raise ValueError(f"rgb must be (H, W, 3) uint8 or float32, got shape {rgb.shape} dtype {rgb.dtype}")
    if not settings.enabled:
        return rgb.copy() if rgb.dtype == np.uint8 else np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    img = rgb.astype(np.float32, copy=False)  # not written to
    if settings.blur_sigma_px > 0.0:
        kernel = _blur_kernel(settings.blur_sigma_px)
        img = cv2.sepFilter2D(img, cv2.CV_32F, kernel, kernel, borderType=cv2.BORDER_REFLECT_101)
    if settings.sigma > 0.0:
        levels = uniform_levels(rng, (img.size,))
        return _noisy_grey_levels(img.ravel(), levels, normal_table(settings.sigma)).reshape(img.shape)
    return np.rint(np.clip(img, 0, 255)).astype(np.uint8)


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
