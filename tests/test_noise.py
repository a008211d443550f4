"""Tests of the sensor and robot noise models (sim/noise.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hec.estimator.common.depth_png import decode_depth, encode_depth
from hec.estimator.geometry.camera import CameraIntrinsics
from hec.sim.noise import apply_depth_models, apply_rgb_models, depth_sigma, perturb_flange_pose
from hec.sim.scenario import (
    DepthBias,
    DepthNoise,
    DepthQuantisation,
    InvalidDepth,
    NoiseSettings,
    RGBNoise,
    RobotPoseNoise,
)

INTR = CameraIntrinsics.from_fovy(640, 480, np.radians(42.5))
# A narrow camera (about 6 x 4.5 degrees) so that a plane is seen at nearly one angle everywhere.
NARROW = CameraIntrinsics(64, 48, 600.0, 600.0, 31.5, 23.5)


def only(**sections) -> NoiseSettings:
    """All models off except the given sections (given enabled)."""
    base = NoiseSettings().all_off()
    return base.model_copy(
        update={name: s.model_copy(update={"enabled": True}) for name, s in sections.items()}
    )


def flat(intr: CameraIntrinsics, z: float) -> np.ndarray:
    return np.full((intr.height, intr.width), z, dtype=np.float32)


def tilted_plane(intr: CameraIntrinsics, distance_m: float, tilt_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """True depth (H, W) of a plane through (0, 0, distance_m) whose normal is tilted by tilt_deg
    from the optical axis about the camera x axis, and the analytic angle (degrees) between each
    pixel's viewing ray and the plane normal. Pixels whose ray misses the plane get depth 0."""
    a = np.radians(tilt_deg)
    n = np.array([0.0, np.sin(a), -np.cos(a)])
    u, v = np.meshgrid(np.arange(intr.width, dtype=np.float64), np.arange(intr.height, dtype=np.float64))
    r = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], axis=-1)
    nr = r @ n
    nd = n @ np.array([0.0, 0.0, distance_m])
    with np.errstate(divide="ignore"):
        z = np.where(nd / nr > 0, nd / nr, 0.0)
    angle = np.degrees(np.arccos(np.abs(nr) / np.linalg.norm(r, axis=-1)))
    return z.astype(np.float32), angle


# --- depth sigma ---------------------------------------------------------------------------------


def test_depth_sigma_formula_and_z_squared() -> None:
    s = DepthNoise()
    expected = 0.45**2 * 0.08 / (425.0 * 0.050)
    assert depth_sigma(np.array(0.45), s) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(7.624e-4, rel=1e-3)  # about 0.76 mm at 0.45 m
    z = np.array([0.2, 0.4, 0.8, 1.6])
    sig = depth_sigma(z, s)
    assert sig.shape == z.shape
    np.testing.assert_allclose(sig[1:] / sig[:-1], 4.0, rtol=1e-12)


# --- Gaussian depth noise ------------------------------------------------------------------------


@pytest.mark.parametrize("z", [0.3, 0.45, 1.0, 2.5])
def test_gaussian_depth_noise_std_matches_sigma(z: float) -> None:
    noise = only(depth=DepthNoise())
    true = flat(INTR, z)
    out = apply_depth_models(true, INTR, noise, np.random.default_rng(1))
    assert out.dtype == np.float32 and out.shape == true.shape
    err = out.astype(np.float64) - true
    sigma = float(depth_sigma(np.array(z), noise.depth))
    assert np.std(err) == pytest.approx(sigma, rel=0.05)
    # 307200 pixels: the standard error of the mean is sigma / 554.
    assert abs(np.mean(err)) < 5 * sigma / np.sqrt(err.size)


# --- invalid depth -------------------------------------------------------------------------------


def test_grazing_plane_80_deg_invalidated_30_deg_kept() -> None:
    noise = only(invalid_depth=InvalidDepth(grazing_angle_deg=75.0, dropout_fraction=0.0))
    steep, steep_angle = tilted_plane(NARROW, 0.45, 80.0)
    assert np.all(steep > 0) and steep_angle.min() > 77.0
    out = apply_depth_models(steep, NARROW, noise, np.random.default_rng(0))
    assert np.mean(out == 0) > 0.99

    mild, mild_angle = tilted_plane(NARROW, 0.45, 30.0)
    assert np.all(mild > 0) and mild_angle.max() < 33.0
    out = apply_depth_models(mild, NARROW, noise, np.random.default_rng(0))
    assert np.mean(out > 0) > 0.99
    np.testing.assert_array_equal(out, mild)


