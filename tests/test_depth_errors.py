"""Tests of the D435-like depth error models (sim/depth_errors.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hec.sim.depth_errors import (
    autocorrelation_length,
    correlated_unit_noise,
    depth_holes,
    flying_pixels,
    misregister_depth,
)

H, W = 480, 640
K = np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])


def transform(t: tuple[float, float, float], rotvec: tuple[float, float, float] = (0, 0, 0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def step_edge() -> np.ndarray:
    """Foreground at 0.5 m left of column 320, background at 1.0 m from it on."""
    depth = np.full((H, W), 1.0, dtype=np.float32)
    depth[:, :320] = 0.5
    return depth


@pytest.mark.parametrize("length_px", [2.0, 4.0, 8.0])
def test_correlated_noise_has_the_set_length_and_unit_variance(length_px: float) -> None:
    field = correlated_unit_noise((1024, 1024), length_px, np.random.default_rng(3))
    assert field.dtype == np.float32 and field.shape == (1024, 1024)
    assert autocorrelation_length(field) == pytest.approx(length_px, rel=0.10)
    assert float(field.var()) == pytest.approx(1.0, rel=0.05)
    # Stationary up to the border: the outer rows and columns are as strong as the rest. Over 32
    # fields, since one field's two border rows hold only ~2 * 1024 / L independent values (at L = 8
    # their mean square scatters by ~0.12 from field to field; here by < 0.03). A field filtered
    # without its padding would be about half as strong there.
    rng = np.random.default_rng(4)
    fields = [correlated_unit_noise((128, 128), length_px, rng) for _ in range(32)]
    border = np.concatenate([np.concatenate([f[[0, -1], :], f[:, [0, -1]].T]) for f in fields])
    assert float(np.mean(border**2)) == pytest.approx(1.0, abs=0.15)


def test_white_noise_length_below_one_pixel() -> None:
    white = np.random.default_rng(0).standard_normal((H, W)).astype(np.float32)
    assert autocorrelation_length(white) < 1.0
    assert autocorrelation_length(correlated_unit_noise((H, W), 0.3, np.random.default_rng(0))) < 1.0


def test_autocorrelation_length_of_a_masked_residual_with_offset() -> None:
    rng = np.random.default_rng(5)
    field = correlated_unit_noise((H, W), 4.0, rng) + np.float32(3.0)
    valid = rng.random((H, W)) > 0.2
    valid[100:200, 150:400] = False
    field[~valid] = 1e3  # garbage in the invalid pixels must not matter
    assert autocorrelation_length(field, valid) == pytest.approx(4.0, rel=0.10)


@pytest.mark.parametrize("dz", [0.002, -0.002])
def test_misregistration_along_z_shifts_a_plane(dz: float) -> None:
    out = misregister_depth(np.full((H, W), 0.5, dtype=np.float32), K, transform((0, 0, dz)))
    inner = out[20:-20, 20:-20]
    assert out.dtype == np.float32
    np.testing.assert_allclose(inner, 0.5 + dz, atol=1e-6)  # no cracks when magnified either
    if dz > 0:  # the image shrinks: a border nothing lands on
        assert np.all(out[:, 0] == 0.0) and np.all(out[0, :] == 0.0)


def test_lateral_misregistration_moves_an_edge() -> None:
    # fx * t / z: the 0.5 m foreground moves by 4 px, the 1.0 m background by 2 px.
    right = misregister_depth(step_edge(), K, transform((0.004, 0, 0)))
    np.testing.assert_array_equal(right[:, 4:324], 0.5)
    np.testing.assert_array_equal(right[:, 324:], 1.0)
    np.testing.assert_array_equal(right[:, :4], 0.0)
    left = misregister_depth(step_edge(), K, transform((-0.004, 0, 0)))
    np.testing.assert_array_equal(left[:, :316], 0.5)
    np.testing.assert_array_equal(left[:, 316:318], 0.0)  # disoccluded, not filled
    np.testing.assert_array_equal(left[:, 318:638], 1.0)


@pytest.mark.parametrize("dz", [0.004, -0.004])
def test_misregistration_of_a_tilted_plane_matches_the_moved_plane(dz: float) -> None:
    normal = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    rx = ((np.arange(W) - K[0, 2]) / K[0, 0])[None, :]
    ry = ((np.arange(H) - K[1, 2]) / K[1, 1])[:, None]
    depth = (0.6 / (normal[0] * rx + normal[1] * ry + normal[2])).astype(np.float32)
    T = transform((0.003, -0.002, dz), (0.01, -0.02, 0.015))
    out = misregister_depth(depth, K, T)
    n2 = T[:3, :3] @ normal
    expected = (0.6 + n2 @ T[:3, 3]) / (n2[0] * rx + n2[1] * ry + n2[2])
    assert np.all(out[40:-40, 40:-40] > 0.0)
    assert np.max(np.abs(out - expected)[out > 0.0]) < 3e-5


def test_misregistration_keeps_invalid_pixels_invalid() -> None:
    depth = np.full((H, W), 0.5, dtype=np.float32)
    depth[100, 100] = 0.0
    out = misregister_depth(depth, K, transform((0, 0, -0.002)))  # magnified: cracks get filled
    np.testing.assert_array_equal(np.argwhere(out == 0.0), [[99, 99]])


def test_flying_pixels_only_at_edges_and_between_the_sides() -> None:
    depth = step_edge()
    depth[:, 500:] += np.linspace(0.0, 0.3, W - 500, dtype=np.float32)  # steep but continuous
    out = flying_pixels(depth, np.random.default_rng(1), edge_threshold_m=0.02, probability=0.5)
    changed = out != depth
    assert set(np.nonzero(changed)[1]) == {319, 320}
    assert 0.5 <= out[changed].min() and out[changed].max() <= 1.0
    assert changed.sum() / (2 * H) == pytest.approx(0.5, abs=0.05)
    wide = flying_pixels(depth, np.random.default_rng(1), probability=1.0, width_px=3)
    assert set(np.nonzero(wide != depth)[1]) <= set(range(317, 323))


def test_holes_cover_the_documented_fraction() -> None:
    depth = np.ones((2000, 2000), dtype=np.float32)
    for per_mp, radius in [(400.0, 6.0), (50.0, 20.0)]:
        out = depth_holes(depth, np.random.default_rng(2), per_mp, radius)
        expected = 1.0 - np.exp(-per_mp * 1e-6 * 1.25 * np.pi * radius**2)
        assert float(np.mean(out == 0.0)) == pytest.approx(expected, rel=0.1)
        assert np.all(out[out != 0.0] == 1.0)


def test_same_seed_same_output() -> None:
    depth = step_edge()

    def run(seed: int) -> list[np.ndarray]:
        rng = np.random.default_rng(seed)
        return [
            correlated_unit_noise((H, W), 4.0, rng),
            flying_pixels(depth, rng),
            depth_holes(depth, rng, 100.0, 8.0),
        ]

    for a, b in zip(run(7), run(7), strict=True):
        assert a.dtype == np.float32
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(run(7)[0], run(8)[0])
