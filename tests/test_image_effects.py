"""Tests of the camera and lighting image effects (sim/image_effects.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hec.sim.image_effects import (
    exposure,
    light_gradient,
    mirror_point,
    motion_blur,
    motion_blur_kernel,
    motion_blur_shift,
    natural_corner_falloff,
    specular_highlight,
    vignetting,
)

H, W = 48, 64
# Principal point on a pixel centre, off the image centre.
K = np.array([[60.0, 0.0, 30.0], [0.0, 62.0, 20.0], [0.0, 0.0, 1.0]])
CORNERS = ([0, 0, -1, -1], [0, -1, 0, -1])


def grey(value: float = 200.0) -> np.ndarray:
    return np.full((H, W, 3), value, dtype=np.float32)


def cos4(K: np.ndarray) -> np.ndarray:
    """cos^4 of the angle between each pixel's ray and the optical axis, (H, W)."""
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    rays = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(K).T
    return (rays[..., 2] / np.linalg.norm(rays, axis=-1)) ** 4


def test_vignetting_corner_and_centre() -> None:
    img = grey()
    out = vignetting(img, K, 0.3)
    assert out.dtype == np.float32 and out is not img and np.all(img == 200.0)
    gain = out[..., 0] / 200.0
    assert gain[20, 30] == pytest.approx(1.0, abs=1e-6)  # the principal point
    assert gain[CORNERS].min() == pytest.approx(0.7, abs=1e-5)  # the farthest corner
    assert gain[-1, -1] == gain[CORNERS].min()  # (63, 47) is the farthest from (30, 20)
    assert np.all(gain <= 1.0 + 1e-6) and np.all(gain >= 0.7 - 1e-5)
    assert np.allclose(out[..., 0], out[..., 2])
    assert np.array_equal(vignetting(img, K, 0.0), img)