def test_grazing_invalidation_follows_the_per_pixel_angle() -> None:
    # The full 640x480 camera sees a 60-degree plane at about 40 to 81 degrees.
    noise = only(invalid_depth=InvalidDepth(grazing_angle_deg=70.0, dropout_fraction=0.0))
    true, angle = tilted_plane(INTR, 0.45, 60.0)
    assert np.all(true > 0)
    out = apply_depth_models(true, INTR, noise, np.random.default_rng(0))
    assert np.any(angle > 71.0) and np.any(angle < 69.0)
    assert np.all(out[angle > 70.5] == 0)
    assert np.all(out[angle < 69.5] > 0)


def test_depth_edges_are_invalidated() -> None:
    noise = only(invalid_depth=InvalidDepth(dropout_fraction=0.0))
    true = flat(INTR, 0.5)
    true[:, 320:] = 0.8  # a step in depth
    out = apply_depth_models(true, INTR, noise, np.random.default_rng(0))
    assert np.all(out[:, 319:321] == 0)
    assert np.all(out[:, :318] > 0) and np.all(out[:, 322:] > 0)


def test_without_invalidation_edges_and_grazing_views_keep_their_depth() -> None:
    true = flat(INTR, 0.5)
    true[:, 320:] = 0.8  # a step in depth
    true[:, :5] = 0.0  # and pixels with no depth next to valid ones
    steep, _ = tilted_plane(NARROW, 0.45, 80.0)
    for depth, intr in ((true, INTR), (steep, NARROW)):
        out = apply_depth_models(
            depth, intr, only(depth_quantisation=DepthQuantisation()), np.random.default_rng(0)
        )
        np.testing.assert_allclose(out, depth, atol=0.0005)
        assert np.array_equal(out > 0, depth > 0)


@pytest.mark.parametrize("fraction", [0.002, 0.05, 0.3])
def test_dropout_fraction(fraction: float) -> None:
    noise = only(invalid_depth=InvalidDepth(dropout_fraction=fraction))
    out = apply_depth_models(flat(INTR, 0.6), INTR, noise, np.random.default_rng(3))
    n = out.size
    dropped = np.count_nonzero(out == 0)
    # Binomial count: within 5 standard deviations.
    assert abs(dropped - fraction * n) < 5 * np.sqrt(n * fraction * (1 - fraction))
    assert np.all(out[out > 0] == np.float32(0.6))


# --- quantisation --------------------------------------------------------------------------------


@pytest.mark.parametrize("scale", [0.001, 0.0001, 0.00025])
def test_quantised_values_are_multiples_of_the_scale(scale: float) -> None:
    rng = np.random.default_rng(5)
    true = rng.uniform(0.2, 3.0, size=(INTR.height, INTR.width)).astype(np.float32)
    noise = only(depth=DepthNoise(), depth_quantisation=DepthQuantisation(depth_scale_m=scale))
    out = apply_depth_models(true, INTR, noise, np.random.default_rng(6))
    codes = encode_depth(out, scale)
    assert codes.dtype == np.uint16
    np.testing.assert_array_equal(decode_depth(codes, scale), out)
    steps = out.astype(np.float64) / scale
    np.testing.assert_allclose(steps, np.rint(steps), atol=1e-3)


def test_quantisation_error_at_most_half_a_step() -> None:
    scale = 0.001
    rng = np.random.default_rng(7)
    true = rng.uniform(0.2, 3.0, size=(INTR.height, INTR.width)).astype(np.float32)
    out = apply_depth_models(true, INTR, only(depth_quantisation=DepthQuantisation()), rng)
    err = np.abs(out.astype(np.float64) - true)
    assert err.max() <= scale / 2 + 1e-6
    assert err.max() > scale / 4  # it really did quantise


def test_quantisation_out_of_uint16_range_becomes_invalid() -> None:
    scale = 0.0001  # largest storable depth 6.5535 m
    true = flat(INTR, 5.0)
    true[:, :100] = 8.0
    out = apply_depth_models(
        true, INTR, only(depth_quantisation=DepthQuantisation(depth_scale_m=scale)), np.random.default_rng(0)
    )
    assert np.all(out[:, :100] == 0)
    assert np.all(out[:, 100:] == np.float32(5.0))


def test_encode_decode() -> None:
    d = np.array([0.0, -1.0, np.nan, np.inf, 0.0004, 0.0006, 1.2344, 65.535, 65.5356, 70.0])
    codes = encode_depth(d, 0.001)
    np.testing.assert_array_equal(codes, [0, 0, 0, 0, 0, 1, 1234, 65535, 0, 0])
    back = decode_depth(codes, 0.001)
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, np.float32([0, 0, 0, 0, 0, 0.001, 1.234, 65.535, 0, 0]))


# --- bias, all off, invalid input ----------------------------------------------------------------


def test_depth_bias() -> None:
    bias = DepthBias(scale=1.02, offset_m=-0.003)
    true = np.random.default_rng(8).uniform(0.2, 3.0, size=(INTR.height, INTR.width)).astype(np.float32)
    out = apply_depth_models(true, INTR, only(depth_bias=bias), np.random.default_rng(0))
    np.testing.assert_allclose(out, 1.02 * true.astype(np.float64) - 0.003, rtol=1e-6)


def test_all_models_off_is_identity_with_invalid_pixels_zeroed() -> None:
    rng = np.random.default_rng(9)
    true = rng.uniform(0.2, 3.0, size=(INTR.height, INTR.width)).astype(np.float32)
    bad = [(0, 0), (5, 7), (100, 200), (479, 639), (300, 300)]
    true[0, 0], true[5, 7], true[100, 200], true[479, 639], true[300, 300] = 0.0, -0.5, 50.0, np.nan, np.inf
    out = apply_depth_models(true, INTR, NoiseSettings().all_off(), np.random.default_rng(0))
    expected = true.copy()
    for r, c in bad:
        expected[r, c] = 0.0
    np.testing.assert_array_equal(out, expected)


def test_invalid_input_stays_zero_with_all_models_on() -> None:
    true = flat(INTR, 0.45)
    true[200:260, 300:380] = 1e4  # far plane: nothing hit
    true[10, 10] = 0.0
    noise = NoiseSettings().model_copy(update={"depth_bias": DepthBias(enabled=True, offset_m=0.01)})
    out = apply_depth_models(true, INTR, noise, np.random.default_rng(0))
    assert np.all(out[200:260, 300:380] == 0) and out[10, 10] == 0
    assert np.mean(out > 0) > 0.95


# --- RGB -----------------------------------------------------------------------------------------


def test_rgb_disabled_returns_identical_copy() -> None:
    rgb = np.random.default_rng(10).integers(0, 256, size=(48, 64, 3), dtype=np.uint8)
    out = apply_rgb_models(rgb, RGBNoise(enabled=False), np.random.default_rng(0))
    np.testing.assert_array_equal(out, rgb)
    assert out is not rgb and not np.shares_memory(out, rgb)


def test_rgb_noise_std() -> None:
    rgb = np.full((480, 640, 3), 128, dtype=np.uint8)
    out = apply_rgb_models(rgb, RGBNoise(sigma=3.0, blur_sigma_px=0.0), np.random.default_rng(11))
    assert out.dtype == np.uint8 and out.shape == rgb.shape
    diff = out.astype(np.float64) - rgb
    assert np.any(diff != 0)
    # Rounding adds a variance of 1/12.
    assert np.std(diff) == pytest.approx(np.sqrt(9.0 + 1.0 / 12.0), rel=0.02)
    assert abs(np.mean(diff)) < 0.05


def test_rgb_blur_and_clipping() -> None:
    rgb = np.zeros((40, 40, 3), dtype=np.uint8)
    rgb[:, 20:] = 255
    out = apply_rgb_models(rgb, RGBNoise(sigma=0.0, blur_sigma_px=2.0), np.random.default_rng(0))
    assert 0 < out[0, 19, 0] < 128 < out[0, 20, 0] < 255  # the edge is smoothed
    np.testing.assert_array_equal(out[:, :5], 0)
    np.testing.assert_array_equal(out[:, 35:], 255)
    noisy = apply_rgb_models(rgb, RGBNoise(sigma=20.0, blur_sigma_px=0.0), np.random.default_rng(0))
    assert noisy[:, :20].min() == 0 and noisy[:, 20:].max() == 255  # clipped, not wrapped
    assert noisy[:, :20].max() < 128 and noisy[:, 20:].min() > 128