@pytest.mark.parametrize("skew", [0.0, 3.0])
def test_vignetting_natural_is_cos4(skew: float) -> None:
    Ks = K + np.array([[0.0, skew, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    falloff = natural_corner_falloff(Ks, W, H)
    assert falloff == pytest.approx(1.0 - cos4(Ks).min())
    out = vignetting(grey(), Ks, falloff)
    np.testing.assert_allclose(out[..., 1] / 200.0, cos4(Ks), atol=1e-5)


@pytest.mark.parametrize("direction", [0.0, np.pi / 2, 0.7, -2.5])
def test_light_gradient_ramp(direction: float) -> None:
    out = light_gradient(grey(), direction, 0.2)
    gain = out[..., 0].astype(np.float64) / 200.0
    u, v = np.meshgrid(np.arange(W) - (W - 1) / 2, np.arange(H) - (H - 1) / 2)
    proj = np.cos(direction) * u + np.sin(direction) * v
    expected = 1.0 + 0.2 * proj / (proj.max() - proj.min())
    np.testing.assert_allclose(gain, expected, atol=1e-6)
    assert gain.max() - gain.min() == pytest.approx(0.2, abs=1e-6)
    assert gain.max() == pytest.approx(1.1, abs=1e-6)


def test_light_gradient_sides() -> None:
    gain = light_gradient(grey(), 0.0, 0.2)[..., 0] / 200.0
    assert np.allclose(gain[:, 0], 0.9) and np.allclose(gain[:, -1], 1.1)  # brighter to the right
    gain = light_gradient(grey(), np.pi / 2, 0.2)[..., 0] / 200.0
    assert np.allclose(gain[0], 0.9) and np.allclose(gain[-1], 1.1)  # brighter at the bottom


def test_specular_highlight_peak_and_radius() -> None:
    out = specular_highlight(grey(100.0), (40, 12), 5.0, 300.0)
    added = out[..., 0] - 100.0
    assert np.unravel_index(np.argmax(added), added.shape) == (12, 40)
    assert added[12, 40] == pytest.approx(300.0, rel=1e-5)
    assert added[12, 45] == pytest.approx(150.0, rel=1e-4) and added[17, 40] == pytest.approx(150.0, rel=1e-4)
    assert out.max() > 255.0  # saturates once the caller clips
    assert np.allclose(out[..., 0], out[..., 2])


def test_specular_highlight_subpixel_centroid() -> None:
    added = specular_highlight(np.zeros((H, W, 3), np.float32), (31.3, 22.6), 3.0, 50.0)[..., 0]
    v, u = np.mgrid[:H, :W]
    assert np.sum(added * u) / added.sum() == pytest.approx(31.3, abs=1e-3)
    assert np.sum(added * v) / added.sum() == pytest.approx(22.6, abs=1e-3)


@pytest.mark.parametrize("seed", range(5))
def test_mirror_point_equal_angles(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cam = rng.uniform([-1, -1, 0.2], [1, 1, 1.5])
    light = rng.uniform([-3, -3, 1.0], [3, 3, 3.0])
    p = mirror_point(cam, light)
    assert p[2] == 0.0
    to_cam, to_light = cam - p, light - p
    normal = np.array([0.0, 0.0, 1.0])
    # Equal angles to the normal, and the normal, incident and reflected rays in one plane.
    cos_c = to_cam @ normal / np.linalg.norm(to_cam)
    cos_l = to_light @ normal / np.linalg.norm(to_light)
    assert cos_c == pytest.approx(cos_l, abs=1e-12)
    assert np.cross(to_cam, to_light) @ normal == pytest.approx(0.0, abs=1e-12)
    # The incident direction reflected by the plane points at the camera.
    d = p - light
    r = d - 2.0 * (d @ normal) * normal
    np.testing.assert_allclose(r / np.linalg.norm(r), to_cam / np.linalg.norm(to_cam), atol=1e-12)


def test_exposure() -> None:
    img = np.random.default_rng(0).uniform(0, 255, (H, W, 3)).astype(np.float32)
    out = exposure(img, 1.3)
    assert out.dtype == np.float32 and out is not img
    np.testing.assert_allclose(out, img * 1.3, rtol=1e-6)


def test_motion_blur_zero_shift_is_identity() -> None:
    img = np.random.default_rng(1).uniform(0, 255, (H, W, 3)).astype(np.float32)
    out = motion_blur(img, (0.0, 0.0))
    assert out is not img and np.array_equal(out, img)
    assert np.array_equal(motion_blur_kernel((0.0, 0.0)), np.ones((1, 1), np.float32))


def test_motion_blur_preserves_mean() -> None:
    img = np.random.default_rng(2).uniform(0, 255, (H, W, 3)).astype(np.float32)
    out = motion_blur(img, (5.3, -2.1))
    assert out.mean() == pytest.approx(img.mean(), abs=0.3)
    assert out.std() < 0.6 * img.std()  # it does blur
    np.testing.assert_allclose(motion_blur(grey(), (5.3, -2.1)), grey(), rtol=1e-5)


@pytest.mark.parametrize("shift", [(0.3, 0.2), (0.0, 0.5), (0.7, 0.0)])
def test_subpixel_kernel_sums_to_one(shift: tuple[float, float]) -> None:
    kernel = motion_blur_kernel(shift)
    assert kernel.sum() == pytest.approx(1.0, abs=1e-6)
    assert kernel.max() < 1.0  # it is not the identity
    assert np.allclose(kernel, kernel[::-1, ::-1])  # centred, point-symmetric


@pytest.mark.parametrize("length, angle", [(6.5, 0.0), (10.0, 0.6), (3.2, 2.0), (15.0, -1.2)])
def test_kernel_is_a_line_along_the_shift(length: float, angle: float) -> None:
    d = np.array([np.cos(angle), np.sin(angle)])
    kernel = motion_blur_kernel(length * d).astype(np.float64)
    half = kernel.shape[0] // 2
    v, u = np.mgrid[-half : half + 1, -half : half + 1]
    along, across = u * d[0] + v * d[1], -u * d[1] + v * d[0]
    assert np.sum(kernel * along) == pytest.approx(0.0, abs=1e-6)
    var_along, var_across = np.sum(kernel * along**2), np.sum(kernel * across**2)
    assert length**2 / 12 <= var_along <= length**2 / 12 + 0.25  # a box of the length (+ anti-aliasing)
    assert var_across <= 0.25


def edge(axis: int) -> np.ndarray:
    """A step from 0 to 255 half way along u (axis 0) or v (axis 1), (H, W, 3) float32."""
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    step = (u >= W // 2) if axis == 0 else (v >= H // 2)
    return np.repeat(step[:, :, None] * np.float32(255.0), 3, axis=2)


@pytest.mark.parametrize("axis", [0, 1])
def test_motion_blur_widens_edge_along_shift_only(axis: int) -> None:
    length = 7.3
    shift = (length, 0.0) if axis == 0 else (0.0, length)
    out = motion_blur(edge(axis), shift)
    profile = out[H // 2, :, 0] if axis == 0 else out[:, W // 2, 0]
    d = np.diff(profile.astype(np.float64)) / 255.0  # the line spread along the shift
    x = np.arange(d.size)
    assert d.sum() == pytest.approx(1.0, abs=1e-5) and np.all(d >= -1e-5)
    var = np.sum(d * (x - np.sum(d * x)) ** 2)
    assert length**2 / 12 <= var <= length**2 / 12 + 0.25  # a ramp |shift| long
    assert np.count_nonzero(d > 1e-5) <= np.ceil(length) + 2
    # An edge along the shift stays sharp.
    np.testing.assert_allclose(motion_blur(edge(1 - axis), shift), edge(1 - axis), atol=1e-3)


def project(K: np.ndarray, p: np.ndarray) -> np.ndarray:
    q = K @ p
    return q[:2] / q[2]


@pytest.mark.parametrize("seed", range(4))
def test_motion_blur_shift_matches_finite_difference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    Ks = np.array([[600.0, 0.5, 322.0], [0.0, 610.0, 238.0], [0.0, 0.0, 1.0]])
    v, w = rng.normal(0, 0.05, 3), rng.normal(0, 0.2, 3)
    depth, exposure_s = 0.6, 0.02
    uv = rng.uniform([0, 0], [640, 480])
    for pixel in (None, uv):
        start = Ks[:2, 2] if pixel is None else pixel
        p = depth * np.linalg.solve(Ks, np.array([*start, 1.0]))  # the static point, camera frame at t = 0

        def seen(t: float, p: np.ndarray = p) -> np.ndarray:
            """The point's pixel at time t: camera at v t, rotated by exp(w t) (frame at t = 0)."""
            R = Rotation.from_rotvec(w * t).as_matrix()
            return project(Ks, R.T @ (p - v * t))

        h = 1e-5
        expected = (seen(h) - seen(-h)) / (2 * h) * exposure_s
        got = motion_blur_shift(Ks, depth, v, w, exposure_s, pixel)
        np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-7)
    # Moving the camera to the right moves the image to the left.
    assert motion_blur_shift(Ks, 1.0, [0.1, 0, 0], [0, 0, 0], 0.01)[0] == pytest.approx(-0.6)