@pytest.mark.parametrize("blur_sigma_px", [0.5, 1.5])
def test_rgb_blur_is_the_gaussian_to_a_fifth_of_a_grey_level(blur_sigma_px: float) -> None:
    from scipy.ndimage import gaussian_filter

    rgb = np.random.default_rng(4).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    out = apply_rgb_models(rgb, RGBNoise(sigma=0.0, blur_sigma_px=blur_sigma_px), np.random.default_rng(0))
    exact = gaussian_filter(rgb.astype(float), (blur_sigma_px, blur_sigma_px, 0), mode="mirror", truncate=8.0)
    assert np.abs(out - exact).max() < 0.5 + 0.2  # rounding, plus the taps left out


# --- robot pose ----------------------------------------------------------------------------------


def _pose(rng: np.random.Generator) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.uniform(-0.5, 0.5, 3)
    return T


@pytest.mark.parametrize("t_sigma, r_sigma_deg", [(1e-4, 0.01), (2e-3, 1.0)])
def test_robot_pose_noise_statistics(t_sigma: float, r_sigma_deg: float) -> None:
    settings = RobotPoseNoise(translation_sigma_m=t_sigma, rotation_sigma_deg=r_sigma_deg)
    rng = np.random.default_rng(12)
    n = 4000
    dts, rotvecs = np.empty((n, 3)), np.empty((n, 3))
    for i in range(n):
        T = _pose(rng)
        R = perturb_flange_pose(T, settings, rng)
        np.testing.assert_allclose(R[3], [0, 0, 0, 1])
        np.testing.assert_allclose(R[:3, :3].T @ R[:3, :3], np.eye(3), atol=1e-12)
        assert np.linalg.det(R[:3, :3]) == pytest.approx(1.0)
        dts[i] = R[:3, 3] - T[:3, 3]
        rotvecs[i] = Rotation.from_matrix(T[:3, :3].T @ R[:3, :3]).as_rotvec()
    np.testing.assert_allclose(dts.std(axis=0), t_sigma, rtol=0.06)
    np.testing.assert_allclose(dts.mean(axis=0), 0.0, atol=5 * t_sigma / np.sqrt(n))
    s = np.radians(r_sigma_deg)
    np.testing.assert_allclose(rotvecs.std(axis=0), s, rtol=0.06)
    # The angle of a 3-D isotropic Gaussian rotation vector is Maxwell distributed.
    angles = np.linalg.norm(rotvecs, axis=1)
    assert angles.mean() == pytest.approx(s * np.sqrt(8 / np.pi), rel=0.03)
    assert np.sqrt(np.mean(angles**2)) == pytest.approx(s * np.sqrt(3), rel=0.03)


def test_robot_pose_disabled_returns_same_pose_copy() -> None:
    T = _pose(np.random.default_rng(13))
    out = perturb_flange_pose(T, RobotPoseNoise(enabled=False), np.random.default_rng(0))
    np.testing.assert_array_equal(out, T)
    assert out is not T
    enabled = perturb_flange_pose(T, RobotPoseNoise(), np.random.default_rng(0))
    assert not np.array_equal(enabled, T)


# --- determinism ---------------------------------------------------------------------------------


def _run_all(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    true, _ = tilted_plane(INTR, 0.5, 60.0)
    depth = apply_depth_models(true, INTR, NoiseSettings(), rng)
    rgb_in = np.full((120, 160, 3), 100, dtype=np.uint8)
    rgb_in[:, 80:] = 200
    rgb = apply_rgb_models(rgb_in, RGBNoise(), rng)
    pose = perturb_flange_pose(np.eye(4), RobotPoseNoise(), rng)
    return depth, rgb, pose


def test_same_seed_same_output_different_seed_different_output() -> None:
    a, b, c = _run_all(42), _run_all(42), _run_all(43)
    for x, y, z in zip(a, b, c, strict=True):
        assert x.tobytes() == y.tobytes()
        assert x.tobytes() != z.tobytes()
